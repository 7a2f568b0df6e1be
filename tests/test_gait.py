"""The scripted gait and the guide forces, against hand-computed values."""

import jax.numpy as jnp
import numpy as np
import pytest

from biped_switch.simulation import gait
from biped_switch.config import default_gait_config

CFG = default_gait_config()
STAND = jnp.array([0, 0, -0.25, 0.5, -0.25, 0] * 2, jnp.float32)


def test_reference_at_swing_start_and_mid_swing():
    q = np.asarray(gait.reference(0.0, STAND, CFG)).reshape(2, 6)
    # left leg at phase 0: hip back by A, knee at rest; right leg at phase 0.5: hip forward by A
    assert q[0, 2] == pytest.approx(-0.25 + CFG.hip_amp_rad, abs=1e-6)
    assert q[0, 3] == pytest.approx(0.5, abs=1e-6)
    assert q[1, 2] == pytest.approx(-0.25 - CFG.hip_amp_rad, abs=1e-6)
    q = np.asarray(gait.reference(CFG.period_s / 4, STAND, CFG)).reshape(2, 6)
    assert q[0, 3] == pytest.approx(0.5 + CFG.knee_amp_rad, abs=1e-5)  # mid-swing knee lift
    assert q[1, 3] == pytest.approx(0.5, abs=1e-6)  # stance knee stays
    assert q[0, 2] == pytest.approx(-0.25, abs=1e-5)  # hip passes the keyframe at mid-swing


def test_reference_keeps_soles_level_and_other_joints_fixed():
    for t in np.linspace(0, 2 * CFG.period_s, 17):
        q = np.asarray(gait.reference(t, STAND, CFG)).reshape(2, 6)
        np.testing.assert_allclose(q[:, 2] + q[:, 3] + q[:, 4], 0.0, atol=1e-5)
        np.testing.assert_allclose(q[:, [0, 1, 5]], 0.0)


def test_reference_is_periodic_and_legs_alternate():
    a = np.asarray(gait.reference(0.3, STAND, CFG)).reshape(2, 6)
    b = np.asarray(gait.reference(0.3 + CFG.period_s, STAND, CFG)).reshape(2, 6)
    c = np.asarray(gait.reference(0.3 + CFG.period_s / 2, STAND, CFG)).reshape(2, 6)
    np.testing.assert_allclose(a, b, atol=1e-5)
    np.testing.assert_allclose(a[0], c[1], atol=1e-5)


def test_joint_guide_is_pd_and_bounded():
    gear = jnp.full(12, 100.0)
    z = jnp.zeros(12)
    np.testing.assert_allclose(gait.joint_guide(STAND, z, STAND, gear, CFG), 0.0)
    tau = gait.joint_guide(z, z, z + 0.1, gear, CFG)
    np.testing.assert_allclose(tau, CFG.kp_per_gear * 100.0 * 0.1, rtol=1e-6)  # 20 Nm
    tau = gait.joint_guide(z, jnp.ones(12), z, gear, CFG)
    np.testing.assert_allclose(tau, -CFG.kd_ratio * CFG.kp_per_gear * 100.0, rtol=1e-6)  # -10 Nm
    np.testing.assert_allclose(gait.joint_guide(z, z, z + 10.0, gear, CFG), 100.0)  # clipped


def test_com_guide_zero_at_target_and_restoring_signs():
    z3 = jnp.zeros(3)
    w = gait.com_guide(z3, jnp.array([0.8, 0, 0]), z3, 0.0, 0.0, 0.0, 1.09, 0.8, 1.09, CFG)
    np.testing.assert_allclose(w, 0.0, atol=1e-6)
    w = np.asarray(gait.com_guide(jnp.array([0, 0.1, 0]), z3, z3, 0.1, 0.2, -0.1, 1.0, 0.8, 1.09, CFG))
    assert w[0] == pytest.approx(CFG.k_speed * 0.8)  # too slow: pushed forward
    assert w[1] == pytest.approx(-CFG.k_lateral * 0.1)  # left of the centre line: pushed right
    assert w[2] == pytest.approx(CFG.k_height * 0.09, rel=1e-5)  # too low: lifted
    assert w[3] > 0 and w[4] < 0 and w[5] < 0  # roll, pitch and yaw all pushed back to 0

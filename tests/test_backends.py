"""The `mujoco` physics backend (native.py) against MJX and against plain MuJoCo loops.

- The same scripted actions through both backends give the same rollout (poses, contacts, reward)
  within the stated tolerances.
- One control step of the backend equals `n_substeps` plain `mj_step` calls with the PD law
  evaluated in Python before each one (the slower reference).
- The geometric sole contacts equal the contact list of MuJoCo's own collision pass.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from biped_switch.simulation import env as env_lib
from biped_switch.simulation import gait
from biped_switch.simulation import native
from biped_switch.simulation import terrain
from biped_switch.simulation import model as model_lib
from conftest import B, DIFFICULTIES, MJX_TORQUE, TRACK_IDS, batch_reset
from helpers import terrain_height_np

# Tolerances over a 45-step (0.9 s) rollout: both backends run float32 state through the same
# solver settings, but MJX and the C engine order their floating-point work differently.
QPOS_TOL = 2e-3  # [m] or [rad]
REWARD_TOL = 2e-2  # per step
CONTACT_AGREE = 0.98  # fraction of (env, step, sole) contact flags that agree


@pytest.fixture(scope="module")
def native_env():
    """The conftest env's configuration (mixed, 4 tracks, torque actions) on the C engine."""
    overrides = dict(MJX_TORQUE, backend="mujoco")
    return env_lib.make_env("mixed", n_tracks=4, **overrides)


def _scripted(t):
    """Torques that swing the hips and knees (as fractions of the motor limits)."""
    a = np.zeros((B, 12), np.float32)
    a[:, [2, 8]] = 0.15 * np.sin(0.3 * t + np.arange(B)[:, None])
    a[:, [3, 9]] = 0.1 * np.cos(0.2 * t)
    return jnp.asarray(a)


def test_backends_agree_on_a_scripted_rollout(env, fns, native_env):
    assert env.backend == "mjx" and native_env.backend == "mujoco"
    reset_n = jax.jit(jax.vmap(native_env.reset))
    step_n = jax.jit(jax.vmap(native_env.step))
    keys = jax.random.split(jax.random.PRNGKey(0), B)
    s_x = batch_reset(fns)
    s_n = reset_n(keys, jnp.asarray(DIFFICULTIES), jnp.asarray(TRACK_IDS))
    np.testing.assert_allclose(s_n.pipeline_state.qpos, s_x.pipeline_state.qpos, atol=1e-5)
    np.testing.assert_allclose(s_n.obs, s_x.obs, atol=1e-5)
    agree, n = 0, 0
    for t in range(45):  # 25 steps of the standing pause, then 20 of scripted torques
        a = _scripted(t)
        s_x, s_n = fns["step"](s_x, a), step_n(s_n, a)
        np.testing.assert_allclose(s_n.pipeline_state.qpos, s_x.pipeline_state.qpos, atol=QPOS_TOL,
                                   err_msg=f"step {t}")
        np.testing.assert_allclose(s_n.reward, s_x.reward, atol=REWARD_TOL, err_msg=f"step {t}")
        c_n, c_x = np.asarray(s_n.obs[:, 24:32]), np.asarray(s_x.obs[:, 24:32])
        agree += int((c_n == c_x).sum())
        n += c_n.size
        np.testing.assert_array_equal(s_n.done, s_x.done)
    assert agree / n >= CONTACT_AGREE
    assert np.asarray(s_x.obs[:, 24:32]).sum() > 0  # the feet touch: contacts were compared


def _ref_step(m, d, actions, env, steps):
    """Plain MuJoCo: the PD law of `pd` actions before every mj_step; returns qpos per control step."""
    b, cfg = env.biped, env.cfg
    stand_q = b.stand_qpos[b.qpos_adr]
    kp = cfg.pd_kp_per_gear * b.gear
    out, t = [], 0.0
    for k in range(steps):
        q_ref = np.asarray(gait.reference(jnp.float32(t), jnp.asarray(stand_q, jnp.float32),
                                          env.gait_cfg), np.float64)
        base = q_ref if cfg.pd_offset == "gait" else stand_q
        target = base + np.clip(actions[k], -1, 1) * cfg.action_scale_rad
        for _ in range(b.n_substeps):
            q, qd = d.qpos[b.qpos_adr], d.qvel[b.dof_adr]
            tau = np.clip(kp * (target - q) - cfg.pd_kd_ratio * kp * qd, -b.gear, b.gear)
            d.ctrl[:] = tau / b.gear
            mujoco.mj_step(m, d)
        t += env.dt
        out.append(d.qpos.copy())
    return np.array(out)


@pytest.mark.parametrize("pd_offset", ["gait", "stand"])
def test_pd_step_matches_a_python_mj_step_loop(pd_offset):
    env = env_lib.make_env("stairs", "random", n_tracks=2, backend="mujoco", action="pd",
                           pd_offset=pd_offset)
    state = env.reset(jax.random.PRNGKey(3), 0.7, 1)
    steps = 12
    actions = np.random.default_rng(1).uniform(-1.2, 1.2, (steps, 12)).astype(np.float32)
    step = jax.jit(env.step)
    got = []
    for k in range(steps):
        state = step(state, jnp.asarray(actions[k]))
        got.append(np.asarray(state.pipeline_state.qpos))
    boxes = np.asarray(env.track_arrays(1, jnp.float32(0.7))[0], np.float64)
    m = model_lib.compile_mj_model(env.model_cfg, boxes)
    d = mujoco.MjData(m)
    d.qpos[:] = np.asarray(env.reset(jax.random.PRNGKey(3), 0.7, 1).pipeline_state.qpos)
    mujoco.mj_forward(m, d)
    ref = _ref_step(m, d, actions, env, steps)
    # float32 state between control steps against float64 throughout
    np.testing.assert_allclose(np.array(got), ref, atol=1e-4)
    assert np.abs(ref[-1] - ref[0]).max() > 0.05  # the robot moved


def test_geometric_contacts_equal_mujoco_contact_list():
    env = env_lib.make_env("mixed", n_tracks=1, backend="mujoco")
    b = env.biped
    boxes_j = env.track_arrays(0, jnp.float32(1.0))[0]
    boxes = np.asarray(boxes_j, np.float64)
    m = model_lib.compile_mj_model(env.model_cfg, boxes)
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    soles = b.sole_geoms.reshape(-1)
    track = terrain.generate_track(env.cfg.seed, "mixed", 1.0, env.terrain_cfg)
    n_touch = 0
    for _ in range(60):
        d.qpos[:] = b.stand_qpos
        d.qpos[b.qpos_adr] += rng.uniform(-0.3, 0.3, 12)
        d.qpos[0] = rng.uniform(0.5, track.end_x_m - 1.0)
        mujoco.mj_kinematics(m, d)
        ground = terrain_height_np(boxes, d.geom_xpos[soles, :2])
        low = np.argmin(d.geom_xpos[soles, 2] - ground)
        d.qpos[2] += ground[low] - d.geom_xpos[soles[low], 2] + 0.02 - rng.uniform(0, 0.01)
        mujoco.mj_forward(m, d)
        ref = np.zeros(8)
        for c in d.contact[: d.ncon]:
            for g in (c.geom1, c.geom2):
                if g in soles and c.dist < 0:
                    ref[list(soles).index(g)] = 1.0
        got = np.asarray(native.sole_contacts_geometric(jnp.asarray(d.geom_xpos[soles]),
                                                        env._sole_radius_m, boxes_j))
        np.testing.assert_array_equal(got, ref)
        n_touch += int(ref.sum())
    assert 60 <= n_touch < 60 * 8  # contacts and non-contacts both occurred


def test_model_bank_caches_per_track_and_difficulty():
    env = env_lib.make_env("stairs", n_tracks=2, backend="mujoco")
    bank = env._native.models
    a = bank.get(0, 0.5)
    assert bank.get(0, 0.50001) is a  # rounded to DIFFICULTY_DECIMALS
    c = bank.get(0, 1.0)
    assert c is not a and len(bank) == 2
    tops = lambda mm: mm.geom_pos[env.biped.box_start:, 2] + mm.geom_size[env.biped.box_start:, 2]
    assert tops(c).max() == pytest.approx(2 * tops(a).max(), rel=1e-6)  # stairs scale with d
    with pytest.raises(IndexError, match="track id 7"):
        bank.get(7, 1.0)


def test_an_unstable_simulation_ends_its_episode():
    """MuJoCo resets a diverged simulation to qpos0; the backend reports it as non-finite (also
    for a non-finite input), and the env ends the episode as a fall at its last finite state
    instead of teleporting the robot back to the start, with nothing non-finite downstream."""
    env = env_lib.make_env("walk", n_tracks=1, backend="mujoco")
    state = env.reset(jax.random.PRNGKey(0), 1.0, 0)
    ps = state.pipeline_state
    blown = ps.replace(qvel=ps.qvel.at[6].set(1e11))
    zeros = {"action": jnp.zeros(12), "paused": jnp.zeros(()), "guide": jnp.zeros(()),
             "q_ref": jnp.zeros(12)}
    for bad in (blown, ps.replace(qpos=ps.qpos.at[2].set(jnp.nan))):
        out = native.step(env._native, 0, 1.0, bad, jnp.zeros(6), zeros)
        assert not np.all(np.isfinite(np.asarray(out.qpos)))
    step = jax.jit(env.step)
    nxt = step(state.replace(pipeline_state=blown), jnp.zeros(12))
    assert float(nxt.done) == 1.0 and float(nxt.metrics["fell"]) == 1.0
    np.testing.assert_array_equal(nxt.pipeline_state.qpos, blown.qpos)  # the last finite state
    assert np.all(np.isfinite(np.asarray(nxt.obs))) and np.isfinite(float(nxt.reward))
    # a state that is finite but moves faster than this robot can (here 300 m/s) has diverged too
    fast = ps.replace(qvel=ps.qvel.at[0].set(300.0))
    nxt = step(state.replace(pipeline_state=fast), jnp.zeros(12))
    assert float(nxt.metrics["fell"]) == 1.0
    np.testing.assert_array_equal(nxt.pipeline_state.qvel, fast.qvel)
    ok = step(state, jnp.zeros(12))  # the standing start is not touched by the check
    assert float(ok.done) == 0.0

"""The rudimentary scripted walking gait and the guide forces of the guided curriculum.

Tidd et al. guide early training with (1) joint torques from a PD controller that tracks a
rudimentary walking gait and (2) a force that stabilises the CoM; both are scaled by the curriculum's
`guide_scale` and annealed to zero once the terrain is at full difficulty.

The gait (joint space, period T, legs half a period apart; phase p in [0, 1) per leg, swing for
p < 0.5):
  hip pitch   q0 + A_hip cos(2 pi p)         back (+A) at swing start, forward (-A) at touch-down
  knee        q0 + A_knee sin(2 pi p)  (p < 0.5, else q0)   lifts the foot during swing
  ankle pitch -(hip pitch + knee)             keeps the sole parallel to the ground
  hip yaw, hip roll, ankle roll: the standing keyframe's values (0)
With A_hip = 0.35 rad on 0.44 m thighs a step is about 0.3 m; at T = 0.8 s that is 0.75 m/s.

The CoM guide is a spring-damper wrench on the pelvis: vertical force to the standing height above
the terrain beneath, forward force to the target speed, lateral force back to the track's centre
line, and torques that level pitch and roll and hold the heading.
All functions are pure and jittable.
"""

from __future__ import annotations

import jax.numpy as jnp

from biped_switch.config import default_gait_config

HIP_PITCH, KNEE, ANKLE_PITCH = 2, 3, 4  # indices within one leg's six joints


def reference(t_s, stand_q, cfg=None):
    """(12,) target joint angles [rad] of the scripted gait at time `t_s` since walking began."""
    cfg = cfg or default_gait_config()
    phase = jnp.mod(t_s / cfg.period_s + jnp.array([0.0, 0.5]), 1.0)  # left, right
    swing = phase < 0.5
    q = stand_q.reshape(2, 6)
    hip = q[:, HIP_PITCH] + cfg.hip_amp_rad * jnp.cos(2 * jnp.pi * phase)
    knee = q[:, KNEE] + jnp.where(swing, cfg.knee_amp_rad * jnp.sin(2 * jnp.pi * phase), 0.0)
    ankle = -(hip + knee)
    q = q.at[:, HIP_PITCH].set(hip).at[:, KNEE].set(knee).at[:, ANKLE_PITCH].set(ankle)
    return q.reshape(12)


def pd_torque(q, qd, q_ref, kp_per_gear, kd_ratio, gear, xp=jnp):
    """PD torques [Nm] towards `q_ref`: stiffness kp_per_gear * gear [Nm/rad], damping kd_ratio *
    stiffness [Nm s/rad], bounded by each motor's limit `gear` [Nm]. `xp`: jax.numpy or numpy
    (the `mujoco` backend evaluates the same law on the host between physics substeps)."""
    kp = kp_per_gear * gear
    return xp.clip(kp * (q_ref - q) - kd_ratio * kp * qd, -gear, gear)


def joint_guide(q, qd, q_ref, gear, cfg=None, xp=jnp):
    """(12,) guide torques [Nm] towards the gait's `q_ref`."""
    cfg = cfg or default_gait_config()
    return pd_torque(q, qd, q_ref, cfg.kp_per_gear, cfg.kd_ratio, gear, xp)


def com_guide(com, lin_vel, ang_vel, yaw, pitch, roll, height_m, target_speed_mps, stand_height_m,
              cfg=None):
    """(6,) world-frame force [N] and torque [Nm] on the pelvis that steadies the CoM."""
    cfg = cfg or default_gait_config()
    force = jnp.stack([
        cfg.k_speed * (target_speed_mps - lin_vel[0]),
        -cfg.k_lateral * com[1] - cfg.d_lateral * lin_vel[1],
        cfg.k_height * (stand_height_m - height_m) - cfg.d_height * lin_vel[2],
    ])
    torque = jnp.stack([
        -cfg.k_tilt * roll - cfg.d_tilt * ang_vel[0],
        -cfg.k_tilt * pitch - cfg.d_tilt * ang_vel[1],
        -cfg.k_yaw * yaw - cfg.d_yaw * ang_vel[2],
    ])
    return jnp.concatenate([force, torque])

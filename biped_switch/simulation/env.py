"""The biped on box-terrain tracks, as a vectorisable MJX environment (Brax `Env` interface).

`reset(rng)` picks a track from a bank of seeded tracks and lays its boxes out at the (traced)
difficulty; the boxes live in the state's info, and `step` writes them into the model's terrain
slots (`model.with_boxes`), so every env of a batch has its own track and nothing recompiles.
Actions, in [-1, 1] (config `action`): "torque", joint torques as fractions of each motor's limit
(the paper); or "pd", joint targets `base + action * action_scale_rad` tracked by a PD law at
every physics substep, its torques clipped to the motor limits, where the base is the scripted
gait's joint angles (`pd_offset="gait"`, a residual on the gait) or the standing pose ("stand").

Physics backends (config `backend`): "mjx" steps MJX inside the jitted step; "mujoco" steps MuJoCo's
C engine through one pure callback per control step for the whole batch (native.py), about 9x
faster on a CPU. Everything else (observation, reward, termination, guides, pushes, the control
laws) is the same code on both; "auto" picks mujoco on a CPU and mjx on an accelerator.

Observation = robot state (51) + heightmap (60 x 40, flattened row-major, rows run forward)
[+ gait phase clock (sin, cos of 2 pi t / gait period, t from the end of the pause) when
`phase_obs`] [+ detected artifact one-hot (3) when `detector_one_hot`]: `env.obs_layout`, an
`observation.ObsLayout` of named slices. Robot state layout (STATE_SLICES):
  0:12   joint positions [rad], order model.JOINT_NAMES (left then right: hip yaw, roll, pitch,
         knee, ankle pitch, roll)
  12:24  joint velocities [rad/s]
  24:33  foot contacts now: left fl, fr, bl, br, right fl, fr, bl, br, then 1 if no point touches
         (the contacts the solver used in the control step's last physics substep, 5 ms earlier)
  33:42  the same one control step earlier
  42:45  pelvis CoM linear velocity, world frame [m/s]
  45:48  pelvis angular velocity, world frame [rad/s]
  48     pelvis pitch [rad], 49 roll [rad] (world frame, ZYX Euler)
  50     pelvis CoM height above the terrain beneath it [m] (clipped to the heightmap depth)
"CoM" is the pelvis body's centre of mass, as the paper's "body CoM". Normalisation of the state
(running mean/std) is left to the trainer (Brax PPO's `normalize_observations`).

Initial states: `stand` starts in the standing keyframe and holds it with a PD controller for
`pause_s` (policy actions are ignored then), so every `stand` policy takes over from the same set
of states (the paper's RoA overlap); `random` starts from random joint angles with no pause.

Reward per control step (weights in config.reward; the spirit of Tidd et al.'s guided-curriculum
reward): progress * min(vx, v*) + speed * exp(-(vx - v*)^2 / speed_width) + alive + upright *
cos(pitch) cos(roll) + height * exp(-(h - h_stand)^2 / height_width) - lateral * (|y| + |yaw|) -
torque * mean(a^2) - fall * [fell], where v* is the target speed (0 during the pause), vx the CoM x
velocity and a the action (0 during the pause, when the PD hold acts instead).
Guided curriculum hooks (traced values in `state.info`, set at reset, kept across steps):
`guide_scale` scales the scripted gait's joint PD torques (qfrc_applied) and the CoM-steadying
wrench on the pelvis (xfrc_applied), see gait.py; `push_scale` scales random horizontal pushes of
up to `max_push_N` (each drawn uniformly below, or all at, that: `push_magnitude`) lasting
`push_duration_s`, every `push_interval_s` on average. Both default to 0.

Termination: a fall (h < fall_height_m, |pitch| or |roll| > fall_tilt_rad, or the CoM below
fall_z_m, i.e. into a gap or off the track) or reaching the finish line (success).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State
from mujoco import mjx

from biped_switch.simulation import gait
from biped_switch.simulation import model as model_lib
from biped_switch.simulation import native
from biped_switch.simulation import terrain
from biped_switch.config import (default_curriculum_config, default_env_config, default_gait_config,
                                 default_model_config, default_terrain_config)
from biped_switch.simulation.heightmap import cell_offsets, heightmap, terrain_height
from biped_switch.names import BACKEND_CHOICES, BACKENDS, INITS  # noqa: F401  (re-exported)
from biped_switch.simulation.detection import blame_kind, detection_zone_entered, kinds_met  # noqa: F401
from biped_switch.simulation.observation import STATE_SIZE, STATE_SLICES, layout  # noqa: F401  (re-exported)
from biped_switch.simulation.physics import _euler, _quat_to_mat, resolve_backend, sole_contacts  # noqa: F401

BACKEND_HELP = "physics backend (auto: mujoco on a CPU, mjx on an accelerator)"
ACTIONS = ("torque", "pd")
PUSH_MAGNITUDES = ("uniform", "max")  # curriculum.push_magnitude: how each push force is drawn
# info keys that Brax's training wrappers (EpisodeWrapper, AutoResetWrapper) own: the env must not
# write them (an env counter named "steps" doubled Brax's and halved every training episode).
BRAX_WRAPPER_KEYS = frozenset({"steps", "truncation", "first_pipeline_state", "first_obs",
                               "episode_metrics", "episode_done"})
REWARD_TERMS = ("progress", "speed", "alive", "upright", "height", "lateral", "torque", "fall")


class BipedEnv(Env):
    """See the module docstring. Configs: env (traced values + `shape`), model, terrain."""

    def __init__(self, env_cfg=None, model_cfg=None, terrain_cfg=None, biped=None, tracks=None,
                 gait_cfg=None, curriculum_cfg=None):
        self.cfg = env_cfg or default_env_config()
        self.gait_cfg = gait_cfg or default_gait_config()
        self.curriculum_cfg = curriculum_cfg or default_curriculum_config()
        self.terrain_cfg = terrain_cfg or default_terrain_config()
        self.model_cfg = model_cfg or default_model_config()
        if self.cfg.init not in INITS:
            raise ValueError(f"unknown init mode {self.cfg.init!r}; expected one of {INITS}")
        if self.cfg.action not in ACTIONS:
            raise ValueError(f"unknown action mode {self.cfg.action!r}; expected one of {ACTIONS}")
        if self.cfg.pd_offset not in ("gait", "stand"):
            raise ValueError(f"unknown pd_offset {self.cfg.pd_offset!r}; expected 'gait' or 'stand'")
        if self.curriculum_cfg.push_magnitude not in PUSH_MAGNITUDES:
            raise ValueError(f"unknown curriculum push_magnitude "
                             f"{self.curriculum_cfg.push_magnitude!r}; expected one of "
                             f"{PUSH_MAGNITUDES}")
        if not self.curriculum_cfg.push_interval_s > 0.0:
            raise ValueError(f"curriculum push_interval_s must be > 0 s (the mean time between "
                             f"pushes), got {self.curriculum_cfg.push_interval_s}")
        self._backend = resolve_backend(self.cfg.backend)
        terrain.check_difficulty(self.cfg.difficulty)
        self.biped = biped or model_lib.build_model(self.model_cfg)
        if tracks is None:
            if self.cfg.n_tracks < 1:
                raise ValueError(f"n_tracks must be >= 1, got {self.cfg.n_tracks}")
            tracks = [terrain.generate_track(self.cfg.seed + i, self.cfg.kind, 1.0, self.terrain_cfg)
                      for i in range(self.cfg.n_tracks)]
        bank = terrain.stack_tracks(tracks, self.biped.box_capacity, self.terrain_cfg.n_artifacts)
        self.bank = bank
        self._bank = jax.tree.map(jnp.asarray, {
            "segments": bank.segments.astype(np.float32), "width": bank.width_m.astype(np.float32),
            "origin": bank.x_origin_m.astype(np.float32), "codes": bank.artifact_codes,
            "spans": bank.artifact_segments, "after": bank.finish_after_m.astype(np.float32)})
        self._offsets = jnp.asarray(cell_offsets(self.cfg.heightmap, self.cfg.shape), jnp.float32)
        self.obs_layout = layout(self.cfg)
        b = self.biped
        if self._backend == "mjx":
            self._data0 = mjx.make_data(b.mj_model, impl="jax")
        else:
            self._native = native.CPhysics(b, native.ModelBank(self.model_cfg, bank),
                                           lambda q, qd, inputs: self._control(q, qd, inputs, np))
        self._sole_radius_m = float(b.mj_model.geom_size[b.sole_geoms[0, 0], 0])
        self._stand_q = jnp.asarray(b.stand_qpos[b.qpos_adr], jnp.float32)
        self._gear = jnp.asarray(b.gear, jnp.float32)
        self._np = {"stand_q": b.stand_qpos[b.qpos_adr].astype(np.float64),
                    "gear": b.gear.astype(np.float64)}
        self._lo = jnp.asarray(b.joint_range[:, 0], jnp.float32)
        self._hi = jnp.asarray(b.joint_range[:, 1], jnp.float32)
        self._h_stand = self._stand_height()
        self._pelvis_ipos = jnp.asarray(b.mj_model.body_ipos[b.pelvis_body], jnp.float32)
        if b.mj_model.body_jntadr[b.pelvis_body] != 0 or b.mj_model.jnt_type[0] != 0:
            raise ValueError("the pelvis must be the body of the model's first (free) joint")
        self._pause_s = self.cfg.pause_s if self.cfg.init == "stand" else 0.0

    # ----------------------------------------------------------------- host-side helpers
    def _stand_height(self) -> float:
        """Pelvis CoM height [m] above flat ground in the standing keyframe."""
        import mujoco

        d = mujoco.MjData(self.biped.mj_model)
        d.qpos[:] = self.biped.stand_qpos
        mujoco.mj_kinematics(self.biped.mj_model, d)
        return float(d.xipos[self.biped.pelvis_body, 2])

    @property
    def policy_observation_size(self) -> int:
        """The leading part of the observation that behaviour policies read: state, heightmap and
        the phase clock (the detector one-hot, last, is the DQN selector's)."""
        return self.obs_layout.policy_size

    @property
    def observation_size(self) -> int:
        return self.obs_layout.size

    @property
    def action_size(self) -> int:
        return 12

    @property
    def backend(self) -> str:
        """The physics backend in use: "mujoco" or "mjx"."""
        return self._backend

    @property
    def dt(self) -> float:
        return self.biped.dt_s

    # ----------------------------------------------------------------- jittable pieces
    def track_arrays(self, track_id, difficulty):
        """Boxes (C, 6), artifact starts/ends/kinds (A,) and finish x of bank track `track_id`."""
        bk = self._bank
        seg = bk["segments"][track_id]
        boxes = terrain.segment_boxes(seg, difficulty, bk["origin"][track_id], bk["width"][track_id],
                                      self.bank.thickness_m, xp=jnp)
        a0, a1, finish = terrain.artifact_extents(
            seg, bk["codes"][track_id], bk["spans"][track_id], difficulty, bk["origin"][track_id],
            bk["after"][track_id], xp=jnp)
        return boxes, a0, a1, bk["codes"][track_id], finish

    def _control(self, q, qd, inputs: dict, xp=jnp):
        """The control laws of one physics substep, for either backend (`xp`: jnp or numpy):
        actuator controls [fraction of the motor limit] and the joint guide torques [Nm].

        q, qd (..., 12) joint positions [rad] and velocities [rad/s]; inputs: "action" (..., 12),
        "paused" (...) 1 while the standing PD hold acts, "guide" (...) guide scale (0 while
        paused), "q_ref" (..., 12) the scripted gait's joint targets [rad]."""
        c = self._np if xp is np else {"stand_q": self._stand_q, "gear": self._gear}
        gear, stand_q = c["gear"], c["stand_q"]
        hold = gait.pd_torque(q, qd, stand_q, self.cfg.hold_kp_per_gear, self.cfg.hold_kd_ratio,
                              gear, xp) / gear
        if self.cfg.action == "pd":
            base = inputs["q_ref"] if self.cfg.pd_offset == "gait" else stand_q
            target = base + inputs["action"] * self.cfg.action_scale_rad
            act = gait.pd_torque(q, qd, target, self.cfg.pd_kp_per_gear, self.cfg.pd_kd_ratio,
                                 gear, xp) / gear
        else:
            act = inputs["action"]
        ctrl = xp.where(inputs["paused"][..., None] > 0.5, hold, act)
        tau = inputs["guide"][..., None] * gait.joint_guide(q, qd, inputs["q_ref"], gear,
                                                            self.gait_cfg, xp)
        return ctrl, tau

    def _forward(self, track_id, difficulty, boxes, qpos):
        """Physics state at rest at `qpos`, with positions and contacts computed."""
        if self._backend == "mujoco":
            return native.forward(self._native, track_id, difficulty, qpos,
                                  jnp.zeros(self.biped.mj_model.nv, qpos.dtype))
        m = model_lib.with_boxes(self.biped.mjx_model, self.biped.box_start, boxes)
        data = self._data0.replace(qpos=qpos, qvel=jnp.zeros_like(self._data0.qvel),
                                   ctrl=jnp.zeros_like(self._data0.ctrl))
        return mjx.forward(m, data)

    def reset(self, rng: jax.Array, difficulty=None, track_id=None, guide_scale=None,
              push_scale=None) -> State:
        """A new episode; `difficulty` (traced ok) defaults to the config's, `track_id` to random;
        `guide_scale` and `push_scale` (traced ok) are the curriculum's guide and push levels."""
        rng, k_track, k_q = jax.random.split(rng, 3)
        if difficulty is None:
            difficulty = self.cfg.difficulty
        guide_scale = self.cfg.guide_scale if guide_scale is None else guide_scale
        push_scale = self.cfg.push_scale if push_scale is None else push_scale
        difficulty = jnp.asarray(difficulty, jnp.float32)
        if track_id is None:
            track_id = jax.random.randint(k_track, (), 0, self.bank.size)
        boxes, a0, a1, codes, finish = self.track_arrays(track_id, difficulty)
        b = self.biped
        qpos = jnp.asarray(b.stand_qpos, jnp.float32)
        if self.cfg.init == "random":
            half = 0.5 * (self._hi - self._lo) * self.cfg.random_joint_scale
            q = self._stand_q + jax.random.uniform(k_q, (12,), minval=-1.0, maxval=1.0) * half
            qpos = qpos.at[b.qpos_adr].set(jnp.clip(q, self._lo, self._hi))
        data = self._forward(track_id, difficulty, boxes, qpos)
        # Lift or lower the robot so its lowest sole sits reset_clearance_m above the ground.
        soles = data.geom_xpos[b.sole_geoms.reshape(-1)]
        ground = terrain_height(boxes, soles[:, :2])
        clearance = jnp.min(soles[:, 2] - self._sole_radius_m - ground)
        data = self._forward(track_id, difficulty, boxes,
                             qpos.at[2].add(self.cfg.reset_clearance_m - clearance))
        contact = self._contacts9(data, boxes)
        info = {
            "rng": rng,
            "boxes": boxes,
            "art_x0": a0, "art_x1": a1, "art_kind": codes, "finish_x": finish,
            "track_id": jnp.asarray(track_id, jnp.int32),
            "difficulty": difficulty,
            "start_x": data.xipos[b.pelvis_body, 0],
            "contact_prev": contact,
            "guide_scale": jnp.asarray(guide_scale, jnp.float32),
            "push_scale": jnp.asarray(push_scale, jnp.float32),
            "push_force": jnp.zeros(3, jnp.float32),  # world-frame force of the current push [N]
            "push_left_s": jnp.zeros((), jnp.float32),
            "time_s": jnp.zeros((), jnp.float32),
        }
        obs, feat = self._observe(data, info, contact)
        zero = jnp.zeros((), jnp.float32)
        metrics = self._metrics(feat, info, fell=zero, success=zero,
                                terms={k: zero for k in REWARD_TERMS})
        return State(pipeline_state=data, obs=obs, reward=zero, done=zero, metrics=metrics, info=info)

    def step(self, state: State, action: jax.Array) -> State:
        return self._step(state, action, hold=False)

    def hold_step(self, state: State) -> State:
        """A control step of the scripted standing controller (PD on the keyframe, run at every
        physics substep: a stiff PD held for a whole 20 ms control period goes unstable)."""
        return self._step(state, jnp.zeros(self.action_size), hold=True)

    def _step(self, state: State, action: jax.Array, hold) -> State:
        info = dict(state.info)
        action = jnp.clip(action, -1.0, 1.0)
        paused = (info["time_s"] < self._pause_s) | hold
        walk_t = info["time_s"] - self._pause_s
        q_ref = jnp.where(walk_t >= 0, gait.reference(walk_t, self._stand_q, self.gait_cfg),
                          self._stand_q)
        target = jnp.where(paused, 0.0, self.cfg.target_speed_mps)
        guide = jnp.where(paused, 0.0, info["guide_scale"])
        info["rng"], push_force, info["push_left_s"] = self._push(info)
        info["push_force"] = push_force

        # The CoM wrench is a soft spring-damper (about 7 rad/s): held over the control period.
        # The joint PDs are stiff, so they are evaluated at every physics substep.
        f = self._features(state.pipeline_state, info["boxes"])
        wrench = guide * gait.com_guide(f["com"], f["lin_vel"], f["ang_vel"], f["yaw"], f["pitch"],
                                        f["roll"], f["com_height"], target, self._h_stand,
                                        self.gait_cfg)
        pelvis_wrench = wrench.at[:3].add(push_force)
        inputs = {"action": action, "paused": paused.astype(jnp.float32), "guide": guide,
                  "q_ref": q_ref}
        data = self._physics_step(state.pipeline_state, info, pelvis_wrench, inputs)
        # A diverged simulation ends its episode as a fall at its last finite state, so that no
        # NaN reaches the observation, the reward or a learner's statistics.
        diverged = ~(jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.abs(data.qvel) < self.cfg.max_qvel))
        data = jax.tree.map(lambda new, old: jnp.where(diverged, old, new), data,
                            state.pipeline_state)
        contact = self._contacts9(data, info["boxes"])
        info["time_s"] = info["time_s"] + self.dt
        obs, feat = self._observe(data, info, contact, prev=info["contact_prev"])
        info["contact_prev"] = contact
        fell = self._fell(feat, diverged)
        success = (feat["com"][0] >= info["finish_x"]) & ~fell
        reward, terms = self._reward(feat, data.ctrl, fell, paused)
        done = (fell | success).astype(jnp.float32)
        metrics = self._metrics(feat, info, fell=fell.astype(jnp.float32),
                                success=success.astype(jnp.float32), terms=terms)
        return state.replace(pipeline_state=data, obs=obs, reward=reward, done=done,
                             metrics=metrics, info=info)

    def _physics_step(self, data, info, pelvis_wrench, inputs):
        """One control step of physics: `n_substeps` steps, the control laws at each one."""
        if self._backend == "mujoco":
            return native.step(self._native, info["track_id"], info["difficulty"], data,
                               pelvis_wrench, inputs)
        b = self.biped
        m = model_lib.with_boxes(b.mjx_model, b.box_start, info["boxes"])
        xfrc = jnp.zeros_like(data.xfrc_applied).at[b.pelvis_body].set(pelvis_wrench)

        def substep(d, _):
            ctrl, tau = self._control(d.qpos[b.qpos_adr], d.qvel[b.dof_adr], inputs)
            d = d.replace(ctrl=ctrl, xfrc_applied=xfrc,
                          qfrc_applied=jnp.zeros_like(d.qfrc_applied).at[b.dof_adr].set(tau))
            return mjx.step(m, d), None

        data, _ = jax.lax.scan(substep, data, None, length=b.n_substeps)
        return data

    def _push(self, info):
        """Random pushes: start one with probability dt / interval when none is running, in a
        random horizontal direction, its force [N] up to push_scale * max_push_N (uniform) or
        exactly that ("max"), `curriculum.push_magnitude`."""
        c = self.curriculum_cfg
        rng, k_start, k_dir, k_mag = jax.random.split(info["rng"], 4)
        start = ((jax.random.uniform(k_start) < self.dt / c.push_interval_s)
                 & (info["push_left_s"] <= 0.0) & (info["push_scale"] > 0.0))
        angle = jax.random.uniform(k_dir, maxval=2 * jnp.pi)
        frac = jax.random.uniform(k_mag) if c.push_magnitude == "uniform" else 1.0
        new = (info["push_scale"] * frac * c.max_push_N
               * jnp.array([jnp.cos(angle), jnp.sin(angle), 0.0]))
        running = info["push_left_s"] > 0.0
        force = jnp.where(start, new, jnp.where(running, info["push_force"], 0.0))
        left = jnp.where(start, c.push_duration_s, jnp.maximum(info["push_left_s"] - self.dt, 0.0))
        return rng, force.astype(jnp.float32), left.astype(jnp.float32)

    # ----------------------------------------------------------------- features
    def _contacts9(self, data, boxes) -> jnp.ndarray:
        if self._backend == "mujoco":
            c8 = native.sole_contacts_geometric(data.geom_xpos[self.biped.sole_geoms.reshape(-1)],
                                                self._sole_radius_m, boxes)
        else:
            c8 = sole_contacts(data, self.biped.sole_geoms)
        return jnp.concatenate([c8, (jnp.sum(c8) == 0).astype(jnp.float32)[None]])

    def _pose(self, qpos):
        """Pelvis origin, rotation, CoM [m] and ZYX Euler angles [rad] from the free joint."""
        pos, xmat = qpos[0:3], _quat_to_mat(qpos[3:7])
        return pos, xmat, pos + xmat @ self._pelvis_ipos, _euler(xmat)

    def _features(self, data, boxes):
        """Pelvis CoM position, velocities (world frame), Euler angles and height above terrain.

        Computed from qpos/qvel of the free joint (the pelvis is its body), not from data.xipos:
        mjx.step evaluates positions before it integrates, so xipos/xmat lag qpos by a substep."""
        pos, xmat, com, (yaw, pitch, roll) = self._pose(data.qpos)
        ang_vel = xmat @ data.qvel[3:6]  # free joint: angular velocity is in the body frame
        lin_vel = data.qvel[0:3] + jnp.cross(ang_vel, com - pos)
        depth = self.cfg.heightmap.depth_m
        ground = terrain_height(boxes, com[None, :2])[0]
        height = jnp.clip(com[2] - ground, -depth, depth)
        return {"com": com, "lin_vel": lin_vel, "ang_vel": ang_vel, "yaw": yaw, "pitch": pitch,
                "roll": roll, "com_height": height}

    def _observe(self, data, info, contact, prev=None):
        b = self.biped
        feat = self._features(data, info["boxes"])
        hmap = heightmap(info["boxes"], feat["com"], feat["yaw"], self.cfg.heightmap.depth_m,
                         self.cfg.heightmap.max_boxes, self._offsets)
        prev = contact if prev is None else prev
        state = jnp.concatenate([
            data.qpos[b.qpos_adr], data.qvel[b.dof_adr], contact, prev, feat["lin_vel"],
            feat["ang_vel"], feat["pitch"][None], feat["roll"][None],
            feat["com_height"][None]]).astype(jnp.float32)
        feat["detect"] = self.detect(info, feat["com"][0])
        lay = self.obs_layout  # the parts in its order: state | heightmap | phase | one-hot
        parts = [state, hmap.reshape(-1).astype(jnp.float32)]
        if lay.n_phase:
            walk_t = jnp.maximum(info["time_s"] - self._pause_s, 0.0)
            angle = 2 * jnp.pi * walk_t / self.gait_cfg.period_s
            parts.append(jnp.stack([jnp.sin(angle), jnp.cos(angle)]).astype(jnp.float32))
        if lay.n_one_hot:
            parts.append(jax.nn.one_hot(feat["detect"]["kind"], lay.n_one_hot))
        return jnp.concatenate(parts), feat

    def switch_inputs(self, state: State) -> dict:
        """What switching rules read besides the observation: the oracle detection at the pelvis
        CoM, the heading, the whole-body CoM and the sole centres (world frame; these two come
        from the last substep's kinematics, 5 ms old), and the 8 sole contacts."""
        d = state.pipeline_state
        _, _, com, (yaw, _, _) = self._pose(d.qpos)  # no velocities or terrain lookup needed
        return {"detect": self.detect(state.info, com[0]), "com_x_m": com[0],
                "yaw": yaw, "body_com": d.subtree_com[self.biped.pelvis_body],
                "soles": d.geom_xpos[self.biped.sole_geoms.reshape(-1)],
                "contact": state.obs[STATE_SLICES["contact"]][:8],
                "contact_prev": state.obs[STATE_SLICES["contact_prev"]][:8]}

    def detect(self, info, x):
        """Oracle detector: the next artifact not yet passed, and its kind once its start is
        within `detect_range_m` of the body (else kind -1). Distances in metres along x."""
        ahead = info["art_x1"] >= x
        nxt = jnp.argmax(ahead)  # first artifact whose end is still ahead
        valid = ahead[nxt] & (info["art_kind"][nxt] >= 0)
        dist = info["art_x0"][nxt] - x
        seen = valid & (dist <= self.cfg.detect_range_m)
        return {"index": jnp.where(valid, nxt, -1), "kind": jnp.where(seen, info["art_kind"][nxt], -1),
                "dist_m": jnp.where(valid, dist, jnp.inf)}

    def _fell(self, feat, diverged):
        """Termination as a fall: pelvis CoM too low above the terrain, tilted too far, below the
        world, or the simulation diverged."""
        c = self.cfg
        return ((feat["com_height"] < c.fall_height_m) | (jnp.abs(feat["pitch"]) > c.fall_tilt_rad)
                | (jnp.abs(feat["roll"]) > c.fall_tilt_rad) | (feat["com"][2] < c.fall_z_m)
                | diverged)

    def _reward_terms(self, feat, ctrl, fell, paused) -> dict:
        """Each weighted reward term (signed, so they sum to the reward), logged as reward/<term>."""
        w = self.cfg.reward
        target = jnp.where(paused, 0.0, self.cfg.target_speed_mps)
        vx = feat["lin_vel"][0]
        terms = {
            "progress": w.progress * jnp.minimum(vx, target),
            "speed": w.speed * jnp.exp(-((vx - target) ** 2) / w.speed_width),
            "alive": w.alive * jnp.ones_like(vx),
            "upright": w.upright * jnp.cos(feat["pitch"]) * jnp.cos(feat["roll"]),
            "height": w.height * jnp.exp(-((feat["com_height"] - self._h_stand) ** 2)
                                         / w.height_width),
            "lateral": -w.lateral * (jnp.abs(feat["com"][1]) + jnp.abs(feat["yaw"])),
            "torque": -w.torque * jnp.mean(jnp.where(paused, 0.0, ctrl) ** 2),  # policy's only
            "fall": -w.fall * jnp.asarray(fell, jnp.float32),
        }
        return {k: v.astype(jnp.float32) for k, v in terms.items()}

    def _reward(self, feat, ctrl, fell, paused):
        terms = self._reward_terms(feat, ctrl, fell, paused)
        return sum(terms.values()).astype(jnp.float32), terms

    def _metrics(self, feat, info, fell, success, terms):
        x = feat["com"][0]
        span = jnp.maximum(info["finish_x"] - info["start_x"], 1e-6)
        passed = jnp.sum((info["art_x1"] < x) & (info["art_kind"] >= 0))
        blamed = blame_kind(x, info["art_x0"], info["art_x1"], info["art_kind"],
                            self.cfg.detect_range_m, self.terrain_cfg.finish_after_m)
        met = kinds_met(x, info["art_x0"], info["art_kind"], self.cfg.detect_range_m)
        return {
            "distance_m": (x - info["start_x"]).astype(jnp.float32),
            "progress_frac": jnp.clip((x - info["start_x"]) / span, 0.0, 1.0).astype(jnp.float32),
            "artifacts_passed": passed.astype(jnp.float32),
            "success": jnp.asarray(success, jnp.float32),
            "fell": jnp.asarray(fell, jnp.float32),
            "fail_kind": jnp.where(fell > 0, blamed, -1).astype(jnp.float32),
            "detected_kind": feat["detect"]["kind"].astype(jnp.float32),
        } | {f"met_{k}": met[i] for i, k in enumerate(terrain.ARTIFACT_KINDS)} | {
            f"reward/{k}": v for k, v in terms.items()}


def make_env(kind: str = "walk", init: str = "stand", curriculum_cfg=None, terrain_cfg=None,
             n_artifacts: int | None = None, tracks=None, **overrides) -> BipedEnv:
    """The one env factory: a BipedEnv on `kind` tracks with env-config overrides (e.g.
    n_tracks=8, difficulty=0.5); `n_artifacts` per track (default: the terrain config's, 7);
    `tracks` (terrain.Track list) instead of the seeded ones of `kind`."""
    if n_artifacts is not None:
        if terrain_cfg is not None:
            raise ValueError("give n_artifacts or terrain_cfg, not both")
        terrain_cfg = default_terrain_config(n_artifacts)
    cfg = default_env_config()
    cfg.kind, cfg.init = kind, init
    for k, v in overrides.items():
        if k not in cfg:
            raise KeyError(f"unknown env config key {k!r}")
        cfg[k] = v
    return BipedEnv(cfg, terrain_cfg=terrain_cfg, curriculum_cfg=curriculum_cfg, tracks=tracks)

"""The `mujoco` physics backend: MuJoCo's C engine stepped from inside the jitted env.

On a CPU the C engine steps the biped about 9x faster than MJX (design.md), so `BipedEnv` with
`backend="mujoco"` keeps all of its JAX code (observation, reward, termination, guides, pushes) and
swaps only the physics: one `jax.pure_callback` per control step that steps the whole batch.

Why this shape (measured on the 2-core CPU, 256 envs, mixed tracks):
- `mujoco.batch.Batch` (nthread=2) with per-env models, four `step()` calls per control step with
  the joint PD laws evaluated in numpy between them: about 39k control steps/s. One `step(nstep=4)`
  call is hardly faster (40k/s), so the stiff PD laws stay per substep, exactly as on MJX.
- A pure callback with `vmap_method="broadcast_all"` costs about 50 us per call for the whole batch;
  "sequential" costs about 140 us per env.
- JAX may drop or repeat a pure callback, so the full physics state goes in and comes back out
  (`PhysState`): the callback has no memory of its own besides caches of compiled models.
- Per-env tracks are separate compiled models (`ModelBank`): editing `geom_pos` of a compiled
  MjModel leaves the bounding-volume tree stale (model.py). Compiling one costs about 7 ms; models
  are cached per (track, difficulty), so a curriculum of 11 difficulty levels on 32 tracks compiles
  352 models once, in about 2.5 s.

Sole contacts: `mujoco.batch` does not expose the contact list, so the backend reports the
contacts the solver used as sole-sphere vs box penetration of the last substep's geometry
(`sole_contacts_geometric`, exact for sphere-box pairs, which are the only colliding pairs).
"""

from __future__ import annotations

import os
import threading
from typing import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from biped_switch.simulation import model as model_lib
from biped_switch.simulation import terrain

def _nthread() -> int:
    """Threads of each mujoco.batch.Batch: all cores, or BIPED_SWITCH_NTHREAD when several runs share them."""
    raw = os.environ.get("BIPED_SWITCH_NTHREAD", "")
    if not raw:
        return max(1, os.cpu_count() or 1)
    if not raw.isdigit() or int(raw) < 1:
        raise ValueError(f"BIPED_SWITCH_NTHREAD={raw!r}: expected a positive integer")
    return int(raw)


NTHREAD = _nthread()
DIFFICULTY_DECIMALS = 4  # models are cached per difficulty rounded to this many decimals
TIME_OFFSET_S = 1e3  # the C clock runs this far ahead during a step, so a reset (clock 0) shows


@struct.dataclass
class PhysState:
    """The physics state of one env on the `mujoco` backend (field names as MjData's).

    qpos, qvel and qacc_warmstart are the state; the rest are derived fields of the last substep
    (positions before its integration, as after mj_step), ctrl is the last substep's control."""

    qpos: jax.Array  # (nq,)
    qvel: jax.Array  # (nv,)
    qacc_warmstart: jax.Array  # (nv,)
    ctrl: jax.Array  # (nu,) last substep's actuator controls [fraction of gear]
    xipos: jax.Array  # (nbody, 3) body CoMs [m]
    subtree_com: jax.Array  # (nbody, 3)
    geom_xpos: jax.Array  # (ngeom, 3)
    time: jax.Array  # () [s]


class ModelBank:
    """Compiled MjModels of a track bank, one per (track id, difficulty), compiled on first use."""

    def __init__(self, model_cfg, bank: terrain.TrackBank):
        self.model_cfg = model_cfg
        self.bank = bank
        self._cache: dict[tuple[int, float], mujoco.MjModel] = {}
        self._lock = threading.Lock()

    def boxes(self, track_id: int, difficulty: float) -> np.ndarray:
        b = self.bank
        return terrain.segment_boxes(b.segments[track_id], difficulty, b.x_origin_m[track_id],
                                     b.width_m[track_id], b.thickness_m)

    def get(self, track_id: int, difficulty: float) -> mujoco.MjModel:
        if not 0 <= track_id < self.bank.size:
            raise IndexError(f"track id {track_id} is outside the bank of {self.bank.size} tracks")
        key = (int(track_id), round(float(difficulty), DIFFICULTY_DECIMALS))
        with self._lock:
            m = self._cache.get(key)
            if m is None:
                m = model_lib.compile_mj_model(self.model_cfg, self.boxes(*key))
                self._cache[key] = m
        return m

    def __len__(self) -> int:
        return len(self._cache)


class CPhysics:
    """Host side of the backend: a `mujoco.batch.Batch` per batch size, models from a ModelBank.

    `control_fn(q, qd, inputs) -> (ctrl, qfrc_joint)` is the env's per-substep control law written
    for numpy (q, qd: (B, 12) joint positions and velocities; inputs: dict of (B, ...) arrays)."""

    def __init__(self, biped: model_lib.BipedModel, models: ModelBank, control_fn: Callable,
                 nthread: int = NTHREAD):
        self.biped = biped
        self.models = models
        self.control_fn = control_fn
        self.nthread = nthread
        self._batches: dict[int, tuple] = {}
        self._lock = threading.Lock()
        m = biped.mj_model
        self.sizes = {"qpos": m.nq, "qvel": m.nv, "qacc_warmstart": m.nv, "ctrl": m.nu,
                      "xipos": (m.nbody, 3), "subtree_com": (m.nbody, 3),
                      "geom_xpos": (m.ngeom, 3), "time": ()}

    def _batch(self, n: int):
        if n not in self._batches:
            import mujoco.batch

            bt = mujoco.batch.Batch(self.biped.mj_model, nsim=n, nthread=self.nthread)
            views = {k: bt.bind(k) for k in ("qpos", "qvel", "qacc_warmstart", "ctrl", "qfrc_applied",
                                               "xfrc_applied", "xipos", "subtree_com", "geom_xpos",
                                               "time")}
            self._batches[n] = (bt, views, [None])
        return self._batches[n]

    def _set_models(self, n, track_id, difficulty):
        bt, views, last = self._batch(n)
        keys = tuple(zip(track_id.tolist(), np.round(difficulty, DIFFICULTY_DECIMALS).tolist()))
        if keys != last[0]:
            bt.set_models([self.models.get(t, d) for t, d in keys])
            last[0] = keys
        return bt, views

    def _load(self, views, qpos, qvel, warm, time):
        views["qpos"][:] = qpos
        views["qvel"][:] = qvel
        views["qacc_warmstart"][:] = warm
        views["time"][:] = time

    def _out(self, views, dtype):
        return {k: np.array(views[k], dtype=dtype) for k in self.sizes}

    def forward(self, track_id, difficulty, qpos, qvel):
        """mj_forward of every env at (qpos, qvel): the state at rest, derived fields current."""
        with self._lock:
            lead = qpos.shape[:-1]
            n = int(np.prod(lead, dtype=int))
            bt, views = self._set_models(n, track_id.reshape(n), difficulty.reshape(n))
            self._load(views, qpos.reshape(n, -1), qvel.reshape(n, -1), 0.0, 0.0)
            views["ctrl"][:] = 0.0
            views["qfrc_applied"][:] = 0.0
            views["xfrc_applied"][:] = 0.0
            bt.forward()
            out = self._out(views, qpos.dtype)
        return {k: v.reshape(lead + v.shape[1:]) for k, v in out.items()}

    def step(self, track_id, difficulty, qpos, qvel, warm, time, xfrc_pelvis, inputs: dict):
        """`n_substeps` mj_steps per env, the control law re-evaluated before each one."""
        b = self.biped
        with self._lock:
            lead = qpos.shape[:-1]
            n = int(np.prod(lead, dtype=int))
            bt, views = self._set_models(n, track_id.reshape(n), difficulty.reshape(n))
            qpos, qvel = qpos.reshape(n, -1), qvel.reshape(n, -1)
            bad_in = ~(np.all(np.isfinite(qpos), axis=1) & np.all(np.isfinite(qvel), axis=1))
            if np.any(bad_in):  # step a harmless state in their place and hand back NaN again
                qpos, qvel = qpos.copy(), qvel.copy()
                qpos[bad_in], qvel[bad_in] = b.mj_model.qpos0, 0.0
            self._load(views, qpos, qvel, warm.reshape(n, -1), time.reshape(n) + TIME_OFFSET_S)
            xfrc = np.zeros((n, b.mj_model.nbody, 6))
            xfrc[:, b.pelvis_body] = xfrc_pelvis.reshape(n, 6)
            views["xfrc_applied"][:] = xfrc
            inputs = {k: v.reshape((n,) + v.shape[len(lead):]) for k, v in inputs.items()}
            qfrc = np.zeros((n, b.mj_model.nv))
            for _ in range(b.n_substeps):
                q, qd = views["qpos"][:, b.qpos_adr], views["qvel"][:, b.dof_adr]
                ctrl, tau = self.control_fn(q, qd, inputs)
                views["ctrl"][:] = ctrl
                qfrc[:, b.dof_adr] = tau
                views["qfrc_applied"][:] = qfrc
                bt.step()
            out = self._out(views, qpos.dtype)
        # A simulation that went unstable (bad qpos/qvel/qacc) was reset by MuJoCo to qpos0 with
        # its clock at 0, which the clock's offset reveals; hand it back as non-finite so the
        # env's termination ends the episode (a fall) instead of teleporting the robot back.
        lost = (out["time"] < 0.5 * TIME_OFFSET_S) | bad_in
        out["time"] = out["time"] - TIME_OFFSET_S
        if np.any(lost):
            for k in ("qpos", "qvel"):
                out[k][lost] = np.nan
        return {k: v.reshape(lead + v.shape[1:]) for k, v in out.items()}


def _shapes(phys: CPhysics, dtype) -> dict:
    return {k: jax.ShapeDtypeStruct(s if isinstance(s, tuple) else (s,), dtype)
            for k, s in phys.sizes.items()}


def forward(phys: CPhysics, track_id, difficulty, qpos, qvel) -> PhysState:
    """Jittable, vmappable: the PhysState at (qpos, qvel) on the env's track model."""
    out = jax.pure_callback(
        lambda t, d, q, v: phys.forward(np.asarray(t), np.asarray(d), np.asarray(q), np.asarray(v)),
        _shapes(phys, qpos.dtype), jnp.asarray(track_id, jnp.int32),
        jnp.asarray(difficulty, jnp.float32), qpos, qvel, vmap_method="broadcast_all")
    return PhysState(**out)


def step(phys: CPhysics, track_id, difficulty, ps: PhysState, xfrc_pelvis, inputs: dict) -> PhysState:
    """Jittable, vmappable: `ps` advanced by one control step (n_substeps physics steps)."""
    names = sorted(inputs)

    def host(t, d, q, v, w, tm, x, *ins):
        return phys.step(np.asarray(t), np.asarray(d), np.asarray(q), np.asarray(v), np.asarray(w),
                         np.asarray(tm), np.asarray(x),
                         {k: np.asarray(a) for k, a in zip(names, ins)})

    out = jax.pure_callback(
        host, _shapes(phys, ps.qpos.dtype), jnp.asarray(track_id, jnp.int32),
        jnp.asarray(difficulty, jnp.float32), ps.qpos, ps.qvel, ps.qacc_warmstart, ps.time,
        xfrc_pelvis, *[inputs[k] for k in names], vmap_method="broadcast_all")
    return PhysState(**out)


def sole_contacts_geometric(sole_xpos, radius_m, boxes):
    """(8,) 1.0 where a sole sphere (centres (8, 3)) penetrates an axis-aligned box (C, 6)."""
    d = jnp.maximum(jnp.abs(sole_xpos[:, None, :] - boxes[None, :, :3]) - boxes[None, :, 3:], 0.0)
    dist = jnp.sqrt(jnp.sum(d * d, axis=-1))  # 0 inside the box
    return jnp.any(dist < radius_m, axis=1).astype(jnp.float32)

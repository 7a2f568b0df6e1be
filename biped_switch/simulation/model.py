"""The biped plus a fixed number of terrain box slots, compiled once; ids resolved on the host.

Every environment in a batch gets its own track by writing its boxes into the slots' `geom_pos`,
`geom_size` and `geom_rbound` (`with_boxes`), a pure function used inside the jitted step, so a new
track or difficulty never recompiles. MJX's broad phase (`max_geom_pairs`) ranks sphere-box pairs by
bounding-sphere distance, which is why `geom_rbound` is written with the sizes.
"""

from __future__ import annotations

import dataclasses
import pathlib

import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from biped_switch.config import default_model_config
from biped_switch.simulation.terrain import PARK_HALF_M, PARK_Z_M

from biped_switch.paths import MODELS_DIR  # noqa: E402,F401
JOINTS = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll")
JOINT_NAMES = tuple(f"{s}_{j}" for s in "lr" for j in JOINTS)  # action / state order
SOLE_CORNERS = ("fl", "fr", "bl", "br")
TERRAIN_GROUP = 2  # geom group of the terrain boxes (the robot is group 0)


@dataclasses.dataclass(frozen=True)
class BipedModel:
    """Compiled model and the indices the hot path needs, resolved once."""

    mj_model: mujoco.MjModel
    mjx_model: mjx.Model
    box_start: int  # first terrain box geom id; slots are box_start .. box_start + capacity - 1
    box_capacity: int
    sole_geoms: np.ndarray  # (2, 4) geom ids, [left, right] x SOLE_CORNERS
    pelvis_body: int
    qpos_adr: np.ndarray  # (12,) in JOINT_NAMES order
    dof_adr: np.ndarray  # (12,)
    joint_range: np.ndarray  # (12, 2) [rad]
    gear: np.ndarray  # (12,) torque limit [Nm] at action 1
    stand_qpos: np.ndarray  # (nq,) standing keyframe
    n_substeps: int

    @property
    def dt_s(self) -> float:
        return float(self.mj_model.opt.timestep) * self.n_substeps


def compile_mj_model(cfg=None, boxes: np.ndarray | None = None) -> mujoco.MjModel:
    """The biped with `box_capacity` terrain slots, filled from `boxes` (N <= C, 6) or parked.

    On the host, a new track means a new compile: editing geom_pos of a compiled MjModel leaves the
    world body's bounding-volume tree stale and MuJoCo (C) then misses the contacts. MJX has no
    such tree, which is why the jitted path can write boxes into the model instead.
    """
    cfg = cfg or default_model_config()
    xml = pathlib.Path(cfg.xml_path) if cfg.xml_path else MODELS_DIR / "biped.xml"
    if not xml.exists():
        raise FileNotFoundError(f"biped MJCF not found at {xml}")
    if cfg.box_capacity < 1:
        raise ValueError(f"box_capacity must be >= 1, got {cfg.box_capacity}")
    boxes = np.zeros((0, 6)) if boxes is None else np.asarray(boxes, np.float64)
    if boxes.shape[0] > cfg.box_capacity:
        raise ValueError(f"{boxes.shape[0]} boxes exceed the compiled box capacity "
                         f"{cfg.box_capacity}; raise model box_capacity")
    spec = mujoco.MjSpec.from_file(str(xml))
    for i in range(cfg.box_capacity):
        pos, half = ((boxes[i, :3], boxes[i, 3:]) if i < boxes.shape[0]
                     else ([0.0, 0.0, PARK_Z_M], [PARK_HALF_M] * 3))
        spec.worldbody.add_geom(
            name=f"box{i}", type=mujoco.mjtGeom.mjGEOM_BOX, size=half, pos=pos, contype=2,
            conaffinity=1, condim=3, group=TERRAIN_GROUP, friction=[1.0, 0.02, 0.01],
            material="terrain")
    if cfg.max_geom_pairs > 0:
        spec.add_numeric(name="max_geom_pairs", data=[float(cfg.max_geom_pairs)])
    spec.option.timestep = cfg.sim_dt_s
    spec.option.iterations = cfg.solver_iterations
    spec.option.ls_iterations = cfg.ls_iterations
    return spec.compile()


def build_model(cfg=None) -> BipedModel:
    cfg = cfg or default_model_config()
    m = compile_mj_model(cfg)

    box_start = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "box0")
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"box{i}") for i in range(cfg.box_capacity)]
    assert ids == list(range(box_start, box_start + cfg.box_capacity)), "box slots not contiguous"
    jid = [m.joint(n).id for n in JOINT_NAMES]
    act = [m.actuator(n).id for n in JOINT_NAMES]
    return BipedModel(
        mj_model=m,
        mjx_model=mjx.put_model(m, impl="jax"),
        box_start=box_start,
        box_capacity=int(cfg.box_capacity),
        sole_geoms=np.array([[m.geom(f"{s}_sole_{c}").id for c in SOLE_CORNERS] for s in "lr"]),
        pelvis_body=m.body("pelvis").id,
        qpos_adr=m.jnt_qposadr[jid].copy(),
        dof_adr=m.jnt_dofadr[jid].copy(),
        joint_range=m.jnt_range[jid].copy(),
        gear=m.actuator_gear[act, 0].copy(),
        stand_qpos=m.key("stand").qpos.copy(),
        n_substeps=int(cfg.n_substeps),
    )


def with_boxes(mjx_model: mjx.Model, box_start: int, boxes: jnp.ndarray) -> mjx.Model:
    """The model with terrain slots set to `boxes` (C, 6): centre xyz, half sizes xyz [m]."""
    sl = slice(box_start, box_start + boxes.shape[0])
    return mjx_model.replace(
        geom_pos=mjx_model.geom_pos.at[sl].set(boxes[:, :3]),
        geom_size=mjx_model.geom_size.at[sl].set(boxes[:, 3:]),
        geom_rbound=mjx_model.geom_rbound.at[sl].set(jnp.linalg.norm(boxes[:, 3:], axis=-1)),
    )

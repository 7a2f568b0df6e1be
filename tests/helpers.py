"""Plain numpy reference implementations shared by the tests (independent of biped_switch's jnp code)."""

from __future__ import annotations

import numpy as np

from biped_switch.simulation import terrain

NO_GROUND = -1e3


def terrain_height_np(boxes: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Top z of the highest box whose ground-plane rectangle holds each point (..., 2); -1e3 if none."""
    boxes = np.asarray(boxes, np.float64)
    xy = np.asarray(xy, np.float64)
    lo = boxes[:, :2] - boxes[:, 3:5]
    hi = boxes[:, :2] + boxes[:, 3:5]
    p = xy[..., None, :]
    inside = np.all((p >= lo) & (p <= hi), axis=-1)
    return np.max(np.where(inside, boxes[:, 2] + boxes[:, 5], NO_GROUND), axis=-1)


def env_boxes(track: terrain.Track, capacity: int = 96, difficulty: float | None = None,
              pad: bool = True) -> np.ndarray:
    """The (capacity, 6) box slots the env writes for `track`: solid boxes, parked holes, and (with
    `pad`) parked zero-length padding rows, exactly as `BipedEnv.track_arrays` lays them out."""
    d = track.difficulty if difficulty is None else difficulty
    seg = terrain.stack_tracks([track], capacity, 7).segments[0] if pad else track.segments
    return terrain.segment_boxes(seg, d, track.x_origin_m, track.width_m, track.thickness_m)


def rect_distance(boxes: np.ndarray, xy) -> np.ndarray:
    """Ground-plane distance [m] from point(s) xy (..., 2) to each box rectangle -> (..., N)."""
    xy = np.asarray(xy, np.float64)[..., None, :]
    gap = np.maximum(np.abs(xy - boxes[:, :2]) - boxes[:, 3:5], 0.0)
    return np.sqrt(np.sum(gap * gap, axis=-1))


def edge_mask(boxes: np.ndarray, xy: np.ndarray, tol: float = 1e-3) -> np.ndarray:
    """True where a point (..., 2) lies within `tol` of any box edge line in x or in y."""
    ex = np.concatenate([boxes[:, 0] - boxes[:, 3], boxes[:, 0] + boxes[:, 3]])
    ey = np.concatenate([boxes[:, 1] - boxes[:, 4], boxes[:, 1] + boxes[:, 4]])
    near_x = np.min(np.abs(xy[..., 0, None] - ex), axis=-1) < tol
    near_y = np.min(np.abs(xy[..., 1, None] - ey), axis=-1) < tol
    return near_x | near_y


def quat_yaw(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def quat_to_pitch_roll_yaw(q: np.ndarray):
    """ZYX Euler angles of a unit quaternion (w, x, y, z): pitch, roll, yaw [rad]."""
    w, x, y, z = q
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return pitch, roll, yaw


def box_intervals_x(boxes: np.ndarray) -> np.ndarray:
    """(N, 2) x-extents of boxes, sorted by x."""
    iv = np.stack([boxes[:, 0] - boxes[:, 3], boxes[:, 0] + boxes[:, 3]], axis=-1)
    return iv[np.argsort(iv[:, 0])]


class FakeEnv:
    """x moves by the mean action; reward 5 per step; episodes end after `end_step` steps. The
    real observation layout (51 + 60x40), trivial dynamics: for loops that need no physics."""

    observation_size = 2451
    policy_observation_size = 2451
    action_size = 12
    backend = "fake"

    def __init__(self, end_step=8):
        import types

        from biped_switch.simulation.observation import ObsLayout

        self.cfg = types.SimpleNamespace(shape=types.SimpleNamespace(grid_forward=60, grid_lateral=40))
        self.obs_layout = ObsLayout((60, 40))
        self.end_step = end_step

    def reset(self, rng, **_):
        import jax
        import jax.numpy as jnp
        from brax.envs.base import State

        obs = jnp.zeros(2451).at[0].set(jax.random.uniform(rng))
        z = jnp.zeros(())
        return State(pipeline_state=jnp.zeros(2), obs=obs, reward=z, done=z,
                     metrics={"progress_frac": z, "distance_m": z, "fell": z, "success": z},
                     info={"t": z})

    def step(self, state, action):
        import jax.numpy as jnp

        t = state.info["t"] + 1
        x = state.pipeline_state[0] + jnp.mean(action)
        done = (t >= self.end_step).astype(jnp.float32)
        metrics = {"progress_frac": t / 10.0, "distance_m": x, "fell": jnp.zeros(()), "success": done}
        return state.replace(pipeline_state=jnp.stack([x, t]), obs=state.obs.at[1].set(x),
                             reward=jnp.asarray(5.0), done=done, metrics=metrics,
                             info={**state.info, "t": t})

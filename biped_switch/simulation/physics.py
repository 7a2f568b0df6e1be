"""Physics backends: the MuJoCo C engine (CPU) or MJX (accelerator), chosen once per env."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx
from biped_switch.names import BACKENDS


# A sole touches when the solver has a contact: signed distance < 0. MJX's sphere-box collider
# reports dist = 1 for any separated pair, so no positive margin is possible.
CONTACT_DIST_M = 0.0


def _quat_to_mat(q):
    """Rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = q / jnp.linalg.norm(q)
    return jnp.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _euler(xmat):
    """ZYX yaw, pitch, roll [rad] of a rotation matrix."""
    yaw = jnp.arctan2(xmat[1, 0], xmat[0, 0])
    pitch = jnp.arcsin(jnp.clip(-xmat[2, 0], -1.0, 1.0))
    roll = jnp.arctan2(xmat[2, 1], xmat[2, 2])
    return yaw, pitch, roll


def resolve_backend(name: str) -> str:
    """"auto" -> "mujoco" on a CPU (the C engine is ~9x faster there), "mjx" on an accelerator."""
    if name == "auto":
        return "mujoco" if jax.default_backend() == "cpu" else "mjx"
    if name not in BACKENDS:
        raise ValueError(f"unknown physics backend {name!r}; expected 'auto' or one of {BACKENDS}")
    return name


def sole_contacts(data: mjx.Data, sole_geoms: np.ndarray) -> jnp.ndarray:
    """(8,) 1.0 where a sole sphere touches (penetrates) the terrain, from the culled contacts."""
    c = data._impl.contact
    active = c.dist < CONTACT_DIST_M
    g = jnp.asarray(sole_geoms.reshape(-1))
    hit = (c.geom[None, :, 0] == g[:, None]) | (c.geom[None, :, 1] == g[:, None])
    return jnp.any(hit & active[None, :], axis=1).astype(jnp.float32)

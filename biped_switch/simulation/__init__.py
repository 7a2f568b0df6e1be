"""The simulated world: terrain, robot model, heightmap, gait guide, physics backends, env, rollout."""

import contextlib
import ctypes.util
import io
import os

from biped_switch.simulation import _compat  # noqa: F401  (jax.device_put_replicated shim for brax)


def _gl_default() -> None:
    """EGL on a GPU host, else OSMesa where libOSMesa is installed; without either MUJOCO_GL is
    left unset (importing mujoco with MUJOCO_GL=osmesa but no libOSMesa fails, so a run that draws
    nothing would fail too; drawing then fails, and says why). MuJoCo fixes its GL backend when
    it is first imported, so this runs before the first import of mujoco, here."""
    if "MUJOCO_GL" not in os.environ:
        if os.path.exists("/dev/nvidia0"):
            os.environ["MUJOCO_GL"] = "egl"
        elif ctypes.util.find_library("OSMesa"):
            os.environ["MUJOCO_GL"] = "osmesa"
    if os.environ.get("MUJOCO_GL") == "osmesa":
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")


_gl_default()

# mujoco.mjx prints "Failed to import warp" (twice) when the optional NVIDIA Warp backend is absent,
# as it is on every CPU machine; MJX's JAX path does not use it. Importing it once here, quietly,
# keeps that out of every command's output.
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: F401,E402

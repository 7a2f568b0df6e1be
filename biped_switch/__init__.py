"""biped_switch: composing DRL locomotion policies on box-terrain tracks, on MuJoCo MJX.

Stages, one module each: terrain (tracks), model (biped + terrain slots), heightmap, env (MJX
environment), bench (speed figures), demo (the main job for now).
"""

from biped_switch import _compat  # noqa: F401  (jax.device_put_replicated shim for brax)

__version__ = "0.1.0"

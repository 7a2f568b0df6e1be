"""The simulated world: terrain, robot model, heightmap, gait guide, physics backends, env, rollout."""

from biped_switch.simulation import _compat  # noqa: F401  (jax.device_put_replicated shim for brax)

"""biped_switch: composing DRL locomotion policies on box-terrain tracks, on MuJoCo MJX.

One module per stage, in layers whose imports flow one way (README, Layout): settings (config,
paper), the world (terrain, model, heightmap, gait, curriculum, native), the environment (env),
building blocks (networks, ppo, rollout, estimator, runs, stats), policies, switching and
baselines (switching, sweep, dqn), results (table1, table2, fig5, table3), and the command lines
(train, evaluate, demo, render, bench).
"""

from biped_switch import _compat  # noqa: F401  (jax.device_put_replicated shim for brax)

__version__ = "0.1.0"

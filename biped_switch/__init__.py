"""biped_switch: composing DRL locomotion policies on box-terrain tracks, on MuJoCo (C engine or MJX).

Sub-packages name the stages, and each imports only those listed before it:
`simulation` (terrain, model, heightmap, gait, physics, env, rollout, render), `learning`
(networks, PPO, curriculum, DQN, checkpoints, run folders, policies), `switching` (rules, sweeps,
lookup tables, estimators), `evaluation` (Table I, Table II), `reports` (tables, figures, stats,
provenance: no JAX import). Under them: `config`, `names`, `paths` and `paper`, which import
nothing of the package. Over them: the command lines (`train`, `sweep`, `estimator`, `dqn`,
`evaluate`, `demo`, `render`, `bench`, `terrain`), thin files of argument parsing and calls.
"""

__version__ = "0.1.0"

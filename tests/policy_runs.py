"""Small behaviour-policy runs in the trainer's checkpoint format (runs.save_ppo, config.json), made
without an env or a training step, for tests that load policies (policies.load_suite,
policies.load_policy, the CLIs)."""

from __future__ import annotations

import pathlib
import types

import jax

from biped_switch.learning import ppo
from biped_switch.learning import checkpoints as ckpt_lib
from biped_switch.learning import runs as runs_lib
from biped_switch.config import default_env_config, default_train_config
from biped_switch.simulation.observation import layout

TINY_NETWORK = {"policy_hidden": (8,), "value_hidden": (8,), "hm_hidden": (4,)}
DONE = {"stage": 3, "stage_name": "pushes", "difficulty": 1.0, "guide_scale": 0.0, "push_scale": 1.0}


def fake_policy_run(runs: pathlib.Path, policy: str, init: str = "stand", env: dict | None = None,
                    network: dict | None = None, seed: int = 0, step: int = 1000) -> pathlib.Path:
    """<runs>/<policy>_<init>/ with config.json and one checkpoint of freshly initialised
    parameters (`seed`); `env` overrides the train config's env section (action, phase_obs),
    `network` its network sizes (default: tiny). Returns the checkpoint directory."""
    cfg = default_train_config("cpu")
    cfg.policy, cfg.init, cfg.seed = policy, init, seed
    cfg.env.update(**(env or {}))
    cfg.network.update(**{**TINY_NETWORK, **(network or {})})
    env_cfg = default_env_config()
    env_cfg.phase_obs = cfg.env.phase_obs
    lay = layout(env_cfg)
    env = types.SimpleNamespace(obs_layout=lay, observation_size=lay.size, action_size=12)
    state = ppo.make_train(cfg, env).init(jax.random.PRNGKey(seed))
    run_dir = pathlib.Path(runs) / f"{policy}_{init}"
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(cfg.to_json_best_effort(indent=2))
    progress = {"step": step, "wall_s": 1.0, "curriculum": DONE, "curriculum_before": DONE,
                "total_steps": step, "backend": "none", "device": "cpu", "n_devices": 1}
    return ckpt_lib.save_ppo(run_dir, step, state, progress)

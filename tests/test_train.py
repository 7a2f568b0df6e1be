"""The trainer's chunk / checkpoint / resume loop and the rollout, on a cheap stand-in env.

The stand-in has the real observation layout (51 + 60x40) but trivial dynamics, so Brax PPO
compiles in seconds; PPO on the real MJX env is in the slow suite (test_train_real_env).
"""

import json
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import Env, State

from biped_switch import curriculum as cl
from biped_switch import train as train_lib
from biped_switch.rollout import rollout, summarize


class FakeEnv(Env):
    """x moves by the mean action; reward 5 per step; episodes end after `end_step` steps."""

    def __init__(self, difficulty=0.0, end_step=8):
        self.cfg = types.SimpleNamespace(shape=types.SimpleNamespace(grid_forward=60, grid_lateral=40))
        self.difficulty, self.end_step = difficulty, end_step

    observation_size = 2451
    action_size = 12
    backend = "fake"

    def reset(self, rng, **_):
        obs = jnp.zeros(2451).at[0].set(jax.random.uniform(rng))
        z = jnp.zeros(())
        return State(pipeline_state=jnp.zeros(2), obs=obs, reward=z, done=z,
                     metrics={"progress_frac": z, "distance_m": z, "fell": z, "success": z},
                     info={"t": z})

    def step(self, state, action):
        t = state.info["t"] + 1
        x = state.pipeline_state[0] + jnp.mean(action)
        done = (t >= self.end_step).astype(jnp.float32)
        metrics = {"progress_frac": t / 10.0, "distance_m": x, "fell": jnp.zeros(()), "success": done}
        return state.replace(pipeline_state=jnp.stack([x, t]), obs=state.obs.at[1].set(x),
                             reward=jnp.asarray(5.0), done=done, metrics=metrics,
                             info={**state.info, "t": t})


def test_rollout_freezes_each_episode_at_its_end():
    env = FakeEnv(end_step=3)
    res = rollout(env, lambda obs, k: jnp.ones((obs.shape[0], 12)), jax.random.PRNGKey(0), 4, 10)
    np.testing.assert_allclose(res["reward"], 15.0)  # 3 live steps of reward 5, none after
    np.testing.assert_allclose(res["length"], 3.0)
    np.testing.assert_allclose(res["done"], 1.0)
    np.testing.assert_allclose(res["distance_m"], 3.0)  # metrics of the last live step
    s = summarize(res, 10)
    assert s["reward_per_step"] == pytest.approx(1.5)


def _tiny_cfg():
    cfg = train_lib.default_train_config("cpu")
    cfg.policy = "gaps"  # starts the terrain stage at difficulty 0 (walk starts at 1: flat)
    cfg.total_timesteps, cfg.chunk_timesteps, cfg.log_per_chunk = 40, 40, 1
    cfg.ppo.update(num_envs=4, batch_size=4, num_minibatches=2, unroll_length=5)
    cfg.network.update(policy_hidden=(16,), value_hidden=(16,), hm_hidden=(8,))
    cfg.eval.update(n_envs=4, horizon_steps=8)
    cfg.episode_length = 8
    return cfg


def test_train_chunk_checkpoint_and_resume(tmp_path):
    seen = []

    def env_fn(cfg, cs):
        seen.append(cl.CurriculumState(*cs))
        return FakeEnv(float(cs.difficulty))

    cfg = _tiny_cfg()
    lines = []
    prog = train_lib.train(cfg, tmp_path, env_fn=env_fn, print_fn=lines.append)
    assert prog["step"] == 40
    assert prog["eval"]["reward_per_step"] == pytest.approx(5.0)  # every step scores 5
    # 5 >= the 3.78 milestone, so the curriculum advanced one notch and was saved.
    assert prog["curriculum"]["difficulty"] == pytest.approx(0.1)
    ckpt = train_lib.latest_checkpoint(tmp_path)
    assert ckpt is not None and ckpt.name == f"{40:012d}"
    params, saved = train_lib.load_checkpoint(ckpt)
    assert saved["curriculum"] == prog["curriculum"]
    assert saved["total_steps"] == 40  # the goal, so Table III can tell a finished run
    leaves = jax.tree.leaves(params)
    assert leaves and all(np.all(np.isfinite(np.asarray(x))) for x in leaves)
    assert (tmp_path / "config.json").exists() and json.loads((tmp_path / "config.json").read_text())

    # Resume: a second run continues from step 40 with the saved curriculum state, and forgets
    # log rows of an abandoned chunk (here a fake row past the checkpoint).
    train_lib.Logger(tmp_path).log(60, {"train/steps_per_s": 1.0})
    cfg.total_timesteps = 80
    prog2 = train_lib.train(cfg, tmp_path, env_fn=env_fn, print_fn=lines.append)
    assert any(line.startswith("resuming") for line in lines)
    assert prog2["step"] == 80 and prog2["total_steps"] == 80
    assert float(seen[-1].difficulty) == pytest.approx(0.1)
    assert prog2["curriculum"]["difficulty"] == pytest.approx(0.2)
    rows = (tmp_path / "metrics.csv").read_text().splitlines()
    header = rows[0].split(",")
    steps = [float(r.split(",")[header.index("step")]) for r in rows[1:]]
    assert steps == sorted(steps) and 60.0 not in steps
    assert "eval/reward_per_step" in header and "training/total_loss" in header
    losses = [r.split(",")[header.index("training/total_loss")] for r in rows[1:]]
    assert [float(v) for v in losses if v] and all(np.isfinite(float(v)) for v in losses if v)
    assert (tmp_path / "tb").is_dir()
    train_lib.plot_curves(tmp_path, tmp_path / "curves.png")
    assert (tmp_path / "curves.png").stat().st_size > 10_000


def test_unknown_policy_and_preset_are_named():
    cfg = train_lib.default_train_config("cpu")
    cfg.policy = "hop"
    with pytest.raises(ValueError, match="'hop'"):
        train_lib.make_env(cfg, cl.CurriculumState())
    with pytest.raises(ValueError, match="'tpu'"):
        train_lib.default_train_config("tpu")

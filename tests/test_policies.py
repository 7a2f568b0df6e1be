"""policies.load_suite on runs in the trainer's checkpoint format: the suite's env overrides, its
stacked deterministic actions against policies.load_policy's, and the errors for policies that
cannot share one env or one stack."""

from __future__ import annotations

import json
import re

import jax
import numpy as np
import pytest

from biped_switch.simulation import env as env_lib
from biped_switch.learning import policies as pol
from biped_switch.learning import runs as runs_lib
from biped_switch.config import default_train_config

from policy_runs import fake_policy_run

# the train config's default env overrides (pd actions, phase clock, ...), less the backend
PD_PHASE = {k: v for k, v in default_train_config().env.items() if k != "backend"}


@pytest.fixture(scope="module")
def suite_runs(tmp_path_factory):
    """Four stand-init policies (default env overrides: pd actions, phase clock), seeds 0..3."""
    runs = tmp_path_factory.mktemp("runs")
    ckpts = {n: fake_policy_run(runs, n, seed=i) for i, n in enumerate(pol.POLICY_NAMES)}
    return runs, ckpts


def test_suite_actions_are_load_policy_actions_on_any_wider_obs(suite_runs):
    runs, ckpts = suite_runs
    assert pol.suite_env_overrides("stand", runs) == PD_PHASE
    # the DQN's env: 3 one-hot columns after the policy observation, which the suite must skip
    env = env_lib.make_env("mixed", n_tracks=1, detector_one_hot=True, **PD_PHASE)
    suite = pol.load_suite("stand", env, runs)
    assert suite.env_overrides == PD_PHASE
    assert [s.split(" ")[0] for s in suite.sources] == [str(ckpts[n]) for n in pol.POLICY_NAMES]
    obs = jax.random.normal(jax.random.PRNGKey(0), (5, env.observation_size))
    acts = np.asarray(pol.all_actions(suite.apply, suite.params, obs))
    assert acts.shape == (4, 5, 12)
    plain = env_lib.make_env("mixed", n_tracks=1, **PD_PHASE)
    assert plain.observation_size == env.policy_observation_size == env.observation_size - 3
    for i, n in enumerate(pol.POLICY_NAMES):
        act, _ = pol.load_policy(ckpts[n], plain)
        np.testing.assert_allclose(acts[i], act(obs[:, :plain.observation_size], None), atol=1e-6)
    assert not np.allclose(acts[0], acts[1])  # each policy its own parameters


def test_stand_in_is_named(tmp_path, monkeypatch):
    # only the fake walk run exists: the committed (real) artifact policies are out of sight
    monkeypatch.setattr(runs_lib, "COMMITTED_DIR", tmp_path / "committed")
    fake_policy_run(tmp_path, "walk")
    env = env_lib.make_env("mixed", n_tracks=1, **pol.suite_env_overrides("stand", tmp_path,
                                                                          stand_in="walk"))
    suite = pol.load_suite("stand", env, tmp_path, stand_in="walk")
    assert suite.sources[0].startswith(str(tmp_path / "walk_stand"))
    assert all(s.startswith(f"stand-in for {n}: {tmp_path / 'walk_stand'}")
               for n, s in zip(pol.POLICY_NAMES[1:], suite.sources[1:]))
    with pytest.raises(FileNotFoundError, match="jumps, gaps, stairs"):
        pol.suite_env_overrides("stand", tmp_path)


PD = {"action": "pd", "pd_offset": "gait", "phase_obs": True}  # not the defaults: differences show


def test_load_suite_rejects_policies_with_other_env_overrides(tmp_path):
    fake_policy_run(tmp_path, "walk", env=PD)
    jumps = fake_policy_run(tmp_path, "jumps", env={"action": "torque", "phase_obs": False})
    names = ("walk", "jumps")
    msg = (rf"{re.escape(str(jumps))} \(jumps\): env overrides .*'action': \('torque', 'pd'\).*"
           rf"'phase_obs': \(False, True\)")
    with pytest.raises(ValueError, match=msg):
        pol.suite_env_overrides("stand", tmp_path, names=names)
    env = env_lib.make_env("mixed", n_tracks=1, **PD)
    with pytest.raises(ValueError, match=msg):
        pol.load_suite("stand", env, tmp_path, names=names)


def test_load_suite_rejects_other_networks_and_envs_without_the_overrides(tmp_path):
    fake_policy_run(tmp_path, "walk", env=PD)
    gaps = fake_policy_run(tmp_path, "gaps", network={"policy_hidden": (16,)}, env=PD)
    env = env_lib.make_env("mixed", n_tracks=1, **PD)
    msg = rf"{re.escape(str(gaps))} \(gaps\): network config .*policy_hidden"
    with pytest.raises(ValueError, match=msg):
        pol.load_suite("stand", env, tmp_path, names=("walk", "gaps"))
    torque = env_lib.make_env("mixed", n_tracks=1, action="torque")
    with pytest.raises(ValueError, match=r"'action': \('torque', 'pd'\).*suite_env_overrides"):
        pol.load_suite("stand", torque, tmp_path, names=("walk",))


def test_runs_without_env_overrides_are_refused(tmp_path):
    """A config.json with no env section (a Brax PPO run, trained with torque actions and no phase
    clock) must not pass for one of today's defaults, which run_config would fill in."""
    ckpt = fake_policy_run(tmp_path, "walk")
    cfg_path = ckpt.parent.parent / "config.json"
    saved = json.loads(cfg_path.read_text())
    del saved["env"]
    cfg_path.write_text(json.dumps(saved))
    with pytest.raises(ValueError, match=r"no env section.*--policy walk --init stand"):
        pol.suite_env_overrides("stand", tmp_path, names=("walk",))

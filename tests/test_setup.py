"""The setup env's phase logic and reward (switching/setup.py) against hand-computed cases, the
setup tracks' layout, and PPO's learner mask on a stub env: pure functions, no physics."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from ml_collections import config_dict

from biped_switch.config import default_setup_config, default_terrain_config
from biped_switch.switching import setup as S


def _advance(phase, index, kind, dist, handover=0.45):
    return int(S.advance_phase(jnp.int32(phase), jnp.int32(index), jnp.int32(kind),
                               jnp.float32(dist), handover))


def test_phase_sequence_along_a_track():
    """The CoM walks along x on a [jumps, gaps] track: jumps 2.0..3.2 m, gaps 4.4..6.0 m.
    Detection (detect range 0.9 m): next artifact = first whose end is ahead; kind once its start
    is within 0.9 m. Hand-over at 0.45 m before the gap."""
    a0, a1, kinds = [2.0, 4.4], [3.2, 6.0], [0, 1]

    def detect(x):
        i = next((k for k in range(2) if a1[k] >= x), -1)
        dist = a0[i] - x if i >= 0 else np.inf
        return i, (kinds[i] if i >= 0 and dist <= 0.9 else -1), dist

    phase, seen = S.SOURCE, []
    for x in np.arange(0.0, 6.5, 0.05):
        i, k, d = detect(x)
        phase = _advance(phase, i, k, d)
        seen.append((round(float(x), 2), phase))
    first = {p: next(x for x, q in seen if q == p) for p in (S.SETUP, S.TARGET)}
    # on the jumps artifact (kind jumps within range) the phase stays SOURCE; past its end the
    # gap is 1.2 m away: still SOURCE until 4.4 - 0.9 = 3.5 m, SETUP until 4.4 - 0.45 = 3.95 m
    assert all(p == S.SOURCE for x, p in seen if x < 3.5 - 1e-6)
    assert first[S.SETUP] == pytest.approx(3.5, abs=0.051)
    assert first[S.TARGET] == pytest.approx(3.95, abs=0.051)
    assert all(p == S.TARGET for x, p in seen if x >= 3.96)  # never goes back, past the end too


def test_phase_jumps_both_transitions_in_one_step_and_ignores_the_source_artifact():
    # detected target already within the hand-over distance: SOURCE -> TARGET at once
    assert _advance(S.SOURCE, 1, 1, 0.3) == S.TARGET
    # the source's own artifact (index 0) detected: no setup
    assert _advance(S.SOURCE, 0, 0, 0.5) == S.SOURCE
    # target not yet in range (kind -1): stays
    assert _advance(S.SOURCE, 1, -1, 1.0) == S.SOURCE
    assert _advance(S.SETUP, 1, 1, 0.46) == S.SETUP
    assert _advance(S.SETUP, 1, 1, 0.45) == S.TARGET


def test_phase_reward_hand_computed():
    scfg = default_setup_config().setup
    scfg.success_bonus, scfg.fall_penalty, scfg.setup_reward_scale = 200.0, 150.0, 0.5
    cases = [  # phase, env reward, fell, success -> reward
        (S.SOURCE, 4.0, 0.0, 0.0, 0.0),
        (S.SOURCE, -6.0, 1.0, 0.0, 0.0),  # a source fall is not the learner's
        (S.SETUP, 4.0, 0.0, 0.0, 2.0),
        (S.SETUP, -6.0, 1.0, 0.0, -3.0 - 150.0),
        (S.TARGET, 4.0, 0.0, 0.0, 0.0),
        (S.TARGET, 4.0, 0.0, 1.0, 200.0),
        (S.TARGET, -6.0, 1.0, 0.0, -150.0),
    ]
    for phase, r, fell, succ, want in cases:
        got, terms = S.phase_reward(jnp.int32(phase), jnp.float32(r), fell, succ, scfg)
        assert float(got) == pytest.approx(want), (phase, r, fell, succ)
        assert float(sum(terms.values())) == pytest.approx(want)


def test_setup_track_layout():
    tcfg = default_terrain_config(2)
    t = S.setup_track(7, "jumps", "gaps", tcfg, (4, 5), (2, 3))
    (k0, s0, e0), (k1, s1, e1) = t.artifacts
    assert (k0, k1) == ("jumps", "gaps")
    assert s0 >= tcfg.runup_m + tcfg.flat_before_m - 1e-9
    assert s1 - e0 >= tcfg.flat_before_m - 1e-9
    n_src = t.artifact_segments[0, 1] - t.artifact_segments[0, 0] + 1
    n_tgt = t.artifact_segments[1, 1] - t.artifact_segments[1, 0] + 1
    assert 4 <= n_src <= 5 and 2 <= n_tgt <= 3
    # the same seed gives the same track
    assert np.array_equal(S.setup_track(7, "jumps", "gaps", tcfg, (4, 5), (2, 3)).segments, t.segments)


class _StubEnv:
    """One scalar 'position'; the learner's action moves it only where learner_acts is 1."""

    observation_size = policy_observation_size = 51 + 60 * 40 + 2
    action_size = 12
    cfg = config_dict.create(shape=config_dict.create(grid_forward=60, grid_lateral=40),
                             phase_obs=True, detector_one_hot=False)

    @property
    def obs_layout(self):
        from biped_switch.simulation.observation import layout
        return layout(self.cfg)

    def reset(self, rng, difficulty=None, guide_scale=None, push_scale=None):
        from brax.envs.base import State
        z = jnp.zeros((), jnp.float32)
        info = {"learner_acts": jnp.float32(0.0), "t": jnp.int32(0)}
        m = {"success": z, "fell": z, "distance_m": z, "progress_frac": z}
        return State(pipeline_state=z, obs=jnp.zeros(self.observation_size), reward=z, done=z,
                     metrics=m, info=info)

    def step(self, state, action):
        t = state.info["t"] + 1
        info = {"learner_acts": (t % 2).astype(jnp.float32), "t": t}
        r = jnp.where(state.info["learner_acts"] > 0, -jnp.sum(action ** 2), 1.0)
        return state.replace(reward=r.astype(jnp.float32), info=info)


def test_ppo_learner_mask_counts_learner_steps():
    from biped_switch.config import default_train_config
    from biped_switch.learning import ppo
    cfg = default_train_config("cpu")
    cfg.ppo.update(num_envs=4, unroll_length=8, num_minibatches=2, num_updates_per_batch=1)
    cfg.network.update(policy_hidden=(8,), value_hidden=(8,), hm_hidden=(8,))
    env = _StubEnv()
    tr = ppo.make_train(cfg, env)
    ts = tr.init(jax.random.PRNGKey(0))
    curr = jnp.asarray([1.0, 0.0, 0.0])
    envs = tr.reset_envs(jax.random.PRNGKey(1), curr)
    ts, envs, m = tr.iteration(ts, envs, jax.random.PRNGKey(2), curr)
    assert float(m["train/learner_frac"]) == pytest.approx(0.5)  # every other step
    assert np.isfinite(float(m["loss/policy"]))


def test_setup_report_tables_by_hand():
    """reports.setup: one table per target, no setup first, then the setup policy by step."""
    from biped_switch.reports.setup import setup_markdown

    cfg = {"target": "gaps", "source_segments": [4, 9], "target_segments": [4, 9]}
    base = {"episodes": 4, "tracks": "setup tracks 70000 + i", "handover_m": 0.45,
            "setup_config": cfg}
    cell = {"n": 2, "success_pct": 50.0, "ci95_pct": [9.5, 90.5]}
    docs = [{**base, "setup_policy": "runs/x/setup_gaps_stand_5/checkpoints/000000000005",
             "setup_policy_step": 2_500_000, "jumps->gaps": {**cell, "success_pct": 100.0}},
            {**base, "setup_policy": "source", "setup_policy_step": None, "jumps->gaps": cell}]
    md = setup_markdown(docs).splitlines()
    assert md[0] == "### Into gaps"
    assert md[4] == "| in the setup phase | jumps->gaps |"
    assert md[6] == "| no setup: the source walks on to the hand-over | 50.0% (9.5-90.5), n=2 |"
    assert md[7] == "| setup_gaps_stand at 2.50M env steps | 100.0% (9.5-90.5), n=2 |"

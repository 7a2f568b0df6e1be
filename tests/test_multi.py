"""The multi-policy switching rollout on the shared env: the shared episode loop against a plain
Python loop, the chunked early-stopping rollout agrees with the per-step trace (a plain scan),
switches happen where the rule says, and the Table II metrics on synthetic outcomes."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_switch.simulation import rollout as ro
from biped_switch import stats
from biped_switch.switching import rules as sw
from biped_switch.switching import when
from biped_switch.evaluation import multi as table2
from biped_switch.reports import table2 as table2_report

from conftest import B, TRACK_IDS

HORIZON = 260  # 0.5 s pause + 4.7 s of guided walking: reaches the first artifact


def _apply(p, obs):  # zero torque from every policy: the scripted guides walk the robot
    return jnp.zeros((obs.shape[0], 12)) * p


def _est(p, obs):  # a fake estimator: "confident" once the pelvis pitches forward by p rad
    return (obs[..., 48] > p).astype(jnp.float32)


PARAMS = jnp.arange(4, dtype=jnp.float32)
EST = jnp.asarray([0.0, 0.0, 0.0], jnp.float32)


@pytest.fixture(scope="module")
def multi_fn(env):
    return jax.jit(lambda rules, rng: sw.multi_rollout(
        env, _apply, PARAMS, _est, EST, rules, rng, B, HORIZON, track_ids=jnp.asarray(TRACK_IDS),
        chunk=40, guide_scale=1.0))


@pytest.fixture(scope="module")
def trace_fn(env):
    return jax.jit(lambda rules, rng, tid: sw.trace_rollout(
        env, _apply, PARAMS, _est, EST, rules, rng, tid, HORIZON, guide_scale=1.0))


# The shared loop against a plain Python loop: envs 0 and 1 unguided (they fall after the stand
# pause), 2 and 3 walked by the guides and ended by `record` at their 40th / 60th live step.
LOOP_GUIDES = np.array([0, 0, 1, 1], np.float32)
LOOP_TORQUE = np.array([0.0, 0.3, 0.0, 0.0], np.float32)
LOOP_END_AT = np.array([10**6, 10**6, 40, 60], np.int32)
LOOP_HORIZON, LOOP_CHUNK = 200, 16


def _loop_act(c, state, live, key):
    count, steps_run, total = c
    action = LOOP_TORQUE[:, None] + 0.05 * jax.random.normal(key, (state.obs.shape[0], 12))
    return action, (count + live.astype(jnp.int32), steps_run + 1, total), None


def _loop_record(c, _, state, nxt, live):
    count, steps_run, total = c
    return (count, steps_run, total + jnp.where(live, nxt.reward, 0.0)), count >= LOOP_END_AT


def test_episode_loop_matches_a_python_loop(env, fns, batch0):
    info = dict(batch0.info)
    info["guide_scale"] = jnp.asarray(LOOP_GUIDES)
    start = batch0.replace(info=info)
    rng = jax.random.PRNGKey(7)
    run = jax.jit(lambda s, rng: ro.run_episodes(
        env, s, LOOP_HORIZON, _loop_act, (jnp.zeros(B, jnp.int32), jnp.int32(0), jnp.zeros(B)),
        record=_loop_record, rng=rng, chunk=LOOP_CHUNK, freeze_state=True))
    ep = jax.device_get(run(start, rng))

    # reference: step the batch by hand; an episode ends at its first done (or its END_AT-th step)
    keys = jax.random.split(rng, LOOP_HORIZON)
    s, end_step = start, np.zeros(B, int)
    total, metrics, qpos = np.zeros(B), [None] * B, [None] * B
    for t in range(LOOP_HORIZON):
        a = LOOP_TORQUE[:, None] + 0.05 * jax.random.normal(keys[t], (B, 12))
        s = jax.device_get(fns["step"](s, jnp.asarray(a, jnp.float32)))
        for b in np.flatnonzero(end_step == 0):
            total[b] += s.reward[b]
            metrics[b] = {k: v[b] for k, v in s.metrics.items()}
            qpos[b] = s.pipeline_state.qpos[b]
            if s.done[b] > 0.5 or t + 1 >= LOOP_END_AT[b]:
                end_step[b] = t + 1
        if np.all(end_step > 0):
            break
    assert np.all(end_step > 0), end_step
    assert [metrics[b]["fell"] for b in range(B)] == [1.0, 1.0, 0.0, 0.0]  # falls and record ends
    np.testing.assert_array_equal(end_step[2:], LOOP_END_AT[2:])

    np.testing.assert_array_equal(ep.length, end_step)
    np.testing.assert_array_equal(ep.done, 1.0)
    np.testing.assert_array_equal(ep.carry[0], end_step)  # `act` saw live exactly while live
    # early stop: the loop ran whole chunks up to the one in which the last episode ended
    assert int(ep.carry[1]) == -(-end_step.max() // LOOP_CHUNK) * LOOP_CHUNK < LOOP_HORIZON
    np.testing.assert_allclose(ep.carry[2], total, rtol=1e-5, atol=1e-4)
    for k in ep.metrics:  # frozen at each episode's last live step
        np.testing.assert_allclose(ep.metrics[k], [metrics[b][k] for b in range(B)],
                                   rtol=1e-5, atol=1e-4, err_msg=k)
    np.testing.assert_allclose(ep.state.pipeline_state.qpos, np.stack(qpos), atol=1e-4)
    assert ep.trace is None


@pytest.mark.parametrize("method", ["detection", "com_over_feet"])
def test_chunked_rollout_matches_per_step_trace(multi_fn, trace_fn, method):
    rules = sw.make_rules(method)
    out = jax.device_get(multi_fn(rules, jax.random.PRNGKey(0)))
    for b in range(2):
        # the trace resets with rng[None] per env; give it the key multi_rollout gave env b
        k_reset, _ = jax.random.split(jax.random.PRNGKey(0))
        rec = jax.device_get(trace_fn(rules, jax.random.split(k_reset, B)[b], jnp.int32(TRACK_IDS[b])))
        live = rec["ended"] < 0.5
        assert int(out["n_switches"][b]) == int(rec["switched"][live].sum())
        # the logged switch distances, slot by slot (slots sorted by x, so in time order), are the
        # detector's distances at the traced switch steps
        ahead = out["switch_ahead_m"][b]
        np.testing.assert_allclose(ahead[~np.isnan(ahead)],
                                   rec["det_dist_m"][(rec["switched"] > 0) & live], atol=1e-5)
        # each switch's log: the policy it left (active the step before), its estimator output
        at = np.flatnonzero((rec["switched"] > 0) & live)
        logged = ~np.isnan(ahead)
        np.testing.assert_array_equal(out["switch_from"][b][logged], rec["active"][at - 1])
        np.testing.assert_allclose(out["switch_output"][b][logged],
                                   rec["est_probs"][at, rec["det_kind"][at]], atol=1e-6)
        np.testing.assert_array_equal(out["switch_forced"][b][logged], rec["det_dist_m"][at] <= 0.01)
        assert out["length"][b] == pytest.approx(live.sum())
        assert out["fell"][b] == pytest.approx(rec["fell"][live].max())
        if method == "detection":  # every switch at the first step that sees a new artifact
            kind = rec["det_kind"]
            first_seen = np.flatnonzero((kind >= 0) & (np.r_[-1, kind[:-1]] != kind))
            np.testing.assert_array_equal(np.flatnonzero(rec["switched"] & live),
                                          first_seen[first_seen < live.sum()])
            assert np.all(rec["active"][first_seen[first_seen < live.sum()]] ==
                          kind[first_seen[first_seen < live.sum()]] + 1)
        else:  # CoM over feet: at a step where it held, or forced within 1 cm
            for i in np.flatnonzero(rec["switched"] & live):
                assert rec["com_ok"][i] or rec["det_dist_m"][i] <= 0.01
    if method == "detection":
        assert out["n_switches"].sum() >= 2  # the guided robots came in sight of artifacts


def _from_half_a_metre(max_m, obs, active, kind, dist_m):
    """A rule model that reads the context (the learned rule's interface): +1 within max_m."""
    return jnp.where(dist_m <= max_m, 1.0, -1.0) + 0.0 * obs[:, 0] + 0.0 * active


def test_a_context_reading_rule_switches_where_the_lookup_does(env, multi_fn):
    """A model read after the detection, with the active policy and the distance (as the learned
    rule is), against the lookup rule at the same distance: the same switches, and its output
    logged at each."""
    rule = when.RuleFn(_from_half_a_metre)
    f = jax.jit(lambda rules, rng: sw.multi_rollout(
        env, _apply, PARAMS, rule, jnp.float32(0.5), rules, rng, B, HORIZON,
        track_ids=jnp.asarray(TRACK_IDS), chunk=40, guide_scale=1.0))
    cfg = sw.default_switching_config()
    cfg.estimator_threshold = 0.0
    a = jax.device_get(f(sw.make_rules("estimator", cfg=cfg), jax.random.PRNGKey(0)))
    b = jax.device_get(multi_fn(sw.make_rules("lookup", lookup_m=np.full((4, 3), 0.5)),
                                jax.random.PRNGKey(0)))
    np.testing.assert_array_equal(a["n_switches"], b["n_switches"])
    np.testing.assert_allclose(a["switch_ahead_m"], b["switch_ahead_m"], atol=1e-6)
    hit = ~np.isnan(a["switch_ahead_m"])
    assert hit.sum() >= 2 and np.all(a["switch_ahead_m"][hit] <= 0.5)
    np.testing.assert_array_equal(a["switch_output"][hit], 1.0)


def test_table2_metrics_on_synthetic_outcomes():
    # 10 trials: 6 succeed, 2 fall on gaps (code 1), 1 on stairs (2), 1 runs out of time
    res = {"progress_frac": np.array([1, 1, 1, 1, 1, 1, .2, .4, .5, .7]),
           "success": np.array([1, 1, 1, 1, 1, 1, 0, 0, 0, 0.]),
           "fell": np.array([0, 0, 0, 0, 0, 0, 1, 1, 1, 0.]),
           "fail_kind": np.array([-1, -1, -1, -1, -1, -1, 1, 1, 2, -1.])}
    row = stats.episode_table(res)
    assert row["distance_pct"] == pytest.approx(78.0)
    assert row["success_pct"] == pytest.approx(60.0)
    assert row["fail_on"] == pytest.approx({"jumps": 0.0, "gaps": 20.0, "stairs": 10.0})
    lo, hi = row["success_ci"]
    assert lo == pytest.approx(31.27, abs=0.01) and hi == pytest.approx(83.18, abs=0.01)  # Wilson
    row.update(method="estimator")
    md = table2_report.table2_markdown([row])
    # Wilson intervals by hand (den 1 + 1.96^2/10 = 1.3842): 2/10 -> centre 0.2833, half 0.2266;
    # 1/10 -> 0.2110, 0.1931; 0/10 -> 0.1388, 0.1388
    assert row["fail_ci"]["gaps"] == pytest.approx([5.67, 50.98], abs=0.01)
    assert row["fail_ci"]["stairs"] == pytest.approx([1.79, 40.42], abs=0.01)
    assert row["fail_ci"]["jumps"] == pytest.approx([0.0, 27.75], abs=0.01)
    assert "| estimator | 10 | 78.0" in md
    assert "| 60.0 (31.3-83.2) | 20.0 (5.7-51.0) | 0.0 (0.0-27.8) | 10.0 (1.8-40.4) |" in md
    assert "82.4 / 71.4" in md  # the paper's row beside ours


def test_baseline_rollout_compares_like_with_like(env, multi_fn):
    """The baselines' rollout (dqn.dqn_rollout, used for the DQN and, with a one-policy suite, the
    end-to-end policy) starts from the same states on the same tracks with the same horizon and
    end-of-episode protocol as the switching methods: with identical (zero-torque) policies under
    the guides, the physics, and so every outcome, must agree."""
    from biped_switch.learning import dqn
    from biped_switch.learning import dqn_train as dqn_train

    def q_first(_, x):  # table2.BaselineSetup's selector for the end-to-end policy
        return jnp.zeros(x.shape[:-1] + (1,))

    run = jax.jit(lambda rng: dqn_train.dqn_rollout(
        env, _apply, PARAMS[:1], q_first, jnp.zeros(()), rng, B, HORIZON,
        track_ids=jnp.asarray(TRACK_IDS), chunk=40, guide_scale=1.0))
    base = jax.device_get(run(jax.random.PRNGKey(0)))
    ref = jax.device_get(multi_fn(sw.make_rules("detection"), jax.random.PRNGKey(0)))
    np.testing.assert_array_equal(base["length"], ref["length"])
    for k in ("progress_frac", "distance_m", "fell", "success", "done"):
        np.testing.assert_allclose(base[k], ref[k], atol=1e-5, err_msg=k)
    assert np.all(base["n_switches"] == 0) and np.all(ref["length"] > 0)

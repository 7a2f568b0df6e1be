"""Table II's method records (biped_switch/methods.py) against what `evaluate multi` builds from
them, the learned rule as Table II runs it, the setup env's policy wiring and the phase clock."""

import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_switch import methods, names
from biped_switch.config import default_switching_config, default_when_config
from biped_switch.evaluation import multi, parts
from biped_switch.learning import runs as runs_lib
from biped_switch.simulation import env as env_lib
from biped_switch.simulation.model import MODELS_DIR
from biped_switch.switching import labels
from biped_switch.switching import rules as sw
from biped_switch.switching import setup as setup_lib
from biped_switch.switching import when

REPO = MODELS_DIR.parent
# Table II, typed in by hand from docs/switching.md: rule, suite, lookup, estimators, learned
# model, setup policies, persistence (None: the config's), threshold (None: the estimator's)
WANT = {
    "random": ("random", "stand", None, None, False, False, None),
    "detection": ("detection", "stand", None, None, False, False, None),
    "lookup": ("lookup", "stand", "sweep", None, False, False, None),
    "com_over_feet": ("com_over_feet", "stand", None, None, False, False, None),
    "estimator": ("estimator", "stand", None, "sweep", False, False, None),
    "estimator_no_overlap": ("estimator", "random", None, "sweep", False, False, None),
    "lookup_context": ("lookup", "stand", "context", None, False, False, None),
    "estimator_context": ("estimator", "stand", None, "context", False, False, 1),
    "estimator_context_persist": ("estimator", "stand", None, "context", False, False, 5),
    "lookup_context_setup": ("lookup", "stand", "context", None, False, True, None),
    "learned": ("estimator", "stand", None, None, True, False, None),
    "learned_no_overlap": ("estimator", "random", None, None, True, False, None),
    "learned_setup": ("estimator", "stand", None, None, True, True, None),
}


def test_records_are_table2():
    """One record per Table II row, in its order; the names' tuples are read off them; every
    rule is a switching rule; the persist run is a sweep sample's window."""
    assert names.MULTI_METHODS == tuple(m.name for m in methods.TABLE2)
    assert set(names.MULTI_METHODS) == set(WANT) | {"dqn", "end_to_end", "student"}
    assert names.BASELINES == ("dqn", "end_to_end", "student")
    # one-policy rows run the run <policy>_stand: the end-to-end policy and the distilled student
    assert [(m, methods.method(m).policy) for m in names.BASELINES] == [
        ("dqn", None), ("end_to_end", "mixed"), ("student", "student")]
    with pytest.raises(ValueError, match="has no switching rule"):
        methods.Method("x", "X", "ours", "red", rule="lookup", policy="student")
    assert names.RANDOM_INIT_METHODS == ("estimator_no_overlap", "learned_no_overlap")
    assert names.HEURISTICS == ("random", "detection", "lookup", "com_over_feet")
    assert set(names.LEARNED_METHODS) == {"learned", "learned_no_overlap", "learned_setup"}
    assert methods.RULES == sw.METHODS
    assert methods.WINDOW_STEPS == labels.N_WINDOW
    for name, (rule, suite, lookup, est, learned, setup, persist) in WANT.items():
        m = methods.method(name)
        assert (m.rule, m.suite, m.lookup, m.estimators, m.when, m.setup, m.persist_steps) == (
            rule, suite, lookup, est, learned, setup, persist), name
        assert m.suite in names.INITS and m.label and m.colour
    assert len({m.label for m in methods.TABLE2}) == len(methods.TABLE2)
    with pytest.raises(ValueError, match="unknown Table II method"):
        methods.method("estimator_sometimes")


def _cfg(**kw):
    return multi.MultiConfig(2, 2, 1.0, str(REPO / "no_runs"), est_dir=str(MODELS_DIR / "estimators"),
                             lookup_dir=str(REPO / "experiments" / "results" / "lookup"),
                             when_dir=str(MODELS_DIR / "switch_when"), **kw)


@pytest.fixture(scope="module")
def built():
    """What `evaluate multi` builds for every switching row of Table II with the committed parts
    (one set-up per rollout, as evaluate_multi makes them): {name: (setup, rules, est_params)}."""
    cfg = _cfg()
    ok, skipped = parts.available_methods(list(WANT), cfg.runs, cfg.est_dir, cfg.lookup_dir,
                                          when_dir=cfg.when_dir)
    assert not skipped, skipped  # the committed models have every row's parts
    recs = [methods.method(m) for m in ok]
    setups, out = {}, {}
    for rec in recs:
        if rec.rollout not in setups:
            setups[rec.rollout] = multi.make_setup(rec, recs, cfg)
        s = setups[rec.rollout]
        out[rec.name] = (s, *s.rules_for(rec.name))
    return out


def test_each_row_runs_its_rule_suite_and_parameters(built):
    """Table-driven: the rules, parts and suite `evaluate multi` builds for each row are the
    hand-typed Table II ones (a wrong persistence, lookup table, estimator set or suite fails)."""
    sc, wc = default_switching_config(), default_when_config()
    for name, (rule, suite, lookup, est, learned, setup, persist) in WANT.items():
        s, rules, est_params = built[name]
        assert int(rules.method) == sw.METHODS.index(rule), name
        assert s.init == suite and s.env.cfg.init == suite, name
        want_persist = (wc.persist_steps if learned else
                        persist if persist is not None else sc.estimator_persist_steps)
        assert int(rules.persist_steps) == want_persist, name
        want_thr = wc.margin if learned else sc.estimator_threshold
        assert float(rules.threshold) == pytest.approx(want_thr), name
        assert bool((np.asarray(rules.setup_of) >= 0).any()) == setup, name
        if lookup == "context":  # with setup policies, the walk-on pairs at their hand-over
            table = (sw.walk_on_lookup(s.context_lookup_m, s.walk_on, s.setup) if setup
                     else s.context_lookup_m)
            np.testing.assert_array_equal(np.asarray(rules.lookup_m)[:4], np.nan_to_num(
                np.asarray(table, np.float32)), name)
        if lookup == "sweep":
            np.testing.assert_array_equal(np.asarray(rules.lookup_m),
                                          np.nan_to_num(np.asarray(s.lookup_m, np.float32)))
        if est == "context":
            assert est_params is s.context_est_params, name
        if learned:
            assert isinstance(s.est_apply, when.RuleFn) and est_params is s.est_params, name
        elif est is not None:
            assert s.est_apply is not None and not isinstance(s.est_apply, when.RuleFn), name
    # the two context estimator rows differ only in their run length
    assert int(built["estimator_context_persist"][1].persist_steps) == labels.N_WINDOW
    assert int(built["estimator_context"][1].persist_steps) == 1


def test_learned_rule_as_table2_runs_it(built):
    """The learned row's output is P(now) minus the best later P on the grid (its advantage over
    later moments), computed here from the ensemble's probabilities, not P(now) itself."""
    s, rules, params = built["learned"]
    wc = default_when_config()
    lay = s.env.obs_layout
    rng = np.random.default_rng(0)
    n = 16
    start = s.env.reset(jax.random.PRNGKey(0), 1.0, jnp.int32(0), 0.0, 0.0).obs  # a real state
    obs = start + jnp.asarray(rng.normal(0, 0.01, (n, lay.size)), jnp.float32)
    active = jnp.asarray(rng.integers(0, 4, n), jnp.int32)
    kind = jnp.asarray(rng.integers(0, 3, n), jnp.int32)
    dist = jnp.asarray(rng.uniform(0.25, 0.9, n), jnp.float32)
    got = np.asarray(s.est_apply(params, obs, active, kind, dist))
    x = when.features(kind, active, dist, obs[:, lay.phase], obs[:, lay.state],
                      obs[:, lay.heightmap], lay.grid)
    grid = when.grid_m(wc)
    d_later = jnp.concatenate([dist[:, None], jnp.broadcast_to(grid, (n, len(grid)))], -1)
    g = np.asarray(when.prob(params, x, dist, d_later))
    want = []
    for i in range(n):
        later = grid <= float(dist[i]) - wc.min_gap_m
        want.append(g[i, 0] - g[i, 1:][later].max() if later.any() else 1.0)
    np.testing.assert_allclose(got, want, rtol=1e-3, atol=1e-12)
    assert not np.allclose(got, g[:, 0], rtol=1e-2, atol=0.0)  # not the chance of success now


def test_setup_env_hands_the_right_policy_the_controls():
    """SetupEnv's frozen actions: the source policy in SOURCE (and in SETUP when the source
    walks on), the learner's action in SETUP, the target policy in TARGET; each policy of the
    fake suite answers with its own index, so a swapped source and target shows."""
    base = env_lib.make_env("walk", "stand", n_tracks=2)
    n_pol = 4
    params = {"a": jnp.arange(n_pol, dtype=jnp.float32)}

    def apply(p, obs):
        return jnp.broadcast_to(p["a"], obs.shape[:-1] + (base.action_size,))

    senv = setup_lib.SetupEnv(base, apply, params, ("walk", "jumps", "gaps", "stairs"),
                              source_of_track=[1, 3], target=2, scfg=types.SimpleNamespace(
                                  handover_m=0.45))
    obs = jnp.zeros(base.observation_size)

    def act(track, phase, source_walks_on=False):
        senv.source_in_setup = source_walks_on
        state = types.SimpleNamespace(obs=obs, info={"track_id": jnp.int32(track),
                                                     "phase": jnp.int32(phase)})
        return float(senv.frozen_action(state)[0])

    assert act(0, setup_lib.SOURCE) == 1.0 and act(1, setup_lib.SOURCE) == 3.0
    assert act(0, setup_lib.TARGET) == 2.0 and act(1, setup_lib.TARGET) == 2.0
    assert act(1, setup_lib.SETUP, source_walks_on=True) == 3.0
    assert act(0, setup_lib.SETUP) == 2.0  # not acting: the learner's action is used in SETUP


def test_phase_clock_observation_by_hand():
    """The phase clock columns (obs_layout.phase) are sin, cos of 2 pi walk_t / period, walk_t the
    time since the standing pause (0 during it), hand-computed from the control step count."""
    env = env_lib.make_env("walk", "stand", n_tracks=1, phase_obs=True, backend="mujoco")
    lay = env.obs_layout
    assert lay.phase.stop - lay.phase.start == 2
    pause_s, period_s = env.cfg.pause_s, env.gait_cfg.period_s  # a stand start pauses
    reset = jax.jit(lambda k: env.reset(k, 1.0, jnp.int32(0), 0.0, 0.0))
    step = jax.jit(env.step)
    state = reset(jax.random.PRNGKey(0))
    zero = jnp.zeros(env.action_size)
    seen = []
    for k in range(int(round((pause_s + 0.3) / env.dt)) + 1):
        t = k * env.dt
        assert float(state.info["time_s"]) == pytest.approx(t, abs=1e-5)
        walk_t = max(t - pause_s, 0.0)
        want = [np.sin(2 * np.pi * walk_t / period_s), np.cos(2 * np.pi * walk_t / period_s)]
        np.testing.assert_allclose(np.asarray(state.obs[lay.phase]), want, atol=1e-5)
        seen.append(walk_t)
        state = step(state, zero)
    assert seen[0] == 0.0 and max(seen) > 0.25  # both the pause and the walk were checked

"""Switching rules on synthetic state traces, the support-polygon test against scipy, policy
selection, and the lookup-table argmax (pure functions; no environment)."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial import Delaunay

from biped_switch.learning import policies as pol
from biped_switch.switching import rules as sw
from biped_switch.reports import fig4b as fig4b
from biped_switch.switching import sweep
from biped_switch.switching import lookup


# ----------------------------------------------------------------------- support polygon
def _ref_in_hull(p, pts):
    if len(pts) < 3:
        return False
    try:
        return bool(Delaunay(pts).find_simplex(p) >= 0)
    except Exception:  # degenerate (collinear) point set: no area
        return False


def test_in_support_matches_scipy_on_random_feet():
    rng = np.random.default_rng(0)
    f = jax.jit(sw.in_support)
    agree = 0
    for _ in range(300):
        pts = rng.uniform(-0.2, 0.2, (8, 2))
        mask = rng.random(8) < 0.6
        p = rng.uniform(-0.25, 0.25, 2)
        got = bool(f(jnp.asarray(p), jnp.asarray(pts), jnp.asarray(mask), 0.0))
        assert got == _ref_in_hull(p, pts[mask]), (p, pts[mask])
        agree += got
    assert 30 < agree < 270  # both outcomes exercised


def test_in_support_hand_cases():
    sq = jnp.array([[0, 0], [0.2, 0], [0.2, 0.1], [0, 0.1]] * 2, jnp.float32)
    m4 = jnp.array([1, 1, 1, 1, 0, 0, 0, 0], bool)
    assert sw.in_support(jnp.array([0.1, 0.05]), sq, m4, 0.0)
    assert not sw.in_support(jnp.array([0.25, 0.05]), sq, m4, 0.0)
    assert sw.in_support(jnp.array([0.25, 0.05]), sq, m4, 0.06)  # 5 cm outside, 6 cm margin
    assert not sw.in_support(jnp.array([0.1, 0.05]), sq, jnp.zeros(8, bool), 0.5)  # airborne
    # two touching soles: a segment; the CoM 1 cm off it counts only with a margin
    m2 = jnp.array([1, 1, 0, 0, 0, 0, 0, 0], bool)
    assert not sw.in_support(jnp.array([0.1, 0.01]), sq, m2, 0.0)
    assert sw.in_support(jnp.array([0.1, 0.01]), sq, m2, 0.015)


def test_com_over_feet_needs_feet_together():
    left = np.array([[0.1, 0.1], [0.1, 0.05], [-0.1, 0.1], [-0.1, 0.05]])
    soles = np.concatenate([left, left - [0, 0.2]])
    soles3 = jnp.asarray(np.c_[soles, np.zeros(8)], jnp.float32)
    com = jnp.array([0.0, -0.05, 0.9])
    on = jnp.ones(8)
    assert sw.com_over_feet(com, soles3, on, 0.0, 0.1, 0.0)
    apart = soles3.at[4:, 0].add(0.3)  # right foot 0.3 m ahead
    assert not sw.com_over_feet(com, apart, on, 0.0, 0.1, 0.0)
    # heading 90 degrees: the 0.3 m x offset is now lateral, and "fore-aft" is y (0.2 m apart)
    assert not sw.com_over_feet(com, soles3, on, jnp.pi / 2, 0.1, 0.0)
    assert sw.com_over_feet(com, soles3, on, jnp.pi / 2, 0.25, 0.0)


# ----------------------------------------------------------------------- decisions on traces
def _run(method, dists, kinds, com_ok=None, est=None, lookup=None, active0=0, u01=0.5,
         persist=None, index=None, setup=None):
    """Feeds a synthetic approach (detections per step) through `decide`; returns switch steps.
    `index` (per step) names the detected artifact (default 0 while one is seen)."""
    rules = sw.make_rules(method, lookup_m=lookup, persist_steps=persist, setup=setup)
    ss = sw.SwitchState(jnp.int32(active0), jnp.int32(-1), jnp.float32(0), jnp.int32(0),
                        jnp.int32(0))
    n = len(dists)
    com_ok = np.zeros(n, bool) if com_ok is None else com_ok
    est = np.zeros((n, 3)) if est is None else est
    out, actives = [], []
    f = jax.jit(sw.decide)
    for t in range(n):
        idx = (0 if kinds[t] >= 0 else -1) if index is None else index[t]
        ss, s = f(ss, jnp.int32(kinds[t]), jnp.int32(idx),
                  jnp.float32(dists[t]), jnp.bool_(com_ok[t]), jnp.asarray(est[t], jnp.float32),
                  jnp.float32(u01), rules)
        if s:
            out.append(t)
        actives.append(int(ss.active))
    return out, actives, ss


# approach of a gap (code 1 -> policy 2): 1.2 m away, 2 cm per step, undetected beyond 0.9 m
DISTS = np.round(np.arange(1.2, -0.1, -0.02), 4)
KINDS = np.where(DISTS <= 0.9, 1, -1)
FIRST_SEEN = int(np.argmax(KINDS >= 0))


def test_detection_switches_at_first_sight():
    steps, actives, ss = _run("detection", DISTS, KINDS)
    assert steps == [FIRST_SEEN]
    assert actives[FIRST_SEEN - 1] == 0 and actives[FIRST_SEEN] == 2 and int(ss.n_switches) == 1


def test_random_switches_at_drawn_distance():
    steps, _, _ = _run("random", DISTS, KINDS, u01=0.5)  # 0.45 m
    assert DISTS[steps[0]] <= 0.45 < DISTS[steps[0] - 1]


def test_lookup_uses_active_target_entry():
    lookup = np.full((4, 3), 0.05)
    lookup[0, 1] = 0.3  # walk -> gaps at 0.30 m
    steps, _, _ = _run("lookup", DISTS, KINDS, lookup=lookup)
    assert DISTS[steps[0]] <= 0.3 < DISTS[steps[0] - 1]
    steps, _, _ = _run("lookup", DISTS, KINDS, lookup=lookup, active0=1)  # from jumps: 0.05 m
    assert DISTS[steps[0]] <= 0.05 < DISTS[steps[0] - 1]


def test_estimator_threshold_and_force_switch():
    est = np.zeros((len(DISTS), 3))
    at = FIRST_SEEN + 10
    est[at:, 1] = 0.9  # gap estimator confident from step `at`
    est[:, 0] = 0.99  # other estimators are ignored
    steps, _, _ = _run("estimator", DISTS, KINDS, est=est)
    assert steps == [at]
    est[at:, 1] = 0.84  # below 0.85: never fires, forced at 1 cm
    steps, _, _ = _run("estimator", DISTS, KINDS, est=est)
    assert len(steps) == 1 and DISTS[steps[0]] <= 0.01 < DISTS[steps[0] - 1]


def test_estimator_persistence_needs_a_run_of_confident_steps():
    est = np.zeros((len(DISTS), 3))
    a = FIRST_SEEN + 2
    est[[a, a + 1, a + 3, a + 4, a + 5, a + 6], 1] = 0.9  # runs of 2, then 4 steps
    est[:, 0] = 0.99  # other estimators are ignored
    assert _run("estimator", DISTS, KINDS, est=est)[0] == [a]  # the paper's rule: the first
    assert _run("estimator", DISTS, KINDS, est=est, persist=1)[0] == [a]
    assert _run("estimator", DISTS, KINDS, est=est, persist=2)[0] == [a + 1]
    assert _run("estimator", DISTS, KINDS, est=est, persist=3)[0] == [a + 5]  # the run of 2 broke
    steps = _run("estimator", DISTS, KINDS, est=est, persist=5)[0]  # no run of 5: forced at 1 cm
    assert len(steps) == 1 and DISTS[steps[0]] <= 0.01 < DISTS[steps[0] - 1]
    # confident steps before detection do not count; nor do those of the previous artifact
    pre = np.zeros((len(DISTS), 3))
    pre[FIRST_SEEN - 3: FIRST_SEEN + 1, 1] = 0.9
    steps = _run("estimator", DISTS, KINDS, est=pre, persist=2)[0]
    assert len(steps) == 1 and DISTS[steps[0]] <= 0.01
    index = np.where(np.arange(len(DISTS)) < FIRST_SEEN + 1, 0, 1)  # artifact 1 from then on
    kinds = np.where(np.arange(len(DISTS)) < FIRST_SEEN, -1, 1)
    est2 = np.zeros((len(DISTS), 3))
    est2[FIRST_SEEN: FIRST_SEEN + 3, 1] = 0.9
    steps, _, _ = _run("estimator", DISTS, kinds, est=est2, persist=3, active0=2, index=index)
    assert steps == []  # already on the gaps policy: nothing to switch
    steps, _, _ = _run("estimator", DISTS, kinds, est=est2, persist=3, index=index)
    assert DISTS[steps[0]] <= 0.01  # the run of 3 straddles the new artifact: it restarts
    with pytest.raises(ValueError, match="persist_steps"):
        sw.make_rules("estimator", persist_steps=0)


def test_com_over_feet_rule_and_force_switch():
    ok = np.zeros(len(DISTS), bool)
    ok[3] = True  # before detection: ignored
    ok[FIRST_SEEN + 7] = True
    steps, _, _ = _run("com_over_feet", DISTS, KINDS, com_ok=ok)
    assert steps == [FIRST_SEEN + 7]
    steps, _, _ = _run("com_over_feet", DISTS, KINDS, com_ok=np.zeros(len(DISTS), bool))
    assert DISTS[steps[0]] <= 0.01 < DISTS[steps[0] - 1]


def test_no_switch_when_already_on_target_policy():
    steps, _, _ = _run("detection", DISTS, KINDS, active0=2)
    assert steps == []


def test_new_artifact_gets_new_random_distance_and_switches_again():
    rules = sw.make_rules("random")
    ss = sw.SwitchState(jnp.int32(2), jnp.int32(0), jnp.float32(0.4), jnp.int32(1), jnp.int32(0))
    # next artifact (index 1, stairs) comes into view at 0.9 m with u = 0.1 -> switch at 0.09 m
    ss, s = sw.decide(ss, jnp.int32(2), jnp.int32(1), jnp.float32(0.9), False, jnp.zeros(3), 0.1, rules)
    assert not s and float(ss.random_m) == pytest.approx(0.09) and int(ss.art_index) == 1
    ss, s = sw.decide(ss, jnp.int32(2), jnp.int32(1), jnp.float32(0.08), False, jnp.zeros(3), 0.9, rules)
    assert s and int(ss.active) == 3 and float(ss.random_m) == pytest.approx(0.09)


# a suite of the four policies and one setup policy (index 4) for jumps/stairs -> gaps at 0.45 m
SETUP = sw.setup_slots(("walk", "jumps", "gaps", "stairs", "setup_gaps"),
                       {"setup_gaps": ("gaps", ("jumps", "stairs"), 0.45)})


def test_setup_slots_by_hand():
    want = np.full((5, 3), -1)
    want[1, 1] = want[3, 1] = 4  # jumps -> gaps and stairs -> gaps through setup_gaps
    np.testing.assert_array_equal(SETUP.setup_of, want)
    np.testing.assert_array_equal(np.isnan(SETUP.handover_m), [True, False, True])
    assert SETUP.handover_m[1] == np.float32(0.45)
    with pytest.raises(ValueError, match="1.2"):
        sw.setup_slots(("walk", "jumps", "gaps", "stairs", "setup_gaps"),
                       {"setup_gaps": ("gaps", ("jumps",), 1.2)})
    with pytest.raises(ValueError, match="'hop'"):
        sw.setup_slots(("walk", "jumps", "gaps", "stairs", "setup_gaps"),
                       {"setup_gaps": ("gaps", ("hop",), 0.45)})


@pytest.mark.parametrize("method", ["lookup", "detection", "estimator"])
def test_setup_policy_from_detection_to_hand_over(method):
    """From jumps: into setup_gaps at first sight (whatever the method), into gaps at 0.45 m."""
    lookup = np.full((4, 3), 0.2)
    steps, actives, _ = _run(method, DISTS, KINDS, lookup=lookup, active0=1, setup=SETUP)
    assert steps[0] == FIRST_SEEN and actives[FIRST_SEEN] == 4
    assert len(steps) == 2 and actives[steps[1]] == 2
    assert DISTS[steps[1]] <= 0.45 < DISTS[steps[1] - 1]


def test_setup_policy_only_for_its_sources():
    """From walk (no setup pair) the lookup rule alone decides; the same rules, no setup slots,
    give the same switches as before."""
    lookup = np.full((4, 3), 0.2)
    with_setup, _, _ = _run("lookup", DISTS, KINDS, lookup=lookup, active0=0, setup=SETUP)
    plain, _, _ = _run("lookup", DISTS, KINDS, lookup=lookup, active0=0)
    assert with_setup == plain and DISTS[plain[0]] <= 0.2 < DISTS[plain[0] - 1]


def test_setup_skipped_when_detected_inside_hand_over():
    """A late detection (0.3 m, inside the 0.45 m hand-over) goes straight to the target."""
    kinds = np.where(DISTS <= 0.3, 1, -1)
    steps, actives, _ = _run("detection", DISTS, kinds, active0=3, setup=SETUP)
    assert len(steps) == 1 and actives[steps[0]] == 2


def test_walk_on_pairs_keep_the_source_to_the_hand_over():
    """A walk-on pair (jumps -> stairs at 0.45 m) is a lookup entry: one switch, straight into
    stairs at 0.45 m whatever the table said; other sources keep the table's distance."""
    slots = sw.setup_slots(("walk", "jumps", "gaps", "stairs", "setup_gaps"),
                           {"setup_gaps": ("gaps", ("jumps", "stairs"), 0.45)})
    lookup = sw.walk_on_lookup(np.full((4, 3), 0.8), {"stairs": (("jumps",), 0.45)}, slots)
    assert lookup[1, 2] == np.float32(0.45) and lookup[2, 2] == np.float32(0.8)
    kinds = np.where(DISTS <= 0.9, 2, -1)  # stairs (code 2 -> policy 3)
    steps, actives, _ = _run("lookup", DISTS, kinds, lookup=lookup, active0=1, setup=slots)
    assert len(steps) == 1 and actives[steps[0]] == 3
    assert DISTS[steps[0]] <= 0.45 < DISTS[steps[0] - 1]
    steps, _, _ = _run("lookup", DISTS, kinds, lookup=lookup, active0=2, setup=slots)
    assert len(steps) == 1 and DISTS[steps[0]] <= 0.8 < DISTS[steps[0] - 1]
    with pytest.raises(ValueError, match="also has a setup policy"):
        sw.walk_on_lookup(np.zeros((4, 3)), {"gaps": (("jumps",), 0.45)}, slots)
    with pytest.raises(ValueError, match="1.2"):
        sw.walk_on_lookup(np.zeros((4, 3)), {"stairs": (("jumps",), 1.2)})


def test_make_rules_errors():
    with pytest.raises(ValueError, match="unknown switching method"):
        sw.make_rules("telepathy")
    with pytest.raises(ValueError, match="lookup table"):
        sw.make_rules("lookup")
    with pytest.raises(ValueError, match="must be"):
        sw.make_rules("lookup", lookup_m=np.zeros((3, 3)))


# ----------------------------------------------------------------------- policy suite selection
def test_all_actions_and_select():
    def apply(p, obs):
        return jnp.tanh(obs[:, :2] @ p["w"])

    params = pol.stack([{"w": jnp.full((2, 12), float(i))} for i in range(4)])
    obs = jnp.asarray(np.random.default_rng(1).normal(size=(5, 7)), jnp.float32)
    acts = pol.all_actions(apply, params, obs)
    assert acts.shape == (4, 5, 12)
    active = jnp.array([0, 3, 1, 2, 3])
    got = pol.select(acts, active)
    for b in range(5):
        np.testing.assert_allclose(got[b], apply({"w": jnp.full((2, 12), float(active[b]))},
                                                 obs[b:b + 1])[0], rtol=1e-6)


# ----------------------------------------------------------------------- lookup tables
def test_lookup_table_rates_and_argmax_by_hand():
    # walk -> gaps: 3 samples at 0.305 m (2 succeed), 2 at 0.601 m (both succeed), 1 at 0.0 (fail)
    dist = np.array([0.305, 0.305, 0.305, 0.601, 0.601, 0.0, 0.2, 0.2])
    label = np.array([1, 1, 0, 1, 1, 0, 1, 0])
    source = np.array([0, 0, 0, 0, 0, 0, 3, 3])  # stairs -> gaps: 1 of 2 at 0.2 m
    t = lookup.lookup_table(dist, label, source, "gaps")
    assert t["rate"].shape == (4, 90)
    assert t["rate"][0, 30] == pytest.approx(2 / 3) and t["count"][0, 30] == 3
    assert t["rate"][0, 60] == 1.0 and t["rate"][0, 0] == 0.0
    assert np.isnan(t["rate"][0, 45])  # no data in that bin
    assert t["best_m"][0] == pytest.approx(0.605)  # bin [0.60, 0.61)
    assert t["best_m"][3] == pytest.approx(0.205)
    assert np.isnan(t["best_m"][2])  # gaps -> gaps: not a switch
    assert np.isnan(t["best_m"][1])  # no data from jumps
    m = lookup.lookup_matrix({"gaps": t})
    assert m.shape == (4, 3) and m[0, 1] == pytest.approx(0.605) and np.isnan(m[0, 0])


def test_lookup_ties_go_to_the_earliest_switch():
    t = lookup.lookup_table(np.array([0.1, 0.5, 0.7]), np.array([1, 1, 1]), np.array([0, 0, 0]),
                           "jumps")
    assert t["best_m"][0] == pytest.approx(0.705)


def test_smoothed_success_pct_hand_values():
    # 3-bin windows: bin 0 sees bins 0-1 (2 successes of 4 points), bin 2 sees bins 1-2 (0 of 2)
    out = fig4b.smoothed_success_pct(np.array([1.0, 0.0, np.nan]), np.array([2.0, 2.0, 0.0]), 3)
    np.testing.assert_allclose(out, [50.0, 50.0, 0.0])
    far = fig4b.smoothed_success_pct(np.array([1.0, np.nan, np.nan, np.nan]), np.array([1.0, 0, 0, 0]), 3)
    assert far[1] == 100.0 and np.isnan(far[2]) and np.isnan(far[3])  # no point within a bin


def test_lookup_pairs_without_data_warn():
    """A NaN entry (no sweep data for that pair) would silently mean 'switch at 0 m': say so. The
    target's own policy (row k + 1, column k) never switches to itself, so its NaN is fine."""
    table = np.full((sw.N_POLICIES, sw.N_TARGETS), 0.3)
    table[np.arange(1, sw.N_POLICIES), np.arange(sw.N_TARGETS)] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rules = sw.make_rules("lookup", table)
    np.testing.assert_array_equal(np.asarray(rules.lookup_m)[1, 0], 0.0)
    table[0, 2] = np.nan  # walk -> stairs missing
    with pytest.warns(UserWarning, match=r"1 pair\(s\).*\(0, 2\)"):
        sw.make_rules("lookup", table)
    sw.make_rules("detection", table)  # other methods never read the table: no warning

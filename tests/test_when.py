"""The learned "when" rule: its decision against a Python loop, its input layout, its rows from a
sweep, the offline table and scores by hand, and that training finds what a table cannot see."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_switch import stats
from biped_switch.config import default_when_config
from biped_switch.simulation.observation import STATE_SIZE
from biped_switch.switching import detector, when

GRID = (60, 40)


def _first_fire(curve, d_path, grid, gap, margin):
    """Python loop: the first distance along a descending path where P(now) >= max P(later) +
    margin, for a state-free P = curve(d)."""
    for d in d_path:
        later = [curve(g) for g in grid if g <= d - gap]
        if not later or curve(d) - max(later) >= margin:
            return d
    return None


@pytest.mark.parametrize("margin", [0.0, -0.05])
def test_advantage_rule_is_the_lookup_when_the_state_says_nothing(margin):
    grid = when.grid_m()
    peak = 0.43

    def curve(d):  # success against switch distance, peaked at 0.43 m
        return 0.95 - 2.0 * (d - peak) ** 2

    d_path = np.round(np.arange(0.9, 0.0, -0.011), 4)
    adv = np.asarray(when.advantage(jnp.asarray([curve(d) for d in d_path]),
                                    jnp.asarray([[curve(g) for g in grid]] * len(d_path)),
                                    grid, jnp.asarray(d_path), 0.02))
    fired = d_path[np.argmax(adv >= margin)]
    assert fired == pytest.approx(_first_fire(curve, d_path, grid, 0.02, margin))
    if margin == 0.0:  # at the curve's maximum, within a grid step and the path's step
        assert abs(fired - peak) <= 0.025 + 0.011
    else:  # a negative margin fires earlier (farther), where the curve is within 0.05 of its top
        assert fired > peak and curve(fired) >= curve(peak) - 0.05 - 1e-6


def test_advantage_is_one_when_no_later_moment_is_left():
    grid = np.asarray([0.2, 0.3], np.float32)
    adv = when.advantage(jnp.asarray([0.1, 0.1]), jnp.asarray([[0.9, 0.9], [0.9, 0.9]]), grid,
                         jnp.asarray([0.21, 0.35]), 0.02)
    np.testing.assert_allclose(adv, [1.0, 0.1 - 0.9], atol=1e-6)


def test_features_lay_out_the_named_parts():
    rng = np.random.default_rng(0)
    state = rng.normal(size=(3, STATE_SIZE)).astype(np.float32)
    hm = rng.uniform(size=(3, GRID[0] * GRID[1])).astype(np.float32)
    phase = rng.normal(size=(3, 2)).astype(np.float32)
    x = np.asarray(when.features(np.array([0, 1, 2]), np.array([3, 0, 1]),
                                 np.array([0.4, 0.5, 0.6]), phase, state, hm, GRID))
    w = when.part_widths(GRID)
    assert list(w) == list(when.PARTS) and x.shape == (3, sum(w.values()))
    cut = np.cumsum([0] + list(w.values()))
    part = {k: x[:, cut[i]:cut[i + 1]] for i, k in enumerate(w)}
    np.testing.assert_array_equal(part["target"], np.eye(3))
    np.testing.assert_array_equal(part["active"], np.eye(4)[[3, 0, 1]])
    np.testing.assert_allclose(part["dist_m"][:, 0], [0.4, 0.5, 0.6])
    np.testing.assert_array_equal(part["phase"], phase)
    np.testing.assert_array_equal(part["state"], state)
    np.testing.assert_allclose(part["profile"], detector.profile(jnp.asarray(hm), GRID), atol=1e-6)


def _sweep_data(n_s=6, seed=0):
    """A context sweep's arrays: n_s switches of 5 rows, two approach records each."""
    rng = np.random.default_rng(seed)
    o = np.tile(np.arange(-2, 3, dtype=np.int8), n_s)
    dist = rng.uniform(0.3, 0.6, n_s).astype(np.float32)
    lab = (np.arange(n_s) % 2).astype(np.int8)
    src = (np.arange(n_s) % 3).astype(np.int8)
    return {"state": rng.normal(size=(5 * n_s, STATE_SIZE)).astype(np.float32),
            "heightmap": rng.uniform(size=(5 * n_s, 2400)).astype(np.float16),
            "phase": rng.normal(size=(5 * n_s, 2)).astype(np.float32), "offset": o,
            "label": np.repeat(lab, 5), "source": np.repeat(src, 5),
            "switch_dist_m": np.repeat(dist, 5), "track_id": np.repeat(np.arange(n_s), 5),
            "approach_state": rng.normal(size=(n_s, 2, STATE_SIZE)).astype(np.float32),
            "approach_heightmap": rng.uniform(size=(n_s, 2, 2400)).astype(np.float16),
            "approach_phase": rng.normal(size=(n_s, 2, 2)).astype(np.float32),
            "approach_dist_m": dist[:, None] + np.array([[0.1, 0.2]], np.float32),
            "approach_valid": np.array([[True, i != 0] for i in range(n_s)])}


def test_rows_from_sweep_pairs_each_state_with_its_switch():
    data = _sweep_data()
    lab0 = data["label"][2]
    r = when.rows_from_sweep(data, "gaps", GRID)
    assert r.now.sum() == 6 and (~r.now).sum() == 11  # one approach record was never reached
    np.testing.assert_array_equal(r.d_later[r.now], r.d_now[r.now])
    assert np.all(r.d_later[~r.now] < r.d_now[~r.now])
    # a wait row carries its switch's label and distance, and its own state
    np.testing.assert_allclose(r.d_now[6], data["approach_dist_m"][0, 0])
    assert r.label[6] == lab0 and r.d_later[6] == data["switch_dist_m"][2]  # sample 0's offset 0
    np.testing.assert_allclose(r.x[6, 8:10], data["approach_phase"][0, 0])  # after 3+4+1 columns
    np.testing.assert_allclose(r.x[0, 8:10], data["phase"][2])  # the switch step: offset 0
    assert np.all(r.target == 1)
    bad = {k: v for k, v in data.items() if k != "approach_state"}
    with pytest.raises(ValueError, match="approach_state"):
        when.rows_from_sweep(bad, "gaps", GRID)


def test_rows_from_sweep_counts_a_fall_while_waiting_as_a_failed_wait():
    """An episode that fell before its switch gives no switch row, but each approach record it
    reached is a wait that failed: label 0, switching at the intended distance."""
    data = _sweep_data()
    base = when.rows_from_sweep(data, "gaps", GRID)
    rng = np.random.default_rng(1)
    lost = {"lost_approach_state": rng.normal(size=(2, 2, STATE_SIZE)).astype(np.float32),
            "lost_approach_heightmap": rng.uniform(size=(2, 2, 2400)).astype(np.float16),
            "lost_approach_phase": rng.normal(size=(2, 2, 2)).astype(np.float32),
            "lost_approach_dist_m": np.array([[0.8, 0.7], [0.6, 0.5]], np.float32),
            "lost_approach_valid": np.array([[True, True], [False, True]]),
            "lost_source": np.array([1, 3], np.int8), "lost_track_id": np.array([7, 9], np.int32),
            "lost_switch_at_m": np.array([0.35, 0.4], np.float32)}
    r = when.rows_from_sweep({**data, **lost}, "gaps", GRID)
    n = len(base.label)
    assert len(r.label) == n + 3 and not r.now[n:].any() and (r.label[n:] == 0).all()
    np.testing.assert_allclose(r.d_now[n:], [0.8, 0.7, 0.5])
    np.testing.assert_allclose(r.d_later[n:], [0.35, 0.35, 0.4])
    assert r.source[n:].tolist() == [1, 1, 3] and r.track[n:].tolist() == [7, 7, 9]
    np.testing.assert_allclose(r.x[n + 2, 8:10], lost["lost_approach_phase"][1, 1])
    np.testing.assert_array_equal(r.x[:n], base.x)  # the rows before are unchanged


def test_table_predict_by_hand():
    def rows(target, source, d, y, now=True):
        n = len(d)
        return when.Rows(np.zeros((n, 1)), np.asarray(d, np.float32), np.asarray(d, np.float32),
                         np.asarray(y, np.float32), np.zeros(n, int), np.full(n, now),
                         np.full(n, source), np.full(n, target))

    tr = when.concat_rows([rows(1, 2, [0.41, 0.42, 0.44], [1, 1, 0]),
                           rows(1, 2, [0.52], [1]), rows(1, 2, [0.43], [0], now=False)])
    va = rows(1, 2, [0.40, 0.53, 0.90], [1, 1, 1])
    # bin 0.40-0.45: 2 of 3 -> (2 + 1) / (3 + 2); bin 0.50-0.55: (1 + 1) / (1 + 2); no bin: the
    # training switches' mean (3 of 4); the wait row never counts
    np.testing.assert_allclose(when.table_predict(tr, va), [3 / 5, 2 / 3, 3 / 4])


def test_brier_and_calibration_error_by_hand():
    p, y = np.array([0.05, 0.15, 0.95, 0.95]), np.array([0, 1, 1, 0])
    assert stats.brier(p, y) == pytest.approx((0.05**2 + 0.85**2 + 0.05**2 + 0.95**2) / 4)
    # bins: [0, 0.1) mean 0.05 freq 0; [0.1, 0.2) 0.15 vs 1; [0.9, 1] 0.95 vs 0.5
    assert stats.ece(p, y) == pytest.approx((0.05 + 0.85 + 2 * 0.45) / 4)
    rel = stats.reliability(p, y)
    assert rel["count"].tolist() == [1, 1, 0, 0, 0, 0, 0, 0, 0, 2]


def test_temperature_fit_recovers_a_known_one():
    rng = np.random.default_rng(0)
    z = rng.normal(0, 3, 20000)
    y = rng.uniform(size=z.size) < 1 / (1 + np.exp(-z / 2.0))  # true logits are z / 2
    assert when.fit_temperature(z, y) == pytest.approx(2.0, rel=0.1)


def test_training_sees_what_the_table_cannot():
    """Success depends on the phase clock, not on the distance: the table is at chance, the
    trained rule is not, and it is calibrated on the held-out tracks."""
    rng = np.random.default_rng(1)
    n = 3000
    phase = rng.uniform(-1, 1, (n, 2)).astype(np.float32)
    p_true = np.where(phase[:, 0] > 0, 0.95, 0.4)
    y = (rng.uniform(size=n) < p_true).astype(np.float32)
    d = rng.uniform(0.3, 0.9, n).astype(np.float32)
    x = np.asarray(when.features(np.ones(n, int), np.ones(n, int), d, phase,
                                 np.zeros((n, STATE_SIZE), np.float32),
                                 np.zeros((n, 2400), np.float32), GRID))
    rows = when.Rows(x, d, d, y, np.arange(n) % 100, np.ones(n, bool), np.ones(n, np.int32),
                     np.ones(n, np.int32))
    cfg = default_when_config()
    cfg.epochs, cfg.ensemble, cfg.patience, cfg.trunk_hidden, cfg.head_hidden = 100, 2, 15, (32,), (16,)
    cfg.batch_size = 128
    params, metrics = when.train(rows, cfg, print_fn=lambda *a: None)
    val = when.is_val(rows.track, cfg)
    tr, va = when.take(rows, ~val), when.take(rows, val)
    p = when.predict_rows(params, va)
    from biped_switch.switching.estimator import roc_auc
    assert roc_auc(p, va.label) > 0.7 > roc_auc(when.table_predict(tr, va), va.label)
    assert stats.ece(p, va.label) < 0.08
    assert metrics["val_tracks"] == 20 and not np.intersect1d(tr.track, va.track).size


def test_tune_tries_each_margin_then_run_lengths_at_the_best(tmp_path, monkeypatch):
    """`when --tune` with a fake Table II setup whose success peaks at margin -0.02 and run
    length 2: every margin is tried at run length 1, then the run lengths at the best margin; the
    choice and the table name them, on the tuning tracks."""
    from biped_switch import when as when_cli
    from biped_switch.config import TUNE_TRACK_SEED
    from biped_switch.evaluation import multi

    made = []

    class FakeSetup:
        def __init__(self, methods, cfg):
            made.append((tuple(methods), cfg.trials, cfg.track_seed, cfg.when_dir))

        def evaluate(self, method, trials, seed, print_fn=None, margin=None, persist_steps=None):
            p = 0.8 - abs(margin + 0.02) - 0.05 * abs(persist_steps - 2)
            succ = np.arange(trials) < round(p * trials)
            return {"success": succ, "fell": ~succ, "progress_frac": succ * 1.0,
                    "fail_kind": np.where(succ, -1, 1)}

    monkeypatch.setattr(multi, "MultiSetup", FakeSetup)
    out = tmp_path / "res"
    assert when_cli.main(["--tune", "--trials", "100", "--persist", "2", "3", "--later", "model",
                          "--results", str(out), "--out", "models/switch_when"]) == 0
    assert made == [(("learned",), 100, TUNE_TRACK_SEED, "models/switch_when")]
    doc = __import__("json").loads((out / "tuning.json").read_text())
    tried = [(r["margin"], r["persist_steps"]) for r in doc["rows"]]
    margins = list(default_when_config().margin_choices)
    assert -0.02 in margins
    assert tried == [(m, 1) for m in margins] + [(-0.02, 2), (-0.02, 3)]
    assert all(r["band_tol"] == 1.0 for r in doc["rows"])
    assert doc["chosen"] == {"later_from": "model", "band_tol": 1.0, "margin": -0.02,
                             "persist_steps": 2}
    assert "| model | 1 | -0.02 | 2 | 80.0 (" in (out / "tuning.md").read_text()


def test_prior_table_by_hand_and_between_bins():
    """(k + 1) / (n + 2) per (target, source, 5 cm bin) of every row's switch distance, read
    linearly between the bins' centres."""
    d = np.array([0.41, 0.42, 0.44, 0.47, 0.43], np.float32)
    y = np.array([1, 1, 0, 1, 1], np.float32)
    rows = when.Rows(np.zeros((5, 1)), d, d, y, np.zeros(5, int), np.array([1, 1, 1, 1, 0], bool),
                     np.full(5, 3), np.full(5, 1))
    prior = when.fit_prior(rows)
    rate = 1 / (1 + np.exp(-prior["prior"][1, 3]))
    assert rate[8] == pytest.approx((3 + 1) / (4 + 2))  # bin 0.40-0.45: 3 of 4 (wait row too)
    assert rate[9] == pytest.approx(2 / 3) and rate[0] == pytest.approx(0.5)  # 0.45-0.50; empty
    x = np.zeros((1, 7), np.float32)
    x[0, 1], x[0, 3 + 3] = 1, 1  # target gaps, source stairs
    got = np.asarray(when.prior_logit(prior, jnp.asarray(x), jnp.asarray([[0.425, 0.45, 0.4625]])))
    lg = prior["prior"][1, 3]
    np.testing.assert_allclose(got[0], [lg[8], (lg[8] + lg[9]) / 2, 0.75 * lg[8] + 0.25 * lg[9]],
                               rtol=1e-5)


def test_an_untrained_model_is_its_prior_and_the_rule_is_the_tables():
    """The network's last layer starts at zero: G is the prior table, and along an approach the
    rule fires at the table's best bin (what lookup_context does), from "model" or "table"."""
    rng = np.random.default_rng(0)
    n = 4000
    d = rng.uniform(0.2, 0.9, n).astype(np.float32)
    y = (rng.uniform(size=n) < 0.95 - 2.0 * (d - 0.43) ** 2).astype(np.float32)
    x = np.asarray(when.features(np.ones(n, int), np.ones(n, int), d, np.zeros((n, 2)),
                                 np.zeros((n, STATE_SIZE)), np.zeros((n, 2400)), GRID))
    rows = when.Rows(x, d, d, y, np.arange(n) % 50, np.ones(n, bool), np.ones(n, np.int32),
                     np.ones(n, np.int32))
    cfg = default_when_config()
    prior = when.fit_prior(rows, cfg)
    net = when.WhenNet((8,), (8,)).init(jax.random.PRNGKey(0), jnp.zeros((1, x.shape[1])),
                                        jnp.zeros(1), jnp.zeros((1, 1)))
    params = {"net": jax.tree.map(lambda a: a[None], net), "mean": np.zeros(x.shape[1], np.float32),
              "std": np.ones(x.shape[1], np.float32), "temp": np.asarray(1.0, np.float32), **prior}
    path = np.round(np.arange(0.9, 0.2, -0.011), 4).astype(np.float32)
    xs = np.repeat(x[:1], len(path), 0)
    xs[:, 7] = path  # the distance column
    grid = when.grid_m(cfg)
    best_bin = (np.argmax(prior["prior"][1, 1]) + 0.5) * cfg.prior_bin_m
    for later_from in ("model", "table"):
        sc, p_now = when.score(params, jnp.asarray(xs), jnp.asarray(path), grid, 0.02, later_from)
        np.testing.assert_allclose(p_now, jax.nn.sigmoid(when.prior_logit(
            prior, jnp.asarray(xs), jnp.asarray(path)[:, None])[:, 0]), atol=1e-6)
        fired = path[np.argmax(np.asarray(sc) >= 0)]
        assert abs(fired - best_bin) <= 0.025 + 0.011, (later_from, fired, best_bin)


def test_band_waits_before_it_picks_inside_it_and_fires_at_its_end():
    """With a band, a state-free rule fires at the table's best bin as before; a P(now) that is
    high everywhere fires at the band's first moment, not before it; one that is low everywhere
    fires at the band's last moment, not at the grid's end."""
    cfg = default_when_config()
    grid = when.grid_m(cfg)
    nb = int(round(cfg.grid_m[1] / cfg.prior_bin_m))
    centres = (np.arange(nb) + 0.5) * cfg.prior_bin_m
    rate = np.clip(0.95 - 2.0 * (centres - 0.43) ** 2, 0.05, 0.95)
    prior = {"prior": np.broadcast_to(np.log(rate / (1 - rate)), (3, 4, nb)).astype(np.float32),
             "prior_lo_m": np.asarray(0.0, np.float32),
             "prior_bin_m": np.asarray(cfg.prior_bin_m, np.float32)}
    x = np.zeros((1, 7), np.float32)
    x[0, 1] = x[0, 3 + 1] = 1
    path = np.round(np.arange(0.9, 0.2, -0.011), 4).astype(np.float32)
    table = lambda d: np.asarray(jax.nn.sigmoid(when.prior_logit(  # noqa: E731
        prior, jnp.asarray(np.repeat(x, len(d), 0)), jnp.asarray(d)[:, None])[:, 0]))
    t_grid = table(grid)
    band = grid[t_grid >= t_grid.max() - 0.05]

    def first_fire(p_now):
        import biped_switch.switching.when as w
        orig = w.prob
        try:  # P(now) given; the later moments from the table (later_from="table")
            w.prob = lambda params, x, dn, dl: jnp.broadcast_to(jnp.asarray(p_now)[:, None],
                                                                dl.shape)
            sc, _ = w.score(prior, jnp.asarray(np.repeat(x, len(path), 0)), jnp.asarray(path),
                            grid, 0.02, "table", 0.05)
        finally:
            w.prob = orig
        return path[np.argmax(np.asarray(sc) >= 0)]

    assert abs(first_fire(table(path)) - 0.43) <= 0.025 + 0.011  # state-free: the table's best
    high = first_fire(np.full(len(path), 0.99))
    assert band.max() - 0.011 <= high <= band.max() + 0.011 + 0.025  # enters the band: fires
    low = first_fire(np.full(len(path), 0.01))
    assert band.min() - 0.011 <= low <= band.min() + 0.02 + 0.011  # the band's last moment


def test_best_bin_counts_falls_before_the_switch_against_their_bin():
    from biped_switch.reports import when as when_report

    dist = np.array([0.21, 0.22, 0.23, 0.31, 0.32, 0.33, 0.34])
    label = np.array([1, 1, 0, 1, 1, 1, 1])
    # bin 0.2-0.25: 2 of 3; bin 0.3-0.35: 4 of 4, but two falls before a switch meant there: 4 of 6
    assert when_report.best_bin(dist, label, np.zeros(0), 0.05, (0.2, 0.4), 3) == (0.3, 4, 4)
    assert when_report.best_bin(dist, label, np.array([0.31, 0.33]), 0.05, (0.2, 0.4), 3) == (
        0.2, 2, 3)
    assert when_report.best_bin(dist, label, np.zeros(0), 0.05, (0.2, 0.4), 5) is None


def test_implied_success_by_hand():
    from biped_switch.reports import when as when_report

    rate = {("gaps", "start"): 0.9, ("jumps", "gaps"): 0.5, ("gaps", "jumps"): 0.8}
    seqs = [[("gaps", "start"), ("jumps", "gaps")], [("gaps", "start"), ("jumps", "gaps"),
                                                    ("gaps", "jumps")]]
    assert when_report.implied_success(seqs, rate) == pytest.approx((0.45 + 0.36) / 2)
    assert when_report.implied_success([[("stairs", "start")]], rate) is None


def test_phase_spread_by_hand():
    from biped_switch.reports import when as when_report

    ang = np.array([-3.0, -2.9, -1.0, -0.9, 0.5, 0.6, 2.0, 2.1])  # two switches per quarter
    phase = np.stack([np.sin(ang), np.cos(ang)], 1)
    lo, hi, n_min, p = when_report.phase_spread(phase, np.array([1, 1, 1, 0, 0, 0, 1, 1]), 4)
    assert (lo, hi, n_min) == (0.0, 100.0, 2) and 0 < p < 1
    assert when_report.phase_spread(phase, np.ones(8), 4)[3] == 1.0  # no failure: nothing to test
    assert when_report.phase_spread(phase[:2], np.ones(2), 4) is None  # empty sectors


def test_bin_counts_against_a_python_loop():
    rng = np.random.default_rng(3)
    d = rng.uniform(-0.1, 1.0, 500).astype(np.float32)
    y = rng.integers(0, 2, 500)
    g = rng.integers(0, 3, 500)
    k, n = stats.bin_counts(d, y, g, 3, 0.05, 18)
    k_ref, n_ref = np.zeros((3, 18)), np.zeros((3, 18), int)
    for di, yi, gi in zip(d, y, g):  # below the first bin or past the last: clipped into them
        b = min(max(int(np.floor(di / np.float32(0.05))), 0), 17)
        k_ref[gi, b] += yi
        n_ref[gi, b] += 1
    np.testing.assert_array_equal(k, k_ref)
    np.testing.assert_array_equal(n, n_ref)

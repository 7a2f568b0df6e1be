"""Switching on a line-up other than the paper's (lineups.LINEUP["stones"], Table II-4): the rules
sized by the line-up and stepped by hand, the failure breakdown per target by hand, which rows a
line-up can have, the set-ups `evaluate multi` builds for it, and the command itself (faked
rollouts, and one short real run on mixed4 tracks with the committed policies)."""

from __future__ import annotations

import json
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_switch import config, kinds, lineups, stats
from biped_switch import evaluate as ev
from biped_switch.evaluation import multi, parts
from biped_switch.learning import runs as runs_lib
from biped_switch.methods import method as method_record
from biped_switch.names import MULTI_METHODS
from biped_switch.products import tables
from biped_switch.simulation.model import MODELS_DIR
from biped_switch.switching import rules as sw

STONES, PAPER = lineups.LINEUP["stones"], lineups.PAPER_LINEUP
REPO = MODELS_DIR.parent
# the rows the stones line-up can run: the heuristics, its context lookup (with or without the
# paper's setup policies) and the baselines as they are; the rest read a paper-only part
STONES_ROWS = ["random", "detection", "com_over_feet", "dqn", "end_to_end", "lookup_context",
               "lookup_context_setup", "student"]


# ----------------------------------------------------------------------- the rules, by hand
def test_rules_are_sized_by_the_lineup():
    """A wrong size (the paper's constants on a 5-policy suite) would mis-index every target."""
    paper, stones = sw.make_rules("detection"), sw.make_rules("detection", lineup=STONES)
    assert (paper.lookup_m.shape, paper.setup_of.shape, paper.handover_m.shape) == ((4, 3), (4, 3), (3,))
    assert (stones.lookup_m.shape, stones.setup_of.shape, stones.handover_m.shape) == ((5, 4), (5, 4), (4,))
    np.testing.assert_array_equal(paper.policy_of_code, [1, 2, 3])  # jumps, gaps, stairs
    np.testing.assert_array_equal(stones.policy_of_code, [1, 2, 3, 4])  # ... and stones
    assert (int(paper.walk_policy), int(paper.n_policies)) == (0, 4)
    assert (int(stones.walk_policy), int(stones.n_policies)) == (0, 5)
    slots = sw.setup_slots(STONES.policies + ("setup_gaps",),
                           {"setup_gaps": ("gaps", ("jumps", "stairs"), 0.45)}, lineup=STONES)
    r = sw.make_rules("lookup", np.full((5, 4), 0.3), setup=slots, lineup=STONES)
    assert r.lookup_m.shape == (6, 4) and r.setup_of.shape == (6, 4)
    assert int(r.setup_of[1, 1]) == int(r.setup_of[3, 1]) == 5 and int((r.setup_of >= 0).sum()) == 2


DISTS = np.round(np.arange(1.2, -0.1, -0.02), 4)  # an approach, 2 cm per step, seen within 0.9 m
FIRST_SEEN = int(np.argmax(DISTS <= 0.9))


def _run(method, code, lineup, active0=0, lookup=None, est=None, setup=None):
    """`decide` stepped over one approach of an artifact of `code`: (switch steps, actives)."""
    rules = sw.make_rules(method, lookup_m=lookup, setup=setup, lineup=lineup)
    ss = sw.SwitchState(jnp.int32(active0), jnp.int32(-1), jnp.float32(0), jnp.int32(0), jnp.int32(0))
    est = np.zeros((len(DISTS), lineup.n_targets)) if est is None else est
    f, steps, actives = jax.jit(sw.decide), [], []
    for t, d in enumerate(DISTS):
        seen = d <= 0.9
        ss, s = f(ss, jnp.int32(code if seen else -1), jnp.int32(0 if seen else -1), jnp.float32(d),
                  jnp.bool_(False), jnp.asarray(est[t], jnp.float32), jnp.float32(0.5), rules)
        steps += [t] if s else []
        actives.append(int(ss.active))
    return steps, actives


def test_a_stones_artifact_targets_the_stones_policy_and_walk_in_the_paper_lineup():
    # stones line-up: at first sight into slot 4 (the stones policy)
    steps, actives = _run("detection", 3, STONES)
    assert steps == [FIRST_SEEN] and actives[FIRST_SEEN] == 4
    # the paper's line-up has no target for code 3: its walk policy takes over (from jumps), and
    # walk already acting does not switch
    steps, actives = _run("detection", 3, PAPER, active0=1)
    assert steps == [FIRST_SEEN] and actives[-1] == 0
    assert _run("detection", 3, PAPER)[0] == []
    # from the stones policy (slot 4: a behaviour policy here, not a setup policy as slot 4 is in
    # the paper's setup suites) the detection rule switches into gaps at first sight
    steps, actives = _run("detection", 1, STONES, active0=4)
    assert steps == [FIRST_SEEN] and actives[-1] == 2


def test_lookup_and_estimator_read_the_stones_column():
    """The lookup reads (active, stones); the estimator the stones output. A code clamped onto
    the stairs column (0.7 m, 0.99) would switch at once."""
    table = np.full((5, 4), 0.7)
    table[0, 3], table[2, 3] = 0.3, 0.1  # walk -> stones at 0.3 m, gaps -> stones at 0.1 m
    steps, actives = _run("lookup", 3, STONES, lookup=table)
    assert DISTS[steps[0]] <= 0.3 < DISTS[steps[0] - 1] and actives[-1] == 4
    steps, _ = _run("lookup", 3, STONES, active0=2, lookup=table)
    assert DISTS[steps[0]] <= 0.1 < DISTS[steps[0] - 1]
    est = np.zeros((len(DISTS), 4))
    est[:, 2] = 0.99  # the stairs estimator: ignored
    est[FIRST_SEEN + 10:, 3] = 0.9  # the stones estimator confident from here on
    assert _run("estimator", 3, STONES, est=est)[0] == [FIRST_SEEN + 10]
    # the paper's line-up has no entry and no estimate for code 3: forced at 1 cm, into walk
    for method, kw in (("lookup", {"lookup": np.full((4, 3), 0.7)}),
                       ("estimator", {"est": np.full((len(DISTS), 3), 0.99)})):
        steps, actives = _run(method, 3, PAPER, active0=1, **kw)
        assert len(steps) == 1 and DISTS[steps[0]] <= 0.01 < DISTS[steps[0] - 1], method
        assert actives[-1] == 0


def test_a_paper_setup_policy_inside_the_stones_lineup():
    """setup_gaps at suite index 5 (after the five behaviours), here also from stones: into it at
    first sight, into gaps at its 0.45 m hand-over."""
    slots = sw.setup_slots(STONES.policies + ("setup_gaps",),
                           {"setup_gaps": ("gaps", ("jumps", "stones"), 0.45)}, lineup=STONES)
    want = np.full((6, 4), -1)
    want[1, 1] = want[4, 1] = 5
    np.testing.assert_array_equal(slots.setup_of, want)
    np.testing.assert_array_equal(np.isnan(slots.handover_m), [True, False, True, True])
    steps, actives = _run("lookup", 1, STONES, active0=4, lookup=np.full((5, 4), 0.2), setup=slots)
    assert steps[0] == FIRST_SEEN and actives[FIRST_SEEN] == 5
    assert len(steps) == 2 and actives[-1] == 2 and DISTS[steps[1]] <= 0.45 < DISTS[steps[1] - 1]


def test_lineup_errors_name_the_lineup_and_the_bad_value():
    with pytest.raises(ValueError, match=r"source 'stones' is not one of line-up paper's"):
        sw.setup_slots(PAPER.policies + ("setup_gaps",),
                       {"setup_gaps": ("gaps", ("stones",), 0.45)})
    with pytest.raises(ValueError, match=r"target 'stones' is not one of line-up paper's"):
        sw.setup_slots(PAPER.policies + ("setup_gaps",),
                       {"setup_gaps": ("stones", ("walk",), 0.45)})
    with pytest.raises(ValueError, match="line-up stones with setup policies starts with"):
        sw.setup_slots(PAPER.policies + ("setup_gaps",), {}, lineup=STONES)
    with pytest.raises(ValueError, match=r"must be \(5, 4\) \(line-up stones"):
        sw.make_rules("lookup", np.zeros((4, 3)), lineup=STONES)
    paper_slots = sw.setup_slots(PAPER.policies + ("setup_gaps",),
                                 {"setup_gaps": ("gaps", ("jumps",), 0.45)})
    with pytest.raises(ValueError, match="do not fit line-up stones"):
        sw.make_rules("detection", setup=paper_slots, lineup=STONES)
    with pytest.raises(ValueError, match=r"line-up stones must be \(5, 4\)"):
        sw.walk_on_lookup(np.zeros((4, 3)), {}, lineup=STONES)
    out = sw.walk_on_lookup(np.full((5, 4), 0.8), {"stairs": (("jumps", "stones"), 0.45)},
                            lineup=STONES)
    assert out[1, 2] == out[4, 2] == np.float32(0.45) and out[2, 2] == np.float32(0.8)
    # the stones table without its own pairs (row k + 1, column k) warns of nothing ...
    table = np.full((5, 4), 0.3)
    table[[1, 2, 3, 4], [0, 1, 2, 3]] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sw.make_rules("lookup", table, lineup=STONES)
    table[4, 0] = np.nan  # ... but stones -> jumps missing is named
    with pytest.warns(UserWarning, match=r"1 pair\(s\).*\(4, 0\)"):
        sw.make_rules("lookup", table, lineup=STONES)


# ----------------------------------------------------------------------- rows and failures
def test_failure_breakdown_per_target_by_hand():
    """10 trials: 3 fall on stones (code 3), 1 on gaps; the paper's breakdown has no stones."""
    res = {"progress_frac": np.full(10, 0.5), "success": np.zeros(10), "fell": np.ones(10),
           "fail_kind": np.array([3, 3, 3, 1, -1, -1, -1, -1, -1, -1.])}
    row = stats.episode_table(res, STONES.targets)
    assert row["fail_on"] == pytest.approx({"jumps": 0.0, "gaps": 10.0, "stairs": 0.0, "stones": 30.0})
    # Wilson 3/10 by hand: den 1.38416, centre (0.3 + 0.19208) / den = 0.35551,
    # half 1.96 sqrt(0.021 + 0.009604) / den = 0.24772
    assert row["fail_ci"]["stones"] == pytest.approx([10.78, 60.32], abs=0.01)
    assert list(stats.episode_table(res)["fail_on"]) == ["jumps", "gaps", "stairs"]


def test_rows_a_lineup_can_have():
    for m in MULTI_METHODS:
        assert parts.lineup_gap(method_record(m), PAPER) is None, m
    can = [m for m in MULTI_METHODS if parts.lineup_gap(method_record(m), STONES) is None]
    assert sorted(can) == sorted(STONES_ROWS)
    for m in set(MULTI_METHODS) - set(STONES_ROWS):
        assert "stones" in parts.lineup_gap(method_record(m), STONES), m
    with pytest.raises(ValueError, match="row learned: line-up stones has no learned when rule"):
        parts.check_rows([method_record("detection"), method_record("learned")], STONES)
    parts.check_rows([method_record("learned")], PAPER)
    with pytest.raises(ValueError, match=r"line-up stones: the learned detector .* not stones"):
        parts.check_detector("models/detector/stand", STONES)
    parts.check_detector("models/detector/stand", PAPER)
    parts.check_detector(None, STONES)


def _fake_ckpt(run_dir):
    ck = run_dir / "checkpoints" / f"{1:012d}"
    ck.mkdir(parents=True)
    (ck / "progress.json").write_text("{}")


def test_available_methods_of_a_lineup(tmp_path, monkeypatch):
    monkeypatch.setattr(runs_lib, "COMMITTED_DIR", tmp_path / "committed")
    monkeypatch.setattr(runs_lib, "BASELINE_DIR", tmp_path / "baselines")
    runs, lookup = tmp_path / "runs", tmp_path / "lookup"
    for n in PAPER.policies:
        _fake_ckpt(runs / f"{n}_stand")
    avail = lambda ms, lineup: parts.available_methods(ms, runs, tmp_path / "est", lookup,  # noqa: E731
                                                       lineup=lineup)
    assert avail(["detection"], PAPER) == (["detection"], [])
    ok, skipped = avail(["detection"], STONES)  # its suite has a fifth policy
    assert ok == [] and "no stand-init stones policy" in skipped[0]
    _fake_ckpt(runs / "stones_stand")
    ok, skipped = avail(["detection", "lookup_context", "learned"], STONES)
    assert ok == ["detection"]
    why = dict(s.split(": ", 1) for s in skipped)
    assert "--context --lineup stones" in why["lookup_context"]
    assert why["learned"].startswith("line-up stones has no learned when rule")


# ----------------------------------------------------------------------- what evaluate multi builds
def _cfg(**kw):
    return multi.MultiConfig(2, 2, 1.0, str(REPO / "no_runs"), est_dir=str(MODELS_DIR / "estimators"),
                             when_dir=str(MODELS_DIR / "switch_when"), lineup=STONES,
                             track_seed=config.LINEUP_TRACK_SEEDS["stones"][0], **kw)


def test_the_setup_row_on_the_stones_lineup(tmp_path):
    """lookup_context_setup on stones: the five policies on mixed4 tracks, then the paper's setup
    policy for its pairs; the rules are (6, 4) with setup_gaps's pairs and the walk-on entries,
    from a hand-made context lookup of the line-up."""
    table = np.round(np.arange(20, dtype=float).reshape(5, 4) / 40, 3)  # 0.0 .. 0.475 m
    (tmp_path / "lookup_stand_context_stones.json").write_text(json.dumps(
        {"matrix_m": table.tolist(), "tables": {k: {} for k in STONES.targets}}))
    s = multi.MultiSetup(["lookup_context_setup"], _cfg(lookup_dir=str(tmp_path)))
    assert s.env.cfg.kind == "mixed4" and s.policy_names == STONES.policies + ("setup_gaps",)
    assert "stones_stand" in s.suite.sources[4] and "setup_gaps_stand" in s.suite.sources[5]
    np.testing.assert_array_equal(multi.trial_track(s, 1).artifact_codes,
                                  multi.mixed_track(100_001, 7, "mixed4").artifact_codes)
    rules, _ = s.rules_for("lookup_context_setup")
    want = table.copy()
    want[[1, 2], 2] = 0.45  # the walk-on pairs jumps, gaps -> stairs (config.SETUP_WALK_ON)
    np.testing.assert_allclose(np.asarray(rules.lookup_m), np.r_[want, np.zeros((1, 4))], atol=1e-6)
    setup_of = np.full((6, 4), -1)
    setup_of[[1, 3], 1] = 5  # setup_gaps: jumps, stairs -> gaps
    np.testing.assert_array_equal(rules.setup_of, setup_of)
    np.testing.assert_array_equal(rules.policy_of_code, [1, 2, 3, 4])
    assert int(rules.n_policies) == 5
    assert any("no setup policy into or out of stones" in p for p in s.parts_for("lookup_context_setup"))
    with pytest.raises(ValueError, match="row learned: line-up stones has no learned when rule"):
        multi.MultiSetup(["learned"], _cfg())


def test_baselines_run_as_they_are_on_stones_tracks():
    """The end-to-end policy and the DQN on mixed4 tracks: the DQN still chooses among the
    paper's four policies (its Q-network's actions)."""
    e2e = multi.BaselineSetup("end_to_end", _cfg())
    assert e2e.env.cfg.kind == "mixed4" and len(e2e.suite.sources) == 1
    dqn = multi.BaselineSetup("dqn", _cfg())
    assert dqn.env.cfg.kind == "mixed4" and dqn.env.cfg.detector_one_hot
    assert [src.split("/")[-3] for src in dqn.suite.sources] == [f"{p}_stand" for p in PAPER.policies]


# ----------------------------------------------------------------------- the command
def _fake_multi(calls, lineup_of_rows):
    def fake(methods, cfg, seed, print_fn=None, per_trial=None):
        calls.append((list(methods), cfg))
        res = {"progress_frac": np.array([1.0, 0.5]), "success": np.array([1.0, 0.0]),
               "fell": np.array([0.0, 1.0]), "fail_kind": np.array([-1.0, 3.0])}
        rows = []
        for m in methods:
            per_trial[m] = {"success": res["success"]}
            row = stats.episode_table(res, lineup_of_rows.targets)
            row.update(method=m, init="stand", wall_s=1.0, switches_per_trial=2.0,
                       policies=[], backend="mujoco", **multi.lineup_meta(lineup_of_rows))
            rows.append(row)
        return rows, {}
    return fake


def test_evaluate_multi_lineup_flags_and_files(tmp_path, monkeypatch, capsys):
    calls, avail = [], []
    monkeypatch.setattr(tables, "evaluate_multi", _fake_multi(calls, STONES))
    monkeypatch.setattr(tables, "available_methods",
                        lambda methods, *a, **k: avail.append(k.get("lineup")) or (list(methods), []))
    out = tmp_path / "t24"
    base = ["multi", "--lineup", "stones", "--trials", "2", "--batch", "2", "--out", str(out)]
    # a row the line-up cannot have is refused before any rollout, naming it, the line-up, the part
    for bad, text in ((["--methods", "detection", "learned"],
                       "row learned: line-up stones has no learned when rule"),
                      (["--detector", "learned"], "line-up stones: the learned detector")):
        with pytest.raises(SystemExit):
            ev.main(base + bad)
        assert text in capsys.readouterr().err
    assert not calls
    assert ev.main(base) == 0
    methods, cfg = calls[-1]
    assert methods == [m for m in MULTI_METHODS if m in STONES_ROWS]  # the rows it can have
    assert cfg.lineup is STONES and avail == [STONES]
    assert cfg.track_seed == config.LINEUP_TRACK_SEEDS["stones"][0] == 100_000
    doc = json.loads((out / "table2.json").read_text())
    assert doc["settings"]["lineup"] == "stones" and doc["settings"]["track_seed"] == 100_000
    assert (doc["lineup"], doc["tracks"], doc["lineup_policies"]) == ("stones", "mixed4",
                                                                      list(STONES.policies))
    assert all(r["lineup"] == "stones" and r["fail_on"]["stones"] == 50.0 for r in doc["rows"])
    head = (out / "table2.csv").read_text().splitlines()[0].split(",")
    assert head[3:15] == [f"{k}_fail_{c}" for k in ("gap", "jump", "stair", "stone")
                          for c in ("pct", "lo", "hi")]
    md = (out / "table2.md").read_text()
    assert "% stone fail (CI)" in md and "| detection | 2 |" in md and "paper" not in md.split("\n")[2]
    assert not (out / "claims.md").exists()  # the paper's claims are the paper line-up's
    assert ev.main(base + ["--methods", "random", "--track-seed", "110000", "--fresh"]) == 0
    assert calls[-1][1].track_seed == 110_000
    # a table of another line-up is refused, naming the setting; `failures` reads the paper's only
    with pytest.raises(SystemExit):
        ev.main(["multi", "--trials", "2", "--batch", "2", "--out", str(out)])
    assert "lineup: 'stones' there, 'paper' now" in capsys.readouterr().err
    assert ev.main(["failures", "--out", str(out)]) == 2
    assert "line-up stones" in capsys.readouterr().err


PAPER_CSV_HEAD = ("method,init,trials,gap_fail_pct,gap_fail_lo,gap_fail_hi,jump_fail_pct,jump_fail_lo,"
                  "jump_fail_hi,stair_fail_pct,stair_fail_lo,stair_fail_hi,switches_per_trial,wall_s,"
                  "distance_pct,distance_lo,distance_hi,success_pct,success_lo,success_hi")


def test_evaluate_multi_paper_lineup_files_unchanged(tmp_path, monkeypatch):
    """The default line-up: Table II's tracks, every row, and no line-up key in any file; a table
    written before line-ups existed (no key) takes more rows."""
    calls = []
    monkeypatch.setattr(tables, "evaluate_multi", _fake_multi(calls, PAPER))
    monkeypatch.setattr(tables, "available_methods", lambda methods, *a, **k: (list(methods), []))
    out = tmp_path / "t2"
    assert ev.main(["multi", "--trials", "2", "--batch", "2", "--fig5-trial", "-1", "--out", str(out)]) == 0
    methods, cfg = calls[-1]
    assert methods == list(MULTI_METHODS) and cfg.lineup is PAPER
    assert cfg.track_seed == config.MULTI_TRACK_SEED
    doc = json.loads((out / "table2.json").read_text())
    assert "lineup" not in doc["settings"] and not {"lineup", "tracks", "lineup_policies"} & set(doc)
    assert multi.lineup_meta(PAPER) == {}  # what evaluate_multi adds to a paper row
    assert (out / "table2.csv").read_text().splitlines()[0] == PAPER_CSV_HEAD
    assert (out / "claims.md").exists()
    assert ev.main(["multi", "--trials", "2", "--batch", "2", "--fig5-trial", "-1", "--out", str(out),
                    "--methods", "detection"]) == 0


def test_evaluate_multi_stones_short_run(tmp_path):
    """Two real trials of the committed five-policy suite with the detection rule on mixed4
    tracks 100,002 (a stones artifact first) and 100,003 (jumps first): the stones policy (slot 4)
    acts as the robot comes over the stones, the jumps policy (1) over the jumps, each switched
    into from walk."""
    assert [multi.mixed_track(100_002 + i, 2, "mixed4").artifact_codes[0] for i in (0, 1)] == [3, 0]
    out = tmp_path / "t24"
    assert ev.main(["multi", "--lineup", "stones", "--methods", "detection", "--trials", "2",
                    "--batch", "2", "--track-seed", "100002", "--n-artifacts", "2", "--horizon-s", "6",
                    "--runs", str(REPO / "no_runs"), "--estimators", str(MODELS_DIR / "estimators"),
                    "--lookup", str(tmp_path / "no_lookup"), "--out", str(out)]) == 0
    doc = json.loads((out / "table2.json").read_text())
    assert doc["settings"]["lineup"] == "stones" and doc["tracks"] == "mixed4"
    assert doc["track_seed"] == 100_002
    (row,) = doc["rows"]
    assert set(row["fail_on"]) == set(STONES.targets) and "stones_stand" in row["policies"][4]
    with np.load(out / "table2_trials.npz") as z:
        np.testing.assert_array_equal(z["detection/active_at_start"][:, 0], [4, 1])
        np.testing.assert_array_equal(z["detection/switch_from"][:, 0], [0, 0])

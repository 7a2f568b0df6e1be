"""Table I metrics on hand-made rollouts, against hand-computed values."""

import functools
import json
import pathlib

import numpy as np
import pytest

from biped_switch import config
from biped_switch.switching import estimator
from biped_switch.switching import sweep
from biped_switch.switching import lookup as lookup_lib
from biped_switch import evaluate as ev
from biped_switch import methods as methods_lib
from biped_switch import names
from biped_switch.products import tables
from biped_switch.learning import runs as runs_lib
from biped_switch import stats
from biped_switch.evaluation import single as table1
from biped_switch.reports import table1 as table1_report
from biped_switch.evaluation import multi as table2, parts
from biped_switch.reports import table2 as table2_report
from biped_switch.reports import table3
from biped_switch.simulation import terrain


def test_wilson_interval_hand_values():
    lo, hi = stats.wilson_ci(5, 10)  # p = 0.5, n = 10: 0.2366 .. 0.7634
    assert (lo, hi) == (pytest.approx(0.23659, abs=1e-5), pytest.approx(0.76341, abs=1e-5))
    lo, hi = stats.wilson_ci(0, 20)  # all failures: [0, 0.1611]
    assert lo == 0.0 and hi == pytest.approx(0.16113, abs=1e-5)
    lo, hi = stats.wilson_ci(20, 20)
    assert hi == 1.0 and lo == pytest.approx(1 - 0.16113, abs=1e-5)


def test_episode_table_from_hand_made_rollouts():
    # 4 episodes: two reach the finish, one falls on a gap at 50%, one on stairs at 25%.
    res = {
        "progress_frac": np.array([1.0, 1.0, 0.5, 0.25]),
        "success": np.array([1.0, 1.0, 0.0, 0.0]),
        "fell": np.array([0.0, 0.0, 1.0, 1.0]),
        "fail_kind": np.array([-1.0, -1.0, 1.0, 2.0]),
    }
    t = stats.episode_table(res)
    assert t["n"] == 4
    assert t["distance_pct"] == pytest.approx(68.75)
    sd = np.std([100, 100, 50, 25], ddof=1)
    assert t["distance_pct"] - t["distance_ci"][0] == pytest.approx(1.96 * sd / 2)
    assert t["distance_ci"][1] == 100.0  # 68.75 + 36.75 would pass 100%: clipped
    assert t["success_pct"] == pytest.approx(50.0)
    assert t["success_ci"] == [pytest.approx(100 * x) for x in stats.wilson_ci(2, 4)]
    assert t["fell_pct"] == pytest.approx(50.0)
    assert t["fail_on"] == {"jumps": 0.0, "gaps": pytest.approx(25.0), "stairs": pytest.approx(25.0)}
    # near the finish the normal interval would pass 100% (97.5 + 1.96 x 5 / 2 = 102.4): clipped
    near = {**res, "progress_frac": np.array([1.0, 1.0, 1.0, 0.9])}
    lo, hi = stats.episode_table(near)["distance_ci"]
    assert lo == pytest.approx(97.5 - 4.9) and hi == 100.0


def test_single_horizon_lets_the_acceptance_speed_finish():
    """Table I's derived time limit: the pause, then the farthest finish line at 0.6 m/s with a
    20% margin (gaps tracks reach 42 m: the old fixed 60 s cut a 0.6 m/s walker off at 35 m)."""
    assert table1.single_horizon_s(27.0, 0.5) == 55.0  # ceil(0.5 + 1.2 * 27 / 0.6) = ceil(54.5)
    assert table1.single_horizon_s(42.3, 0.0) == 85.0  # ceil(84.6)
    for finish in (20.0, 27.3, 42.3):
        h = table1.single_horizon_s(finish, 0.5)
        assert 0.5 + finish / 0.6 < h <= 0.5 + 1.2 * finish / 0.6 + 1.0


def test_speed_table_by_hand():
    # stand init: 0.5 s pause; 3 episodes of 50 Hz steps: 10 m in 20.5 s alive, 6 m in 10.5 s, and
    # a fall in the pause (0 m in 0.2 s: the walking time is floored at one step)
    res = {"distance_m": np.array([10.0, 6.0, 0.0]), "length": np.array([1025, 525, 10]),
           "success": np.array([1.0, 0.0, 0.0])}
    t = table1.speed_table(res, 0.02, 0.5)
    assert t["speed_mps"] == pytest.approx((0.5 + 0.6 + 0.0) / 3)
    assert t["speed_success_mps"] == pytest.approx(0.5)
    assert t["speed_alive_mps"] == pytest.approx((10 / 20.5 + 6 / 10.5 + 0.0) / 3)
    half = 1.96 * np.std([0.5, 0.6, 0.0], ddof=1) / np.sqrt(3)
    assert t["speed_ci"] == [pytest.approx(t["speed_mps"] - half), pytest.approx(t["speed_mps"] + half)]


def test_markdown_row_has_paper_figures():
    row = {"policy": "gaps", "init": "random", "n": 4, "distance_pct": 68.75, "distance_ci": [40, 90],
           "success_pct": 50.0, "success_ci": [15, 85], "train_step": 1000,
           "curriculum": {"stage_name": "terrain", "difficulty": 0.3, "guide_scale": 1.0}}
    md = table1_report.table1_markdown([row])
    assert "| gaps | random | 4 | 68.8 (40.0-90.0) | 50.0 (15.0-85.0) | 87.4 | 75.5 |" in md
    row.update(speed_mps=0.61, speed_ci=[0.58, 0.64], horizon_s=85.0, track_seed=123,
               backend="mujoco")
    md = table1_report.table1_markdown([row])
    assert "| 1,000 | - | terrain d=0.3 g=1.0 p=0.0 | 0.61 (0.58-0.64) | 85 | 123 | mujoco |" in md
    row.update(train_h=11.537, curriculum_done=False)
    assert "| 1,000 | 11.54 | terrain d=0.3 g=1.0 p=0.0, in training |" in table1_report.table1_markdown([row])
    row.update(curriculum={"stage_name": "pushes", "difficulty": 1.0, "guide_scale": 0.0,
                           "push_scale": 1.0}, curriculum_done=True, curriculum_end="push plateau",
               push_held=0.9)
    row.update(warm_start="models/policies/walk_stand/checkpoints/000073506816",
               full_push=runs_lib.full_push({"curriculum": {"max_push_N": 150.0, "push_duration_s": 0.2}}))
    md = table1_report.table1_markdown([row])
    assert "| pushes d=1.0 g=0.0 p=1.0, done on a push plateau (holds p=0.9) |" in md
    assert md.endswith("\n\n- gaps/random was warm-started from models/policies/walk_stand/"
                       "checkpoints/000073506816 (its parameters and normaliser; `train` without "
                       "`--warm-start` trains from scratch)\n- gaps/random's push stage ended on a "
                       "plateau: it holds push 0.90 of the full scale (150 N for 0.2 s), not 1")
    row["warm_start"] = ""
    row.update(curriculum_end="full pushes", push_held=1.0)
    assert "| pushes d=1.0 g=0.0 p=1.0, done |" in table1_report.table1_markdown([row])


def test_single_runs_on_the_tracks_of_track_seed(tmp_path, monkeypatch):
    """`evaluate single --track-seed N`: trial i runs on track N + i (not on the default
    evaluation tracks), in an env with the policy's env overrides on the chosen backend, and the
    table and JSON say which tracks, backend and horizon it ran with."""
    from biped_switch.simulation import terrain
    from policy_runs import fake_policy_run

    ckpt = fake_policy_run(tmp_path / "runs", "walk")
    made = []
    make_env = table1.env_lib.make_env

    def spy(*args, **kw):
        made.append((kw, make_env(*args, **kw)))
        return made[-1][1]

    monkeypatch.setattr(table1.env_lib, "make_env", spy)
    out = tmp_path / "table1"
    argv = ["single", "--policies", "walk", "--inits", "stand", "--trials", "2", "--batch", "2",
            "--horizon-s", "0.1", "--track-seed", "123", "--runs", str(tmp_path / "runs"),
            "--out", str(out)]
    assert ev.main(argv) == 0
    (kw, env), = made
    assert kw["seed"] == 123 and kw["backend"] == "auto"
    assert {k: kw[k] for k in runs_lib.policy_env_overrides(ckpt)} == \
        runs_lib.policy_env_overrides(ckpt)

    def bank(seed):
        return terrain.stack_tracks([terrain.generate_track(seed + i, "walk", 1.0) for i in range(2)],
                                    env.biped.box_capacity, env.terrain_cfg.n_artifacts).segments

    np.testing.assert_array_equal(env.bank.segments, bank(123))
    assert not np.array_equal(env.bank.segments, bank(config.EVAL_TRACK_SEED))  # other tracks
    doc = json.loads((out / "table1.json").read_text())
    row, = doc["rows"]
    assert doc["settings"]["track_seed"] == doc["track_seed"] == row["track_seed"] == 123
    assert row["backend"] == env.backend == table1.env_lib.resolve_backend("auto")
    assert row["horizon_s"] == 0.1 and row["horizon_from"] == "--horizon-s"
    finish = max(terrain.generate_track(123 + i, "walk", 1.0).finish_x_m for i in range(2))
    assert row["finish_m_max"] == pytest.approx(finish, abs=1e-4)
    assert row["n"] == 2 and row["timed_out_pct"] == 100.0 and np.isfinite(row["speed_mps"])
    assert f"| 0.1 | 123 | {env.backend} |" in (out / "table1.md").read_text()


def _two_trials(success):
    """The episode table of two trials: the first finishes (`success`), the second falls halfway."""
    return stats.episode_table({"progress_frac": np.array([1.0, 0.5]),
                                "success": np.array([success, 0.0]),
                                "fell": np.array([0.0, 1.0]), "fail_kind": np.array([-1, 1.0])})


def _table1_row(policy, init, success):
    row = _two_trials(success)
    row.update(policy=policy, init=init, checkpoint=f"runs/{policy}_{init}/checkpoints/1",
               train_step=1, train_h=0.5, curriculum={"stage_name": "pushes"},
               curriculum_end="full pushes", push_held=1.0, speed_mps=0.5, speed_ci=[0.4, 0.6],
               horizon_s=0.1, horizon_from="--horizon-s", timed_out_pct=0.0, track_seed=10_000,
               backend="mujoco")
    return row


def test_single_adds_rows_to_a_table_of_the_same_trials(tmp_path, monkeypatch):
    """`evaluate single` for the stand suite, then for one random-init policy that finished its
    curriculum later, leaves one Table I with both in order (stand rows first, then random; a
    rerun policy replaces its row). Another trial count is refused before any rollout, naming
    the setting, and --fresh replaces the table."""
    calls = []

    def fake_single(policy, init, ckpt, trials, *args, **kw):
        calls.append((policy, init, trials))
        return _table1_row(policy, init, 1.0 if len(calls) > 2 else 0.0)

    monkeypatch.setattr(tables, "evaluate_single", fake_single)
    monkeypatch.setattr(tables, "find_policy", lambda policy, init, runs: pathlib.Path(f"{policy}_{init}"))
    out = tmp_path / "table1"
    base = ["single", "--trials", "2", "--batch", "2", "--out", str(out)]
    assert ev.main(base + ["--policies", "stairs", "jumps", "--inits", "stand"]) == 0
    assert ev.main(base + ["--policies", "stairs", "--inits", "random", "stand"]) == 0
    doc = json.loads((out / "table1.json").read_text())
    assert [(r["policy"], r["init"]) for r in doc["rows"]] == [
        ("jumps", "stand"), ("stairs", "stand"), ("stairs", "random")]
    assert [r["success_pct"] for r in doc["rows"]] == [0.0, 50.0, 50.0]  # stairs/stand: the rerun's
    assert doc["settings"]["policies"] == ["jumps", "stairs"]
    assert doc["settings"]["inits"] == ["stand", "random"]
    md = (out / "table1.md").read_text()
    assert md.index("| jumps | stand |") < md.index("| stairs | stand |") < md.index("| stairs | random |")
    assert (out / "table1.csv").read_text().count("\n") == 4  # header + 3 rows
    with pytest.raises(SystemExit):
        ev.main(["single", "--trials", "3", "--batch", "2", "--out", str(out)])
    assert len(calls) == 4  # refused before rolling out
    with pytest.raises(ValueError, match=r"track_seed: 10000 there, 5 now"):
        table1.merge_rows(doc, [], {**doc["settings"], "track_seed": 5})
    assert ev.main(base + ["--policies", "gaps", "--inits", "random", "--fresh"]) == 0
    assert [(r["policy"], r["init"]) for r in json.loads((out / "table1.json").read_text())["rows"]] == [
        ("gaps", "random")]


def _fake_run(run_dir, wall_s, device="cuda:0", step=1000, **extra):
    ck = run_dir / "checkpoints" / f"{step:012d}"
    ck.mkdir(parents=True)
    (ck / "progress.json").write_text(json.dumps({"wall_s": wall_s, "device": device, "step": step,
                                                  **extra}))


def test_retrain_cost_from_logs(tmp_path, monkeypatch):
    runs, res = tmp_path / "runs", tmp_path / "results"
    # only these fake runs: not the committed ones (models/policies/mixed_stand,
    # models/baselines/dqn_stand, ...)
    monkeypatch.setattr(runs_lib, "COMMITTED_DIR", tmp_path / "committed")
    monkeypatch.setattr(runs_lib, "BASELINE_DIR", tmp_path / "baselines")
    _fake_run(runs / "jumps_stand", 1800.0)
    _fake_run(runs / "gaps_stand", 3600.0)
    _fake_run(runs / "stairs_stand", 5400.0)  # mean policy: 1 h
    (res / "lookup").mkdir(parents=True)
    (res / "lookup" / "lookup_stand.json").write_text(json.dumps({"meta": {"sweeps": {
        k: {"wall_s": 360.0} for k in ("jumps", "gaps", "stairs")}}}))  # 0.1 h each
    (res / "estimators").mkdir()
    for k in ("jumps", "gaps", "stairs"):
        (res / "estimators" / f"stand_{k}.json").write_text(json.dumps({"metrics": {"train_s": 720.0}}))  # 0.2 h
    doc = table3.retrain_cost(runs, res)
    rows = {r["method"]: r for r in doc["rows"]}
    assert rows["ours"]["hours"] == pytest.approx(1.0 + 3 * 0.1 + 3 * 0.2)
    assert rows["dqn"]["hours"] is None and rows["end_to_end"]["hours"] is None
    assert any("DQN" in m for m in doc["missing"])
    _fake_run(runs / "dqn_stand", 7200.0)
    _fake_run(runs / "mixed_stand", 3 * 3600.0, step=5000)
    rows = {r["method"]: r for r in table3.retrain_cost(runs, res)["rows"]}
    assert rows["dqn"]["hours"] == pytest.approx(1.0 + 2.0)
    assert rows["end_to_end"]["hours"] == pytest.approx(3.0)
    md = table3.table3_markdown(table3.retrain_cost(runs, res))
    assert "| ours | 1.90 |" in md and "| end_to_end | 3.00 |" in md
    assert all(r["status"] == "complete" for r in rows.values())  # no goal or curriculum recorded
    # ours with the learned when rule: the policy, its three sweeps and its training (from meta)
    when_dir = tmp_path / "when"
    assert "ours_learned" not in {r["method"] for r in table3.retrain_cost(
        runs, res, when_dir=when_dir)["rows"]}
    (when_dir / "stand").mkdir(parents=True)
    (when_dir / "stand" / "meta.json").write_text(json.dumps({
        "sweeps": {k: {"wall_s": 720.0} for k in ("jumps", "gaps", "stairs")},
        "train_s": 30.0, "data_s": 6.0, "device": "cpu:0"}))
    rows = {r["method"]: r for r in table3.retrain_cost(runs, res, when_dir=when_dir)["rows"]}
    assert rows["ours_learned"]["hours"] == pytest.approx(1.0 + 3 * 0.2 + 0.01)
    assert rows["ours_learned"]["parts"]["when sweep gaps"] == pytest.approx(0.2)
    # compose, then distil: ours with the setup policy, plus the distillation
    assert "distilled" not in rows
    _fake_run(runs / "setup_gaps_stand", 0.5 * 3600.0)
    _fake_run(runs / "student_stand", 2 * 3600.0)
    rows = {r["method"]: r for r in table3.retrain_cost(runs, res)["rows"]}
    assert rows["ours_setup"]["hours"] == pytest.approx(1.9 + 0.5)
    assert rows["distilled"]["hours"] == pytest.approx(1.9 + 0.5 + 2.0)
    assert rows["distilled"]["parts"]["distillation"] == pytest.approx(2.0)
    assert "| distilled | 4.40 |" in table3.table3_markdown(table3.retrain_cost(runs, res))


def test_retrain_cost_flags_unfinished_and_stand_in_runs(tmp_path):
    """Hours of a snapshot must not sit beside the paper's unflagged: a run short of its goal, with
    guides still on, or choosing among stand-ins is named in the row's status."""
    runs, res = tmp_path / "runs", tmp_path / "results"
    done = {"curriculum": {"stage_name": "pushes", "difficulty": 1.0, "guide_scale": 0.0}}
    for k in ("jumps", "gaps"):
        _fake_run(runs / f"{k}_stand", 3600.0, step=100, total_steps=100, n_devices=2, **done)
    _fake_run(runs / "stairs_stand", 3600.0, step=100, total_steps=100, n_devices=2,
              curriculum={"stage_name": "guides", "difficulty": 1.0, "guide_scale": 0.8})
    _fake_run(runs / "mixed_stand", 7200.0, step=50, total_steps=100, **done)
    _fake_run(runs / "dqn_stand", 3600.0, step=10, total_env_steps=10, stand_in="walk")
    doc = table3.retrain_cost(runs, res)
    rows = {r["method"]: r for r in doc["rows"]}
    assert rows["ours"]["hours"] is None and rows["ours"]["status"] == "not measured"  # no sweeps
    assert rows["ours"]["device"] == "cuda:0 x2"
    assert rows["dqn"]["hours"] == pytest.approx(2.0)
    assert rows["dqn"]["status"] == ("stairs_stand curriculum unfinished (guides d=1.0 guide=0.8); "
                                     "dqn_stand chose among stand-ins (walk)")
    assert rows["end_to_end"]["status"] == "mixed_stand at step 50 of 100"
    md = table3.table3_markdown(doc)
    assert "| end_to_end | 2.00 | policy 2.00 | cuda:0 x1 | mixed_stand at step 50 of 100 | 34 |" in md


def _fake_ckpt(run_dir, step=1):
    ck = run_dir / "checkpoints" / f"{step:012d}"
    ck.mkdir(parents=True)
    (ck / "progress.json").write_text("{}")


def in_order(methods) -> list:
    """`methods` in Table II's order (available_methods keeps it)."""
    return [m for m in names.MULTI_METHODS if m in set(methods)]


def test_available_methods_names_what_is_missing(tmp_path, monkeypatch):
    # only these fakes count: not the policies committed under models/policies/ (walk_random is)
    # nor the DQN under models/baselines/
    monkeypatch.setattr(runs_lib, "COMMITTED_DIR", tmp_path / "committed")
    monkeypatch.setattr(runs_lib, "BASELINE_DIR", tmp_path / "baselines")
    runs, est, lookup = tmp_path / "runs", tmp_path / "est", tmp_path / "lookup"
    when_dir = tmp_path / "when"
    avail = functools.partial(parts.available_methods, when_dir=when_dir)
    for n in ("walk", "jumps", "gaps", "stairs"):  # the stand suite
        _fake_ckpt(runs / f"{n}_stand")
    ok, skipped = avail(names.MULTI_METHODS, runs, est, lookup)
    assert ok == ["random", "detection", "com_over_feet"]
    why = dict(s.split(": ", 1) for s in skipped)
    assert set(why) == {"lookup", "estimator", "estimator_no_overlap", "dqn", "end_to_end",
                        "lookup_context", "estimator_context", "estimator_context_persist",
                        "lookup_context_setup", "learned", "learned_no_overlap", "learned_setup",
                        "student"}
    assert "python -m biped_switch.distill" in why["student"]
    assert f"no learned when rule in {when_dir}/stand" in why["learned"]
    assert "--policy setup_gaps" in why["learned_setup"]  # its first missing part
    assert "--policy setup_gaps" in why["lookup_context_setup"]
    assert "make train-dqn" in why["dqn"] and "--policy mixed" in why["end_to_end"]
    assert "random-init walk" in why["estimator_no_overlap"]
    # a suite with a policy missing is skipped, naming it
    _fake_ckpt(runs / "walk_random")
    ok, skipped = avail(["estimator_no_overlap"], runs, est, lookup)
    assert ok == [] and "no random-init jumps, gaps, stairs policy" in skipped[0]
    # once the parts exist, every method is available
    for n in ("jumps", "gaps", "stairs"):
        _fake_ckpt(runs / f"{n}_random")
    _fake_ckpt(runs / "mixed_stand")
    _fake_ckpt(runs / "student_stand")
    _fake_ckpt(runs / "dqn_stand")
    for init in ("stand", "random"):
        for k in ("jumps", "gaps", "stairs"):
            (est / f"{init}_{k}").mkdir(parents=True)
    lookup.mkdir()
    (lookup / "lookup_stand.json").write_text('{"tables": {"jumps": {}}}')  # one target swept
    ok, skipped = avail(names.MULTI_METHODS, runs, est, lookup)
    assert "lookup" not in ok and skipped[0] == (
        f"lookup: the lookup table in {lookup} has no gaps, stairs (python -m biped_switch.sweep "
        "--targets gaps stairs)")
    later = list(dict.fromkeys(names.CONTEXT_METHODS + names.SETUP_METHODS
                               + names.LEARNED_METHODS))  # learned_setup is in both
    assert [s.split(":")[0] for s in skipped[1:]] == later
    (lookup / "lookup_stand.json").write_text('{"tables": {"jumps": {}, "gaps": {}, "stairs": {}}}')
    ok, skipped = avail(names.MULTI_METHODS, runs, est, lookup)
    assert ok == in_order(names.SWITCH_METHODS + names.BASELINES)
    assert [s.split(":")[0] for s in skipped] == later
    # a context sweep of one target: the other targets keep the plain sweep's parts
    (est / "stand_context_gaps").mkdir()
    (lookup / "lookup_stand_context.json").write_text('{"tables": {"gaps": {}}}')
    ok, skipped = avail(names.MULTI_METHODS, runs, est, lookup)
    assert ok == in_order(names.SWITCH_METHODS + names.BASELINES + names.CONTEXT_METHODS)
    assert [s.split(":")[0] for s in skipped] == later[len(names.CONTEXT_METHODS):]
    # a setup policy: its run's config says what it serves
    _fake_ckpt(runs / "setup_gaps_stand")
    (runs / "setup_gaps_stand" / "config.json").write_text(
        '{"setup": {"target": "gaps", "sources": ["jumps", "stairs"], "handover_m": 0.45}}')
    assert parts.find_setup_policies("stand", runs) == {
        "setup_gaps": ("gaps", ("jumps", "stairs"), 0.45)}
    ok, skipped = avail(names.MULTI_METHODS, runs, est, lookup)
    assert [s.split(":")[0] for s in skipped] == [m for m in names.MULTI_METHODS
                                                  if m in names.LEARNED_METHODS]
    # the learned when rule of each suite
    for init in ("stand", "random"):
        (when_dir / init).mkdir(parents=True)
        (when_dir / init / "meta.json").write_text("{}")
    ok, skipped = avail(names.MULTI_METHODS, runs, est, lookup)
    assert ok == list(names.MULTI_METHODS) and skipped == []
    assert runs_lib.find_dqn(runs) == runs / "dqn_stand"
    assert runs_lib.find_dqn(runs, dqn_dir=tmp_path / "no_dqn") is None  # an explicit directory only
    assert runs_lib.find_dqn(tmp_path / "no_runs", "random") is None


def test_demo_horizon_lets_the_target_speed_finish():
    """Every demo track can be finished at the target speed within the limit (the old fixed 30 s
    on 7-artifact tracks made success impossible), with the 1.4 margin and no more."""
    from biped_switch import demo
    from biped_switch.simulation import terrain
    from biped_switch.config import default_terrain_config

    tcfg = default_terrain_config()
    tcfg.n_artifacts = 3
    h = demo.horizon_for(6, 3)
    finish = [terrain.generate_track(config.MULTI_TRACK_SEED + i, "mixed", 1.0, tcfg).artifacts[-1][2]
              + tcfg.finish_after_m for i in range(6)]
    need = [0.5 + f / 0.8 for f in finish]  # pause, then walking at 0.8 m/s
    assert h >= 1.4 * max(need) - 1.4 * 0.5 and h < 1.4 * max(need) + 1.0
    assert 10.0 < max(finish) < 20.0  # 3 artifacts of 4-9 segments of ~0.4 m, flats between


def test_demo_flags_policies_still_in_training(tmp_path, monkeypatch):
    """A found policy (the end-to-end `mixed` one too) with an unfinished curriculum is named with
    its stage; a finished one is not; a policy's run short of its step goal alone is not flagged
    (the curriculum decides), a DQN selector's is."""
    from biped_switch.products import demo

    monkeypatch.setattr(runs_lib, "COMMITTED_DIR", tmp_path / "committed")
    runs = tmp_path / "runs"
    cur = {"stage": 1, "stage_name": "guides", "difficulty": 1.0, "guide_scale": 0.05,
           "push_scale": 0.0}
    _fake_run(runs / "jumps_stand", 60.0, curriculum=cur, curriculum_done=False)
    _fake_run(runs / "stairs_stand", 60.0, curriculum=cur | {"stage": 2, "stage_name": "pushes",
              "guide_scale": 0.0, "push_scale": 0.5}, curriculum_done=False)
    _fake_run(runs / "gaps_stand", 60.0, total_steps=10**9, curriculum=cur | {
        "stage": 2, "stage_name": "pushes", "guide_scale": 0.0, "push_scale": 1.0},
        curriculum_done=True)
    _fake_run(runs / "mixed_stand", 60.0, curriculum={  # the end-to-end policy is named too
        "stage": 0, "stage_name": "terrain", "difficulty": 0.6, "guide_scale": 1.0,
        "push_scale": 0.0}, curriculum_done=False)
    monkeypatch.setattr(runs_lib, "BASELINE_DIR", tmp_path / "baselines")  # no committed DQN
    flagged = ["jumps: curriculum unfinished (guides d=1.0 guide=0.05)",
               "stairs: push stage unfinished (push=0.5)",
               "mixed: curriculum unfinished (terrain d=0.6 guide=1.0)"]
    assert demo.in_training(runs) == flagged
    # a DQN selector has no curriculum: short of its step goal, it is in training
    _fake_run(runs / "dqn_stand", 60.0, step=256, total_env_steps=1000)
    assert demo.in_training(runs) == flagged + ["dqn selector: at step 256 of 1,000"]
    _fake_run(runs / "dqn_stand", 60.0, step=1000, total_env_steps=1000)
    assert demo.in_training(runs) == flagged


def test_demo_runs_end_to_end_on_the_trained_suite(tmp_path, monkeypatch, capsys):
    """`make demo` at a tiny size on the committed trained suite (models/policies, models/
    estimators, experiments/results/lookup): a row per available method, the table, Fig. 5 and the
    summary written, no stand-in or pipeline-check label. Without a stand-init policy it stops
    first, naming the policy and the command that trains it. (About 25 s on 2 busy cores: the
    mujoco backend compiles little; 2 trials of 1-artifact tracks, 4 s limit, no video.)"""
    from biped_switch import demo
    from biped_switch.simulation.model import MODELS_DIR

    repo = MODELS_DIR.parent
    paths = ["--runs", str(tmp_path / "no_runs"),  # the committed runs only, not a live runs/
             "--estimators", str(MODELS_DIR / "estimators"),
             "--lookup", str(repo / "experiments" / "results" / "lookup")]
    with monkeypatch.context() as mp:  # no committed policies: an error, nothing stands in
        mp.setattr(runs_lib, "COMMITTED_DIR", tmp_path / "no_committed")
        assert demo.main(["--trials", "1", "--out", str(tmp_path / "none"), *paths]) == 1
        err = capsys.readouterr().err
        for p in ("walk", "jumps", "gaps", "stairs"):
            assert (f"no trained stand-init {p} policy" in err
                    and f"python -m biped_switch.train --policy {p} --init stand" in err), err
        assert not (tmp_path / "none").exists()
    out = tmp_path / "demo"
    assert demo.main(["--trials", "2", "--n-artifacts", "1", "--horizon-s", "4", "--no-video",
                      "--out", str(out), *paths]) == 0
    summary = json.loads((out / "demo_summary.json").read_text())
    assert summary["trials"] == 2 and summary["n_artifacts"] == 1 and summary["guide_scale"] == 0.0
    methods = summary["methods"]
    # every method is run or skipped with its reason; the committed suite has what the switching
    # methods need (all four stand-init policies, the estimators and the lookup table)
    assert set(methods) | {s.split(":")[0] for s in summary["skipped"]} == set(names.MULTI_METHODS)
    assert {"random", "detection", "lookup", "com_over_feet", "estimator"} <= set(methods)
    assert [r["method"] for r in summary["rows"]] == methods
    assert not any(s.startswith("stand-in") for s in summary["policies"])
    assert all(f"{n}_stand" in s for n, s in zip(("walk", "jumps", "gaps", "stairs"),
                                                  summary["policies"]))
    md = (out / "table2_demo.md").read_text()
    assert "PIPELINE CHECK" not in md and "stand-in" not in md
    for m in methods:
        assert f"| {m} | 2 |" in md, m
    assert (out / "fig5_demo.png").stat().st_size > 10_000


def _table2_row(method, success, wall_s=10.0):
    row = _two_trials(success)
    row.update(method=method, init="stand", wall_s=wall_s, switches_per_trial=3.0,
               policies=[f"{method} suite"], backend="mujoco")
    return row


def test_multi_adds_rows_to_a_table_of_the_same_trials(tmp_path, monkeypatch):
    """`evaluate multi` run for some methods, then for others, leaves one table with the rows of
    both in Table II's order (a rerun method replaces its row); the table's wall time is the sum
    of its rows'. Another trial count is refused before any rollout, naming the setting, and
    --fresh replaces the table."""
    calls = []

    def fake_multi(methods, cfg, seed, print_fn=None, per_trial=None):
        trials = cfg.trials
        calls.append((list(methods), trials, cfg.batch))
        for m in methods:  # the run's index in the trials' successes, to tell the runs apart
            per_trial[m] = {"success": np.full(trials, float(len(calls)))}
        return [_table2_row(m, 1.0 if len(calls) > 1 else 0.0) for m in methods], {}

    monkeypatch.setattr(tables, "evaluate_multi", fake_multi)
    monkeypatch.setattr(tables, "available_methods", lambda methods, *a, **k: (list(methods), []))
    out = tmp_path / "table2"
    base = ["multi", "--trials", "2", "--batch", "2", "--fig5-trial", "-1", "--out", str(out)]
    assert ev.main(base + ["--methods", "estimator", "detection"]) == 0
    assert ev.main(base + ["--methods", "random", "detection"]) == 0
    doc = json.loads((out / "table2.json").read_text())
    assert [r["method"] for r in doc["rows"]] == ["random", "detection", "estimator"]
    assert [r["success_pct"] for r in doc["rows"]] == [50.0, 50.0, 0.0]  # detection: the rerun's
    assert doc["wall_s"] == pytest.approx(30.0)
    assert doc["settings"]["methods"] == ["random", "detection", "estimator"]
    with np.load(out / "table2_trials.npz") as z:  # per-trial outcomes: each row's own run
        assert {k: z[k].tolist() for k in z.files} == {
            "random/success": [2.0, 2.0], "detection/success": [2.0, 2.0],
            "estimator/success": [1.0, 1.0]}
    md = (out / "table2.md").read_text()
    assert md.index("| random |") < md.index("| detection |") < md.index("| estimator |")
    claims = (out / "claims.md").read_text()  # on the merged table: every row, both runs'
    assert "| the estimator beats every heuristic (success) | not tested | missing rows: lookup" in claims
    with pytest.raises(SystemExit):
        ev.main(["multi", "--trials", "3", "--batch", "2", "--methods", "lookup", "--out", str(out)])
    assert len(calls) == 2  # refused before rolling out
    with pytest.raises(ValueError, match=r"trials: 2 there, 3 now"):
        table2.merge_rows(doc, [], {**doc["settings"], "trials": 3})
    assert ev.main(base[:-2] + ["--out", str(out), "--methods", "lookup", "--fresh"]) == 0
    assert [r["method"] for r in json.loads((out / "table2.json").read_text())["rows"]] == ["lookup"]
    with np.load(out / "table2_trials.npz") as z:
        assert z.files == ["lookup/success"]


def _ci_row(method, pct, lo, hi):
    return {"method": method, "success_pct": pct, "success_ci": [lo, hi]}


def test_paper_claims_by_hand():
    """Each claim by the 95% CIs on % success: disjoint above = better, overlap = comparable; a
    claim whose rows were not run is "not tested", naming them."""
    assert table2_report.compare(_ci_row("a", 50, 45, 55), _ci_row("b", 40, 35, 44.9)) == 1
    assert table2_report.compare(_ci_row("a", 50, 45, 55), _ci_row("b", 40, 35, 45.0)) == 0  # touching
    assert table2_report.compare(_ci_row("a", 30, 25, 34), _ci_row("b", 40, 35, 45)) == -1
    heur = [_ci_row("random", 10, 9, 11), _ci_row("detection", 60, 58, 62),
            _ci_row("lookup", 59, 57, 61), _ci_row("com_over_feet", 66, 64, 68)]
    rows = heur + [_ci_row("estimator", 71, 69, 73), _ci_row("estimator_no_overlap", 1, 0, 2),
                   _ci_row("dqn", 72, 70, 74), _ci_row("end_to_end", 90, 89, 91)]
    got = {c["claim"].split(" (")[0]: c for c in table2_report.paper_claims(rows)}  # the paper's table
    assert [c["verdict"] for c in got.values()] == ["holds"] * 4 + ["not tested"] * 4
    assert "above all 7 other rows" in got["end-to-end is best"]["evidence"]
    rows[3] = _ci_row("com_over_feet", 70, 68, 72)  # overlaps the estimator: not beaten
    rows[6] = _ci_row("dqn", 80, 78, 82)
    rows.append(_ci_row("lookup_context", 90, 88.5, 91.5))  # ties end-to-end
    got = {c["claim"].split(" (")[0]: c for c in table2_report.paper_claims(rows)}
    beats = got["the estimator beats every heuristic"]
    assert beats["verdict"] == "fails" and beats["evidence"].endswith("not beaten: com_over_feet")
    assert got["the DQN is comparable to the estimator"]["verdict"] == "fails"
    assert got["the DQN is comparable to the estimator"]["evidence"].endswith("the DQN is better")
    e2e = got["end-to-end is best"]
    assert e2e["verdict"] == "fails" and "not beaten: lookup_context 90.0 (88.5-91.5)" in e2e["evidence"]
    assert got["without overlap the estimator collapses"]["verdict"] == "holds"
    # ours: the learned rule against the heuristics and the context lookup table
    rows += [_ci_row("learned", 80, 78, 82), _ci_row("learned_no_overlap", 60, 58, 62)]
    got = {c["claim"].split(" (")[0]: c for c in table2_report.paper_claims(rows)}
    ours = got["ours: a learned rule beats every hand-made rule"]
    assert ours["verdict"] == "fails" and ours["evidence"].endswith("not beaten: lookup_context")
    rows[-3] = _ci_row("lookup_context", 73, 71, 75)
    got = {c["claim"].split(" (")[0]: c for c in table2_report.paper_claims(rows)}
    assert got["ours: a learned rule beats every hand-made rule"]["verdict"] == "holds"
    assert got["ours: without overlap the learned rule collapses"]["verdict"] == "holds"
    setup = "ours: with setup policies too, the learned rule beats the lookup table"
    assert got[setup]["evidence"] == "missing rows: learned_setup, lookup_context_setup"
    rows += [_ci_row("learned_setup", 93, 92, 94), _ci_row("lookup_context_setup", 91, 90, 92)]
    got = {c["claim"].split(" (")[0]: c for c in table2_report.paper_claims(rows)}
    assert got[setup]["verdict"] == "fails"  # 92 touches 92: the CIs overlap
    rows[-1] = _ci_row("lookup_context_setup", 91, 90, 91.9)
    got = {c["claim"].split(" (")[0]: c for c in table2_report.paper_claims(rows)}
    assert got[setup]["verdict"] == "holds"
    # ours: the distilled student against end-to-end (89-91): its lower bound must clear 91
    student = "ours: a student distilled from the composed suite beats the end-to-end policy trained by RL"
    assert got[student]["evidence"] == "missing rows: student"
    for lo, verdict in ((91.0, "fails"), (91.1, "holds")):
        got = {c["claim"].split(" (")[0]: c for c in table2_report.paper_claims(
            rows + [_ci_row("student", 92, lo, 93)])}
        assert got[student]["verdict"] == verdict, lo
    part = table2_report.paper_claims(heur + [_ci_row("estimator", 71, 69, 73)])
    assert [c["verdict"] for c in part] == ["holds"] + ["not tested"] * 7
    assert part[1]["evidence"] == "missing rows: estimator_no_overlap"
    md = table2_report.claims_markdown(part)
    assert md.count("\n") == 9 and "| the DQN is comparable" in md


def test_run_batches_covers_each_trial_once_and_reports_progress():
    """Trial i runs on track i with the rng of its batch's start; the last batch wraps round and is
    cut; one progress line per batch with the running success over the trials done."""
    seen, lines = [], []

    def run(rng, ids):
        seen.append((int(np.asarray(rng)[-1]), np.asarray(ids).tolist()))  # PRNGKey(n) = [0, n]
        return {"success": (np.asarray(ids) % 2 == 0).astype(float), "track": np.asarray(ids)}

    out = table2._run_batches(run, 5, 2, seed=10, print_fn=lines.append, label="stand/x")
    assert [s[1] for s in seen] == [[0, 1], [2, 3], [4, 0]]
    assert [s[0] for s in seen] == [10, 12, 14]  # PRNGKey(seed + batch start)
    assert out["track"].tolist() == [0, 1, 2, 3, 4] and out["success"].tolist() == [1, 0, 1, 0, 1]
    assert len(lines) == 3 and "[stand/x] 2/5 trials, success so far 50.0%" in lines[0]
    assert "5/5 trials, success so far 60.0%" in lines[2] and "~0.0 min left" in lines[2]


def test_context_parts_fall_back_per_target_to_the_plain_sweeps(tmp_path):
    est = tmp_path / "est"
    for k in ("jumps", "gaps"):
        (est / f"stand_{k}").mkdir(parents=True)
    assert estimator.context_estimator_paths("stand", est) is None  # no context estimator
    (est / "stand_context_stairs").mkdir()
    assert estimator.context_estimator_paths("stand", est) == [
        est / "stand_jumps", est / "stand_gaps", est / "stand_context_stairs"]
    (est / "stand_jumps").rmdir()  # a target with neither
    assert estimator.context_estimator_paths("stand", est) is None

    look = tmp_path / "lookup"
    look.mkdir()
    nan = None
    plain = [[0.8, 0.7, 0.6], [nan, 0.5, 0.4], [0.3, nan, 0.2], [0.1, 0.15, nan]]
    ctx = [[nan, 0.33, nan], [nan, 0.44, nan], [nan, nan, nan], [nan, 0.55, nan]]
    (look / "lookup_stand.json").write_text(json.dumps(
        {"matrix_m": plain, "tables": {"jumps": {}, "gaps": {}, "stairs": {}}}))
    assert lookup_lib.context_lookup_missing("stand", look) is None
    with pytest.raises(FileNotFoundError, match="--context"):
        lookup_lib.load_context_lookup("stand", look)
    (look / "lookup_stand_context.json").write_text(json.dumps(
        {"matrix_m": ctx, "tables": {"gaps": {}}}))
    assert lookup_lib.context_lookup_missing("stand", look) == []
    m, used = lookup_lib.load_context_lookup("stand", look)
    want = np.array([[0.8, 0.33, 0.6], [np.nan, 0.44, 0.4], [0.3, np.nan, 0.2], [0.1, 0.55, np.nan]])
    np.testing.assert_array_equal(m, want)
    assert used == [f"jumps: {look / 'lookup_stand.json'}", f"gaps: {look / 'lookup_stand_context.json'}",
                    f"stairs: {look / 'lookup_stand.json'}"]
    assert methods_lib.method("lookup_context").rule == "lookup"
    assert methods_lib.method("estimator_context").rule == "estimator"
    assert methods_lib.method("estimator_context_persist").rule == "estimator"
    assert methods_lib.method("estimator_no_overlap").rule == "estimator"


def test_failures_by_context_by_hand():
    from biped_switch.simulation import terrain

    cfg = config.default_terrain_config(2)
    a = terrain.sequence_track(1, ["jumps", "gaps"], 1.0, cfg)
    b = terrain.sequence_track(2, ["gaps", "stairs"], 1.0, cfg)
    gap_x0 = a.artifacts[1][1]
    jumps_x0 = a.artifacts[0][1]
    tracks = [a, b, a, a]
    x = [gap_x0 + 0.1,  # falls just past the gap's start, after jumps
         b.finish_x_m,  # finishes: reaches both, falls on none
         jumps_x0 - 1.0,  # falls on the flat before jumps comes in range: reaches nothing
         gap_x0 - 0.5]  # falls 0.5 m before the gap: gaps is in range, and the env blamed it
    progress = np.array([xi / t.finish_x_m for xi, t in zip(x, tracks)])
    fell = np.array([1.0, 0.0, 1.0, 1.0])
    kinds = terrain.ARTIFACT_KINDS
    fail_kind = np.array([kinds.index("gaps"), -1, -1, kinds.index("gaps")])
    out = table2_report.failures_by_context(tracks, progress, fell, fail_kind)
    assert out["gaps"] == {"jumps": [2, 2], "start": [1, 0]}
    assert out["jumps"] == {"start": [2, 0]}
    assert out["stairs"] == {"gaps": [1, 0]}
    md = table2_report.failures_markdown({"m": out})
    assert "| m | 0 / 1 (0.0%) | 2 / 2 (100.0%) |" in md  # "after start" first
    # where: 0.1 m onto the gap, and 0.5 m before it (in range, blamed on gaps)
    where = table2_report.fall_positions(tracks, progress, fell, fail_kind)
    assert where["gaps"]["on"] == 1 and where["gaps"]["before"] == 1 and where["gaps"]["after"] == 0
    assert where["gaps"]["x_m"] == pytest.approx([0.1, -0.5], abs=1e-3)
    assert where["jumps"]["x_m"] == [] and where["stairs"]["x_m"] == []
    md = table2_report.fall_positions_markdown({"m": where})
    assert "| m | 0 / 0 / 0 (-) | 1 / 1 / 0 (-0.20) | 0 / 0 / 0 (-) |" in md

    # the same four trials with their switches logged (slot per artifact, NaN: no switch)
    nan = np.nan
    ahead = np.array([[0.85, 0.40], [0.89, 0.005], [nan, nan], [0.70, 0.60]])
    recs = table2_report.switch_outcomes(tracks, ahead, progress, fell, fail_kind)
    assert [(r["kind"], r["prev"], r["ahead_m"], r["outcome"]) for r in recs] == [
        ("jumps", "start", 0.85, "crossed"), ("gaps", "jumps", 0.40, "fell"),
        ("gaps", "start", 0.89, "crossed"), ("stairs", "gaps", 0.005, "crossed"),
        ("jumps", "start", 0.70, "crossed"), ("gaps", "jumps", 0.60, "fell")]
    summ = table2_report.switch_summary(recs)
    g = summ["gaps"]["jumps"]
    assert g["n"] == 2 and g["lost_pct"] == 100.0 and g["forced_pct"] == 0.0
    assert g["ahead_m_q"] == pytest.approx([0.45, 0.50, 0.55])
    assert g["lost_by_ahead"] == [[0.4, 0.5, 1, 1], [0.6, 0.7, 1, 1]]
    assert summ["stairs"]["gaps"]["forced_pct"] == 100.0  # 5 mm: within the forced 1 cm
    assert summ["stairs"]["gaps"]["lost_by_ahead"] == [[0.0, 0.1, 1, 0]]
    assert summ["jumps"]["start"]["lost_pct"] == 0.0 and list(summ["gaps"]) == ["start", "jumps"]
    md = table2_report.switches_markdown({"m": summ})
    assert "| m | jumps | 2 | 0.50 (0.45-0.55) | 0.0 | 100.0 | - |" in md
    # with the rollout's logs: the model output at each switch, and forced as logged
    out = np.array([[0.9, 0.2], [0.95, 0.1], [nan, nan], [0.8, 0.6]])
    forced = np.array([[False, False], [False, True], [False, False], [False, True]])
    recs = table2_report.switch_outcomes(tracks, ahead, progress, fell, fail_kind,
                                         switch_output=out, switch_forced=forced)
    assert [(r["output"], r["forced"]) for r in recs] == [
        (0.9, False), (0.2, False), (0.95, False), (0.1, True), (0.8, False), (0.6, True)]
    summ = table2_report.switch_summary(recs)
    assert summ["gaps"]["jumps"]["forced_pct"] == 50.0  # the log, not the distance, says forced
    assert summ["gaps"]["jumps"]["output_q"] == pytest.approx([0.3, 0.4, 0.5])
    md = table2_report.switches_markdown({"m": summ})
    assert "| m | jumps | 2 | 0.50 (0.45-0.55) | 50.0 | 100.0 | 0.40 (0.30-0.50) |" in md


def test_switches_cli_writes_the_summary_of_its_rollouts(tmp_path, monkeypatch, capsys):
    """`evaluate switches` on a faked rollout of 2 trials: trial 0 switches into its first
    artifact 0.8 m out and falls on it; trial 1 switches into its first two at 0.5 and 0.3 m and
    finishes. The JSON, Markdown and figure hold exactly those switches; bad flags are refused
    naming their values, before any rollout."""
    tracks = [table2.mixed_track(config.MULTI_TRACK_SEED + i, 7) for i in range(2)]
    kinds = terrain.ARTIFACT_KINDS
    first = tracks[0].artifacts[0]
    ahead = np.full((2, 7), np.nan)
    ahead[0, 0], ahead[1, :2] = 0.8, [0.5, 0.3]
    calls = []

    def fake_multi(methods, cfg, seed, print_fn=None, per_trial=None):
        calls.append((list(methods), cfg.trials, cfg.batch, cfg.horizon_s, cfg.n_artifacts))
        for m in methods:
            per_trial[m] = {"switch_ahead_m": ahead, "fell": np.array([1.0, 0.0]),
                            "fail_kind": np.array([kinds.index(first[0]), -1]),
                            "progress_frac": np.array([(first[1] + 0.2) / tracks[0].finish_x_m, 1.0])}
        return [], {}

    monkeypatch.setattr(tables, "evaluate_multi", fake_multi)
    monkeypatch.setattr(tables, "available_methods", lambda methods, *a, **k: (list(methods), []))
    for bad, text in ((["--trials", "0"], "argument --trials: must be >= 1, got '0'"),
                      (["--horizon-s", "-1"], "argument --horizon-s: must be > 0, got '-1'")):
        with pytest.raises(SystemExit):
            ev.main(["switches", "--out", str(tmp_path), *bad])
        assert text in capsys.readouterr().err
    assert not calls
    assert ev.main(["switches", "--trials", "2", "--methods", "lookup", "--out", str(tmp_path)]) == 0
    assert calls == [(["lookup"], 2, 2, 60.0, 7)]
    doc = json.loads((tmp_path / "switch_distances.json").read_text())
    assert doc["settings"]["trials"] == 2 and doc["settings"]["methods"] == ["lookup"]
    by = doc["by_method"]["lookup"]
    k0, k1 = tracks[0].artifacts[0][0], tracks[1].artifacts[0][0]
    got = {(k, prev): (c["n"], c["lost_pct"]) for k, d in by.items() for prev, c in d.items()}
    want = {}
    for (kind, prev), lost in (((k0, "start"), 100.0), ((k1, "start"), 0.0),
                               ((tracks[1].artifacts[1][0], k1), 0.0)):
        n, l0 = want.get((kind, prev), (0, 0.0))
        want[(kind, prev)] = (n + 1, (l0 * n + lost) / (n + 1))
    assert got == want
    assert (tmp_path / "switch_distances_gaps.png").stat().st_size > 5_000
    assert "| lookup | start |" in (tmp_path / "switch_distances.md").read_text()


def test_each_method_has_its_rollout_and_rule():
    """Methods share a compiled rollout only when they share the init, the suite (setup
    policies or not) and the rule's model; `learned_setup` is the learned rule on the setup
    suite, and every method is listed once."""
    keys = {m: methods_lib.method(m).rollout for m in ("lookup", "lookup_context", "estimator_no_overlap",
                                              "lookup_context_setup", "learned", "learned_setup",
                                              "learned_no_overlap")}
    assert keys == {"lookup": "stand", "lookup_context": "stand", "estimator_no_overlap": "random",
                    "lookup_context_setup": "stand+setup", "learned": "stand+learned",
                    "learned_setup": "stand+setup+learned",
                    "learned_no_overlap": "random+learned"}
    assert methods_lib.method("learned_setup").setup_of == "learned"
    assert methods_lib.method("learned_setup").rule == "estimator"
    assert len(set(names.MULTI_METHODS)) == len(names.MULTI_METHODS)

"""Recipes that replay (learning/recipe.py): every committed run has one, and what `make train-all`
would run from it matches what the run recorded. No training: the commands' trainers are replaced
by a stub that keeps the config each call would train with."""

from __future__ import annotations

import json
import pathlib
import re

import pytest

from biped_switch.learning import recipe as recipe_lib
from biped_switch.learning import runs as runs_lib
from biped_switch.paths import REPO

RUNS = recipe_lib.committed_runs()
IDS = [d.name for d in RUNS]
CKPT = re.compile(r"(?:^|/)([A-Za-z0-9_]+)/(?:checkpoints|warm_start)/(\d{12})$")


def _recorded(run_dir: pathlib.Path) -> tuple[dict, dict]:
    ckpt = runs_lib.latest_checkpoint(run_dir)
    return runs_lib.read_json(run_dir / "config.json"), runs_lib.read_progress(ckpt)


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    """{run: (config of its last segment, argv, warm-start path)}: each recipe's last segment
    given to its command's real `main`, whose trainer only keeps the config."""
    from biped_switch import distill, dqn, train
    from biped_switch.learning import dqn_train, trainer
    from biped_switch.products import student

    seen = {}

    def keep_ppo(cfg, run_dir, *a, **k):
        seen["cfg"] = json.loads(cfg.to_json_best_effort())
        return {}

    def keep_dqn(cfg, run_dir, *a, **k):
        seen["cfg"] = json.loads(cfg.to_json_best_effort())

    mp = pytest.MonkeyPatch()
    mp.setattr(trainer, "train", keep_ppo)
    mp.setattr(dqn_train, "train_dqn", keep_dqn)
    mp.setattr(student, "train", keep_dqn)
    out, results = tmp_path_factory.mktemp("replay"), {}
    try:
        for d in RUNS:
            rec = recipe_lib.load(d)
            seg = recipe_lib.segments(rec)[-1]
            warm = str(REPO / rec["warm_start"]["path"]) if rec.get("warm_start") else None
            flags = {**seg["flags"], **({"--warm-start": warm} if warm else {})}
            args = recipe_lib.command_argv(rec, flags, out)
            main = {"train": train.main, "dqn": dqn.main, "distill": distill.main}[rec["command"]]
            seen.clear()
            with runs_lib.no_committed_copy():
                assert main(args) == 0
            results[d.name] = (seen["cfg"], args, warm)
    finally:
        mp.undo()
    return results


def test_every_committed_run_has_a_recipe():
    assert {d.name for d in RUNS} >= {"walk_stand", "mixed_stand", "dqn_stand"}
    for d in RUNS:
        rec = recipe_lib.load(d)
        assert rec["run"] == d.name
        assert rec["initial_config"]["config"], d.name
        for c in rec["changes"]:
            assert c["why"] and c["flag"].startswith("--"), (d.name, c)


@pytest.mark.parametrize("run", IDS)
def test_recipe_matches_the_recorded_run(run, replayed):
    d = next(d for d in RUNS if d.name == run)
    rec = recipe_lib.load(d)
    cfg, prog = _recorded(d)
    # the final step, and how the run ended
    assert prog["step"] == rec["final_step"]
    if rec["ends"] == "curriculum":
        assert prog.get("curriculum_done") or cfg.get("stop_when_done", True)
    total = prog.get("total_steps", prog.get("total_env_steps"))
    if rec["ends"] == "total steps":
        assert prog["step"] >= total
    # the last segment's config is the recorded one, up to the differences the recipe declares
    mine, args, warm = replayed[run]
    diff = recipe_lib.replay_config_diff(cfg, mine)
    diff.pop("warm_start", None)
    if rec["ends"] == "by hand":  # the replay stops where the run was stopped
        ceiling = {"distill": "distill.total_env_steps"}.get(rec["command"], "total_timesteps")
        assert diff.pop(ceiling) == [total, rec["final_step"]]
    declared = {k: [v["recorded"], v["replay"]] for k, v in rec["config_differences"].items()}
    assert diff == declared, f"{run}: replayed config differs from config.json beyond the recipe"
    assert all(v["why"] for v in rec["config_differences"].values())
    # the warm start: the step config.json names, from a committed checkpoint of the same run
    recorded_warm = cfg.get("warm_start") or ""
    if not rec.get("warm_start"):
        assert recorded_warm == "" or rec["command"] == "dqn"
        return
    w = rec["warm_start"]
    src, step = CKPT.search(recorded_warm).groups()
    assert (src, int(step)) == (w["run"], w["step"]) and recorded_warm == w["recorded"]
    assert CKPT.search(w["path"]).groups() == (w["run"], f"{w['step']:012d}")
    assert runs_lib.read_progress(REPO / w["path"])["step"] == w["step"]
    assert args[args.index("--warm-start") + 1] == warm


def test_continuations_start_where_their_source_ended():
    for d in RUNS:
        c = recipe_lib.load(d).get("continues")
        if c:
            src = recipe_lib.load(recipe_lib.source_dir(c["run"]))
            assert c["step"] == src["final_step"]
            assert runs_lib.read_progress(REPO / c["path"])["step"] == c["step"]


def test_segments_cut_at_each_change_and_export():
    rec = recipe_lib.load(REPO / "models/policies/mixed_stand")
    segs = recipe_lib.segments(rec)
    assert [s["until"] for s in segs[:-1]] == sorted({c["step"] for c in rec["changes"]})
    assert segs[-1]["until"] == rec["final_step"]
    assert segs[0]["flags"]["--guide-notch"] == 0.5 and segs[-1]["flags"]["--guide-notch"] == 0.25
    assert segs[-1]["flags"]["--max-action-std"] == 0.5
    assert segs[0]["flags"]["--total-steps"] == segs[0]["until"]  # each stops where the next starts
    walk = recipe_lib.load(REPO / "models/policies/walk_stand")
    recipes = [recipe_lib.load(d) for d in RUNS]
    keep = recipe_lib.exports("walk_stand", recipes)
    assert keep == {32_366_592}  # the stand artifact policies' warm start
    assert 32_366_592 in [s["until"] for s in recipe_lib.segments(walk, keep)]


def test_train_all_replays_every_policy_sources_first():
    make = (REPO / "Makefile").read_text()
    rule = make.split("\ntrain-all:", 1)[1].split("\n\n", 1)[0]
    assert "--recipe $(RECIPES)" in rule and "\nRECIPES ?= models/policies/*/\n" in make
    ordered = [d.name for d in recipe_lib.order(d for d in RUNS if d.parent.name == "policies")]
    assert set(ordered) == {d.name for d in RUNS if d.parent.name == "policies"}
    for d in RUNS:
        rec = recipe_lib.load(d)
        for need in recipe_lib._needs(rec):
            if d.name in ordered:
                assert ordered.index(need) < ordered.index(d.name)


def test_replay_runs_each_segment_then_resumes(tmp_path):
    """`replay` with stub commands: one call per segment with --total-steps at each cut, the
    warm start passed on, nothing from the committed copy; a second replay does nothing."""
    calls = []

    def fake_train(argv):
        calls.append(argv)
        run = pathlib.Path(argv[argv.index("--out") + 1]) / argv[argv.index("--name") + 1]
        step = int(argv[argv.index("--total-steps") + 1])
        ckpt = run / "checkpoints" / f"{min(step, 55_107_584):012d}"
        ckpt.mkdir(parents=True, exist_ok=True)
        (ckpt / "progress.json").write_text(json.dumps({"step": min(step, 55_107_584)}))
        return 0

    out = tmp_path / "replay"
    assert recipe_lib.replay(REPO / "models/policies/jumps_stand", out, {"train": fake_train},
                             say=lambda s: None) == 0
    rec = recipe_lib.load(REPO / "models/policies/jumps_stand")
    assert len(calls) == len(rec["changes"]) + 1
    assert calls[0][calls[0].index("--total-steps") + 1] == str(rec["changes"][0]["step"])
    assert calls[-1][calls[-1].index("--learning-rate") + 1] == "0.0001"
    assert calls[0][calls[0].index("--warm-start") + 1].endswith("walk_stand/warm_start/000032366592")
    assert (out / "jumps_stand" / recipe_lib.DONE).is_file()
    calls.clear()
    assert recipe_lib.replay(REPO / "models/policies/jumps_stand", out, {"train": fake_train},
                             say=lambda s: None) == 0
    assert not calls


def test_no_committed_copy_is_scoped(tmp_path):
    run = tmp_path / "walk_stand"
    run.mkdir()
    with runs_lib.no_committed_copy():
        runs_lib.restore_committed(run, print_fn=lambda s: None)
        assert runs_lib.latest_checkpoint(run) is None
        assert runs_lib.read_config(run, committed=True) == {}
    assert runs_lib.read_config(run, committed=True)["policy"] == "walk"



def _fake_train(calls):
    def fake_train(argv):
        calls.append(argv)
        run = pathlib.Path(argv[argv.index("--out") + 1]) / argv[argv.index("--name") + 1]
        step = int(argv[argv.index("--total-steps") + 1]) if "--total-steps" in argv else 90_000_000
        ckpt = run / "checkpoints" / f"{step:012d}"
        ckpt.mkdir(parents=True, exist_ok=True)
        (ckpt / "progress.json").write_text(json.dumps({"step": step}))
        return 0
    return fake_train


def test_a_seeded_replay_starts_from_its_own_sources_only(tmp_path, monkeypatch):
    """`train --recipe ... --seed 1`: into runs/replay_seed1/, every call with --seed 1, and the
    artifact policy's warm start is the seed-1 walk at the recipe's step, never the committed
    walk (an error naming the missing source until it exists)."""
    monkeypatch.setattr(recipe_lib, "REPO", tmp_path / "repo")  # no committed seed-1 replays
    calls = []
    out = recipe_lib.replay_dir(tmp_path, 1)
    assert out == tmp_path / "replay_seed1" and recipe_lib.replay_dir(tmp_path, None).name == "replay"
    with pytest.raises(recipe_lib.RecipeError, match="walk_stand.*32,366,592"):
        recipe_lib.replay(REPO / "models/policies/jumps_stand", out, {"train": _fake_train(calls)},
                          say=lambda s: None, seed=1)
    assert not calls
    assert recipe_lib.replay(REPO / "models/policies/walk_stand", out, {"train": _fake_train(calls)},
                             say=lambda s: None, seed=1) == 0
    assert (out / "walk_stand" / "warm_start" / f"{32_366_592:012d}" / "progress.json").is_file()
    calls.clear()
    assert recipe_lib.replay(REPO / "models/policies/jumps_stand", out, {"train": _fake_train(calls)},
                             say=lambda s: None, seed=1) == 0
    assert all(c[c.index("--seed") + 1] == "1" for c in calls)
    warm = calls[0][calls[0].index("--warm-start") + 1]
    assert pathlib.Path(warm) == out / "walk_stand" / "warm_start" / f"{32_366_592:012d}"
    with pytest.raises(recipe_lib.RecipeError, match="stairs_stand, gaps_stand"):
        recipe_lib.replay(REPO / "models/policies/setup_gaps_stand", out,
                          {"train": _fake_train(calls)}, say=lambda s: None, seed=1)
    for r in ("stairs_stand", "gaps_stand"):
        assert recipe_lib.replay(REPO / "models/policies" / r, out, {"train": _fake_train(calls)},
                                 say=lambda s: None, seed=1) == 0
    calls.clear()
    assert recipe_lib.replay(REPO / "models/policies/setup_gaps_stand", out,
                             {"train": _fake_train(calls)}, say=lambda s: None, seed=1) == 0
    assert calls[0][calls[0].index("--suite-runs") + 1] == str(out)  # the seed-1 suite
    with pytest.raises(recipe_lib.RecipeError, match="-1"):
        recipe_lib.replay_dir(tmp_path, -1)


def test_train_all_with_jobs_starts_each_recipe_once_its_source_is_there(tmp_path, monkeypatch):
    """`replay_all(jobs=3)`: walk first and alone; the three artifact policies side by side once
    the walk's warm-start copy exists, never more than `jobs` at a time, each with one mujoco
    thread and --seed; the setup policy after gaps."""
    import subprocess

    monkeypatch.setattr(recipe_lib, "REPO", tmp_path / "repo")  # no committed seed-1 replays
    events, live = [], set()
    out = recipe_lib.replay_dir(tmp_path, 1)

    class FakeProc:
        def __init__(self, cmd, stdout, stderr, env):
            self.run = pathlib.Path(cmd[cmd.index("--recipe") + 1]).name
            assert env["BIPED_SWITCH_NTHREAD"] == "1" and cmd[cmd.index("--seed") + 1] == "1"
            live.add(self.run)
            events.append(("start", self.run, len(live)))
            self.polls = 0
            self.returncode = None

        def poll(self):
            self.polls += 1
            if self.polls < 2:
                return None
            run = out / self.run
            rec = recipe_lib.load(REPO / "models/policies" / self.run)
            for s in recipe_lib.exports(self.run, [recipe_lib.load(d) for d in RUNS]):
                (run / "warm_start" / f"{s:012d}").mkdir(parents=True, exist_ok=True)
                (run / "warm_start" / f"{s:012d}" / "progress.json").write_text("{}")
            (run / recipe_lib.DONE).write_text(json.dumps({"step": rec["final_step"]}))
            live.discard(self.run)
            events.append(("end", self.run, len(live)))
            self.returncode = 0
            return 0

    monkeypatch.setattr(subprocess, "Popen", FakeProc)
    dirs = [REPO / "models/policies" / n for n in ("setup_gaps_stand", "gaps_stand", "jumps_stand",
                                                    "stairs_stand", "walk_stand")]
    assert recipe_lib.replay_all(dirs, tmp_path, say=lambda s: None, seed=1, jobs=3,
                                 poll_s=0, report_s=0) == 0
    starts = [e[1] for e in events if e[0] == "start"]
    assert starts[0] == "walk_stand" and starts[-1] == "setup_gaps_stand"
    assert events[1] == ("end", "walk_stand", 0)  # nothing else ran before the walk was there
    assert max(n for kind, _, n in events if kind == "start") == 3
    ends = [e[1] for e in events if e[0] == "end"]
    assert all(ends.index(r) < starts.index("setup_gaps_stand")
               for r in ("jumps_stand", "stairs_stand", "gaps_stand"))  # its frozen suite


def test_a_committed_seeded_replay_goes_on_where_it_stopped(tmp_path, monkeypatch):
    """`train --recipe ... --seed 1 --commit` copies each replay's latest checkpoint, warm-start
    copies and logs to models/replay_seed1/<run>/; a fresh clone's replay restores that copy and
    goes on from its step, with the warm-start copy there for the artifact policies."""
    monkeypatch.setattr(recipe_lib, "REPO", tmp_path / "repo")
    calls = []
    out = recipe_lib.replay_dir(tmp_path / "runs", 1)
    fake = _fake_train(calls)

    def stop_early(argv):  # the session ends after walk's fourth segment
        if len(calls) == 4:
            return 1
        return fake(argv)

    rec = recipe_lib.load(REPO / "models/policies/walk_stand")
    assert recipe_lib.replay(REPO / "models/policies/walk_stand", out, {"train": stop_early},
                             say=lambda s: None, seed=1) == 1
    step = int(runs_lib.latest_checkpoint(out / "walk_stand").name)
    (out / "walk_stand" / "train.log").write_text("log\n")
    saved = recipe_lib.commit_replays([REPO / "models/policies/walk_stand"], tmp_path / "runs", 1)
    assert saved == [tmp_path / "repo" / "models" / "replay_seed1" / "walk_stand"]
    assert [c.name for c in (saved[0] / "checkpoints").iterdir()] == [f"{step:012d}"]
    assert (saved[0] / "warm_start" / f"{32_366_592:012d}" / "progress.json").is_file()
    fresh = recipe_lib.replay_dir(tmp_path / "clone_runs", 1)  # a fresh clone: no runs/
    calls.clear()
    said = []
    assert recipe_lib.replay(REPO / "models/policies/walk_stand", fresh, {"train": fake},
                             say=said.append, seed=1) == 0
    assert any("going on from its committed copy" in s for s in said)
    firsts = [int(c[c.index("--total-steps") + 1]) for c in calls if "--total-steps" in c]
    assert all(t > step for t in firsts) and len(calls) == len(recipe_lib.segments(
        rec, recipe_lib.exports("walk_stand", [recipe_lib.load(d) for d in RUNS]))) - 4


def test_train_all_status_gives_the_hours_left_to_the_recorded_final_step(tmp_path):
    log = tmp_path / "replay.log"
    assert recipe_lib._status(log, 100) == "starting"
    log.write_text("resuming ...\n[walk/stand] step 1,000,000  stage pushes d=1.00  2,000 steps/s"
                   "  elapsed 0.10 h  left ~0.2 h\n")
    line = recipe_lib._status(log, 8_200_000)
    assert line.startswith("[walk/stand] step 1,000,000") and "elapsed" not in line
    assert line.endswith("~1.0 h to 8,200,000")  # 7.2M steps at 2,000/s


def test_a_warm_start_source_replays_past_its_export_without_a_rule_its_run_lacked():
    """A run that others warm-start from at a step before its end must reach that step in its
    replay: if it trained before the push plateau rule existed, the segments up to the export
    turn the rule off (walk_stand's seed-1 replay otherwise ended at 24.24M, short of 32.37M)."""
    recipes = [recipe_lib.load(d) for d in RUNS]
    checked = 0
    for d in RUNS:
        rec = recipe_lib.load(d)
        keep = recipe_lib.exports(rec["run"], recipes)
        if not keep or rec["command"] != "train":
            continue
        cfg, _ = _recorded(d)
        had_rule = cfg.get("curriculum", {}).get("push_plateau_steps") is not None
        for seg in recipe_lib.segments(rec, keep):
            if seg["until"] <= max(keep) and not had_rule:
                assert seg["flags"].get("--push-plateau-steps") == 0, (rec["run"], seg["until"])
                checked += 1
    assert checked >= 4  # walk_stand's segments up to 32.37M


def test_a_replay_pins_the_update_its_run_trained_with():
    """A committed `train` run's replay passes the PPO update of its initial config.json
    (`recipe.PINNED`), whatever today's preset says; a flag the recipe sets itself wins, and a
    command without those flags (dqn, distill) gets none."""
    rec = {"command": "train", "start": {"--policy": "walk"}, "changes": [],
           "initial_config": {"config": {"ppo": {"num_updates_per_batch": 4, "num_minibatches": 4}}}}
    assert recipe_lib.flags_at(rec, 0) == {"--update-epochs": 4, "--minibatches": 4, "--policy": "walk"}
    rec["start"]["--minibatches"] = 8
    assert recipe_lib.flags_at(rec, 0)["--minibatches"] == 8
    assert recipe_lib.pinned({**rec, "command": "dqn"}) == {}
    assert recipe_lib.pinned({**rec, "initial_config": {"config": {"ppo": {}}}}) == {}
    walk = recipe_lib.load(REPO / "models" / "policies" / "walk_stand")
    assert recipe_lib.segments(walk)[0]["flags"]["--update-epochs"] == 4

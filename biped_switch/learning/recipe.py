"""Training recipes: how each committed run was trained, step by step, and its replay from scratch.

Plain Python (no JAX): the reports layer and the tests read recipes fast. A committed run folder
(models/policies/<run>/, models/baselines/<run>/) holds `recipe.json`:

    run, command       the run's name and the command line that trains it ("train", "dqn" or
                       "distill")
    start              the flags it was first trained with ({"--flag": value}; true: a bare flag)
    changes            every mid-run change of a flag: [{step, flag, value, why}], oldest first;
                       the change holds from that step (a resume from the checkpoint there) on
    warm_start         the checkpoint its parameters started from ({run, step, path: committed,
                       recorded: the path config.json names, note}), or null
    suite              the runs whose final checkpoints it trains beside (a setup policy's frozen
                       source and target policies), or absent
    continues          the run it is a continuation of ({run, step, path}), or null
    final_step, ends   where it stopped and why ("curriculum": its curriculum finished;
                       "total steps": --total-steps; "by hand": stopped, so the replay stops there)
    initial_config     config.json as first committed ({commit, step, config})
    code_changes       settings the code changed under the run (no flag replays them)
    config_differences what a replay's config.json will differ in from the recorded one, and why
    notes              anything else a replay does not reproduce

`segments` cuts a recipe into the calls of its command line that replay it, one per stretch of
unchanged flags, each run up to the step where the next change came (`--total-steps`); `replay`
makes those calls into <out>/<run>/, never falling back on the committed copy
(`runs.no_committed_copy`), and resumes a replay that was cut off.

A replay with a `seed` (`train --recipe ... --seed 1`) is a second training seed of the suite: the
recipe's own `--seed` is replaced, it goes into its own folder (`replay_dir`: runs/replay_seed1/),
and a warm start or a continuation must come from the replay of its source in that folder, never
from a committed checkpoint (trained on another seed).
"""

from __future__ import annotations

import json
import pathlib
import re
import shutil

from biped_switch.learning import runs as runs_lib
from biped_switch.paths import BASELINE_DIR, COMMITTED_DIR, REPO, rel

RECIPE = "recipe.json"
DONE = "replay.json"  # written in a replay's run folder once every segment has run
ENDS = ("curriculum", "total steps", "by hand")
# each command's step ceiling flag
TOTAL = {"train": "--total-steps", "dqn": "--total-steps", "distill": "--total-steps"}
# settings whose default may change under a committed run: its replay passes the run's own
# (initial_config) by these flags of `train`, unless the recipe sets them
PINNED = {"--update-epochs": ("ppo", "num_updates_per_batch"),
          "--minibatches": ("ppo", "num_minibatches")}


class RecipeError(ValueError):
    """A recipe that cannot be replayed: the message names the file and what is wrong."""


def committed_runs() -> list[pathlib.Path]:
    """Every committed training run: the folders under models/policies/ and models/baselines/
    with a checkpoint."""
    return [d for root in (COMMITTED_DIR, BASELINE_DIR) if root.is_dir()
            for d in sorted(root.iterdir()) if runs_lib.latest_checkpoint(d) is not None]


def load(run_dir) -> dict:
    """A run folder's recipe.json, checked for the keys a replay needs."""
    path = pathlib.Path(run_dir) / RECIPE
    if not path.is_file():
        raise RecipeError(f"{path}: no recipe (every committed run has one)")
    rec = runs_lib.read_json(path)
    keys = ("run", "command", "start", "changes", "final_step", "ends")
    missing = [k for k in keys if k not in rec]
    if missing:
        raise RecipeError(f"{path}: missing {', '.join(missing)}")
    if rec["ends"] not in ENDS:
        raise RecipeError(f"{path}: ends {rec['ends']!r} is not one of {ENDS}")
    steps = [c["step"] for c in rec["changes"]]
    first = (rec.get("continues") or {}).get("step", 0)
    if steps != sorted(steps) or any(not first < s < rec["final_step"] for s in steps):
        raise RecipeError(f"{path}: change steps {steps} are not in order within "
                          f"({first:,}, {rec['final_step']:,})")
    return rec


def pinned(rec: dict) -> dict:
    """{flag: the run's own value} of the `PINNED` settings its initial config.json records
    (a `train` recipe only)."""
    if rec["command"] != "train":
        return {}
    cfg = (rec.get("initial_config") or {}).get("config") or {}
    return {flag: cfg[sec][key] for flag, (sec, key) in PINNED.items()
            if key in cfg.get(sec, {})}


def flags_at(rec: dict, step: int) -> dict:
    """The flags in force after `step`: the pinned settings, then `start`, with every change at
    or before it applied."""
    flags = {**pinned(rec), **rec["start"]}
    for c in rec["changes"]:
        if c["step"] <= step:
            flags[c["flag"]] = c["value"]
    return flags


def segments(rec: dict, exports=()) -> list[dict]:
    """The calls that replay `rec`: [{from, until, flags, why}], one per stretch of unchanged
    flags, also cut at `exports` (steps another recipe warm-starts from). Each but the last runs
    to `until` (`--total-steps until`); the last keeps the run's own ceiling, unless the run was
    stopped by hand, when it stops where the run did."""
    first = (rec.get("continues") or {}).get("step", 0)
    final = rec["final_step"]
    cuts = sorted({c["step"] for c in rec["changes"]} | {s for s in exports if first < s < final})
    bounds = [first] + cuts + [final]
    out = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        flags = flags_at(rec, a)
        if b != final or rec["ends"] == "by hand":
            flags[TOTAL[rec["command"]]] = b
        why = [f"{c['flag']} {c['value']}: {c['why']}" for c in rec["changes"] if c["step"] == a]
        out.append({"from": a, "until": b, "flags": flags,
                    "why": "; ".join(why) or ("start" if a == first else "a warm-start source")})
    return out


def argv(flags: dict) -> list[str]:
    """Command-line arguments of a flags dict (true: a bare flag; false or null: left out)."""
    out = []
    for k, v in flags.items():
        if v is True:
            out.append(k)
        elif v is not None and v is not False:
            out += [k, format(v, "g") if isinstance(v, float) else str(v)]
    return out


def command_argv(rec: dict, flags: dict, out: pathlib.Path) -> list[str]:
    """A segment's arguments for its command line, writing into <out>/<run>/."""
    if rec["command"] in ("train", "distill"):
        return argv(flags) + ["--out", str(out), "--name", rec["run"]]
    return argv(flags) + ["--out", str(pathlib.Path(out) / rec["run"])]


def source_dir(name: str) -> pathlib.Path:
    """The committed folder of a run named in a recipe (a warm-start source, a continued run)."""
    for root in (COMMITTED_DIR, BASELINE_DIR):
        if (root / name).is_dir():
            return root / name
    raise RecipeError(f"no committed run {name!r} under {rel(COMMITTED_DIR)} or "
                      f"{rel(BASELINE_DIR)}")


def exports(name: str, recipes) -> set[int]:
    """The steps of run `name` that other recipes warm-start from, short of its final step."""
    mine = next((r for r in recipes if r["run"] == name), None)
    final = mine["final_step"] if mine else None
    return {r["warm_start"]["step"] for r in recipes
            if (r.get("warm_start") or {}).get("run") == name and r["warm_start"]["step"] != final}


def order(run_dirs) -> list[pathlib.Path]:
    """Run folders with each warm-start source and continued run before the runs that need it."""
    todo = [pathlib.Path(d) for d in run_dirs]
    recs = {d: load(d) for d in todo}
    names = {recs[d]["run"] for d in todo}
    done, out = set(), []
    while todo:
        ready = [d for d in todo if all(n in done or n not in names for n in _needs(recs[d]))]
        if not ready:
            raise RecipeError(f"recipes depend on each other in a circle: {[str(d) for d in todo]}")
        out.append(ready[0])
        done.add(recs[ready[0]]["run"])
        todo.remove(ready[0])
    return out


def _needs(rec: dict) -> list[str]:
    return [s["run"] for s in (rec.get("warm_start"), rec.get("continues")) if s] + list(
        rec.get("suite", []))


def _step(run_dir: pathlib.Path) -> int:
    ckpt = runs_lib.latest_checkpoint(run_dir)
    return 0 if ckpt is None else int(runs_lib.read_progress(ckpt)["step"])


def committed_replay_dir(out: pathlib.Path) -> pathlib.Path:
    """Where a seeded replay folder's unfinished or final runs are committed, for a later session
    or a fresh clone to go on from: models/<replay folder name>/ (models/replay_seed1/)."""
    return REPO / "models" / pathlib.Path(out).name


def commit_replay(target: pathlib.Path) -> pathlib.Path:
    """Copies a replayed run (<out>/<run>/) to `committed_replay_dir`: its latest checkpoint only,
    the warm-start copies later recipes start from, its logs and replay.json."""
    dest = committed_replay_dir(target.parent) / target.name
    runs_lib.commit_run(target, dest)
    for name in ("replay.log", DONE):
        if (target / name).is_file():
            shutil.copy2(target / name, dest / name)
    if (target / "warm_start").is_dir():
        shutil.copytree(target / "warm_start", dest / "warm_start", dirs_exist_ok=True)
    return dest


def _restore_replay(target: pathlib.Path, say) -> None:
    """A seeded replay with nothing under <out>/<run>/ goes on from its committed copy."""
    src = committed_replay_dir(target.parent) / target.name
    if runs_lib.latest_checkpoint(target) is None and runs_lib.latest_checkpoint(src) is not None:
        shutil.copytree(src, target, dirs_exist_ok=True)
        say(f"{rel(target)}: going on from its committed copy {rel(src)} "
            f"(step {_step(target):,})")


def replay_dir(runs, seed: int | None) -> pathlib.Path:
    """Where a replay goes: <runs>/replay/, or <runs>/replay_seed<seed>/ for a seeded replay."""
    if seed is not None and seed < 0:
        raise RecipeError(f"--seed {seed}: a replay's seed must be >= 0")
    return pathlib.Path(runs) / ("replay" if seed is None else f"replay_seed{seed}")


def _warm_start(rec: dict, out: pathlib.Path, say, strict: bool = False) -> str | None:
    """The warm-start checkpoint of a replay: the source's replay under `out` when there is one
    (its copy at that step, or its final checkpoint for a source's final step), else (unless
    `strict`, a seeded replay) the committed checkpoint the recipe names."""
    w = rec.get("warm_start")
    if not w:
        return None
    src = out / w["run"]
    kept = src / "warm_start" / f"{w['step']:012d}"
    if (kept / runs_lib.PROGRESS).is_file():
        say(f"warm start: {rel(kept)}, the replayed {w['run']} at its step {w['step']:,}")
        return str(kept)
    final = load(source_dir(w["run"]))["final_step"]
    if (src / DONE).is_file() and w["step"] == final:
        ckpt = runs_lib.latest_checkpoint(src)
        say(f"warm start: {rel(ckpt)}, the replayed {w['run']}'s final checkpoint")
        return str(ckpt)
    if strict:
        raise RecipeError(f"{rec['run']}: a seeded replay warm-starts from its own replay of "
                          f"{w['run']} at step {w['step']:,} ({rel(kept)}), which is not there "
                          f"yet: replay {w['run']}'s recipe with the same seed first")
    path = REPO / w["path"]
    if not (path / runs_lib.PROGRESS).is_file():
        raise RecipeError(f"{rec['run']}: its warm start {w['path']} is not a checkpoint")
    say(f"warm start: the committed {w['path']} (no replay of {w['run']} under {rel(out)})")
    return str(path)


def _continue(rec: dict, target: pathlib.Path, out: pathlib.Path, say, strict: bool = False) -> None:
    """A continuation starts from its source's replay under `out` (its final checkpoint), else
    (unless `strict`) from the committed checkpoint the recipe names, copied with the source's
    logs."""
    c = rec["continues"]
    src = out / c["run"]
    if (src / DONE).is_file():
        ckpt, logs = runs_lib.latest_checkpoint(src), src
    elif strict:
        raise RecipeError(f"{rec['run']}: a seeded replay continues its own replay of {c['run']} "
                          f"under {rel(out)}, which has not finished: replay it first")
    else:
        ckpt, logs = REPO / c["path"], source_dir(c["run"])
    say(f"{rec['run']} continues {c['run']}: starting from {rel(ckpt)}")
    (target / "checkpoints").mkdir(parents=True, exist_ok=True)
    shutil.copytree(ckpt, target / "checkpoints" / ckpt.name, dirs_exist_ok=True)
    for name in ("config.json", "metrics.csv", "train.log"):
        if (logs / name).is_file():
            shutil.copy2(logs / name, target / name)


def replay(run_dir, out, mains: dict, say=print, seed: int | None = None) -> int:
    """Replays a run's recipe from scratch into <out>/<run>/: each segment one call of
    `mains[command](argv)` (train.py's or dqn.py's main). Resumes where an earlier replay stopped;
    keeps a copy of each checkpoint another recipe warm-starts from under <run>/warm_start/.
    With `seed`, the recipe's --seed is replaced and its sources must be replays (module doc)."""
    run_dir, out = pathlib.Path(run_dir), pathlib.Path(out)
    rec = load(run_dir)
    strict = seed is not None
    target = out / rec["run"]
    if strict:
        _restore_replay(target, say)
    if (target / DONE).is_file():
        say(f"{rel(target)}: {rec['run']} was replayed already ({DONE}); remove it to replay again")
        return 0
    recipes = [load(d) for d in committed_runs() if (d / RECIPE).is_file()]
    keep = exports(rec["run"], recipes)
    flags_extra = {}
    with runs_lib.no_committed_copy():
        if rec.get("continues") and runs_lib.latest_checkpoint(target) is None:
            _continue(rec, target, out, say, strict)
        warm = _warm_start(rec, out, say, strict)
        if warm:
            flags_extra["--warm-start"] = warm
        if strict:
            flags_extra["--seed"] = seed
            if rec.get("suite"):
                missing = [r for r in rec["suite"] if not (out / r / DONE).is_file()]
                if missing:
                    raise RecipeError(f"{rec['run']}: a seeded replay trains beside its own "
                                      f"replays of {', '.join(missing)} under {rel(out)}, which "
                                      f"have not finished: replay them first")
                flags_extra["--suite-runs"] = str(out)
        segs = segments(rec, keep)
        for i, seg in enumerate(segs, 1):
            if _step(target) >= seg["until"]:
                continue
            args = command_argv(rec, {**seg["flags"], **flags_extra}, out)
            say(f"[recipe {rec['run']}] segment {i}/{len(segs)}, steps {seg['from']:,} -> "
                f"{seg['until']:,} ({seg['why']}):\n  python -m biped_switch.{rec['command']} "
                f"{' '.join(args)}")
            code = mains[rec["command"]](args)
            if code:
                return code
            if seg["until"] in keep:
                _keep(target, seg["until"], say)
    (target / DONE).write_text(json.dumps({
        "recipe": rel(run_dir / RECIPE), "step": _step(target), "seed": seed,
        "recorded_final_step": rec["final_step"]}, indent=2) + "\n")
    say(f"[recipe {rec['run']}] replayed to step {_step(target):,} (the committed run: "
        f"{rec['final_step']:,}) in {rel(target)}")
    return 0


def _keep(target: pathlib.Path, step: int, say) -> None:
    """Copies the replay's checkpoint at `step` (its latest, if the curriculum ended before it)
    to <run>/warm_start/<step>, where a later recipe's replay finds it."""
    ckpt = target / "checkpoints" / f"{step:012d}"
    if not (ckpt / runs_lib.PROGRESS).is_file():
        ckpt = runs_lib.latest_checkpoint(target)
        say(f"no checkpoint at step {step:,} (training stopped before it): keeping {rel(ckpt)}")
    dst = target / "warm_start" / f"{step:012d}"
    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(ckpt, dst)


def replay_config_diff(recorded: dict, replayed: dict) -> dict:
    """{dotted key: [recorded, replayed]} where two config.json dicts differ (absent: null)."""
    a, b = _flat(recorded), _flat(replayed)
    return {k: [a.get(k), b.get(k)] for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)}


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _ready(rec: dict, out: pathlib.Path) -> bool:
    """Whether a recipe's sources are replayed far enough under `out` for it to start."""
    w, c = rec.get("warm_start"), rec.get("continues")
    if c and not (out / c["run"] / DONE).is_file():
        return False
    if any(not (out / r / DONE).is_file() for r in rec.get("suite", [])):
        return False
    if w:
        src = out / w["run"]
        return ((src / "warm_start" / f"{w['step']:012d}" / runs_lib.PROGRESS).is_file()
                or (src / DONE).is_file())
    return True


def _status(log: pathlib.Path, final_step: int) -> str:
    """A replay's newest progress line ("[policy/init] step N ... stage ... R steps/s ..."),
    shortened, with the hours left to the recorded run's final step at that rate."""
    if not log.is_file():
        return "starting"
    lines = [ln for ln in log.read_text(errors="replace").splitlines() if "] step " in ln]
    if not lines:
        return "compiling"
    last = lines[-1].strip()
    step = re.search(r"\] step ([\d,]+)", last)
    rate = re.search(r"([\d,]+) steps/s", last)
    eta = ""
    if step and rate and int(rate.group(1).replace(",", "")) > 0:
        left = max(final_step - int(step.group(1).replace(",", "")), 0)
        eta = f"; ~{left / int(rate.group(1).replace(',', '')) / 3600:.1f} h to {final_step:,}"
    return last.split("  elapsed")[0][:170] + eta


def replay_all(run_dirs, runs, say=print, seed: int | None = None, jobs: int = 1,
               mains: dict | None = None, poll_s: float = 30.0, report_s: float = 600.0) -> int:
    """Replays recipes, sources first, into `replay_dir(runs, seed)`. With `jobs` 1, one after
    another in this process (`mains`: each command's main); with more, up to `jobs` at a time,
    each in its own process (`python -m biped_switch.train --recipe RUN`, one mujoco thread
    each, its output in <out>/<run>/replay.log), a recipe starting once its sources have
    replayed to its warm-start step; a status line per running replay every `report_s`."""
    import os
    import subprocess
    import sys
    import time

    out = replay_dir(runs, seed)
    todo = order(run_dirs)
    if seed is not None:
        for d in todo:
            _restore_replay(out / load(d)["run"], say)
    if jobs <= 1:
        for d in todo:
            if code := replay(d, out, mains, say, seed):
                return code
        say(f"replayed into {rel(out)}/; evaluate with --runs {rel(out)}")
        return 0
    recs = {d: load(d) for d in todo}
    running, failed, last_report = {}, [], 0.0
    env = {**os.environ, "BIPED_SWITCH_NTHREAD": "1"}
    while todo or running:
        for d, (proc, log) in list(running.items()):
            if proc.poll() is not None:
                del running[d]
                say(f"[train-all] {recs[d]['run']}: "
                    f"{'done' if proc.returncode == 0 else f'failed (exit {proc.returncode})'}; "
                    f"log {rel(log)}")
                if proc.returncode:
                    failed.append(recs[d]["run"])
        for d in [d for d in todo if _ready(recs[d], out)]:
            if len(running) >= jobs:
                break
            log = out / recs[d]["run"] / "replay.log"
            log.parent.mkdir(parents=True, exist_ok=True)
            cmd = [sys.executable, "-m", "biped_switch.train", "--recipe", str(d), "--out",
                   str(runs)] + ([] if seed is None else ["--seed", str(seed)])
            running[d] = (subprocess.Popen(cmd, stdout=log.open("a"), stderr=subprocess.STDOUT,
                                           env=env), log)
            todo.remove(d)
            say(f"[train-all] {recs[d]['run']}: started ({' '.join(cmd[1:])}); log {rel(log)}")
        if todo and not running:
            say(f"[train-all] cannot start {[recs[d]['run'] for d in todo]}: their sources did "
                f"not replay (failed: {failed})")
            return 1
        if running and time.time() - last_report >= report_s:
            last_report = time.time()
            for d, (_, log) in running.items():
                say(f"[train-all] {recs[d]['run']}: {_status(log, recs[d]['final_step'])}")
        time.sleep(poll_s if running else 0)
    if failed:
        say(f"[train-all] failed: {', '.join(failed)}")
        return 1
    say(f"replayed into {rel(out)}/; evaluate with --runs {rel(out)}")
    return 0


def commit_replays(run_dirs, runs, seed: int) -> list[pathlib.Path]:
    """`commit_replay` of each recipe's replay under `replay_dir(runs, seed)` that has a
    checkpoint."""
    out = replay_dir(runs, seed)
    targets = [out / load(d)["run"] for d in run_dirs]
    return [commit_replay(t) for t in targets if runs_lib.latest_checkpoint(t) is not None]

"""Run folders: where a run's config, logs and checkpoints live, and how a fresh clone finds them.
Plain Python (no JAX, no Orbax), so the reports layer reads runs fast; the checkpoint codec itself
is `learning.checkpoints`.

A training run (PPO: train.py; the DQN selector: dqn.py) lives in one folder:

    <run>/config.json                         the run's config (config.default_train_config, saved)
    <run>/metrics.csv, <run>/tb/              one row per logged point (`Logger`)
    <run>/checkpoints/<step:012d>/            an Orbax PyTree checkpoint (`save_tree`) ...
    <run>/checkpoints/<step:012d>/progress.json   ... and its progress record (step, wall time,
                                              curriculum, evaluation, device); a checkpoint
                                              without it is unfinished and never read

Runs are made under runs/<policy>_<init>/ (PPO) and runs/dqn_<init>/; their latest checkpoints are
committed under models/policies/ (`COMMITTED_DIR`, `commit_run`) and models/baselines/
(`BASELINE_DIR`), where a fresh clone finds them (`find_policy`, `find_dqn`) and a training run
resumes from them (`restore_committed`).
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import pathlib
import shutil
import time

import numpy as np
from ml_collections import config_dict

from biped_switch.config import default_train_config
from biped_switch.paths import BASELINE_DIR, COMMITTED_DIR  # noqa: F401  (re-exported)

try:  # optional: TensorBoard logs (tensorboardX ships with brax)
    from tensorboardX import SummaryWriter
except ImportError:  # pragma: no cover
    SummaryWriter = None

PROGRESS = "progress.json"
CHOSEN_FILE = "chosen.json"  # in a committed run: {"step", "from"} of a checkpoint chosen, not its latest
_FALLBACK = [True]  # whether a run folder may fall back on its committed copy (`no_committed_copy`)


@contextlib.contextmanager
def no_committed_copy():
    """Within it, a run folder never falls back on its committed copy under models/ (no resume
    from it, no config or train.log taken from it): a recipe replay (`learning.recipe`) trains
    from scratch, though its run has the committed run's name."""
    _FALLBACK.append(False)
    try:
        yield
    finally:
        _FALLBACK.pop()


class RunFileError(ValueError):
    """A run folder's file that cannot be read: the message names the file and what is wrong."""


def read_json(path: pathlib.Path) -> dict:
    """A run folder's JSON file; a damaged one raises RunFileError naming it (not a bare
    JSONDecodeError from deep inside a resume)."""
    path = pathlib.Path(path)
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise RunFileError(f"{path} is not valid JSON (line {e.lineno}, column {e.colno}: {e.msg}); "
                           f"restore it from git (`git checkout -- {path}`) or remove the run "
                           f"folder") from None
    except UnicodeDecodeError as e:
        raise RunFileError(f"{path} is not a text file ({e.reason})") from None


# ----------------------------------------------------------------------- checkpoints
def checkpoints(run_dir: pathlib.Path) -> list[pathlib.Path]:
    """The run's finished checkpoints (those with a progress.json), oldest first."""
    return sorted(p for p in (pathlib.Path(run_dir) / "checkpoints").glob("[0-9]" * 12)
                  if (p / PROGRESS).exists())


def latest_checkpoint(run_dir: pathlib.Path) -> pathlib.Path | None:
    """The run's newest finished checkpoint (one with a progress.json), or None."""
    ckpts = checkpoints(run_dir)
    return ckpts[-1] if ckpts else None


def read_progress(ckpt: pathlib.Path) -> dict:
    """The progress record saved beside a checkpoint."""
    return read_json(pathlib.Path(ckpt) / PROGRESS)


# ----------------------------------------------------------------------- a run's config
def read_config(run_dir: pathlib.Path, committed: bool = False) -> dict:
    """The run's config.json as saved ({} when it has none); `committed`: else its committed
    copy's under models/policies/ (what a resume on a fresh clone restores)."""
    for d in (pathlib.Path(run_dir),) + ((COMMITTED_DIR / pathlib.Path(run_dir).name,)
                                          if committed and _FALLBACK[-1] else ()):
        if (d / "config.json").is_file():
            return read_json(d / "config.json")
    return {}


def run_config(run_dir: pathlib.Path) -> config_dict.ConfigDict:
    """The train config a PPO run was made with (its config.json over today's defaults: a key
    the run predates keeps its default, one no longer known is dropped)."""
    saved = read_json(pathlib.Path(run_dir) / "config.json")
    cfg = default_train_config()
    for section in ("env", "network", "ppo", "eval", "curriculum"):
        for k, v in saved.get(section, {}).items():
            if k in cfg[section]:
                cfg[section][k] = tuple(v) if isinstance(v, list) else v
    for k in ("policy", "init", "seed", "episode_length", "n_tracks"):
        if k in saved:
            cfg[k] = saved[k]
    return cfg


def env_overrides(cfg) -> dict:
    """Env-config overrides a run config's policy needs (action mode, phase clock); never the
    physics backend, which is the evaluator's choice."""
    env = dict(cfg.env)
    env.pop("backend", None)
    return env


def policy_env_overrides(ckpt: pathlib.Path) -> dict:
    """`env_overrides` of the run a checkpoint belongs to."""
    return env_overrides(run_config(pathlib.Path(ckpt).parent.parent))


# ----------------------------------------------------------------------- metrics.csv
class Logger:
    """stdout + CSV + TensorBoard; one row per logged point."""

    def __init__(self, run_dir: pathlib.Path):
        self.csv_path = pathlib.Path(run_dir) / "metrics.csv"
        self.tb = None if SummaryWriter is None else SummaryWriter(str(pathlib.Path(run_dir) / "tb"))

    def drop_after(self, step: int) -> None:
        """On resume: forget CSV rows of an abandoned chunk (steps past the checkpoint)."""
        if not self.csv_path.exists():
            return
        with self.csv_path.open() as f:
            reader = csv.DictReader(f)
            fields, rows = reader.fieldnames, [r for r in reader if float(r["step"]) <= step]
        with self.csv_path.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=fields)
            w.writeheader()
            w.writerows(rows)

    def rows(self, until: int | None = None) -> list[dict]:
        """The CSV rows logged so far (up to step `until`), oldest first."""
        if not self.csv_path.exists():
            return []
        with self.csv_path.open() as f:
            return [r for r in csv.DictReader(f) if until is None or float(r["step"]) <= until]

    def log(self, step: int, row: dict) -> None:
        row = {"step": step, **{k: (round(v, 5) if isinstance(v, float) else v) for k, v in row.items()}}
        new = not self.csv_path.exists()
        fields = list(row)
        if not new:
            with self.csv_path.open() as f:
                fields = next(csv.reader(f))
            fields += [k for k in row if k not in fields]
        rows = [] if new else list(csv.DictReader(self.csv_path.open()))
        with self.csv_path.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=fields)
            w.writeheader()
            w.writerows(rows + [row])
        if self.tb is not None:
            for k, v in row.items():
                if isinstance(v, (int, float)) and k != "step":
                    self.tb.add_scalar(k, v, step)
            self.tb.flush()


def curve_series(rows: list[dict], key: str) -> np.ndarray:
    """(N, 2) (step, value) of `key` over metrics.csv rows. A row logged again after a restart
    supersedes the older rows from its step on, so the curve never runs backwards."""
    pts = []
    for r in rows:
        if r.get(key) not in (None, ""):
            step = float(r["step"])
            pts = [pt for pt in pts if pt[0] < step] + [(step, float(r[key]))]
    return np.array(pts).reshape(-1, 2)


# ----------------------------------------------------------------------- committed runs
def restore_committed(run_dir: pathlib.Path, print_fn=print,
                      committed_root: pathlib.Path | None = None) -> None:
    """A run absent from runs/ resumes from its committed copy under `committed_root`
    (default `COMMITTED_DIR`, models/policies/, for PPO; models/baselines/ for the DQN)."""
    committed = (committed_root or COMMITTED_DIR) / run_dir.name
    if (_FALLBACK[-1] and latest_checkpoint(run_dir) is None
            and latest_checkpoint(committed) is not None):
        run_dir.mkdir(parents=True, exist_ok=True)
        for item in committed.iterdir():
            dst = run_dir / item.name
            if item.is_dir():
                shutil.copytree(item, dst, dirs_exist_ok=True)
            else:
                shutil.copy2(item, dst)
        print_fn(f"no checkpoint under {run_dir}: resuming from the committed {committed}")


def train_log(run_dir: pathlib.Path, print_fn=print, committed_root: pathlib.Path | None = None):
    """A print function that also appends each line to <run_dir>/train.log, the run's progress
    history across sessions (`commit_run` commits it). A run folder without one continues its
    committed copy's. Starts the session's part with a dated header."""
    path = pathlib.Path(run_dir) / "train.log"
    committed = (committed_root or COMMITTED_DIR) / pathlib.Path(run_dir).name / "train.log"
    if _FALLBACK[-1] and not path.exists() and committed.exists():
        shutil.copy2(committed, path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as f:
        f.write(f"# {time.strftime('%Y-%m-%d %H:%M:%S', time.gmtime())} UTC: a session starts\n")

    def say(line: str) -> None:
        print_fn(line)
        with path.open("a") as f:
            f.write(f"{line}\n")

    return say


def commit_run(run_dir: pathlib.Path, out_dir: pathlib.Path | None = None,
               plot_fn=None, ckpt: pathlib.Path | None = None) -> pathlib.Path:
    """Copies a run's latest checkpoint (or `ckpt`, one chosen on tuning tracks), config, metrics
    and curves (`plot_fn(run_dir, png)`, e.g. `reports.curves.ppo_curves`; none when None) to
    models/policies/<run>/ (that checkpoint only), for a later session or a fresh clone to
    resume from."""
    out = out_dir or COMMITTED_DIR / run_dir.name
    chosen_ckpt = ckpt is not None
    ckpt = pathlib.Path(ckpt) if chosen_ckpt else latest_checkpoint(run_dir)
    if ckpt is None:
        raise FileNotFoundError(f"no checkpoint under {run_dir}")
    if not (ckpt / PROGRESS).is_file():
        raise FileNotFoundError(f"{ckpt} is not a checkpoint folder (no {PROGRESS})")
    if out.exists():
        shutil.rmtree(out / "checkpoints", ignore_errors=True)
    (out / "checkpoints").mkdir(parents=True, exist_ok=True)
    shutil.copytree(ckpt, out / "checkpoints" / ckpt.name)
    chosen = out / CHOSEN_FILE  # says the step goal does not count: the checkpoint was chosen
    if chosen_ckpt:
        chosen.write_text(json.dumps({"step": int(read_progress(ckpt)["step"]), "from": str(ckpt)}))
    else:
        chosen.unlink(missing_ok=True)
    for name in ("config.json", "metrics.csv", "train.log"):
        if (run_dir / name).exists():
            shutil.copy2(run_dir / name, out / name)
    if (run_dir / "metrics.csv").exists():
        if plot_fn is not None:
            plot_fn(run_dir, out / "curves.png")
    return out


def find_policy(policy: str, init: str, runs: pathlib.Path) -> pathlib.Path | None:
    """The latest checkpoint of <runs>/<policy>_<init>, else of its committed copy under
    models/policies/, else None."""
    for base in (pathlib.Path(runs), COMMITTED_DIR):
        ckpt = latest_checkpoint(base / f"{policy}_{init}")
        if ckpt is not None:
            return ckpt
    return None


def resolve_checkpoint(spec: str, runs: pathlib.Path = pathlib.Path("runs")) -> pathlib.Path:
    """A checkpoint named by `spec`: a checkpoint folder, a run folder (its latest checkpoint), or
    a run name such as `walk_stand` (<runs>/<name>, else its committed copy)."""
    path = pathlib.Path(spec)
    if (path / "progress.json").is_file():
        return path
    for run_dir in (path, pathlib.Path(runs) / spec, COMMITTED_DIR / spec):
        ckpt = latest_checkpoint(run_dir)
        if ckpt is not None:
            return ckpt
    raise FileNotFoundError(f"no checkpoint for {spec!r}: not a checkpoint folder, and no run of "
                            f"that name under {runs}/ or {COMMITTED_DIR}/")


def find_dqn(runs, init: str = "stand", dqn_dir=None) -> pathlib.Path | None:
    """The DQN run directory with a checkpoint: `dqn_dir` if given, else <runs>/dqn_<init>, then
    models/baselines/dqn_<init> (find_policy's search, for the selector)."""
    dirs = [dqn_dir] if dqn_dir else [pathlib.Path(runs) / f"dqn_{init}", BASELINE_DIR / f"dqn_{init}"]
    return next((pathlib.Path(d) for d in dirs if latest_checkpoint(pathlib.Path(d)) is not None),
                None)


# ----------------------------------------------------------------------- what a run is
def run_notes(run_dir, step_goal: bool = True) -> list[str]:
    """Why a training run (PPO or DQN) is not a finished, real one; [] when nothing says so
    (`step_goal` False: being short of the step goal is not a reason).

    It lies in a pipeline_check folder; its latest checkpoint is short of the step goal
    (progress.json's total_steps / total_env_steps, else config.json's) and its curriculum did
    not finish (a PPO run stops when it does: `--total-steps` is then only a ceiling); its
    curriculum is unfinished (guide forces on or difficulty below 1: progress.json's, else the last logged in
    metrics.csv, for folders of copied logs); a DQN selector chose among stand-in policies.
    A curriculum that ended on a push plateau is finished (Table I's curriculum cell says so)."""
    d = pathlib.Path(run_dir)
    notes = ["is a pipeline check"] if "pipeline_check" in d.resolve().parts else []
    ck = latest_checkpoint(d)
    prog = read_progress(ck) if ck else {}
    cfg = read_config(d)
    total = next((v for v in (prog.get("total_steps"), prog.get("total_env_steps"),
                              cfg.get("total_timesteps"), cfg.get("total_env_steps")) if v), None)
    finished = bool(prog.get("curriculum_done"))  # a PPO run stops there, short of its ceiling
    chosen = d / CHOSEN_FILE  # a checkpoint chosen on tuning tracks (commit_run's ckpt)
    if chosen.is_file() and "step" in prog:
        finished |= json.loads(chosen.read_text()).get("step") == int(prog["step"])
    if (step_goal and not finished and "step" in prog and total is not None
            and int(prog["step"]) < int(total)):
        notes.append(f"at step {int(prog['step']):,} of {int(total):,}")
    c = prog.get("curriculum")
    if c is None and (d / "metrics.csv").is_file():
        rows = list(csv.DictReader((d / "metrics.csv").open()))
        last = {k: curve_series(rows, k)[-1:, 1] for k in ("difficulty", "guide_scale")}
        if all(len(v) for v in last.values()):
            c = {"stage_name": "last logged", **{k: float(v[0]) for k, v in last.items()}}
    # a run without a curriculum (the distilled student) records only its stage name
    if c is not None and (c.get("guide_scale", 0.0) > 1e-6 or c.get("difficulty", 1.0) < 1 - 1e-6):
        notes.append(f"curriculum unfinished ({c['stage_name']} d={round(float(c['difficulty']), 3)} "
                     f"guide={round(float(c['guide_scale']), 3)})")
    elif ("curriculum_done" in prog and not prog["curriculum_done"]
          and "setup" not in cfg):  # PPO runs since 2026-12-01; a setup run has no pushes
        notes.append(f"push stage unfinished (push={round(float(c['push_scale']), 3)})")
    stand_in = prog.get("stand_in") or any("stand-in" in str(p) for p in prog.get("policies") or ())
    if stand_in:
        notes.append(f"chose among stand-ins ({prog.get('stand_in') or 'see progress.json'})")
    return notes


def run_record(ckpt: pathlib.Path | None) -> dict | None:
    """What a run's latest checkpoint recorded (Table III): wall time, device, step, and the
    reasons (`run_notes`, prefixed with the run's name) its hours are not those of a finished,
    real training run."""
    if ckpt is None:
        return None
    prog = read_progress(ckpt)
    run = ckpt.parent.parent
    return {"wall_s": float(prog["wall_s"]), "step": int(prog.get("step", 0)),
            "notes": [f"{run.name} {n}" for n in run_notes(run)],
            "device": f"{prog.get('device', '?')} x{prog.get('n_devices', 1)}"}


# ----------------------------------------------------------------------- runs as the notebooks list them
def training_rows(run_dirs, name=str):
    """(headers, rows): per run folder, its last logged values (metrics.csv) and device (its
    newest progress.json); `name(run_dir)` is the run's first cell."""
    headers = ["run", "env steps", "hours", "last episode reward", "last eval reward/step",
               "difficulty", "guide_scale", "push_scale", "device"]
    rows = []
    for d in map(pathlib.Path, run_dirs):
        with (d / "metrics.csv").open(newline="") as f:
            logged = list(csv.DictReader(f))

        def last(k):
            y = curve_series(logged, k)[:, 1]
            y = y[np.isfinite(y)]
            return float(y[-1]) if len(y) else math.nan

        def num(v, f):
            return "-" if not math.isfinite(v) else format(v, f)

        prog = sorted(d.glob("progress*.json")) + sorted(d.glob("checkpoints/*/progress.json"))
        try:
            dev = json.loads(prog[-1].read_text()).get("device", "?") if prog else "not recorded"
        except (OSError, ValueError):  # being written by a running job
            dev = "?"
        steps = [s for s in (_float(r.get("step")) for r in logged) if math.isfinite(s)]
        rows.append([name(d), f"{int(max(steps)):,}" if steps else "-",
                     num(last("wall_s") / 3600, ".2f"), num(last("episode/sum_reward"), ".1f"),
                     num(last("eval/reward_per_step"), ".2f"), num(last("difficulty"), ".2f"),
                     num(last("guide_scale"), ".2f"), num(last("push_scale"), ".2f"), dev])
    return headers, rows


def _float(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def training_checks(run_dirs, name=str) -> list[str]:
    """Verdict reasons over run folders: "<name(run)>: <its run_notes>" for each run with notes."""
    return [f"{name(d)}: {', '.join(n)}" for d in map(pathlib.Path, run_dirs) if (n := run_notes(d))]


def full_push(run_cfg: dict) -> str:
    """A run's full push scale, as its config.json has it ('?' when it does not)."""
    c = run_cfg.get("curriculum", {})
    if "max_push_N" not in c or "push_duration_s" not in c:
        return "?"
    return f"{float(c['max_push_N']):g} N for {float(c['push_duration_s']):g} s"

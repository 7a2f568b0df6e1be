"""Shared helpers of the result notebooks in this folder (loading, provenance, tables, figures).

Every notebook reads saved results from one results root:

    RESULTS = $BIPED_RESULTS, or <repo>/experiments/results when unset

laid out as the package's CLIs write it (table1/, table2/, table3/, lookup/, estimators/,
training/). Policy training runs are read from the runs root (`runs_root`, `run_roots`):

    RUNS = $BIPED_RUNS, else <repo>/runs (where `python -m biped_switch.train`, `make train-all`
           and `make reproduce` write; runs.find_policy looks there, then in models/policies/),
           and for a pipeline-check results root models/pipeline_check (the runs it was made from)

A missing input raises `MissingResult`, whose message names the command that makes it; nothing is
skipped silently. Nothing here builds an environment, steps the simulator or compiles JAX code:
the notebooks only read files (and the terrain generator, which is plain numpy). The paper's values
come from `biped_switch.paper` (plain numbers); the figures and run checks import the modules that
made them (fig5, table2, runs), which import JAX and MuJoCo-MJX.
"""

from __future__ import annotations

import csv
import json
import math
import os
import pathlib
import shlex
import subprocess
import sys
from typing import Iterable, Sequence

import numpy as np


def _find_repo() -> pathlib.Path:
    here = pathlib.Path(__file__).resolve().parent
    for d in (here, *here.parents, pathlib.Path.cwd(), *pathlib.Path.cwd().parents):
        if (d / "pyproject.toml").is_file() and (d / "biped_switch" / "__init__.py").is_file():
            return d
    raise RuntimeError(f"cannot find the biped_switch repository above {here}")


REPO = _find_repo()
NB_DIR = REPO / "experiments" / "notebooks"
DEFAULT_RESULTS = REPO / "experiments" / "results"
PIPELINE_CHECK = DEFAULT_RESULTS / "pipeline_check"
DEFAULT_RUNS = REPO / "runs"  # where train, make train-all and make reproduce write their runs
PIPELINE_MODELS = REPO / "models" / "pipeline_check"  # the pipeline check's runs (not trained)
if str(REPO) not in sys.path:  # biped_switch importable even without `pip install -e .`
    sys.path.insert(0, str(REPO))

from biped_switch.paper import ARTIFACTS as PAPER_ARTIFACTS  # noqa: E402  (the paper's numbers)
from biped_switch.paper import SWEEP_POINTS as PAPER_SWEEP_POINTS  # noqa: E402
from biped_switch.paper import TABLE1 as PAPER_TABLE1  # noqa: E402
from biped_switch.paper import TABLE2 as PAPER_TABLE2  # noqa: E402
from biped_switch.paper import TABLE3_H as PAPER_TABLE3  # noqa: E402
from biped_switch.paper import TRIALS as PAPER_TRIALS  # noqa: E402

METHOD_LABELS = {"random": "Random", "detection": "On detection", "lookup": "Lookup table",
                 "com_over_feet": "CoM over feet", "estimator": "Ours (estimator)",
                 "estimator_no_overlap": "Ours no overlap", "dqn": "*DQN",
                 "end_to_end": "*End-to-end", "ours": "Ours"}


def _repo_path(p) -> pathlib.Path:
    """`p` with a relative path taken from the repository root."""
    p = pathlib.Path(p).expanduser()
    return p if p.is_absolute() else REPO / p


def _env_path(name: str) -> pathlib.Path | None:
    env = os.environ.get(name)
    return _repo_path(env) if env else None


def results_root() -> pathlib.Path:
    """$BIPED_RESULTS (relative paths taken from the repository root), else experiments/results."""
    return _env_path("BIPED_RESULTS") or DEFAULT_RESULTS


def is_pipeline_check(path) -> bool:
    """Whether `path` lies in a pipeline-check tree (experiments/results/pipeline_check,
    models/pipeline_check, or any other folder named pipeline_check)."""
    return "pipeline_check" in pathlib.Path(path).resolve().parts


def runs_root(results=None) -> pathlib.Path:
    """The runs folder a results root was (or is to be) made from: $BIPED_RUNS (relative paths
    from the repository root); else models/pipeline_check for a pipeline-check `results`; else
    <repo>/runs, where `train` writes (find_policy then also looks in models/policies/)."""
    env = _env_path("BIPED_RUNS")
    if env is not None:
        return env
    if results is not None and is_pipeline_check(results):
        return PIPELINE_MODELS
    return DEFAULT_RUNS


def run_roots(results=None) -> list[pathlib.Path]:
    """Every folder searched for training runs: [$BIPED_RUNS] when set, else <repo>/runs and, for
    a pipeline-check `results`, models/pipeline_check."""
    env = _env_path("BIPED_RUNS")
    if env is not None:
        return [env]
    return [DEFAULT_RUNS] + ([PIPELINE_MODELS] if results is not None and is_pipeline_check(results)
                             else [])


class MissingResult(FileNotFoundError):
    """A notebook's input file is not there; the message names the command that makes it."""


def rel(path) -> str:
    """`path` relative to the repository root when it is inside it (for commands and messages)."""
    p = pathlib.Path(path)
    try:
        return str(p.resolve().relative_to(REPO))
    except ValueError:
        return str(p)


def command_str(argv: Sequence[str]) -> str:
    """`python -m ...` as a reader would type it from the repository root."""
    return "python " + " ".join(shlex.quote(str(a)) for a in argv)


def require(path, argv: Sequence[str], what: str) -> pathlib.Path:
    """`path` if it is a file, else MissingResult naming `argv` (the command that writes it)."""
    path = pathlib.Path(path)
    if path.is_file():
        return path
    msg = (f"{what} not found: {path} is missing.\nMake it with (from {REPO}):\n    "
           f"{command_str(argv)}\nor point BIPED_RESULTS at a results root that has it "
           f"(now: {results_root()}).")
    root = results_root().resolve()
    alt = (PIPELINE_CHECK / path.resolve().relative_to(root)) if _inside(path, root) else None
    if alt is not None and alt.is_file() and alt.resolve() != path.resolve():
        msg += (f"\nA pipeline-check copy exists at {rel(alt)} "
                f"(BIPED_RESULTS={rel(PIPELINE_CHECK)}): a pipeline check, not a result.")
    raise MissingResult(msg)


def _inside(path: pathlib.Path, root: pathlib.Path) -> bool:
    try:
        path.resolve().relative_to(root.resolve())
        return True
    except ValueError:
        return False


def load_json(path, argv: Sequence[str], what: str) -> dict:
    return json.loads(require(path, argv, what).read_text())


def run_cli(argv: Sequence[str]) -> None:
    """Runs `python <argv>` from the repository root with this interpreter (RECOMPUTE cells)."""
    print("running:", command_str(argv), flush=True)
    subprocess.run([sys.executable, *map(str, argv)], cwd=REPO, check=True)


# ------------------------------------------------------------------ the commands that make results
def table1_command(results: pathlib.Path, settings: dict | None = None) -> list[str]:
    argv = ["-m", "biped_switch.evaluate", "single", "--out", rel(results / "table1")]
    return argv + _carry(settings, ("policies", "inits", "trials", "batch", "horizon_s", "seed",
                                    "track_seed", "backend", "runs"))


def table2_command(results: pathlib.Path, settings: dict | None = None) -> list[str]:
    argv = ["-m", "biped_switch.evaluate", "multi", "--out", rel(results / "table2"),
            "--lookup", rel(results / "lookup")]
    return argv + _carry(settings, MULTI_KEYS)


def fig5_command(results: pathlib.Path, trial: int = 0, settings: dict | None = None) -> list[str]:
    """Only the estimator method, trials 0..trial, with the Fig. 5 trace, into <results>/fig5."""
    s = dict(settings or {})
    s.update(methods=["estimator"], trials=trial + 1, batch=trial + 1, fig5_trial=trial)
    argv = ["-m", "biped_switch.evaluate", "multi", "--out", rel(results / "fig5"),
            "--lookup", rel(results / "lookup")]
    return argv + _carry(s, MULTI_KEYS)


MULTI_KEYS = ("methods", "trials", "batch", "horizon_s", "n_artifacts", "seed", "runs", "estimators",
              "dqn", "stand_in", "guide_scale", "fig5_trial", "backend")  # evaluate multi's settings


def table3_command(results: pathlib.Path, runs=None, init: str = "stand") -> list[str]:
    """retrain-cost reading the runs in `runs` (default `runs_root(results)`) and the sweeps and
    estimators of `results`, writing <results>/table3: the same root the notebook reads."""
    runs = runs_root(results) if runs is None else pathlib.Path(runs)
    return ["-m", "biped_switch.evaluate", "retrain-cost", "--runs", rel(runs),
            "--results", rel(results), "--init", init, "--out", rel(results / "table3")]


def lookup_command(results: pathlib.Path, init: str = "stand", runs=None) -> list[str]:
    runs = runs_root(results) if runs is None else pathlib.Path(runs)
    return ["-m", "biped_switch.sweep", "--init", init, "--runs", rel(runs),
            "--results", rel(results / "lookup")]


def estimator_command(results: pathlib.Path, init: str = "stand") -> list[str]:
    return ["-m", "biped_switch.estimator", "--init", init, "--results",
            rel(results / "estimators")]


def train_command(runs=None, policy: str = "walk", init: str = "stand") -> list[str]:
    """Training of one policy into <runs>/<policy>_<init> (default `runs_root()`: runs/, where
    runs.find_policy looks; a rerun resumes from the run's latest checkpoint)."""
    runs = runs_root() if runs is None else pathlib.Path(runs)
    return ["-m", "biped_switch.train", "--policy", policy, "--init", init, "--out", rel(runs)]


def _carry(settings: dict | None, keys: Iterable[str]) -> list[str]:
    """CLI flags reproducing the recorded `settings` (so a recompute redoes the same experiment)."""
    out = []
    for k in keys:
        v = (settings or {}).get(k)
        if v is None or v is False:
            continue
        flag = "--" + k.replace("_", "-")
        out += [flag, *map(str, v)] if isinstance(v, (list, tuple)) else [flag, str(v)]
    return out


# ------------------------------------------------------------------------------- provenance
def stand_ins(sources: Iterable[str]) -> list[str]:
    return [s for s in sources if str(s).startswith("stand-in")]


def pipeline_label(doc: dict) -> str | None:
    """The "PIPELINE_CHECK" note a results file carries (top level, settings or meta), if any."""
    for d in (doc, doc.get("settings") or {}, doc.get("meta") or {}):
        for k in ("PIPELINE_CHECK", "pipeline_check"):
            if isinstance(d, dict) and d.get(k):
                return str(d[k])
    return None


def _conclude(doc: dict, reasons: list[str], rows=None, table: str = "", per: str = "",
              ok: str | None = None) -> list[str]:
    """Adds the file's own pipeline-check label (and, for a table's `rows`, too few trials per
    `per` against the paper) to `reasons`, prints the verdict line (`ok`: its text when there is
    no reason) and returns the reasons."""
    if rows is not None:
        n = min((r["n"] for r in rows), default=0)
        if n < PAPER_TRIALS[table]:
            reasons.append(f"{n} trials per {per} (paper: {PAPER_TRIALS[table]})")
    lab = pipeline_label(doc)
    if lab:
        print(f"  labelled PIPELINE_CHECK: {lab}")
        reasons.insert(0, f"labelled so ({lab})")
    print(verdict(reasons, ok))
    return reasons


def verdict(reasons: list[str], ok: str | None = None) -> str:
    """One line saying whether the file is a pipeline check or can be read as a result."""
    if reasons:
        return "VERDICT: PIPELINE CHECK, not a result: " + "; ".join(reasons) + "."
    return "VERDICT: " + (ok or "no pipeline-check markers (no stand-ins, no guide forces, the "
                          "paper's trial count).")


def _fmt(v) -> str:
    if v is None:
        return "not recorded"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def provenance_table1(doc: dict, path) -> list[str]:
    s, rows = doc.get("settings", {}), doc["rows"]
    print(f"file: {rel(path)}")
    for k in ("trials", "seed", "horizon_s", "runs"):
        print(f"  {k}: {_fmt(s.get(k))}")
    print(f"  device: {_fmt(doc.get('device'))}")
    reasons, stand_in, unfinished = [], [], []
    for r in rows:
        c = r.get("curriculum") or {}
        print(f"  {r['policy']}/{r['init']}: {r.get('checkpoint')} (step {r.get('train_step', 0):,}, "
              f"curriculum {c.get('stage_name')} difficulty {_fmt(c.get('difficulty'))} "
              f"guide_scale {_fmt(c.get('guide_scale'))} push_scale {_fmt(c.get('push_scale'))})")
        if "stand-in" in str(r.get("checkpoint", "")):
            stand_in.append(f"{r['policy']}/{r['init']}")
        if (c.get("guide_scale") or 0) > 0 or c.get("stage_name") not in (None, "pushes"):
            unfinished.append(f"{r['policy']}/{r['init']} ({c.get('stage_name')}, guide_scale "
                              f"{_fmt(c.get('guide_scale'))})")
    if stand_in:
        reasons.append("stand-in policies: " + ", ".join(stand_in))
    if unfinished:
        reasons.append("policies not through their curriculum: " + ", ".join(unfinished))
    return _conclude(doc, reasons, rows, "table1", "row")


def provenance_table2(doc: dict, path) -> list[str]:
    s, rows = doc.get("settings", {}), doc["rows"]
    print(f"file: {rel(path)}")
    for k in ("trials", "seed", "horizon_s", "n_artifacts", "stand_in", "guide_scale", "runs",
              "estimators", "dqn", "lookup"):
        print(f"  {k}: {_fmt(s.get(k))}")
    for sk in doc.get("skipped") or []:
        print(f"  not run: {sk}")
    print(f"  device: {_fmt(doc.get('device'))}   track_seed: {_fmt(doc.get('track_seed'))}   "
          f"wall: {_fmt(round(doc['wall_s'])) if doc.get('wall_s') is not None else 'not recorded'} s")
    reasons, seen, subs = [], set(), {}
    for r in rows:
        srcs = tuple(r.get("policies") or ())
        if srcs and (r["init"], srcs) not in seen:
            seen.add((r["init"], srcs))
            print(f"  policies ({r['init']} init), walk/jumps/gaps/stairs:")
            for src in srcs:
                print(f"    {src}")
            subs[r["init"]] = [x.split(":")[0].removeprefix("stand-in for ")
                               for x in stand_ins(srcs)]
    subs = {k: v for k, v in subs.items() if v}
    if subs:
        reasons.append("stand-in policies: " + "; ".join(f"{k} init {', '.join(v)}"
                                                         for k, v in subs.items()))
    if s.get("stand_in"):
        reasons.append(f"--stand-in {s['stand_in']}")
    if (s.get("guide_scale") or 0) > 0:
        reasons.append(f"scripted guide forces on (guide_scale {s['guide_scale']:g})")
    if s.get("n_artifacts") not in (None, PAPER_ARTIFACTS):
        reasons.append(f"{s['n_artifacts']} artifacts per track (paper: {PAPER_ARTIFACTS})")
    mismatch = sorted({x for r in rows for x in (r.get("policies") or ()) if "MISMATCH" in str(x)})
    if mismatch:
        reasons.append("DQN selector trained with other policies than those evaluated")
    return _conclude(doc, reasons, rows, "table2", "method")


def provenance_lookup(doc: dict, path) -> list[str]:
    meta = doc.get("meta") or {}
    print(f"file: {rel(path)} (init {doc.get('init')})")
    reasons, few, sub, guided, easy = [], [], [], [], []
    gs = meta.get("guide_scale")
    per = meta.get("settings") or {}  # per target: difficulty, guide_scale (when recorded)
    for target, st in (meta.get("sweeps") or {}).items():
        t_set = {**st, **(per.get(target) or {})}
        g = t_set.get("guide_scale", gs)
        print(f"  sweep {target}: {st.get('points', 0):,} points, {_fmt(st.get('success_pct'))}% "
              f"successful switches, {_fmt(st.get('wall_s'))} s on {_fmt(st.get('device'))}; "
              f"difficulty {_fmt(t_set.get('difficulty'))}, guide_scale {_fmt(g)}; data "
              f"{_fmt(st.get('data'))}")
        if st.get("points", 0) < PAPER_SWEEP_POINTS:
            few.append(f"{target} {st.get('points', 0):,}")
        if (g or 0) > 0:
            guided.append(f"{target} {g:g}")
        if t_set.get("difficulty") is not None and t_set["difficulty"] < 1:
            easy.append(f"{target} {t_set['difficulty']:g}")
    if not meta.get("sweeps"):
        print(f"  guide_scale: {_fmt(gs)}")
        if (gs or 0) > 0:
            guided.append(f"{gs:g}")
    for target, pols in (meta.get("policies") or {}).items():
        items = list(pols.items()) if isinstance(pols, dict) else list(enumerate(pols))
        print(f"  policies of the {target} sweep:")
        for name, src in items:
            print(f"    {name}: {src}")
        if stand_ins(src for _, src in items):
            sub.append(target)
    if sub:
        reasons.append("stand-in policies in the " + ", ".join(sub) + " sweeps")
    if guided:
        reasons.append("scripted guide forces on (guide_scale " + ", ".join(guided) + ")")
    if easy:
        reasons.append("artifacts below full difficulty (" + ", ".join(easy) + ")")
    if few:
        reasons.append(f"sweep points {', '.join(few)} (paper: {PAPER_SWEEP_POINTS:,} per target)")
    return _conclude(doc, reasons)


# ------------------------------------------------------------------------------- tables
def text_table(headers: Sequence[str], rows: Sequence[Sequence]) -> str:
    """A fixed-width table (like a printed DataFrame)."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    w = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    line = lambda r: "  ".join(c.rjust(w[i]) if i else c.ljust(w[i]) for i, c in enumerate(r))  # noqa: E731
    return "\n".join([line(cells[0]), "  ".join("-" * x for x in w)] + [line(r) for r in cells[1:]])


def show_table(headers, rows, title: str = "") -> str:
    """Prints the table, fixed width (like a printed DataFrame); returns its text."""
    txt = text_table(headers, rows)
    print((title + "\n" if title else "") + txt)
    return txt


def _ci(v, ci) -> str:
    if v is None:
        return "-"
    lo, hi = (ci or [math.nan, math.nan])
    if lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
        return f"{v:.1f}"
    return f"{v:.1f} ({lo:.1f}-{hi:.1f})"


def table1_rows(doc: dict):
    headers = ["policy", "init", "trials", "% dist. (95% CI)", "paper % dist.",
               "% success (95% CI)", "paper % success", "% fell", "trained steps", "curriculum"]
    rows = []
    for r in doc["rows"]:
        p = PAPER_TABLE1.get(r["policy"])
        pd, ps = ((p[0], p[1]) if r["init"] == "stand" else (p[2], p[3])) if p else ("-", "-")
        c = r.get("curriculum") or {}
        rows.append([r["policy"], r["init"], r["n"], _ci(r["distance_pct"], r.get("distance_ci")),
                     pd, _ci(r["success_pct"], r.get("success_ci")),
                     ps, f"{r.get('fell_pct', math.nan):.1f}", f"{r.get('train_step', 0):,}",
                     f"{c.get('stage_name', '?')} d={c.get('difficulty', math.nan):.1f} "
                     f"g={c.get('guide_scale', math.nan):.1f}"])
    return headers, rows


def table2_rows(doc: dict, with_paper_only: bool = True):
    headers = ["method", "init", "trials", "% dist. (95% CI)", "% success (95% CI)", "% gap fail",
               "% jump fail", "% stair fail", "switches/trial",
               "paper dist. / success / gap / jump / stair"]
    rows, seen = [], set()
    for r in doc["rows"]:
        f, p = r["fail_on"], PAPER_TABLE2.get(r["method"])
        seen.add(r["method"])
        rows.append([r["method"], r["init"], r["n"], _ci(r["distance_pct"], r.get("distance_ci")),
                     _ci(r["success_pct"], r.get("success_ci")), f"{f['gaps']:.1f}",
                     f"{f['jumps']:.1f}", f"{f['stairs']:.1f}",
                     f"{r.get('switches_per_trial', math.nan):.2f}",
                     " / ".join(f"{v}" for v in p) if p else "-"])
    if with_paper_only:
        for m, p in PAPER_TABLE2.items():
            if m not in seen:
                rows.append([m, "-", "not run", "-", "-", "-", "-", "-", "-",
                             " / ".join(f"{v}" for v in p)])
    return headers, rows


def _hours(v) -> str:
    if v is None:
        return "n/a"
    if v >= 0.1:
        return f"{v:.2f}"
    return f"{v:.2f} ({60 * v:.1f} min)" if v >= 1 / 60 else f"{v:.4f} ({3600 * v:.1f} s)"


def table3_rows(doc: dict, checks: dict | None = None):
    """Per method: total hours (n/a unless every part was measured), the measured parts' sum; with
    `checks` (table3_checks), a column saying whether the hours come from complete real runs."""
    headers = ["method", "our hours"] + (["hours from"] if checks is not None else []) + [
        "measured parts (sum)", "parts not measured", "paper hours", "device"]
    rows = []
    for r in doc["rows"]:
        paper = r.get("paper_hours", PAPER_TABLE3.get(r["method"]))
        parts = r.get("parts") or {}
        known = [v for v in parts.values() if v is not None]
        src = []
        if checks is not None:
            notes = checks.get(r["method"]) or []
            src = ["-" if not known and r.get("hours") is None else
                   "PIPELINE CHECK" if any("pipeline" in n for n in notes) else
                   "UNFINISHED RUNS" if notes else "complete runs"]
        rows.append([r["method"], _hours(r.get("hours"))] + src + [
                     (f"{len(known)}/{len(parts)}" + (f" ({_hours(sum(known))})" if known else ""))
                     if parts else "-",
                     ", ".join(k for k, v in parts.items() if v is None) or "-",
                     "-" if paper is None else f"{paper:g}", r.get("device") or "not recorded"])
    return headers, rows


def table3_checks(doc: dict, results, runs=None) -> tuple[pathlib.Path, dict]:
    """(the runs root, {method: notes}) of a Table III file: why each method's measured hours are
    not those of complete, real training runs ([] when they are, or when nothing was measured).

    A row's notes are its recorded `status` when the file has one for it (retrain-cost writes it;
    "not measured" does not count), else the `run_notes` of the runs behind its measured parts, found again as retrain-cost finds them
    (runs.find_policy / find_dqn) under the file's recorded runs root, else `runs`, else
    `runs_root(results)`. Sweep and estimator hours of a pipeline-check results root, or of
    sweeps smaller than the paper's, are noted too."""
    results = pathlib.Path(results)
    init = doc.get("init") or "stand"
    if doc.get("runs"):
        runs = _repo_path(doc["runs"])
    else:
        runs = runs_root(results) if runs is None else pathlib.Path(runs)
    from biped_switch.runs import find_dqn, find_policy

    pols = [_run_dir(find_policy(k, init, runs)) for k in ("jumps", "gaps", "stairs")]
    deps = {"new policy": pols, "selector": [find_dqn(runs, init)],
            "policy": [_run_dir(find_policy("mixed", init, runs))]}
    lookup = results / "lookup" / f"lookup_{init}.json"
    try:
        sweeps = (json.loads(lookup.read_text()).get("meta") or {}).get("sweeps") or {}
    except (OSError, ValueError):
        sweeps = {}
    checks = {}
    for r in doc["rows"]:
        parts, notes = r.get("parts") or {}, []
        measured = [k for k, v in parts.items() if v is not None]
        if not measured and r.get("hours") is None:
            checks[r["method"]] = notes
            continue
        status = r.get("status")  # "not measured" (a part missing) says nothing about the others
        own = status in (None, "not measured")
        if not own and status != "complete":
            notes += [n.strip() for n in str(status).split(";") if n.strip()]
        if own and not parts:
            notes.append("no parts recorded: its runs cannot be checked")
        for k in measured:
            if k in deps and own:
                found = [d for d in deps[k] if d is not None]
                if not found:
                    notes.append(f"{k}: no run under {rel(runs)}/ or models/ (cannot tell whether "
                                 "it finished)")
                notes += [f"{d.name}: {n}" for d in found for n in run_notes(d)]
            if k.startswith(("sweep", "estimator")) and is_pipeline_check(results):
                notes.append(f"{k}: from a pipeline-check results root")
            if k.startswith("sweep ") and k[6:] in sweeps:
                n_pts = sweeps[k[6:]].get("points", 0)
                if n_pts < PAPER_SWEEP_POINTS:
                    notes.append(f"{k}: {n_pts:,} points (paper: {PAPER_SWEEP_POINTS:,})")
        checks[r["method"]] = list(dict.fromkeys(notes))
    return runs, checks


def provenance_table3(doc: dict, path, results, runs=None) -> list[str]:
    """Prints where each method's hours come from (runs, their steps and curriculum, devices, the
    parts not measured) and the verdict: complete real training runs, or a pipeline check /
    unfinished runs / missing parts."""
    results = pathlib.Path(results)
    runs, checks = table3_checks(doc, results, runs)
    print(f"file: {rel(path)}   init: {doc.get('init', 'not recorded')}")
    print(f"  runs: {rel(runs)}" + ("" if doc.get("runs") else
                                   " (not recorded in the file: the runs root of the recompute "
                                   "command)"))
    print(f"  results: {_fmt(doc.get('results'))}   notes: {doc.get('notes') or 'none recorded'}")
    for r in doc["rows"]:
        print(f"  {r['method']}: {_hours(r.get('hours'))} h on {r.get('device') or 'not recorded'}, "
              f"status {r.get('status', 'not recorded')}")
        for n in checks.get(r["method"]) or []:
            print(f"    - {n}")
    for m in doc.get("missing") or []:
        print("  missing:", m)
    reasons = []
    if is_pipeline_check(results):
        reasons.append(f"the results root {rel(results)} is a pipeline check")
    flagged = [m for m, n in checks.items() if n]
    if flagged:
        reasons.append("hours of " + ", ".join(flagged) + " are from pipeline-check, unfinished or "
                       "unverified runs (listed above), not complete training runs")
    incomplete = [r["method"] for r in doc["rows"] if r.get("hours") is None]
    if incomplete:
        reasons.append("no total hours for " + ", ".join(incomplete) + " (parts not measured)")
    return _conclude(doc, reasons, ok="every method's hours come from complete training runs "
                     "(step goal reached, curriculum finished), outside any pipeline check.")


def table3_parts_rows(doc: dict):
    headers = ["method", "part", "hours"]
    return headers, [[r["method"], k, _hours(v)] for r in doc["rows"]
                     for k, v in (r.get("parts") or {}).items()]


# ------------------------------------------------------------------------------- figures
def _plt():
    import matplotlib.pyplot as plt

    return plt


def _yerr(vals, cis):
    lo = [v - (c[0] if c and c[0] is not None else v) for v, c in zip(vals, cis)]
    hi = [(c[1] if c and c[1] is not None else v) - v for v, c in zip(vals, cis)]
    return np.nan_to_num(np.array([lo, hi], float), nan=0.0).clip(min=0)


def bars_ours_vs_paper(ax, labels, ours, ours_ci, paper, ylabel, title):
    """Grouped bars: ours (with 95% CI error bars) beside the paper's value, per label."""
    x = np.arange(len(labels))
    w = 0.38
    o = np.array([np.nan if v is None else v for v in ours], float)
    has = np.isfinite(o)
    ax.bar(x[has] - w / 2, o[has], w, yerr=_yerr(o[has], [c for c, h in zip(ours_ci, has) if h]),
           capsize=3, color="tab:blue", label="ours (95% CI)")
    pp = np.array([np.nan if v is None else v for v in paper], float)
    ax.bar(x + w / 2, np.nan_to_num(pp), w, color="0.75", hatch="//", edgecolor="0.4",
           label="paper")
    for i in np.flatnonzero(~has):
        ax.text(x[i] - w / 2, 1, "not run", rotation=90, ha="center", va="bottom", fontsize=7)
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.set_ylim(0, 105)
    ax.grid(axis="y", alpha=0.3)


def plot_table1(doc: dict, title: str = ""):
    plt = _plt()
    rows = doc["rows"]
    labels = [f"{r['policy']}/{r['init']}" for r in rows]
    paper = [PAPER_TABLE1.get(r["policy"]) for r in rows]
    off = [0 if r["init"] == "stand" else 2 for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.8))
    bars_ours_vs_paper(axes[0], labels, [r["distance_pct"] for r in rows],
                       [r.get("distance_ci") for r in rows],
                       [p[o] if p else None for p, o in zip(paper, off)], "% of total distance",
                       "Table I: distance")
    bars_ours_vs_paper(axes[1], labels, [r["success_pct"] for r in rows],
                       [r.get("success_ci") for r in rows],
                       [p[o + 1] if p else None for p, o in zip(paper, off)], "% success",
                       "Table I: success")
    axes[1].legend(fontsize=8, loc="upper right")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def plot_table2(doc: dict, title: str = ""):
    """Distance, success and per-artifact failure rates of every method, ours beside the paper's."""
    plt = _plt()
    ours = {r["method"]: r for r in doc["rows"]}
    methods = list(ours) + [m for m in PAPER_TABLE2 if m not in ours]
    labels = [METHOD_LABELS.get(m, m) for m in methods]
    paper = [PAPER_TABLE2.get(m) for m in methods]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.2), gridspec_kw={"width_ratios": [1, 1, 1.4]})
    for ax, key, i, name in ((axes[0], "distance", 0, "% of total distance"),
                             (axes[1], "success", 1, "% success")):
        bars_ours_vs_paper(ax, labels, [ours[m][f"{key}_pct"] if m in ours else None for m in methods],
                           [ours[m].get(f"{key}_ci") if m in ours else None for m in methods],
                           [p[i] if p else None for p in paper], name, f"Table II: {key}")
    axes[1].legend(fontsize=8, loc="upper right")
    # failure location: grouped by artifact, ours (solid) and paper (hatched)
    ax = axes[2]
    kinds = (("gaps", 2, "tab:purple"), ("jumps", 3, "tab:orange"), ("stairs", 4, "tab:brown"))
    x = np.arange(len(methods))
    w = 0.13
    for j, (k, pi, col) in enumerate(kinds):
        o = [ours[m]["fail_on"][k] if m in ours else np.nan for m in methods]
        n = [ours[m]["n"] if m in ours else 0 for m in methods]
        # Wilson interval of each failure proportion (as recorded, else from the rate and n)
        ci = [(ours[m].get("fail_ci") or {}).get(k) or _wilson_pct(v, nn) if m in ours else None
              for m, v, nn in zip(methods, o, n)]
        xo = x + (2 * j - 2.5) * w
        ax.bar(xo, np.nan_to_num(o), w, yerr=_yerr(np.nan_to_num(o), ci), capsize=2, color=col,
               label=f"ours: {k}")
        ax.bar(xo + w, [p[pi] if p else 0 for p in paper], w, color=col, alpha=0.35, hatch="//",
               edgecolor="0.3", label=f"paper: {k}")
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("% of trials failing on")
    ax.set_title("Table II: where trials fail", fontsize=10)
    ax.legend(fontsize=7, ncol=3)
    ax.grid(axis="y", alpha=0.3)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def _wilson_pct(pct, n):
    if n <= 0 or not np.isfinite(pct):
        return None
    from biped_switch.stats import wilson_ci

    lo, hi = wilson_ci(pct / 100.0 * n, n)
    return [100 * lo, 100 * hi]


def plot_table3(doc: dict, title: str = ""):
    plt = _plt()
    rows = doc["rows"]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    x = np.arange(len(rows))
    w = 0.38
    cmap = plt.get_cmap("tab20")
    names, labelled = [], set()
    for r in rows:
        names += [k for k in (r.get("parts") or {}) if k not in names]
    for i, r in enumerate(rows):
        bottom = 0.0
        parts = r.get("parts") or {}
        for k, v in parts.items():  # the measured parts, stacked
            if v is None:
                continue
            ax.bar(x[i] - w / 2, v, w, bottom=bottom, color=cmap(names.index(k) % 20),
                   label=None if k in labelled else k)
            labelled.add(k)
            bottom += v
        if not parts and r.get("hours") is not None:
            ax.bar(x[i] - w / 2, r["hours"], w, color="tab:blue")
            bottom = r["hours"]
        missing = [k for k, v in parts.items() if v is None]
        if r.get("hours") is not None:
            note = f"{r['hours']:.1f}"
        elif missing:
            note = f"incomplete: {len(missing)} of {len(parts)} parts\nnot measured"
        else:
            note = "n/a"
        ax.text(x[i] - w / 2, bottom, note, ha="center", va="bottom", fontsize=7)
        paper = r.get("paper_hours", PAPER_TABLE3.get(r["method"]))
        if paper is not None:
            ax.bar(x[i] + w / 2, paper, w, color="0.75", hatch="//", edgecolor="0.4",
                   label="paper" if i == 0 else None)
            ax.text(x[i] + w / 2, paper, f"{paper:g}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(x)
    ax.set_xticklabels([METHOD_LABELS.get(r["method"], r["method"]) for r in rows])
    ax.set_ylabel("wall-clock hours to retrain")
    ax.set_title("Table III: retraining cost when a new terrain is introduced", fontsize=10)
    ax.legend(fontsize=7)
    ax.grid(axis="y", alpha=0.3)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


# ------------------------------------------------------------------------------- Fig. 4b
def lookup_arrays(doc: dict) -> dict:
    """{target: {"rate": (P, nb) NaN where no data, "count": (P, nb), "bins_m": (nb,)}}."""
    out = {}
    for target, t in doc["tables"].items():
        rate = np.array([[np.nan if v is None else v for v in r] for r in t["rate"]], float)
        count = np.asarray(t["count"], float)
        out[target] = {"rate": rate, "count": count, "bins_m": np.arange(rate.shape[1]) * 0.01}
    return out


def lookup_rows(doc: dict):
    """Per pair: points, overall success, best switch distance."""
    from biped_switch.policies import POLICY_NAMES

    headers = ["pair", "switches", "% success (all distances)", "best switch distance [m]"]
    rows = []
    for target, t in lookup_arrays(doc).items():
        for j, name in enumerate(POLICY_NAMES):
            n = t["count"][j].sum()
            if name == target:
                continue
            succ = np.nansum(t["rate"][j] * t["count"][j])
            best = doc["best_m"].get(f"{name}->{target}")
            rows.append([f"{name} -> {target}", int(n), f"{100 * succ / n:.1f}" if n else "-",
                         "-" if best is None else f"{best:.2f}"])
    return headers, rows


def plot_fig4b(doc: dict, smooth_bins: int = 5, title: str = ""):
    """Success of switching against distance to the artifact, per (source -> target) pair."""
    from biped_switch.policies import POLICY_NAMES
    from biped_switch.switching import smoothed_success_pct

    plt = _plt()
    tables = lookup_arrays(doc)
    fig, axes = plt.subplots(1, len(tables), figsize=(5.2 * len(tables), 3.8), squeeze=False)
    colours = {"walk": "tab:blue", "jumps": "tab:orange", "gaps": "tab:purple", "stairs": "tab:brown"}
    for ax, (target, t) in zip(axes[0], tables.items()):
        for j, name in enumerate(POLICY_NAMES):
            cnt = t["count"][j]
            if name == target or cnt.sum() == 0:
                continue
            sm = smoothed_success_pct(t["rate"][j], cnt, smooth_bins)
            c = colours.get(name)
            ax.scatter(t["bins_m"] + 0.005, 100 * t["rate"][j], s=4 + 20 * cnt / cnt.max(),
                       color=c, alpha=0.25, lw=0)
            ax.plot(t["bins_m"] + 0.005, sm, color=c, label=f"{name} -> {target} (n={int(cnt.sum())})")
            best = doc["best_m"].get(f"{name}->{target}")
            if best is not None:
                ax.axvline(best, ls=":", lw=1, color=c)
        ax.set_xlim(0.9, 0)  # the robot approaches from the left: far -> near
        ax.set_ylim(-2, 102)
        ax.set_xlabel("switch distance before the artifact [m]")
        ax.set_ylabel(f"% success (moving mean, {smooth_bins} cm)")
        ax.set_title(f"switch to {target}", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower left")
    fig.suptitle(title or f"{doc.get('init')} init: switch success against distance "
                 "(dots: 1 cm bins, size ~ points; dotted: best distance)", fontsize=9)
    fig.tight_layout()
    return fig


# ------------------------------------------------------------------------------- Fig. 5
FIG5_KEYS = ("time_s", "com_x_m", "body_com", "soles", "contact", "det_kind", "det_dist_m",
             "est_probs", "com_ok", "active", "switched", "ended", "fell", "success", "track_seed")


def load_trial(path) -> dict:
    with np.load(path) as z:
        rec = {k: np.asarray(z[k]) for k in z.files}
    missing = [k for k in FIG5_KEYS if k not in rec]
    if missing:
        raise KeyError(f"{path} lacks {missing}; rewrite it with the current evaluate multi")
    return rec


def trial_track(track_seed: int, n_artifacts: int | None = None):
    """The `mixed` track of a Table II trial (table2.mixed_track): `n_artifacts` per track as
    recorded in the run's settings (None: the default 7)."""
    from biped_switch.table2 import mixed_track

    return mixed_track(track_seed, 7 if n_artifacts is None else n_artifacts)


def trial_length(rec: dict) -> int:
    from biped_switch.fig5 import trial_length as f

    return f(rec)


def trial_events(rec: dict):
    """(headers, rows) of the trial's detections and switches, in order."""
    from biped_switch.policies import POLICY_NAMES
    from biped_switch.terrain import ARTIFACT_KINDS

    n = trial_length(rec)
    kind = rec["det_kind"][:n].astype(int)
    rows = []
    for i in np.flatnonzero((kind >= 0) & (np.r_[-1, kind[:-1]] != kind)):
        rows.append([int(i), f"{rec['time_s'][i]:.2f}", "detect", ARTIFACT_KINDS[kind[i]],
                     f"{rec['det_dist_m'][i]:.2f}", "-", "-"])
    for i in np.flatnonzero(rec["switched"][:n] > 0.5):
        k = int(kind[i])
        e = f"{rec['est_probs'][i, k]:.2f}" if k >= 0 else "-"
        rows.append([int(i), f"{rec['time_s'][i]:.2f}", "switch",
                     f"{POLICY_NAMES[int(rec['active'][i])]}",
                     f"{rec['det_dist_m'][i]:.2f}" if k >= 0 else "-", e,
                     "yes" if rec["com_ok"][i] > 0.5 else "no"])
    rows.sort(key=lambda r: (r[0], r[2] == "switch"))
    return ["step", "t [s]", "event", "kind / new policy", "distance [m]", "E_target", "CoM over feet"], rows


def trial_outcome(rec: dict) -> str:
    from biped_switch.fig5 import trial_outcome as f

    return f(rec)


def plot_fig5(rec: dict, track, title: str = "", threshold: float | None = None):
    """The paper's Fig. 5 (`biped_switch.fig5.fig5_figure`, which the CLI and demo save)."""
    _plt()
    from biped_switch.fig5 import fig5_figure

    return fig5_figure(rec, track, title, threshold)


# ------------------------------------------------------------------------------- training curves
def read_csv(path) -> dict:
    """{column: float array} of a CSV (blank cells NaN)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    cols = rows[0].keys() if rows else []

    def num(v):
        try:
            return float(v)
        except (TypeError, ValueError):
            return math.nan

    return {c: np.array([num(r.get(c)) for r in rows]) for c in cols}


def find_training_runs(results: pathlib.Path, roots: Sequence | None = None,
                       extra: Sequence = ()) -> list[pathlib.Path]:
    """Run folders with a metrics.csv: <root>/*/ for each of `roots` (default `run_roots(results)`:
    runs/, where train writes), <results>/training/*/, <results>/training_*/ and `extra`."""
    roots = run_roots(results) if roots is None else roots
    found = ({p.parent for p in results.glob("training/*/metrics.csv")}
             | {p.parent for p in results.glob("training_*/metrics.csv")}
             | {p.parent for r in roots for p in pathlib.Path(r).glob("*/metrics.csv")}
             | {pathlib.Path(e) for e in extra if (pathlib.Path(e) / "metrics.csv").is_file()})
    return sorted({d.resolve(): d for d in found}.values())


def _read_json(path) -> dict:
    try:
        return json.loads(pathlib.Path(path).read_text())
    except (OSError, ValueError):  # absent, or being written by a running job
        return {}


def run_notes(run_dir) -> list[str]:
    """runs.run_notes: why a run is not a finished, real training run ([] if nothing says so)."""
    from biped_switch.runs import run_notes as f

    return f(run_dir)


def _run_dir(ckpt) -> pathlib.Path | None:
    return None if ckpt is None else pathlib.Path(ckpt).parent.parent


def training_checks(runs: Sequence[pathlib.Path]) -> list[str]:
    """Verdict reasons of the training-curves notebook: each run's `run_notes`."""
    return [f"{run_name(d)}: {', '.join(n)}" for d in runs if (n := run_notes(d))]


def run_name(d: pathlib.Path) -> str:
    """A run folder's path relative to the results root (else to the repository)."""
    try:
        return str(d.resolve().relative_to(results_root().resolve()))
    except ValueError:
        return rel(d)


def series(m: dict, key: str):
    if key not in m or "step" not in m:
        return np.zeros(0), np.zeros(0)
    ok = np.isfinite(m[key]) & np.isfinite(m["step"])
    return m["step"][ok], m[key][ok]


def training_rows(runs: Sequence[pathlib.Path]):
    headers = ["run", "env steps", "hours", "last episode reward", "last eval reward/step",
               "difficulty", "guide_scale", "push_scale", "device"]
    rows = []
    for d in runs:
        m = read_csv(d / "metrics.csv")
        last = lambda k: (series(m, k)[1][-1] if len(series(m, k)[1]) else math.nan)  # noqa: E731
        num = lambda v, f: "-" if not math.isfinite(v) else format(v, f)  # noqa: E731
        prog = sorted(d.glob("progress*.json")) + sorted(d.glob("checkpoints/*/progress.json"))
        dev = _read_json(prog[-1]).get("device", "?") if prog else "not recorded"
        steps = m.get("step", np.zeros(0))
        steps = steps[np.isfinite(steps)]
        rows.append([run_name(d), f"{int(steps.max()):,}" if len(steps) else "-",
                     num(last("wall_s") / 3600, ".2f"), num(last("episode/sum_reward"), ".1f"),
                     num(last("eval/reward_per_step"), ".2f"), num(last("difficulty"), ".2f"),
                     num(last("guide_scale"), ".2f"), num(last("push_scale"), ".2f"), dev])
    return headers, rows


def plot_training_overview(runs: Sequence[pathlib.Path]):
    """Every run on shared axes: episode reward, eval reward per step, guide scale."""
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(16, 3.8))
    for d in runs:
        m = read_csv(d / "metrics.csv")
        for ax, key in zip(axes, ("episode/sum_reward", "eval/reward_per_step", "guide_scale")):
            x, y = series(m, key)
            if len(x):
                (ax.step(x, y, where="post", label=run_name(d)) if key == "guide_scale"
                 else ax.plot(x, y, "-" if key.startswith("episode") else "o-", ms=3,
                              label=run_name(d)))
    for ax, t in zip(axes, ("training episodes: sum of rewards", "milestone rollouts: reward per step",
                            "curriculum: guide scale")):
        ax.set_title(t, fontsize=10)
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    return fig


def plot_training_run(run_dir: pathlib.Path):
    """runs.plot_curves, inline: episode reward and length, eval reward per step, curriculum."""
    plt = _plt()
    m = read_csv(run_dir / "metrics.csv")
    fig, axes = plt.subplots(1, 3, figsize=(16, 3.6))
    x, y = series(m, "episode/sum_reward")
    axes[0].plot(x, y, "-", color="tab:blue", label="episode/sum_reward")
    axes[0].set_ylabel("episode/sum_reward", color="tab:blue")
    tw = axes[0].twinx()
    x, y = series(m, "episode/length")
    tw.plot(x, y, ":", color="tab:gray", label="episode/length")
    tw.set_ylabel("episode/length", color="tab:gray")
    axes[0].set_title("training episodes", fontsize=10)
    x, y = series(m, "eval/reward_per_step")
    axes[1].plot(x, y, "o-")
    axes[1].set_title("milestone rollout: reward per step", fontsize=10)
    for key in ("difficulty", "guide_scale", "push_scale"):
        x, y = series(m, key)
        if len(x):
            axes[2].step(x, y, where="post", label=key)
    axes[2].set_ylim(-0.05, 1.05)
    axes[2].set_title("curriculum", fontsize=10)
    if axes[2].get_legend_handles_labels()[0]:  # a DQN run logs no curriculum
        axes[2].legend(fontsize=8)
    for ax in axes:
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
    fig.suptitle(rel(run_dir), fontsize=9)
    fig.tight_layout()
    return fig


def find_estimators(results: pathlib.Path) -> list[tuple[str, pathlib.Path, pathlib.Path]]:
    """(name, metrics JSON, history CSV) of every estimator under <results>/estimators/."""
    out = []
    for h in sorted(results.glob("estimators/*_history.csv")):
        name = h.name[: -len("_history.csv")]
        out.append((name, h.with_name(name + ".json"), h))
    return out


def estimator_rows(ests):
    headers = ["estimator", "points (train / val)", "val acc", "best val acc (epoch)", "val AUC",
               "epochs", "train s", "device", "data"]
    rows = []
    for name, js, _ in ests:
        if not js.is_file():
            rows.append([name] + ["metrics JSON missing"] + ["-"] * 7)
            continue
        d = json.loads(js.read_text())
        m = d.get("metrics", {})
        rows.append([name, f"{m.get('train_points', 0):,} / {m.get('val_points', 0):,}",
                     f"{m.get('val_acc', math.nan):.3f}",
                     f"{m.get('best_val_acc', math.nan):.3f} ({m.get('best_val_acc_epoch', '?')})",
                     f"{m.get('val_auc', math.nan):.3f}", m.get("epochs", "?"),
                     f"{m.get('train_s', math.nan):.0f}", m.get("device", "not recorded"),
                     d.get("data_file", "?")])
    return headers, rows


def provenance_estimators(ests) -> list[str]:
    """Prints each estimator's data and checkpoint; verdict on the amount of sweep data."""
    reasons, few = [], []
    for name, js, _ in ests:
        d = json.loads(js.read_text()) if js.is_file() else {}
        m = d.get("metrics", {})
        print(f"  {name}: data {d.get('data_file', 'not recorded')}, checkpoint "
              f"{d.get('checkpoint', 'not recorded')}")
        if m.get("points_total", 0) < PAPER_SWEEP_POINTS:
            few.append(f"{name} {m.get('points_total', 0):,}")
        lab = pipeline_label(d)
        if lab:
            reasons.append(f"{name} labelled PIPELINE_CHECK ({lab})")
    if few:
        reasons.append(f"sweep points {', '.join(few)} (paper: {PAPER_SWEEP_POINTS:,} per target)")
    print(verdict(reasons))
    return reasons


def plot_estimators(ests):
    plt = _plt()
    fig, (a, b) = plt.subplots(1, 2, figsize=(14, 3.8))
    for name, _, h in ests:
        m = read_csv(h)
        (line,) = a.plot(m["epoch"], m["train_loss"], label=f"{name} train")
        a.plot(m["epoch"], m["val_loss"], "--", color=line.get_color(), label=f"{name} val")
        b.plot(m["epoch"], m["val_acc"], color=line.get_color(), label=name)
    a.set_ylabel("loss (E(s) - y)^2")
    b.set_ylabel("validation accuracy (threshold 0.5)")
    b.axhline(0.5, color="k", ls=":", lw=0.8)
    for ax in (a, b):
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    fig.suptitle("switch estimators: training curves", fontsize=9)
    fig.tight_layout()
    return fig

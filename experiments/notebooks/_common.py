"""Plumbing and drawing of the result notebooks in this folder: where results are, the commands
that make them, fixed-width tables, and the figures of ours beside the paper's. What the notebooks
print about a result (its rows, provenance and verdict) comes from the package's reports layer
(biped_switch.reports: table1, table2, table3, fig4b, fig5, estimators and provenance: labels,
stand-ins, the verdict line), and so do the figures the package also saves (Fig. 4b, Fig. 5 and
the training curves: `plot_fig4b` and `plot_training_run` call it); the paper's numbers come from
`biped_switch.paper`.

Every notebook reads saved results from one results root:

    RESULTS = $BIPED_SWITCH_RESULTS, or <repo>/experiments/results when unset

laid out as the package's CLIs write it (table1/, table2/, table3/, lookup/, estimators/,
training/). Policy training runs are read from the runs root (`runs_root`, `run_roots`):

    RUNS = $BIPED_SWITCH_RUNS, else <repo>/runs (where `python -m biped_switch.train`, `make train-all`
           and `make reproduce` write; runs.find_policy looks there, then in models/policies/);
           the training curves are looked for in <repo>/runs and models/policies/ (`run_roots`)

A missing input raises `MissingResult`, whose message names the command that makes it; nothing is
skipped silently. Nothing here builds an environment, steps the simulator or compiles JAX code:
the notebooks only read files (and the terrain generator, which is plain numpy).
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
DEFAULT_RUNS = REPO / "runs"  # where train, make train-all and make reproduce write their runs
if str(REPO) not in sys.path:  # biped_switch importable even without `pip install -e .`
    sys.path.insert(0, str(REPO))

from biped_switch import paper  # noqa: E402  (the paper's numbers)
from biped_switch.reports import curves, fig4b  # noqa: E402  (the figures drawn by the package)
from biped_switch.reports.provenance import rel, repo_path  # noqa: E402
from biped_switch.learning.runs import COMMITTED_DIR, curve_series  # noqa: E402
from biped_switch.stats import wilson_ci  # noqa: E402

METHOD_LABELS = {"random": "Random", "detection": "On detection", "lookup": "Lookup table",
                 "com_over_feet": "CoM over feet", "estimator": "Ours (estimator)",
                 "estimator_no_overlap": "Ours no overlap", "dqn": "*DQN",
                 "end_to_end": "*End-to-end", "ours": "Ours",
                 "lookup_context": "Lookup table (context sweep)",
                 "estimator_context": "Ours, estimator (context sweep)",
                 "estimator_context_persist": "Ours, estimator (context sweep, 5-step run)"}


def _env_path(name: str) -> pathlib.Path | None:
    env = os.environ.get(name)
    return repo_path(env) if env else None


def results_root() -> pathlib.Path:
    """$BIPED_SWITCH_RESULTS (relative paths taken from the repository root), else experiments/results."""
    return _env_path("BIPED_SWITCH_RESULTS") or DEFAULT_RESULTS


def runs_root() -> pathlib.Path:
    """The runs folder results are (or are to be) made from: $BIPED_SWITCH_RUNS (relative paths from the
    repository root), else <repo>/runs, where `train` writes (find_policy then also looks in
    models/policies/)."""
    env = _env_path("BIPED_SWITCH_RUNS")
    return env if env is not None else DEFAULT_RUNS


def run_roots() -> list[pathlib.Path]:
    """Every folder searched for training runs: [$BIPED_SWITCH_RUNS] when set, else <repo>/runs and the
    committed runs in models/policies/ (where runs.find_policy looks after runs/)."""
    env = _env_path("BIPED_SWITCH_RUNS")
    return [env] if env is not None else [DEFAULT_RUNS, COMMITTED_DIR]


class MissingResult(FileNotFoundError):
    """A notebook's input file is not there; the message names the command that makes it."""


def command_str(argv: Sequence[str]) -> str:
    """`python -m ...` as a reader would type it from the repository root."""
    return "python " + " ".join(shlex.quote(str(a)) for a in argv)


def require(path, argv: Sequence[str], what: str) -> pathlib.Path:
    """`path` if it is a file, else MissingResult naming `argv` (the command that writes it)."""
    path = pathlib.Path(path)
    if path.is_file():
        return path
    msg = (f"{what} not found: {path} is missing.\nMake it with (from {REPO}):\n    "
           f"{command_str(argv)}\nor point BIPED_SWITCH_RESULTS at a results root that has it "
           f"(now: {results_root()}).")
    raise MissingResult(msg)


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
    """retrain-cost reading the runs in `runs` (default `runs_root()`) and the sweeps and
    estimators of `results`, writing <results>/table3: the same root the notebook reads."""
    runs = runs_root() if runs is None else pathlib.Path(runs)
    return ["-m", "biped_switch.evaluate", "retrain-cost", "--runs", rel(runs),
            "--results", rel(results), "--init", init, "--out", rel(results / "table3")]


def lookup_command(results: pathlib.Path, init: str = "stand", runs=None) -> list[str]:
    runs = runs_root() if runs is None else pathlib.Path(runs)
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
    ref = [paper.TABLE1.get(r["policy"]) for r in rows]
    off = [0 if r["init"] == "stand" else 2 for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.8))
    bars_ours_vs_paper(axes[0], labels, [r["distance_pct"] for r in rows],
                       [r.get("distance_ci") for r in rows],
                       [p[o] if p else None for p, o in zip(ref, off)], "% of total distance",
                       "Table I: distance")
    bars_ours_vs_paper(axes[1], labels, [r["success_pct"] for r in rows],
                       [r.get("success_ci") for r in rows],
                       [p[o + 1] if p else None for p, o in zip(ref, off)], "% success",
                       "Table I: success")
    axes[1].legend(fontsize=8, loc="upper right")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def plot_table2(doc: dict, title: str = ""):
    """Distance, success and per-artifact failure rates of every method, ours beside the paper's."""
    plt = _plt()
    ours = {r["method"]: r for r in doc["rows"]}
    methods = list(ours) + [m for m in paper.TABLE2 if m not in ours]
    labels = [METHOD_LABELS.get(m, m) for m in methods]
    ref = [paper.TABLE2.get(m) for m in methods]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.2), gridspec_kw={"width_ratios": [1, 1, 1.4]})
    for ax, key, i, name in ((axes[0], "distance", 0, "% of total distance"),
                             (axes[1], "success", 1, "% success")):
        bars_ours_vs_paper(ax, labels, [ours[m][f"{key}_pct"] if m in ours else None for m in methods],
                           [ours[m].get(f"{key}_ci") if m in ours else None for m in methods],
                           [p[i] if p else None for p in ref], name, f"Table II: {key}")
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
        ax.bar(xo + w, [p[pi] if p else 0 for p in ref], w, color=col, alpha=0.35, hatch="//",
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
        ref = r.get("paper_hours", paper.TABLE3_H.get(r["method"]))
        if ref is not None:
            ax.bar(x[i] + w / 2, ref, w, color="0.75", hatch="//", edgecolor="0.4",
                   label="paper" if i == 0 else None)
            ax.text(x[i] + w / 2, ref, f"{ref:g}", ha="center", va="bottom", fontsize=8)
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
def plot_fig4b(doc: dict, smooth_bins: int = 5, title: str = ""):
    """Success of switching against distance to the artifact, per (source -> target) pair: the
    package's Fig. 4b (`reports.fig4b.switch_success_figure`) of a lookup JSON."""
    return fig4b.switch_success_figure(
        fig4b.lookup_arrays(doc), title or f"{doc.get('init')} init: switch success against "
        "distance (dots: 1 cm bins, size ~ points; dotted: best distance)", smooth_bins)


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
    """Run folders with a metrics.csv: <root>/*/ for each of `roots` (default `run_roots()`:
    runs/, where train writes), <results>/training/*/, <results>/training_*/ and `extra`."""
    roots = run_roots() if roots is None else roots
    found = ({p.parent for p in results.glob("training/*/metrics.csv")}
             | {p.parent for p in results.glob("training_*/metrics.csv")}
             | {p.parent for r in roots for p in pathlib.Path(r).glob("*/metrics.csv")}
             | {pathlib.Path(e) for e in extra if (pathlib.Path(e) / "metrics.csv").is_file()})
    return sorted({d.resolve(): d for d in found}.values())


def run_name(d: pathlib.Path) -> str:
    """A run folder's path relative to the results root (else to the repository)."""
    try:
        return str(d.resolve().relative_to(results_root().resolve()))
    except ValueError:
        return rel(d)


def metrics_rows(run_dir) -> list[dict]:
    """The rows of a run's metrics.csv (the curves are drawn from them with `series`)."""
    with (pathlib.Path(run_dir) / "metrics.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def series(rows: list[dict], key: str):
    """(steps, values) of `key` (runs.curve_series), finite values only."""
    xy = curve_series(rows, key)
    ok = np.isfinite(xy).all(1)
    return xy[ok, 0], xy[ok, 1]


def plot_training_overview(runs: Sequence[pathlib.Path]):
    """Every run on shared axes: episode reward, eval reward per step, guide scale."""
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(16, 3.8))
    for d in runs:
        m = metrics_rows(d)
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
    """The run's curves.png, inline: the package's figure of a PPO or DQN run
    (`reports.curves.run_figure`)."""
    return curves.run_figure(run_dir, title=rel(run_dir))


def find_estimators(results: pathlib.Path) -> list[tuple[str, pathlib.Path, pathlib.Path]]:
    """(name, metrics JSON, history CSV) of every estimator under <results>/estimators/."""
    out = []
    for h in sorted(results.glob("estimators/*_history.csv")):
        name = h.name[: -len("_history.csv")]
        out.append((name, h.with_name(name + ".json"), h))
    return out


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

"""Plumbing of the result notebooks in this folder: where results are, the commands that make
them and fixed-width tables. Every figure and table is drawn by the package's reports layer
(biped_switch.reports: plots for Tables I-III, the training runs and the estimators; fig4b, fig5,
curves; table1/2/3 for the rows, provenance and verdict), re-exported here under the names the
notebooks call; the paper's numbers come from `biped_switch.paper`.

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

import json
import os
import pathlib
import shlex
import subprocess
import sys
from typing import Iterable, Sequence


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

from biped_switch.reports.provenance import rel, repo_path  # noqa: E402
from biped_switch.learning.runs import COMMITTED_DIR  # noqa: E402
from biped_switch.reports import plots  # noqa: E402  (the figures, drawn by the package)
from biped_switch.reports.plots import (bars_ours_vs_paper, metrics_rows, plot_estimators,  # noqa: E402,F401
                                        plot_fig4b, plot_table1, plot_table2, plot_table3,
                                        read_csv, series)


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


# ------------------------------------------------------------------------------- training curves
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


def plot_training_overview(runs: Sequence[pathlib.Path]):
    """Every run on shared axes (`plots.plot_training_overview`), labelled by `run_name`."""
    return plots.plot_training_overview(runs, run_name)


def plot_training_run(run_dir: pathlib.Path):
    """The run's curves.png, inline (`plots.plot_training_run`)."""
    return plots.plot_training_run(run_dir, title=rel(run_dir))


def find_estimators(results: pathlib.Path) -> list[tuple[str, pathlib.Path, pathlib.Path]]:
    """(name, metrics JSON, history CSV) of every estimator under <results>/estimators/."""
    out = []
    for h in sorted(results.glob("estimators/*_history.csv")):
        name = h.name[: -len("_history.csv")]
        out.append((name, h.with_name(name + ".json"), h))
    return out

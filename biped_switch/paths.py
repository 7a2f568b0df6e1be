"""Where things live: the repository root, committed models and the default folders of every
command line. Plain Python, importing nothing of the package."""

from __future__ import annotations

import pathlib

REPO = pathlib.Path(__file__).resolve().parents[1]  # the repository (or install) root
MODELS_DIR = REPO / "models"
COMMITTED_DIR = MODELS_DIR / "policies"  # final (or resume) checkpoint of every PPO run, committed
BASELINE_DIR = MODELS_DIR / "baselines"  # committed DQN runs, as models/policies/ for PPO
ESTIMATOR_DIR = MODELS_DIR / "estimators"  # committed switch estimators, one folder per target
WHEN_DIR = MODELS_DIR / "switch_when"  # the learned when rule, one folder per suite

# Defaults of the command lines' shared flags, relative to the working directory.
RUNS = "runs"  # --runs: the parent of training run folders
ESTIMATORS = "models/estimators"
LOOKUP = "experiments/results/lookup"
WHEN = "models/switch_when"  # --when-dir / when --out: the learned when rule's models
WHEN_SWEEPS = "runs/sweeps_when"  # the when rule's sweeps (context and lead-in)
RESULTS = "experiments/results"
SWEEPS = "runs/sweeps"


def rel(path) -> str:
    """`path` relative to the repository root when it is inside it (for commands and messages)."""
    p = pathlib.Path(path)
    try:
        return str(p.resolve().relative_to(REPO))
    except ValueError:
        return str(p)


def repo_path(p) -> pathlib.Path:
    """`p` with a relative path taken from the repository root."""
    p = pathlib.Path(p).expanduser()
    return p if p.is_absolute() else REPO / p

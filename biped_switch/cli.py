"""`biped-switch <command> [args]`: one entry point for every command line of the package.

Each command is also `python -m biped_switch.<command>`; both run the same `main(argv)`.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import threading

from biped_switch import paths
from biped_switch.names import BACKEND_CHOICES, INITS

COMMANDS = {
    "train": "train a behaviour policy (PPO, guided curriculum)",
    "sweep": "switch-point sweeps: estimator data and lookup tables",
    "estimator": "train the switch estimators from the sweeps",
    "dqn": "train the DQN selector baseline",
    "distill": "distil the composed controller into one student policy (DAgger)",
    "evaluate": "Tables I-III, failures and switches",
    "demo": "a short end-to-end check of the committed models",
    "render": "a GIF of a rollout",
    "bench": "speed benchmarks (JSON)",
    "terrain": "lay out and plot a track",
    "detector": "train the learned terrain detector and measure it",
    "when": "train the learned when rule, tune it, and its timing ceiling",
}


# ----------------------------------------------------------------------- shared flags
# Each flag that several commands take is defined once here, so it means one thing everywhere.
def add_runs(p: argparse.ArgumentParser, help: str = "") -> None:
    """--runs: the parent folder of training run folders (<runs>/<policy>_<init>/); a run not
    there is taken from its committed copy under models/."""
    p.add_argument("--runs", default=paths.RUNS,
                   help=help or "parent folder of training runs (then the committed models/)")


def add_backend(p: argparse.ArgumentParser) -> None:
    """--backend: the physics backend; auto is the C engine on a CPU and MJX on an accelerator."""
    p.add_argument("--backend", default="auto", choices=BACKEND_CHOICES,
                   help="physics backend (auto: mujoco on a CPU, mjx on an accelerator)")


def add_out(p: argparse.ArgumentParser, default, what: str) -> None:
    """--out: the folder this command writes into (created if missing), in every command."""
    p.add_argument("--out", default=default, help=f"the folder this command writes into: {what}"
                   + (f" (default {default})" if default else ""))


def add_when_dir(p: argparse.ArgumentParser, help: str = "") -> None:
    """--when-dir: the learned when rule's models, one folder per suite (`when --out`)."""
    p.add_argument("--when-dir", default=paths.WHEN,
                   help=help or "the learned when rule's models (python -m biped_switch.when)")


def add_init(p: argparse.ArgumentParser, default: str = "stand") -> None:
    """--init: which policy suite (its episodes start standing, or from random joints)."""
    p.add_argument("--init", default=default, choices=INITS,
                   help="policy suite: stand (standing start) or random (random joints)")


# ----------------------------------------------------------------------- numeric flags
def at_least(lo: float, kind=int, strict: bool = False):
    """An argparse `type` that reads a `kind` >= `lo` (> `lo` if `strict`); anything else is an
    argparse error naming the flag and the value given."""
    op = ">" if strict else ">="

    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            what = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if not (v > lo if strict else v >= lo):  # NaN fails both
            raise argparse.ArgumentTypeError(f"must be {op} {lo:g}, got {text!r}")
        return v

    parse.__name__ = f"{kind.__name__} {op} {lo:g}"
    return parse


positive_int = at_least(1)  # counts: trials, batch, artifacts, epochs
nonneg_int = at_least(0)  # seeds, indices
positive_float = at_least(0.0, float, strict=True)  # durations, distances
nonneg_float = at_least(0.0, float)  # scales that may be off (0)


def usage() -> str:
    width = max(map(len, COMMANDS))
    rows = "\n".join(f"  {c:<{width}}  {h}" for c, h in COMMANDS.items())
    return f"usage: biped-switch <command> [args]\n\ncommands:\n{rows}\n"


def run(main) -> None:
    """Exits with `main()`'s status; a damaged run folder (a file that is not JSON, a truncated
    checkpoint) ends in one line naming the file instead of a traceback, and nothing after it:
    the process exits at once, before Orbax's background event loop is torn down (which prints
    'Event loop is closed' tracebacks at interpreter exit)."""
    from biped_switch.learning.runs import RunFileError
    try:
        code = main()
    except Exception as e:
        # learning.checkpoints.CheckpointError by name: cli.py imports no Orbax
        if not isinstance(e, RunFileError) and type(e).__name__ != "CheckpointError":
            raise
        # Orbax's loop thread may fail on the closed loop while this process exits: say nothing
        threading.excepthook = sys.unraisablehook = lambda *_: None
        print(f"error: {e}", file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(2)
    sys.exit(code)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0 if argv else 2
    cmd, rest = argv[0], argv[1:]
    if cmd not in COMMANDS:
        print(f"biped-switch: unknown command {cmd!r}\n\n{usage()}", file=sys.stderr)
        return 2
    return importlib.import_module(f"biped_switch.{cmd}").main(rest)


def console() -> None:
    """The `biped-switch` console script."""
    run(main)


if __name__ == "__main__":
    run(main)

"""Trains the learned "when" switch rule and checks it offline (`switching/when.py`).

    python -m biped_switch.when --init stand [--data runs/sweeps_when] [--out models/switch_when]

Reads the context sweeps with approach records (`python -m biped_switch.sweep --init stand
--context --switch-min 0.2 --out runs/sweeps_when`), trains the ensemble, and scores it on the
held-out tracks' switches at 0.3-0.9 m beside the paper's estimator and the (target, active
policy, distance) table: AUC, Brier score and calibration error per target and source
(experiments/results/when/offline.md). The model goes to <out>/<init>. `--lead-in use|only`
also reads the lead-in sweeps (`sweep --lead-in`).

    python -m biped_switch.when --init stand --tune      # margin and run length, tuning tracks
    python -m biped_switch.when --init stand --ceiling   # how far timing alone can go
"""

from __future__ import annotations

import argparse

from biped_switch import cli, paths
from biped_switch.config import default_when_config
from biped_switch.products import when as when_lib


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.when", description=__doc__.split("\n")[0])
    cli.add_init(p)
    p.add_argument("--data", default=paths.WHEN_SWEEPS, help="the sweeps' --out")
    p.add_argument("--out", default=paths.WHEN)
    p.add_argument("--lead-in", choices=("use", "only", "skip"), default="skip",
                   help="the lead-in sweeps (`sweep --lead-in`), where a target has one: train on "
                        "them and the context sweep (use), in place of it (only), or not (skip: "
                        "the committed model)")
    p.add_argument("--estimators", default="models/estimators",
                   help="the paper's estimators, scored beside it offline")
    p.add_argument("--results", default="experiments/results/when")
    p.add_argument("--epochs", type=cli.positive_int, default=None)
    p.add_argument("--ensemble", type=cli.positive_int, default=None)
    p.add_argument("--tune", action="store_true",
                   help="instead of training: run the trained rule on tuning tracks (TUNE_TRACK_SEED"
                        " + i, never Table II's) for each margin of the config's margin_choices, "
                        "then for longer runs at the best margin; writes RESULTS/tuning.md")
    p.add_argument("--trials", type=cli.positive_int, default=400, help="tuning trials per setting")
    p.add_argument("--persist", type=cli.positive_int, nargs="+", default=[2, 3],
                   help="run lengths tried at the best margin (1 is always tried)")
    p.add_argument("--later", nargs="+", default=["model", "table"], choices=("model", "table"),
                   help="where the later moments' P come from, each tried")
    p.add_argument("--margins", type=float, nargs="+", default=None,
                   help="margins tried (default: the config's margin_choices)")
    p.add_argument("--band", type=float, nargs="+", default=[],
                   help="band tolerances tried at the best margin (1: no band, always tried)")
    cli.add_runs(p)
    p.add_argument("--ceiling", action="store_true",
                   help="instead of training: the timing ceiling, each sweep's best switch-distance "
                        "bin per (target, source) beside Table II's success there "
                        "(RESULTS/ceiling.md)")
    p.add_argument("--table2", default="experiments/results/table2",
                   help="`evaluate failures`' output, read by --ceiling")
    p.add_argument("--trials-ceiling", type=cli.positive_int, default=2500,
                   help="Table II's tracks whose artifact sequences the ceiling is implied on")
    a = p.parse_args(argv)
    cfg = default_when_config()
    if a.ceiling:
        return when_lib.ceiling(a, cfg)
    if a.tune:
        if any(not 0 < b <= 1 for b in a.band):
            p.error(f"--band values must lie in (0, 1], got {a.band}")
        a.margins = list(cfg.margin_choices if a.margins is None else a.margins)
        return when_lib.tune(a)
    if a.epochs is not None:
        cfg.epochs = a.epochs
    if a.ensemble is not None:
        cfg.ensemble = a.ensemble
    return when_lib.train_rule(a, cfg)


if __name__ == "__main__":
    cli.run(main)

"""Switch-point sweeps (paper Sec. III-C): estimator data and lookup tables.

The command line of `biped_switch.switching.sweep`: `python -m biped_switch.sweep` or `biped-switch sweep`.
"""

from __future__ import annotations

import argparse
import pathlib

from biped_switch import cli
from biped_switch import kinds, lineups
from biped_switch.config import default_sweep_config
from biped_switch.products import sweep as sweep_products
from biped_switch.simulation import terrain
from biped_switch.switching.estimator import sweep_name
from biped_switch.switching.sweep_tracks import check_sweep_kind


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.sweep", description=__doc__.split("\n")[0])
    cli.add_init(p)
    p.add_argument("--lineup", default=lineups.PAPER_LINEUP.name, choices=list(lineups.LINEUP),
                   help="whose policies switch into which targets (lineups.LINEUPS; default the "
                        "paper's); another than paper: --context only, named <init>_context_<it>")
    p.add_argument("--targets", nargs="+", default=None, choices=kinds.ALL_ARTIFACT_KINDS,
                   help="the targets to sweep (default: every target of the line-up)")
    p.add_argument("--points", type=cli.positive_int, default=None, help="data points per target (default 100,000)")
    p.add_argument("--batch", type=cli.positive_int, default=None, help="episodes per jitted batch")
    p.add_argument("--tracks", type=cli.positive_int, default=512, help="single-artifact tracks in the bank")
    p.add_argument("--seed", type=cli.nonneg_int, default=0)
    cli.add_runs(p, "where the trained policies are (then models/policies/)")
    cli.add_out(p, "runs/sweeps", "the sweep data, one part per batch (large; not committed)")
    p.add_argument("--results", default="experiments/results/lookup")
    p.add_argument("--stand-in", default=None, choices=kinds.ALL_POLICY_NAMES,
                   help="use this policy for any that is not trained yet (pipeline checks only)")
    p.add_argument("--guide-scale", type=cli.nonneg_float, default=0.0,
                   help="scripted guide forces on (pipeline checks with untrained policies only)")
    p.add_argument("--difficulty", type=float, default=None, help="terrain difficulty (default 1)")
    cli.add_backend(p)
    p.add_argument("--context", action="store_true",
                   help="switch after the source policy has crossed its own artifact, as on mixed "
                        "tracks (two-artifact tracks; data and lookup named <init>_context)")
    p.add_argument("--lead-in", action="store_true",
                   help="a context sweep whose episodes all start with walk, the controller handing "
                        "over along the track by the context lookup, as on Table II (up to three-"
                        "artifact tracks; data and lookup named <init>_leadin)")
    p.add_argument("--switch-min", type=float, default=None,
                   help="switch at U(this, 0.9) m before the artifact (default 0: the paper's); "
                        "a floor puts the data where the rules decide")
    p.add_argument("--replay", type=cli.nonneg_int, default=0, metavar="N",
                   help="instead of sweeping: replay N recorded switches (0.3-0.9 m) of each "
                        "target's sweep in a program of another batch size, and report how often "
                        "the label agrees (RESULTS/label_noise.json)")
    p.add_argument("--replay-batch", type=cli.positive_int, default=128)
    a = p.parse_args(argv)
    lineup = lineups.LINEUP[a.lineup]  # resolved once: everything below reads the record
    try:
        check_sweep_kind(lineup, a.context, a.lead_in)
    except ValueError as e:
        p.error(str(e))
    a.targets = list(lineup.targets) if a.targets is None else a.targets
    if bad := [t for t in a.targets if t not in lineup.targets]:
        p.error(f"--targets {' '.join(bad)}: not a target of line-up {lineup.name} "
                f"({', '.join(lineup.targets)})")
    name = sweep_name(a.init, a.context, a.lead_in, lineup=lineup)
    cfg = default_sweep_config()
    if a.points is not None:
        cfg.n_points = a.points
    if a.batch is not None:
        cfg.batch = a.batch
    if a.switch_min is not None:
        if not 0.0 <= a.switch_min < cfg.switch_max_m:
            p.error(f"--switch-min must lie in [0, {cfg.switch_max_m}) m, got {a.switch_min}")
        cfg.switch_min_m = a.switch_min
    if a.difficulty is not None:
        terrain.check_difficulty(a.difficulty)
        cfg.difficulty = a.difficulty
    out = pathlib.Path(a.out)
    if a.replay:
        return sweep_products.replay(a, out / name, pathlib.Path(a.results), lineup)
    return sweep_products.sweeps_and_lookup(a, cfg, name, out, lineup)


if __name__ == "__main__":
    cli.run(main)

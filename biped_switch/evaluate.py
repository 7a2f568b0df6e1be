"""Evaluations and the paper's tables.

    python -m biped_switch.evaluate single [--trials 500] [--runs runs] [--policies walk jumps ...]
                                           [--track-seed 10000] [--backend auto] [--horizon-s S] [--kind K]

`single` (Table I): each policy on tracks of its own terrain kind (7 artifacts, 500 trials by
default; trial i on the track of seed `--track-seed` + i, by default tracks training never saw),
for both init modes, without switching, in an env made with the env overrides (action mode, phase
clock) the policy was trained with. Reports % of the total track distance covered (distance along
x from the start to the finish line, capped at 100%) and % success (reached the finish line
without falling), each with a 95% confidence interval (normal interval of the mean for distance,
Wilson score interval for success), and the mean forward speed (distance / time alive after the
standing pause); prints a Markdown table and saves it with a CSV and a JSON of the settings
(backend, track seed, horizon) under experiments/results/table1/. The time limit, unless
`--horizon-s` is given, lets a walker at 0.6 m/s reach the farthest finish line of the tracks
evaluated, with a 20% margin (`single_horizon_s`); each row says which limit it ran with.
`--kind K`: every policy on tracks of kind K instead (e.g. the paper's four on a new kind).
The rows join those already in table1.json for other policies and inits (the random-init suite
finishes after the stand suite), unless `--fresh`; a table of other trials is refused.
Policies load from `<runs>/<policy>_<init>/checkpoints/<latest>` (or models/policies/).

    python -m biped_switch.evaluate multi [--trials 2500] [--methods random detection ...]

`multi` (Table II): every method (biped_switch/methods.py: a record per row) on the same `mixed`
tracks (7 artifacts; trial i uses track i and rng seed + batch start), each trial starting with the
walk policy, on the physics `--backend` with the env overrides its policy suite was trained with.
Reports % distance, % success and % of trials failing on gaps / jumps / stairs, with 95% CIs;
saves Markdown, CSV and JSON under experiments/results/table2/, plus the paper's Fig. 5 (one
trial of each row with a model or setup policies) as fig5_trial<i>[_<row>].png; `--lineup stones`: Table II-4.

    python -m biped_switch.evaluate retrain-cost [--runs runs] [--results R] [--when-dir W]

`retrain-cost` (Table III): hours to add a new terrain, from the recorded training logs.

This module is the command line only: it parses the flags; products/tables.py runs each
command and writes its files.
"""

from __future__ import annotations

import argparse

from biped_switch import cli
from biped_switch.config import EVAL_TRACK_SEED, LINEUP_TRACK_SEEDS
from biped_switch.lineups import LINEUP, PAPER_LINEUP
from biped_switch.products import tables
from biped_switch.evaluation.single import HORIZON_MARGIN, HORIZON_SPEED_MPS
from biped_switch.learning.runs import BASELINE_DIR
from biped_switch.names import ARTIFACT_KINDS, BASELINES, INITS, MULTI_METHODS, POLICY_NAMES
from biped_switch.names import ALL_POLICY_NAMES, TERRAIN_KINDS

SWITCHES_DEFAULT = ["com_over_feet", "lookup", "lookup_context", "estimator",
                    "estimator_context_persist", "learned"]


def _common(s, trials: int, batch: int, horizon_s: float | None, horizon_help: str) -> None:
    """The flags every rollout command takes: trials, batch, horizon, rng seed, runs, backend."""
    s.add_argument("--trials", type=cli.positive_int, default=trials)
    s.add_argument("--batch", type=cli.positive_int, default=batch, help="episodes per jitted rollout")
    s.add_argument("--horizon-s", type=cli.positive_float, default=horizon_s, help=horizon_help)
    s.add_argument("--seed", type=cli.nonneg_int, default=0)
    cli.add_runs(s)
    cli.add_backend(s)


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m biped_switch.evaluate",
                                description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("single", help="Table I: each policy on its own terrain kind")
    s.add_argument("--policies", nargs="+", default=list(ARTIFACT_KINDS), choices=ALL_POLICY_NAMES)
    s.add_argument("--kind", default=None, choices=TERRAIN_KINDS, help="every policy on K's tracks")
    s.add_argument("--inits", nargs="+", default=list(INITS), choices=INITS)
    _common(s, 500, 100, None, f"episode time limit [s] (default: per policy, the standing pause "
            f"plus {HORIZON_MARGIN:g} x the time to its farthest finish line at "
            f"{HORIZON_SPEED_MPS:g} m/s)")
    s.add_argument("--track-seed", type=cli.nonneg_int, default=EVAL_TRACK_SEED,
                   help=f"trial i runs on the track of seed TRACK_SEED + i (default "
                        f"{EVAL_TRACK_SEED:,}: tracks training never saw)")
    cli.add_out(s, "experiments/results/table1", "table1.md, .csv and .json")
    s.add_argument("--fresh", action="store_true", help="replace OUT/table1.json (by default this "
                   "run's rows join its rows of the other policies and inits made with the same "
                   "trials, batch, seed, horizon and track seed)")
    m = sub.add_parser("multi", help="Table II: switching methods on multi-artifact tracks")
    m.add_argument("--methods", nargs="+", default=None, choices=MULTI_METHODS, help="default: all the line-up has")
    m.add_argument("--lineup", default=PAPER_LINEUP.name, choices=tuple(LINEUP), help="policies, targets, tracks")
    _common(m, 2500, 250, 60.0, "episode time limit [s]")
    m.add_argument("--n-artifacts", type=cli.positive_int, default=7, help="artifacts per track (paper: 7)")
    m.add_argument("--track-seed", type=cli.nonneg_int, default=None,
                   help=f"trial i runs on the line-up's track of seed TRACK_SEED + i (default: its "
                        f"reporting seed, for reporting only; tune on others: (report, tune) "
                        f"{LINEUP_TRACK_SEEDS})")
    m.add_argument("--detector", default="oracle", choices=("oracle", "learned"),
                   help="what names the next artifact: the paper's oracle, or the learned "
                        "detector on the heightmap (python -m biped_switch.detector)")
    m.add_argument("--detector-dir", default="models/detector/stand",
                   help="the learned detector's folder (with --detector learned)")
    m.add_argument("--estimators", default="models/estimators")
    cli.add_when_dir(m)
    m.add_argument("--when-margin", type=float, default=None, help="learned rule: switch once "
                   "P(now) >= best later P + this (default: config's, chosen on tuning tracks)")
    m.add_argument("--when-persist", type=cli.positive_int, default=None,
                   help="learned rule: ... on this many control steps in a row (default: config's)")
    m.add_argument("--when-later", default=None, choices=("model", "table"), help="learned rule: "
                   "the later moments' P from the model or the prior table (default: config's)")
    m.add_argument("--lookup", default="experiments/results/lookup")
    m.add_argument("--dqn", default=None,
                   help=f"DQN run directory (default: RUNS/dqn_stand, then {BASELINE_DIR}/dqn_stand)")
    m.add_argument("--stand-in", default=None, choices=POLICY_NAMES,
                   help="use this policy for any that is not trained yet (pipeline checks only)")
    m.add_argument("--guide-scale", type=cli.nonneg_float, default=0.0,
                   help="scripted guide forces on (pipeline checks with untrained policies only)")
    m.add_argument("--fig5-trial", type=cli.at_least(-1), default=0, help="trial drawn as Fig. 5 "
                   "for each row with a model or setup policies: fig5_trial<i>[_<row>] (-1: none)")
    cli.add_out(m, "experiments/results/table2",
                "table2.md, .csv, .json, claims.md, the per-trial outcomes and Fig. 5")
    m.add_argument("--fresh", action="store_true", help="replace OUT/table2.json (by default this "
                   "run's rows join its rows of the other methods made with the same settings)")
    r = sub.add_parser("retrain-cost", help="Table III: hours to add a new terrain, from logs")
    cli.add_runs(r)
    r.add_argument("--results", default="experiments/results")
    cli.add_when_dir(r, "the learned when rule, whose meta.json gives ours_learned's hours")
    cli.add_init(r)
    cli.add_out(r, "experiments/results/table3", "table3.md and .json")
    f = sub.add_parser("failures", help="Table II's falls by artifact and the artifact before it")
    cli.add_out(f, "experiments/results/table2", "failures_by_context.md and .json, and claims.md "
                "afresh, beside the table2.json and table2_trials.npz of `evaluate multi` it reads")
    w = sub.add_parser("switches", help="where each rule switched, and what it cost "
                                        "(switch_distances.md/.json/.png)")
    w.add_argument("--methods", nargs="+", default=SWITCHES_DEFAULT,
                   choices=[m for m in MULTI_METHODS if m not in BASELINES])
    _common(w, 500, 250, 60.0, "episode time limit [s]")
    w.add_argument("--n-artifacts", type=cli.positive_int, default=7, help="artifacts per track (paper: 7)")
    w.add_argument("--estimators", default="models/estimators")
    w.add_argument("--lookup", default="experiments/results/lookup")
    cli.add_out(w, "experiments/results/table2", "switch_distances.md, .json and .png")
    return p


def main(argv=None) -> int:
    p = parser()
    a = p.parse_args(argv)
    run = {"single": lambda: tables.single(a, p.error), "multi": lambda: tables.multi(a, p.error),
           "switches": lambda: tables.switches(a), "failures": lambda: tables.failures(a.out),
           "retrain-cost": lambda: tables.retrain_cost(a.runs, a.results, a.init, a.out, a.when_dir)}
    return run[a.cmd]()


if __name__ == "__main__":
    cli.run(main)

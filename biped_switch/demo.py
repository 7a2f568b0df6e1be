"""`make demo`: the switching pipeline end to end on a CPU, at a small size.

With the committed stand-init policy suite (models/policies/{walk,jumps,gaps,stairs}_stand, or newer
runs under runs/), switch estimators (models/estimators/) and lookup table
(experiments/results/lookup/), runs every switching method, the no-overlap ablation where the
random-init suite is trained, and the DQN and end-to-end baselines where they are trained
(models/baselines/dqn_stand, models/policies/mixed_stand), on the same two dozen short `mixed`
tracks (2 artifacts of different kinds, so that a good policy can finish within a time limit a
2-core CPU can afford in under 10 minutes), prints Table II, draws the paper's Fig. 5 for one trial
of the estimator method and renders that trial to a GIF (offscreen MuJoCo; skipped with a message
when no OpenGL backend is available). Where a learned terrain detector is trained
(models/detector/stand/), `lookup_context` runs once more with it in place of the oracle, and its
success is printed beside the oracle's. Everything goes to runs/demo/ (git-ignored);
`--refresh-example` rewrites the committed example output, experiments/results/demo/ (then
`make docs`: docs/results.md copies its table).

A missing stand-init policy is an error naming it and the command that trains it; nothing stands
in for it. It reports honestly what it ran on: the provenance of every policy is printed and saved,
and policies whose training runs are unfinished (curriculum or push stage not done) are flagged as
"policies in training, not results".
"""

from __future__ import annotations

import argparse

from biped_switch import cli
from biped_switch.products.demo import horizon_for, run_demo

OUT = "runs/demo"  # git-ignored: a demo run leaves the tree clean
EXAMPLE = "experiments/results/demo"  # the committed example output (--refresh-example)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.demo", description=__doc__.split("\n")[0])
    # A step costs ~13 ms + 0.5 ms per env on 2 CPU cores (measured), so the time limit, not the
    # trials, sets the demo's length: 32 trials of 3 artifacts (32 s) took 9 min 13 s.
    p.add_argument("--trials", type=cli.positive_int, default=24)
    p.add_argument("--n-artifacts", type=cli.positive_int, default=2, help="artifacts per track (paper: 7)")
    p.add_argument("--horizon-s", type=cli.positive_float, default=None,
                   help="episode time limit [s] (default: the longest track at the 0.8 m/s target speed, x1.4)")
    p.add_argument("--seed", type=cli.nonneg_int, default=0)
    cli.add_runs(p)
    p.add_argument("--estimators", default="models/estimators")
    p.add_argument("--lookup", default="experiments/results/lookup")
    p.add_argument("--dqn", default=None, help="DQN run directory (default: RUNS/dqn_stand, then models/baselines/)")
    cli.add_backend(p)
    p.add_argument("--no-video", action="store_true")
    cli.add_out(p, None, f"the demo's tables, figure and GIF (default {OUT}, git-ignored)")
    p.add_argument("--refresh-example", action="store_true",
                   help=f"write the committed example output, {EXAMPLE}/, instead (then `make docs`)")
    a = p.parse_args(argv)
    if a.refresh_example and a.out:
        p.error("--refresh-example writes to " + EXAMPLE + "; give it or --out, not both")
    a.out = EXAMPLE if a.refresh_example else (a.out or OUT)
    if a.horizon_s is None:
        a.horizon_s = horizon_for(a.trials, a.n_artifacts)
    return run_demo(a)


if __name__ == "__main__":
    cli.run(main)

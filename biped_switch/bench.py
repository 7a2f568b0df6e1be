"""Speed figures of the environment as one JSON object (a benchmark, never a timed test).

The command line of `biped_switch.evaluation.bench`: `python -m biped_switch.bench` or `biped-switch bench`.
"""

from __future__ import annotations

import argparse
import json
import sys
import jax
from biped_switch import cli
from biped_switch.simulation import terrain
from biped_switch.evaluation import bench as bench_lib


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.bench", description=__doc__.split("\n")[0])
    p.add_argument("--batch", type=cli.positive_int, default=256)
    p.add_argument("--kind", default=None, choices=terrain.KINDS,
                   help="track kind (default: mixed; --train: walk)")
    p.add_argument("--steps", type=cli.positive_int, default=20, help="timed control steps")
    p.add_argument("--seed", type=cli.nonneg_int, default=0)
    p.add_argument("--n-artifacts", type=cli.positive_int, default=None, help="artifacts per track (paper: 7)")
    p.add_argument("--json", action="store_true", help="print only the JSON object")
    p.add_argument("--estimator", action="store_true", help="time switch-estimator training instead")
    p.add_argument("--train", action="store_true",
                   help="time PPO training (collection + updates) and its ratio to --physics")
    p.add_argument("--physics", action="store_true",
                   help="the raw C physics rate of the same env (no learner, no JAX in the loop)")
    p.add_argument("--profile", action="store_true",
                   help="one PPO iteration split into physics, heightmap, env, policy, update, host")
    cli.add_backend(p)
    p.add_argument("--encoding", default="pool", choices=("pool", "mlp"),
                   help="--train: the policy's heightmap input (pool: 150 values; mlp: 2,400)")
    p.add_argument("--iterations", type=cli.positive_int, default=5, help="--train: timed PPO iterations")
    p.add_argument("--preset", default="cpu", choices=("cpu", "gpu"), help="--train: batch sizes")
    p.add_argument("--points", type=cli.positive_int, default=100_000, help="--estimator: data points")
    p.add_argument("--epochs", type=cli.positive_int, default=None,
                   help="--estimator: epochs, the first compiles (default 3); --train: PPO update "
                        "epochs per batch (default: the preset's)")
    p.add_argument("--minibatches", type=cli.positive_int, default=None,
                   help="--train: PPO minibatches per epoch (default: the preset's)")
    a = p.parse_args(argv)
    if a.estimator:
        a.epochs = 3 if a.epochs is None else a.epochs
        if a.points < 100 or a.epochs < 2:
            p.error("--estimator needs --points >= 100 and --epochs >= 2")
        res = bench_lib.run_estimator(a.points, a.epochs, a.seed)
        print(json.dumps(res) if a.json else json.dumps(res, indent=2))
        return 0
    if a.physics or a.profile:
        if a.steps < 1:
            p.error(f"--steps must be >= 1 (got {a.steps})")
        res = (bench_lib.run_physics(a.batch, a.kind or "mixed", max(a.steps, 50), a.seed,
                                     a.n_artifacts) if a.physics
               else bench_lib.profile_train(a.kind or "mixed", a.preset, a.seed))
        print(json.dumps(res) if a.json else json.dumps(res, indent=2))
        return 0
    if a.train:
        if a.iterations < 1:
            p.error(f"--iterations must be >= 1 (got {a.iterations})")
        res = bench_lib.run_train(a.backend, a.kind or "walk", a.iterations, a.preset, a.encoding, a.seed,
                                  epochs=a.epochs, minibatches=a.minibatches)
        print(json.dumps(res) if a.json else json.dumps(res, indent=2))
        return 0
    if a.batch < 1 or a.steps < 1:
        p.error(f"--batch and --steps must be >= 1 (got {a.batch}, {a.steps})")
    a.kind = a.kind or "mixed"
    if not a.json:
        print(f"benchmarking batch {a.batch} on {a.kind} tracks on {jax.devices()[0]} ...",
              file=sys.stderr)
    res = bench_lib.run(a.batch, a.kind, a.steps, a.seed, a.n_artifacts, backend=a.backend)
    print(json.dumps(res) if a.json else json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    from biped_switch.cli import run

    run(main)

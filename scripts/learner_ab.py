"""One arm of a learner A/B: `walk` from scratch (random init) under the CPU preset, with the PPO
update's epochs and minibatches set, so that a cheaper update is measured against today's on the
same seed and budget (issue: trainer at the physics limit).

    BIPED_SWITCH_NTHREAD=1 python scripts/learner_ab.py --epochs 4 --minibatches 4 --steps 10000000
    BIPED_SWITCH_NTHREAD=1 python scripts/learner_ab.py --epochs 2 --minibatches 8 --steps 10000000
    python scripts/compare_runs.py --steps 10000000 --out experiments/results/learner_ab \
        e4x4=runs/learner_ab/walk_e4_mb4 e2x8=runs/learner_ab/walk_e2_mb8

Each arm is a resumable run folder, runs/learner_ab/walk_e<E>_mb<M>/ (rerun the same command to
go on).
"""

from __future__ import annotations

import argparse
import functools
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))
from biped_switch import cli  # noqa: E402
from biped_switch.config import default_train_config  # noqa: E402
from biped_switch.learning import trainer  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--epochs", type=cli.positive_int, required=True, help="update epochs per batch")
    p.add_argument("--minibatches", type=cli.positive_int, required=True, help="minibatches per epoch")
    p.add_argument("--steps", type=cli.positive_int, default=10_000_000, help="env steps")
    p.add_argument("--seed", type=cli.nonneg_int, default=0)
    p.add_argument("--out", default="runs/learner_ab")
    a = p.parse_args(argv)
    cfg = default_train_config("cpu")
    n_batch = cfg.ppo.num_envs * cfg.ppo.unroll_length
    if n_batch % a.minibatches:
        p.error(f"--minibatches {a.minibatches} must divide the batch of {n_batch} samples")
    cfg.policy, cfg.init, cfg.seed = "walk", "random", a.seed
    cfg.ppo.num_updates_per_batch, cfg.ppo.num_minibatches = a.epochs, a.minibatches
    cfg.total_timesteps = a.steps
    run_dir = pathlib.Path(a.out) / f"walk_e{a.epochs}_mb{a.minibatches}"
    print(f"walk/random, {a.epochs} epochs x {a.minibatches} minibatches, {a.steps:,} env steps "
          f"-> {run_dir}", flush=True)
    trainer.train(cfg, run_dir, print_fn=functools.partial(print, flush=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The DQN selector baseline (paper Sec. IV-C, Table II "DQN", Table III): a discrete Q-network

The command line of `biped_switch.learning.dqn`: `python -m biped_switch.dqn` or `biped-switch dqn`.
"""

from __future__ import annotations

import argparse
import functools
import pathlib
import jax
from biped_switch import cli
from biped_switch.learning import policies as pol
from biped_switch.learning import runs as runs_lib
from biped_switch.config import default_dqn_config
from biped_switch.learning import dqn_train as dqn_train
from biped_switch.reports import curves


def main(argv=None) -> int:

    p = argparse.ArgumentParser(prog="python -m biped_switch.dqn", description=__doc__.split("\n")[0])
    p.add_argument("--preset", default=None, choices=("gpu", "cpu"),
                   help="default: cpu on a CPU host, else gpu")
    cli.add_init(p)
    p.add_argument("--total-steps", type=cli.positive_int, default=None)
    p.add_argument("--chunk-steps", type=cli.positive_int, default=None)
    p.add_argument("--num-envs", type=cli.positive_int, default=None)
    p.add_argument("--max-chunks", type=cli.positive_int, default=None, help="stop after this many chunks")
    p.add_argument("--seed", type=cli.nonneg_int, default=0)
    p.add_argument("--oracle-bonus", type=cli.nonneg_float, default=None)
    cli.add_runs(p, "where the behaviour policies are (then models/policies/)")
    cli.add_out(p, None, "the DQN's run folder (default RUNS/dqn_<init>)")
    p.add_argument("--stand-in", default=None, choices=pol.POLICY_NAMES,
                   help="use this policy for any that is not trained yet (pipeline checks only)")
    cli.add_backend(p)
    p.add_argument("--commit", action="store_true",
                   help=f"copy the run's latest checkpoint, config, metrics and curves to "
                        f"{runs_lib.BASELINE_DIR}/<run>/ (then git-commit that folder) and exit")
    a = p.parse_args(argv)
    run_dir = pathlib.Path(a.out or pathlib.Path(a.runs) / f"dqn_{a.init}")
    if a.commit:
        out = runs_lib.commit_run(run_dir, runs_lib.BASELINE_DIR / run_dir.name, curves.dqn_curves)
        print(f"committed copy: {out}")
        return 0
    preset = a.preset or ("cpu" if jax.default_backend() == "cpu" else "gpu")
    cfg = default_dqn_config(preset)
    cfg.init, cfg.seed = a.init, a.seed
    for attr, val in (("total_env_steps", a.total_steps), ("chunk_env_steps", a.chunk_steps),
                      ("num_envs", a.num_envs), ("oracle_bonus", a.oracle_bonus)):
        if val is not None:
            cfg[attr] = val
    runs_lib.restore_committed(run_dir, print, runs_lib.BASELINE_DIR)
    say = runs_lib.train_log(run_dir, functools.partial(print, flush=True), runs_lib.BASELINE_DIR)
    say(f"training the DQN selector ({a.init} policies) on {jax.devices()[0].platform}: "
          f"{cfg.total_env_steps:,} env steps, {cfg.num_envs} envs, checkpoints every "
          f"{cfg.chunk_env_steps:,} ({preset} preset) -> {run_dir}")
    dqn_train.train_dqn(cfg, run_dir, a.runs, a.stand_in, a.max_chunks, print_fn=say, backend=a.backend)
    return 0


if __name__ == "__main__":
    from biped_switch.cli import run

    run(main)

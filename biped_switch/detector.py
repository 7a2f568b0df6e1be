"""Train the learned terrain detector and measure it against the oracle and a hand rule.

Data: each stand policy on its own terrain kind (walk on flat tracks), never a mixed track;
validation: held-out seeds of the same, and mixed tracks crossed by the end-to-end policy.
Writes the detector to OUT (default models/detector/stand) and its report (confusion matrices,
detection-distance errors, the cost, a figure along one mixed trial) to RESULTS.

The command line of `biped_switch.switching.detector`: `python -m biped_switch.detector` or
`biped-switch detector`.
"""

from __future__ import annotations

import argparse
import pathlib

from biped_switch import cli
from biped_switch.config import default_detector_config
from biped_switch.learning import runs as runs_lib
from biped_switch.products import detector as detector_products


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.detector",
                                description=__doc__.split("\n")[0])
    cli.add_runs(p, "where the trained policies are (then models/policies/)")
    cli.add_backend(p)
    p.add_argument("--e2e", default="mixed_stand_more",
                   help="the policy that crosses the mixed validation tracks (a run name)")
    p.add_argument("--envs", type=cli.positive_int, default=None, help="episodes per kind (default: config)")
    cli.add_out(p, "models/detector/stand", "the detector's parameters and meta.json")
    p.add_argument("--results", default="experiments/results/detector", help="its report's folder")
    p.add_argument("--data", default="runs/detector/data.npz",
                   help="the collected heightmap profiles and labels (reused when made with the "
                        "same settings; not committed)")
    a = p.parse_args(argv)
    cfg = default_detector_config()
    n_envs = a.envs or cfg.n_envs
    if n_envs < 1:
        p.error(f"--envs must be >= 1 (got {n_envs})")
    e2e = runs_lib.resolve_checkpoint(a.e2e, pathlib.Path(a.runs))
    return detector_products.train_and_report(a, cfg, n_envs, e2e)


if __name__ == "__main__":
    from biped_switch.cli import run

    run(main)

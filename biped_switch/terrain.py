"""Box-terrain tracks of the paper: flat run-ups and artifacts (stairs, gaps, jumps) along +x.

The command line of `biped_switch.simulation.terrain`: `python -m biped_switch.terrain` or `biped-switch terrain`.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Sequence
from biped_switch import cli
from biped_switch.names import TERRAIN_KINDS as KINDS
from biped_switch.simulation import terrain as terrain_lib


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.terrain", description=__doc__.split("\n")[0])
    p.add_argument("--kind", default="mixed", choices=KINDS, help="track kind")
    p.add_argument("--seed", type=cli.nonneg_int, default=0)
    p.add_argument("--difficulty", type=float, default=1.0)
    p.add_argument("--json", action="store_true", help="print the track as JSON")
    p.add_argument("--png", help="draw the track (side view) to this file")
    a = p.parse_args(argv)
    try:
        track = terrain_lib.generate_track(a.seed, a.kind, a.difficulty)
    except ValueError as e:
        p.error(str(e))
    if a.json or not a.png:
        json.dump(track.to_json(), sys.stdout)
        print()
    if a.png:
        import matplotlib

        matplotlib.use("Agg")
        ax = terrain_lib.plot_track(track)
        ax.figure.tight_layout()
        ax.figure.savefig(a.png, dpi=120)
        print(f"wrote {a.png}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    from biped_switch.cli import run

    run(main)

"""`biped-switch <command> [args]`: one entry point for every command line of the package.

Each command is also `python -m biped_switch.<command>`; both run the same `main(argv)`.
"""

from __future__ import annotations

import importlib
import sys

COMMANDS = {
    "train": "train a behaviour policy (PPO, guided curriculum)",
    "sweep": "switch-point sweeps: estimator data and lookup tables",
    "estimator": "train the switch estimators from the sweeps",
    "dqn": "train the DQN selector baseline",
    "evaluate": "Tables I-III, failures and switches",
    "demo": "a short end-to-end check of the committed models",
    "render": "a GIF of a rollout",
    "bench": "speed benchmarks (JSON)",
    "terrain": "lay out and plot a track",
}


def usage() -> str:
    width = max(map(len, COMMANDS))
    rows = "\n".join(f"  {c:<{width}}  {h}" for c, h in COMMANDS.items())
    return f"usage: biped-switch <command> [args]\n\ncommands:\n{rows}\n"


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


if __name__ == "__main__":
    sys.exit(main())

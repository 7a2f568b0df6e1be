"""Side-by-side curves of training runs (their metrics.csv): milestone reward, guide level, speed.

    python scripts/compare_runs.py --steps 3000000 --out experiments/results/action_space \
        torque=runs/cmp/walk_stand_torque_cmp pd_gait=runs/walk_stand ...

Writes compare.png and compare.md (each run's figures at the budget `--steps`).
"""

from __future__ import annotations

import argparse
import csv
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))
from biped_switch.learning.runs import curve_series  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("runs", nargs="+", help="label=run_dir")
    p.add_argument("--steps", type=float, required=True, help="the budget compared [env steps]")
    p.add_argument("--out", required=True)
    a = p.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 3, figsize=(15, 3.6))
    lines = [f"Budget: {a.steps:,.0f} env steps per run.", "",
             "| run | guide scale reached | push scale reached | last milestone reward/step | "
             "last eval distance [m] (5 s) | last eval fell | train steps/s |",
             "|---|---|---|---|---|---|---|"]
    for spec in a.runs:
        label, run = spec.split("=", 1)
        rows = list(csv.DictReader((pathlib.Path(run) / "metrics.csv").open()))

        def s(key):
            xy = curve_series(rows, key)
            return xy[xy[:, 0] <= a.steps] if len(xy) else xy

        ev, guide, push = s("eval/reward_per_step"), s("curriculum/guide_scale"), s("curriculum/push_scale")
        dist, fell, sps = s("eval/distance_m"), s("eval/fell"), s("train/steps_per_s")
        axes[0].plot(ev[:, 0], ev[:, 1], "o-", label=label)
        line = axes[1].step(guide[:, 0], guide[:, 1], where="post", label=f"{label}: guide")[0]
        axes[1].step(push[:, 0], push[:, 1], ":", where="post", color=line.get_color(),
                     label=f"{label}: push")
        axes[2].plot(dist[:, 0], dist[:, 1], "o-", label=label)
        lines.append(f"| {label} | {guide[-1, 1]:.1f} | {push[-1, 1]:.1f} | {ev[-1, 1]:.2f} | {dist[-1, 1]:.2f} | "
                     f"{fell[-1, 1]:.2f} | {np.median(sps[:, 1]):,.0f} |")
    for ax, title in zip(axes, ("milestone rollout: reward per step", "curriculum after the check",
                                "milestone rollout: distance in 5 s [m]")):
        ax.set_title(title)
        ax.set_xlabel("environment steps")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "compare.png", dpi=110)
    (out / "compare.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

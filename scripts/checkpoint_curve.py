"""Success of one Table II method against env steps, from `evaluate multi` runs on snapshots of
one training run, and whether it is still rising.

    python scripts/checkpoint_curve.py --trials 500 --window-from 390e6 \
        --out experiments/results/end_to_end_curve \
        303218688=experiments/results/table2 500006912=experiments/results/end_to_end_more \
        experiments/results/end_to_end_curve/s*

Each point is `STEP=DIR`, or a folder named `s<STEP>`, holding `table2_trials.npz`. Only the
first `--trials` trials of each are used, so a 2,500-trial run and a 500-trial run are compared
on the same tracks (trial i is track seed 30,000 + i in both). The snapshots themselves come
from `scripts/watch_checkpoints.sh`.

Why a trend test across checkpoints and not only the CIs: successive checkpoints of one PPO run
differ by more than the trials' binomial noise, so a single checkpoint can look better or worse
than the run is. The slope's interval comes from the scatter of the points about the line, which
holds both kinds of noise.

Writes curve.png, curve.md and curve.json under `--out`.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import re
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))
from biped_switch.stats import wilson_ci  # noqa: E402


def parse_point(spec: str) -> tuple[int, pathlib.Path]:
    if "=" in spec:
        step, path = spec.split("=", 1)
        return int(float(step)), pathlib.Path(path)
    path = pathlib.Path(spec)
    m = re.fullmatch(r"s(\d+)", path.name)
    if m is None:
        raise SystemExit(f"{spec!r}: give STEP=DIR, or a folder named s<STEP>")
    return int(m.group(1)), path


def load_point(step: int, path: pathlib.Path, method: str, trials: int) -> dict:
    npz = path / "table2_trials.npz"
    if not npz.is_file():
        raise SystemExit(f"{npz}: missing (run `evaluate multi --methods {method}` with --out {path})")
    z = np.load(npz)
    key = f"{method}/success"
    if key not in z.files:
        raise SystemExit(f"{npz}: no {key!r}; it holds {sorted(z.files)}")
    s = z[key].astype(float)
    if len(s) < trials:
        raise SystemExit(f"{npz}: {len(s)} trials, fewer than --trials {trials}")
    s, prog = s[:trials], z[f"{method}/progress_frac"][:trials].astype(float)
    lo, hi = wilson_ci(float(s.sum()), trials)
    return {"step": step, "dir": str(path), "trials": trials, "success_pct": 100 * s.mean(),
            "success_ci": [100 * lo, 100 * hi], "distance_pct": 100 * prog.mean(),
            "success": s}


def trend(steps: np.ndarray, y: np.ndarray) -> dict:
    """OLS slope of y [%] per 10M env steps, with its 95% t interval from the residuals."""
    from scipy import stats as sps

    x = (steps - steps.mean()) / 1e7
    n = len(x)
    slope = float((x * (y - y.mean())).sum() / (x * x).sum())
    resid = y - y.mean() - slope * x
    se = math.sqrt(float((resid ** 2).sum()) / (n - 2) / float((x * x).sum()))
    t = float(sps.t.ppf(0.975, n - 2))
    return {"n": n, "slope_pct_per_10M": slope, "slope_ci": [slope - t * se, slope + t * se],
            "resid_std_pct": float(resid.std(ddof=2)), "mean_pct": float(y.mean())}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("points", nargs="+", help="STEP=DIR or DIR named s<STEP>")
    p.add_argument("--method", default="end_to_end")
    p.add_argument("--trials", type=int, default=500, help="first trials of each point")
    p.add_argument("--window-from", type=float, default=0.0,
                   help="the trend test uses points at or after this env step")
    p.add_argument("--tracks", default="Table II's",
                   help="whose tracks the points ran on, for the titles (e.g. \"the tuning\")")
    p.add_argument("--out", required=True)
    a = p.parse_args(argv)
    if a.trials < 1:
        p.error(f"--trials must be >= 1 (got {a.trials})")
    pts = sorted((load_point(*parse_point(s), a.method, a.trials) for s in a.points),
                 key=lambda r: r["step"])
    steps = np.array([r["step"] for r in pts], float)
    y = np.array([r["success_pct"] for r in pts])
    win = steps >= a.window_from
    if win.sum() < 3:
        p.error(f"--window-from {a.window_from:,.0f} leaves {int(win.sum())} points; need 3")
    tr = trend(steps[win], y[win])
    binom_std = float(np.sqrt(np.mean(y[win] / 100 * (1 - y[win] / 100)) / a.trials) * 100)
    half = int(win.sum()) // 2
    w = [r for r, k in zip(pts, win) if k]
    first, second = w[:half], w[half:]
    halves = {"first": [first[0]["step"], first[-1]["step"]],
              "second": [second[0]["step"], second[-1]["step"]],
              "first_mean_pct": float(np.mean([r["success_pct"] for r in first])),
              "second_mean_pct": float(np.mean([r["success_pct"] for r in second]))}
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {"method": a.method, "trials": a.trials, "window_from": a.window_from,
           "points": [{k: v for k, v in r.items() if k != "success"} for r in pts],
           "trend": tr, "binomial_std_pct": binom_std, "halves": halves}
    (out / "curve.json").write_text(json.dumps(doc, indent=2) + "\n")
    lines = [f"# {a.method}: success on the first {a.trials} trials of {a.tracks} tracks against "
             f"env steps", "",
             "| env steps | success % (95% CI) | distance % | from |", "|---|---|---|---|"]
    for r in pts:
        lo, hi = r["success_ci"]
        lines.append(f"| {r['step']:,} | {r['success_pct']:.1f} ({lo:.1f}-{hi:.1f}) | "
                     f"{r['distance_pct']:.1f} | `{r['dir']}` |")
    lo, hi = tr["slope_ci"]
    lines += ["", f"Trend over the {tr['n']} points from {a.window_from:,.0f} env steps: "
              f"{tr['slope_pct_per_10M']:+.2f} points of success per 10M env steps "
              f"(95% CI {lo:+.2f} to {hi:+.2f}); mean {tr['mean_pct']:.1f}%. The points scatter "
              f"{tr['resid_std_pct']:.1f} points about the line, against {binom_std:.1f} from "
              f"the trials alone.",
              f"Mean of the window's first half ({halves['first'][0]:,}-{halves['first'][1]:,}): "
              f"{halves['first_mean_pct']:.1f}%; second half ({halves['second'][0]:,}-"
              f"{halves['second'][1]:,}): {halves['second_mean_pct']:.1f}%."]
    (out / "curve.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.6))
    ci = np.array([r["success_ci"] for r in pts])
    ax.errorbar(steps / 1e6, y, yerr=[y - ci[:, 0], ci[:, 1] - y], fmt="o", capsize=3,
                label=f"first {a.trials} trials of {a.tracks} tracks (95% Wilson CI)")
    xs = np.array([steps[win].min(), steps[win].max()])
    ax.plot(xs / 1e6, tr["mean_pct"] + tr["slope_pct_per_10M"] * (xs - steps[win].mean()) / 1e7,
            "k--", lw=1, label=f"trend {tr['slope_pct_per_10M']:+.2f} pts / 10M steps")
    ax.set_xlabel("env steps [M]")
    ax.set_ylabel("success [%]")
    ax.set_title(f"{a.method}: success against training")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(out / "curve.png", dpi=110)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

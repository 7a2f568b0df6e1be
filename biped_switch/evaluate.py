"""Evaluations and the paper's tables.

    python -m biped_switch.evaluate single [--trials 500] [--runs runs] [--policies walk jumps ...]

`single` (Table I): each policy on tracks of its own terrain kind (7 artifacts, 500 trials by
default), for both init modes, without switching. Reports % of the total track distance covered
(distance along x from the start to the finish line, capped at 100%) and % success (reached the
finish line without falling), each with a 95% confidence interval (normal interval of the mean for
distance, Wilson score interval for success), prints a Markdown table and saves it with a CSV and a
JSON of the settings under experiments/results/table1/.
Policies load from `<runs>/<policy>_<init>/checkpoints/<latest>` (or models/policies/).
"""

from __future__ import annotations

import argparse
import csv
import functools
import json
import math
import pathlib
import sys
import time

import jax
import numpy as np

from biped_switch import env as env_lib
from biped_switch import train as train_lib
from biped_switch.rollout import rollout

PAPER_TABLE1 = {  # % total distance, % success: stand init / random init (Tidd et al., Table I)
    "jumps": (93.1, 87.8, 86.2, 77.5),
    "gaps": (76.0, 56.3, 87.4, 75.5),
    "stairs": (71.4, 52.1, 78.7, 59.0),
}


def wilson_ci(successes: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """95% Wilson score interval of a proportion (fractions in [0, 1])."""
    if n <= 0:
        return (math.nan, math.nan)
    p = successes / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def mean_ci(x: np.ndarray, z: float = 1.96) -> tuple[float, float, float]:
    """Mean and its 95% normal interval."""
    x = np.asarray(x, float)
    m = float(x.mean())
    half = z * float(x.std(ddof=1)) / math.sqrt(len(x)) if len(x) > 1 else math.nan
    return m, m - half, m + half


def episode_table(result: dict) -> dict:
    """% distance and % success (with CIs) from per-episode rollout results."""
    dist = 100.0 * np.asarray(result["progress_frac"])
    succ = np.asarray(result["success"]) > 0.5
    n = len(succ)
    d, d_lo, d_hi = mean_ci(dist)
    s_lo, s_hi = wilson_ci(float(succ.sum()), n)
    fail = np.asarray(result["fail_kind"])
    return {"n": n, "distance_pct": d, "distance_ci": [d_lo, d_hi],
            "success_pct": 100.0 * succ.mean(), "success_ci": [100 * s_lo, 100 * s_hi],
            "fell_pct": 100.0 * float((np.asarray(result["fell"]) > 0.5).mean()),
            "fail_on": {k: 100.0 * float((fail == i).mean())
                        for i, k in enumerate(("jumps", "gaps", "stairs"))}}


def find_policy(policy: str, init: str, runs: pathlib.Path) -> pathlib.Path | None:
    for base in (runs, pathlib.Path("models/policies")):
        ckpt = train_lib.latest_checkpoint(base / f"{policy}_{init}")
        if ckpt is not None:
            return ckpt
    return None


def evaluate_single(policy: str, init: str, ckpt: pathlib.Path, trials: int, seed: int,
                    horizon_s: float, batch: int) -> dict:
    """Table I row: `trials` episodes of `policy` on its own terrain kind, track i for trial i."""
    # difficulty 1, no guides, no pushes (the config's defaults)
    env = env_lib.make_env(policy, init, n_tracks=trials, seed=EVAL_TRACK_SEED)
    act, progress = train_lib.load_policy(ckpt, env)
    run = jax.jit(functools.partial(rollout, env, act, n_envs=batch,
                                    horizon=int(round(horizon_s / env.dt))))
    results = []
    for start in range(0, trials, batch):
        ids = jax.numpy.arange(start, start + batch) % trials
        results.append(jax.device_get(run(jax.random.PRNGKey(seed + start), track_ids=ids)))
    merged = {k: np.concatenate([r[k] for r in results])[:trials] for k in results[0]}
    out = episode_table(merged)
    out.update(policy=policy, init=init, checkpoint=str(ckpt), train_step=progress["step"],
               curriculum=progress["curriculum"])
    return out


def table1_markdown(rows: list[dict]) -> str:
    lines = ["| policy | init | trials | % total dist. (95% CI) | % success (95% CI) | paper dist. | "
             "paper success | trained steps | curriculum |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        paper = PAPER_TABLE1.get(r["policy"])
        pd, ps = ((paper[0], paper[1]) if r["init"] == "stand" else (paper[2], paper[3])) if paper \
            else ("-", "-")
        c = r["curriculum"]
        lines.append(
            f"| {r['policy']} | {r['init']} | {r['n']} | {r['distance_pct']:.1f} "
            f"({r['distance_ci'][0]:.1f}-{r['distance_ci'][1]:.1f}) | {r['success_pct']:.1f} "
            f"({r['success_ci'][0]:.1f}-{r['success_ci'][1]:.1f}) | {pd} | {ps} | "
            f"{r['train_step']:,} | {c['stage_name']} d={c['difficulty']:.1f} g={c['guide_scale']:.1f} |")
    return "\n".join(lines)


EVAL_TRACK_SEED = 10_000  # evaluation tracks never overlap training tracks (seeds 0..n_tracks-1)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.evaluate", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("single", help="Table I: each policy on its own terrain kind")
    s.add_argument("--policies", nargs="+", default=["jumps", "gaps", "stairs"],
                   choices=train_lib.POLICIES)
    s.add_argument("--inits", nargs="+", default=list(env_lib.INITS), choices=env_lib.INITS)
    s.add_argument("--trials", type=int, default=500)
    s.add_argument("--batch", type=int, default=100, help="episodes per jitted rollout")
    s.add_argument("--horizon-s", type=float, default=60.0, help="episode time limit [s]")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--runs", default="runs")
    s.add_argument("--out", default="experiments/results/table1")
    a = p.parse_args(argv)
    if a.trials < 1 or a.batch < 1:
        p.error(f"--trials and --batch must be >= 1 (got {a.trials}, {a.batch})")
    rows, missing = [], []
    for init in a.inits:
        for policy in a.policies:
            ckpt = find_policy(policy, init, pathlib.Path(a.runs))
            if ckpt is None:
                missing.append(f"{policy}_{init}")
                continue
            t0 = time.perf_counter()
            print(f"evaluating {policy}/{init} ({ckpt}) on {a.trials} {policy} tracks ...", flush=True)
            row = evaluate_single(policy, init, ckpt, a.trials, a.seed, a.horizon_s,
                                  min(a.batch, a.trials))
            row["wall_s"] = time.perf_counter() - t0
            rows.append(row)
    if missing:
        print(f"no trained policy found for: {', '.join(missing)} (looked in {a.runs}/ and "
              f"models/policies/); train with `make train-all`", file=sys.stderr)
    if not rows:
        return 1
    md = table1_markdown(rows)
    print(md)
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table1.md").write_text(md + "\n")
    with (out / "table1.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["policy", "init", "trials", "distance_pct", "distance_lo", "distance_hi",
                    "success_pct", "success_lo", "success_hi", "checkpoint", "train_step"])
        for r in rows:
            w.writerow([r["policy"], r["init"], r["n"], r["distance_pct"], *r["distance_ci"],
                        r["success_pct"], *r["success_ci"], r["checkpoint"], r["train_step"]])
    (out / "table1.json").write_text(json.dumps({"settings": vars(a), "rows": rows}, indent=2,
                                                default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Evaluations and the paper's tables.

    python -m biped_switch.evaluate single [--trials 500] [--runs runs] [--policies walk jumps ...]
                                           [--track-seed 10000] [--backend auto] [--horizon-s S]

`single` (Table I): each policy on tracks of its own terrain kind (7 artifacts, 500 trials by
default; trial i on the track of seed `--track-seed` + i, by default tracks training never saw),
for both init modes, without switching, in an env made with the env overrides (action mode, phase
clock) the policy was trained with. Reports % of the total track distance covered (distance along
x from the start to the finish line, capped at 100%) and % success (reached the finish line
without falling), each with a 95% confidence interval (normal interval of the mean for distance,
Wilson score interval for success), and the mean forward speed (distance / time alive after the
standing pause); prints a Markdown table and saves it with a CSV and a JSON of the settings
(backend, track seed, horizon) under experiments/results/table1/. The time limit, unless
`--horizon-s` is given, lets a walker at 0.6 m/s reach the farthest finish line of the tracks
evaluated, with a 20% margin (`single_horizon_s`); each row says which limit it ran with.
The rows join those already in table1.json for other policies and inits (the random-init suite
finishes after the stand suite), unless `--fresh`; a table of other trials is refused.
Policies load from `<runs>/<policy>_<init>/checkpoints/<latest>` (or models/policies/).

    python -m biped_switch.evaluate multi [--trials 2500] [--methods random detection ...]

`multi` (Table II): every method on the same `mixed` tracks (7 artifacts, no kind twice in a
row, >= 0.9 m of flat before each; trial i uses track i and rng seed + batch start), each trial
starting with the walk policy; the methods differ only in when they switch (switching.py). The
stand-init suite is used for every method but `estimator_no_overlap` and `learned_no_overlap`,
which use the random-init policies (with their estimators or learned rule) and start from random
joints with no pause, as they were trained. `learned` is our learned "when" rule
(switching/when.py, `python -m biped_switch.when`).
Every env runs on the physics `--backend`, with the env overrides its policy suite was trained with.
Reports % distance, % success and % of trials failing on gaps / jumps / stairs, with 95% CIs;
saves Markdown, CSV and JSON under experiments/results/table2/, plus the paper's Fig. 5 (one
trial of the estimator method over time) as fig5_trial<i>.png.

    python -m biped_switch.evaluate retrain-cost [--runs runs] [--results experiments/results]

`retrain-cost` (Table III): hours to add a new terrain, from the recorded training logs.

This module is the command line only: it parses the flags and writes the files. The work is done by
one module per product: table1.py (`single`), table2.py (`multi`), fig5.py (Fig. 5 of a `multi`
run), table3.py (`retrain-cost`), with stats.py's confidence intervals and paper.py's numbers.
"""

from __future__ import annotations

import argparse
import csv
import json
import pathlib
import sys
import time

import jax
import numpy as np

from biped_switch import cli, paths
from biped_switch.simulation import env as env_lib
from biped_switch.config import (EVAL_TRACK_SEED, MULTI_TRACK_SEED, TUNE_TRACK_SEED,
                                 default_when_config)
from biped_switch.reports.fig5 import plot_trial
from biped_switch.evaluation.trace import trace_trial
from biped_switch.paper import TABLE2_FAIL_ORDER
from biped_switch.learning.policies import POLICY_NAMES
from biped_switch.learning.runs import BASELINE_DIR, find_policy
from biped_switch.evaluation.single import (HORIZON_MARGIN, HORIZON_SPEED_MPS, evaluate_single, merge_rows as merge_table1)
from biped_switch.reports.table1 import table1_markdown
from biped_switch.reports.fig4b import plot_switch_distances
from biped_switch.evaluation.multi import (BASELINES, LEARNED_METHODS, MULTI_METHODS,
                                           RANDOM_INIT_METHODS, SETUP_METHODS, available_methods,
                                           setup_key,
                                           evaluate_multi, merge_rows, mixed_track, trial_track)
from biped_switch.reports.table2 import (claims_markdown, failures_by_context, failures_markdown,
                                         paper_claims, policy_on_falls, policy_on_falls_markdown, suite_ceiling, ceiling_markdown,
                                         switch_outcomes, switch_summary, switches_markdown,
                                         table2_markdown)
from biped_switch.reports.table3 import retrain_cost, table3_markdown
from biped_switch.simulation.terrain import ARTIFACT_KINDS



def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.evaluate", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("single", help="Table I: each policy on its own terrain kind")
    s.add_argument("--policies", nargs="+", default=list(ARTIFACT_KINDS),
                   choices=POLICY_NAMES)
    s.add_argument("--inits", nargs="+", default=list(env_lib.INITS), choices=env_lib.INITS)
    s.add_argument("--trials", type=int, default=500)
    s.add_argument("--batch", type=int, default=100, help="episodes per jitted rollout")
    s.add_argument("--horizon-s", type=float, default=None,
                   help=f"episode time limit [s] (default: per policy, the standing pause plus "
                        f"{HORIZON_MARGIN:g} x the time to its farthest finish line at "
                        f"{HORIZON_SPEED_MPS:g} m/s)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--track-seed", type=int, default=EVAL_TRACK_SEED,
                   help=f"trial i runs on the track of seed TRACK_SEED + i (default "
                        f"{EVAL_TRACK_SEED:,}: tracks training never saw)")
    cli.add_backend(s)
    cli.add_runs(s)
    cli.add_out(s, "experiments/results/table1", "table1.md, .csv and .json")
    s.add_argument("--fresh", action="store_true",
                   help="replace OUT/table1.json (by default this run's rows join its rows of the "
                        "other policies and inits, when made with the same trials, batch, seed, "
                        "horizon and track seed)")
    m = sub.add_parser("multi", help="Table II: switching methods on multi-artifact tracks")
    m.add_argument("--methods", nargs="+", default=list(MULTI_METHODS), choices=MULTI_METHODS)
    m.add_argument("--trials", type=int, default=2500)
    m.add_argument("--batch", type=int, default=250, help="episodes per jitted rollout")
    m.add_argument("--horizon-s", type=float, default=60.0, help="episode time limit [s]")
    m.add_argument("--n-artifacts", type=int, default=7, help="artifacts per track (paper: 7)")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--track-seed", type=int, default=MULTI_TRACK_SEED,
                   help=f"trial i runs on the mixed track of seed TRACK_SEED + i (default "
                        f"{MULTI_TRACK_SEED:,}: Table II's, for reporting only; tune on others, "
                        f"e.g. {TUNE_TRACK_SEED:,})")
    m.add_argument("--detector", default="oracle", choices=("oracle", "learned"),
                   help="what names the next artifact: the paper's oracle, or the learned "
                        "detector on the heightmap (python -m biped_switch.detector)")
    m.add_argument("--detector-dir", default="models/detector/stand",
                   help="the learned detector's folder (with --detector learned)")
    cli.add_runs(m)
    m.add_argument("--estimators", default="models/estimators")
    m.add_argument("--when-dir", default=paths.WHEN,
                   help="the learned when rule's models (python -m biped_switch.when)")
    m.add_argument("--when-margin", type=float, default=None,
                   help="learned rule: switch once P(now) >= best later P + this (default: "
                        "config's, chosen on tuning tracks)")
    m.add_argument("--when-persist", type=int, default=None,
                   help="learned rule: ... on this many control steps in a row (default: config's)")
    m.add_argument("--when-later", default=None, choices=("model", "table"),
                   help="learned rule: the later moments' P from the model or the prior table "
                        "(default: config's)")
    m.add_argument("--lookup", default="experiments/results/lookup")
    m.add_argument("--dqn", default=None,
                   help=f"DQN run directory (default: RUNS/dqn_stand, then {BASELINE_DIR}/dqn_stand)")
    m.add_argument("--stand-in", default=None, choices=POLICY_NAMES,
                   help="use this policy for any that is not trained yet (pipeline checks only)")
    m.add_argument("--guide-scale", type=float, default=0.0,
                   help="scripted guide forces on (pipeline checks with untrained policies only)")
    m.add_argument("--fig5-trial", type=int, default=0, help="trial drawn as Fig. 5 for each estimator method run: fig5_trial<i>[_context] (-1: none)")
    cli.add_backend(m)
    cli.add_out(m, "experiments/results/table2", "table2.md, .csv, .json, claims.md, the per-trial outcomes and Fig. 5")
    m.add_argument("--fresh", action="store_true",
                   help="replace OUT/table2.json (by default this run's rows join its rows of the "
                        "other methods, when made with the same trials, batch, seed and horizon)")
    r = sub.add_parser("retrain-cost", help="Table III: hours to add a new terrain, from logs")
    cli.add_runs(r)
    r.add_argument("--results", default="experiments/results")
    cli.add_init(r)
    cli.add_out(r, "experiments/results/table3", "table3.md and .json")
    f = sub.add_parser("failures", help="Table II's falls by artifact and the artifact before it")
    cli.add_out(f, "experiments/results/table2", "failures_by_context.md and .json, and claims.md "
                "afresh, beside the table2.json and table2_trials.npz of `evaluate multi` it reads")
    w = sub.add_parser("switches", help="where each rule switched, and what it cost "
                                        "(switch_distances.md/.json/.png)")
    w.add_argument("--methods", nargs="+", default=["com_over_feet", "lookup", "lookup_context",
                                                    "estimator", "estimator_context_persist",
                                                    "learned"],
                   choices=[m for m in MULTI_METHODS if m not in BASELINES])
    w.add_argument("--trials", type=int, default=500, help="Table II's first trials (tracks)")
    for flag, default in (("--batch", 250), ("--seed", 0)):
        w.add_argument(flag, type=int, default=default)
    cli.add_runs(w)
    for flag, default in (("--estimators", "models/estimators"),
                          ("--lookup", "experiments/results/lookup")):
        w.add_argument(flag, default=default)
    cli.add_out(w, "experiments/results/table2", "switch_distances.md, .json and .png")
    w.add_argument("--horizon-s", type=float, default=60.0, help="episode time limit [s]")
    w.add_argument("--n-artifacts", type=int, default=7, help="artifacts per track (paper: 7)")
    cli.add_backend(w)
    a = p.parse_args(argv)
    if a.cmd == "switches":
        return _main_switches(a, p)
    if a.cmd == "failures":
        return _main_failures(pathlib.Path(a.out))
    if a.cmd == "multi":
        return _main_multi(a, p)
    if a.cmd == "retrain-cost":
        doc = retrain_cost(pathlib.Path(a.runs), pathlib.Path(a.results), a.init)
        md = table3_markdown(doc)
        print(md)
        out = pathlib.Path(a.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "table3.json").write_text(json.dumps(doc, indent=2))
        (out / "table3.md").write_text(md + "\n")
        return 0
    if a.trials < 1 or a.batch < 1:
        p.error(f"--trials and --batch must be >= 1 (got {a.trials}, {a.batch})")
    if a.horizon_s is not None and a.horizon_s <= 0:
        p.error(f"--horizon-s must be > 0 (got {a.horizon_s})")
    json_path = pathlib.Path(a.out) / "table1.json"
    settings = {**vars(a), "batch": min(a.batch, a.trials)}
    try:  # before the rollouts, not after
        merge_table1(_read_table(json_path, a.fresh), [], settings)
    except ValueError as e:
        p.error(f"{json_path}: {e}")
    rows, missing = [], []
    for init in a.inits:
        for policy in a.policies:
            ckpt = find_policy(policy, init, pathlib.Path(a.runs))
            if ckpt is None:
                missing.append(f"{policy}_{init}")
                continue
            t0 = time.perf_counter()
            print(f"evaluating {policy}/{init} ({ckpt}) on {a.trials} {policy} tracks of seeds "
                  f"{a.track_seed:,}.. ({a.backend} backend) ...", flush=True)
            row = evaluate_single(policy, init, ckpt, a.trials, a.seed, a.horizon_s,
                                  min(a.batch, a.trials), a.backend, a.track_seed)
            row["wall_s"] = time.perf_counter() - t0
            print(f"  {policy}/{init}: success {row['success_pct']:.1f}%, distance "
                  f"{row['distance_pct']:.1f}%, mean speed {row['speed_mps']:.2f} m/s, timed out "
                  f"{row['timed_out_pct']:.1f}%; horizon {row['horizon_s']:g} s "
                  f"({row['horizon_from']}), {row['backend']} backend ({row['wall_s']:.0f} s)",
                  flush=True)
            rows.append(row)
    if missing:
        print(f"no trained policy found for: {', '.join(missing)} (looked in {a.runs}/ and "
              f"models/policies/); train with `make train-all`", file=sys.stderr)
    if not rows:
        return 1
    lock = _lock(pathlib.Path(a.out), "table1")  # another `evaluate single` may have added rows
    old = _read_table(json_path, a.fresh)
    done = {(r["policy"], r["init"]) for r in rows}
    rows = merge_table1(old, rows, settings)
    if old:
        kept = [f"{r['policy']}_{r['init']}" for r in rows if (r["policy"], r["init"]) not in done]
        print(f"kept from {json_path}: {', '.join(kept) or 'no rows'}", flush=True)
    settings["policies"] = list(dict.fromkeys(r["policy"] for r in rows))  # the table's, not this run's
    settings["inits"] = list(dict.fromkeys(r["init"] for r in rows))
    out = _write_table(a.out, "table1", table1_markdown(rows),
                       ["policy", "init", "trials", "checkpoint", "train_step", "train_h",
                        "curriculum_end", "push_held", "speed_mps", "speed_lo", "speed_hi",
                        "horizon_s", "track_seed", "backend"],
                       [[r["policy"], r["init"], r["n"], r["checkpoint"], r["train_step"],
                         r["train_h"], r["curriculum_end"], r["push_held"], r["speed_mps"],
                         *r["speed_ci"], r["horizon_s"], r["track_seed"], r["backend"]]
                        for r in rows],
                       rows)
    (out / "table1.json").write_text(json.dumps(
        {"settings": settings, "rows": rows, "track_seed": a.track_seed,
         "backend": sorted({r["backend"] for r in rows}),
         "horizon_s": {f"{r['policy']}_{r['init']}": r["horizon_s"] for r in rows},
         "speed_note": "speed_mps: distance / time alive after the standing pause, mean over "
                       "episodes; speed_alive_mps: the same with the pause"},
        indent=2, default=str))
    lock.close()
    return 0


def _read_table(path: pathlib.Path, fresh: bool) -> dict | None:
    """A saved table's JSON, or None when there is none or `--fresh` replaces it."""
    return None if fresh or not path.exists() else json.loads(path.read_text())


def _write_table(out_dir, name: str, md: str, head: list, cols: list, rows: list) -> pathlib.Path:
    """Prints a table's Markdown and saves it with a CSV: `head`/`cols` per row, followed by the
    distance and success columns with their 95% intervals that every episode table has."""
    print(md)
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.md").write_text(md + "\n")
    with (out / f"{name}.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(head + ["distance_pct", "distance_lo", "distance_hi", "success_pct",
                           "success_lo", "success_hi"])
        for c, r in zip(cols, rows):
            w.writerow(c + [r["distance_pct"], *r["distance_ci"], r["success_pct"], *r["success_ci"]])
    return out


def _lock(out: pathlib.Path, name: str = "table2"):
    """An exclusive lock on OUT/.<name>.lock (released when the returned file is closed), so that
    two evaluations of other rows into one table read and write it in turn."""
    import fcntl

    out.mkdir(parents=True, exist_ok=True)
    f = (out / f".{name}.lock").open("w")
    fcntl.flock(f, fcntl.LOCK_EX)
    return f


def save_trials(path: pathlib.Path, per_trial: dict, keep: set) -> None:
    """Per-trial outcomes as `<method>/<field>` arrays, joined with those already in `path` for
    the methods of the table (`keep`) that this run did not redo."""
    arrays = {}
    if path.exists():
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files if k.split("/")[0] in keep - set(per_trial)}
    arrays.update({f"{m}/{k}": v for m, d in per_trial.items() for k, v in d.items()})
    np.savez_compressed(path, **arrays)


def _main_failures(out: pathlib.Path) -> int:
    trials_path = out / "table2_trials.npz"
    if not trials_path.exists():
        print(f"error: {trials_path} missing: run `python -m biped_switch.evaluate multi` first",
              file=sys.stderr)
        return 2
    settings = json.loads((out / "table2.json").read_text())["settings"]
    seed0 = settings.get("track_seed", MULTI_TRACK_SEED)
    tracks = [mixed_track(seed0 + i, settings["n_artifacts"]) for i in range(settings["trials"])]
    by_method, on_falls = {}, {}
    with np.load(trials_path) as z:
        for m in dict.fromkeys(k.split("/")[0] for k in z.files):
            by_method[m] = failures_by_context(tracks, z[f"{m}/progress_frac"], z[f"{m}/fell"],
                                               z[f"{m}/fail_kind"])
            if f"{m}/active_at_start" in z.files:
                on_falls[m] = policy_on_falls(tracks, z[f"{m}/progress_frac"], z[f"{m}/fell"],
                                              z[f"{m}/fail_kind"], z[f"{m}/active_at_start"])
    md = failures_markdown(by_method)
    if on_falls:
        md += "\n\n" + policy_on_falls_markdown(on_falls)
    table1 = out.parent / "table1" / "table1.json"
    if table1.exists():  # what the policies alone allow on these tracks
        rows = [r for r in json.loads((out / "table2.json").read_text())["rows"]
                if r["method"] not in BASELINES]
        ceil = suite_ceiling(json.loads(table1.read_text())["rows"], tracks)
        md += "\n\n" + ceiling_markdown(ceil, rows)
        (out / "ceiling.json").write_text(json.dumps(ceil, indent=1))
    print(md)
    (out / "failures_by_context.md").write_text(md + "\n")
    # the claims on the table as it stands (rows joined from several `evaluate multi` runs)
    claims = claims_markdown(paper_claims(json.loads((out / "table2.json").read_text())["rows"]))
    (out / "claims.md").write_text(claims + "\n")
    (out / "failures_by_context.json").write_text(json.dumps(by_method, indent=1))
    if on_falls:
        (out / "policy_on_falls.json").write_text(json.dumps(on_falls, indent=1))
    return 0


def _main_switches(a, p) -> int:
    """Table II's rollouts (the same first `--trials` tracks and seeds) with every switch logged:
    its distance before the artifact and whether that artifact was lost."""
    if a.trials < 1 or a.batch < 1 or a.n_artifacts < 1 or not a.horizon_s > 0:
        p.error(f"--trials, --batch and --n-artifacts must be >= 1 and --horizon-s > 0 (got "
                f"{a.trials}, {a.batch}, {a.n_artifacts}, {a.horizon_s})")
    methods, skipped = available_methods(a.methods, a.runs, a.estimators, a.lookup)
    for sk in skipped:
        print(f"skipped {sk}", file=sys.stderr)
    if not methods:
        return 1
    t0, per_trial, n_art = time.perf_counter(), {}, a.n_artifacts
    evaluate_multi(methods, a.trials, min(a.batch, a.trials), a.horizon_s, a.seed, a.runs, None,
                   a.estimators, a.lookup, print_fn=lambda *s: print(*s, flush=True),
                   n_artifacts=n_art, backend=a.backend, per_trial=per_trial)
    tracks = [mixed_track(MULTI_TRACK_SEED + i, n_art) for i in range(a.trials)]
    # a rule with a model logs its output at each switch; the others have none to show
    model = {m for m in per_trial if m.startswith("estimator") or m in LEARNED_METHODS}
    by_method = {m: switch_summary(switch_outcomes(
        tracks, d["switch_ahead_m"], d["progress_frac"], d["fell"], d["fail_kind"],
        switch_output=d.get("switch_output") if m in model else None,
        switch_forced=d.get("switch_forced"))) for m, d in per_trial.items()}
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    md = switches_markdown(by_method)
    print(md)
    (out / "switch_distances.md").write_text(md + "\n")
    wall = time.perf_counter() - t0
    (out / "switch_distances.json").write_text(json.dumps(
        {"settings": {"trials": a.trials, "batch": min(a.batch, a.trials), "seed": a.seed,
                      "horizon_s": a.horizon_s, "n_artifacts": n_art, "track_seed": MULTI_TRACK_SEED,
                      "backend": a.backend, "methods": methods},
         "wall_s": wall, "by_method": by_method}, indent=1))
    plot_switch_distances(by_method, out / "switch_distances_gaps.png", "gaps")
    print(f"wrote {out / 'switch_distances.md'}, .json and switch_distances_gaps.png "
          f"({wall:.0f} s)")
    return 0


def _setup_trial(setup, first: int, trials: int) -> int:
    """The first trial from `first` on whose track has an artifact pair (source, target) that one
    of `setup`'s setup policies serves (a Fig. 5 with a setup phase), else `first`."""
    for i in range(first, first + trials):
        codes = trial_track(setup, i % trials).artifact_codes
        for a, b in zip(codes[:-1], codes[1:]):
            if setup.setup.setup_of[int(a) + 1, int(b)] >= 0:
                return i % trials
    return first


def _when_cfg(a):
    """The learned rule's config with this command's overrides."""
    cfg = default_when_config()
    for key, value in (("margin", a.when_margin), ("persist_steps", a.when_persist),
                       ("later_from", a.when_later)):
        if value is not None:
            cfg[key] = value
    return cfg


def _main_multi(a, p) -> int:
    if a.trials < 1 or a.batch < 1 or a.n_artifacts < 1:
        p.error(f"--trials, --batch and --n-artifacts must be >= 1 (got {a.trials}, {a.batch}, "
                f"{a.n_artifacts})")
    if a.when_persist is not None and a.when_persist < 1:
        p.error(f"--when-persist must be >= 1, got {a.when_persist}")
    batch = min(a.batch, a.trials)
    t0 = time.perf_counter()
    json_path = pathlib.Path(a.out) / "table2.json"
    old = _read_table(json_path, a.fresh)
    settings = {**vars(a), "batch": batch}
    if a.detector == "oracle":
        settings.pop("detector_dir")
    try:  # before an hour of rollouts, not after
        merge_rows(old, [], settings)
    except ValueError as e:
        p.error(f"{json_path}: {e}")
    a.methods, skipped = available_methods(a.methods, a.runs, a.estimators, a.lookup, a.dqn,
                                           a.stand_in, a.when_dir)
    for s in skipped:
        print(f"skipped {s}", file=sys.stderr)
    if not a.methods:
        print("evaluate multi: no method has its trained parts", file=sys.stderr)
        return 1
    print(f"Table II: {len(a.methods)} methods x {a.trials} trials of mixed tracks (batch {batch}, "
          f"{jax.local_device_count()} {jax.devices()[0].platform} device(s))", flush=True)
    per_trial = {}
    rows, setups = evaluate_multi(a.methods, a.trials, batch, a.horizon_s, a.seed, a.runs,
                                  a.stand_in, a.estimators, a.lookup,
                                  print_fn=lambda *s: print(*s, flush=True), guide_scale=a.guide_scale,
                                  dqn_dir=a.dqn, n_artifacts=a.n_artifacts, backend=a.backend,
                                  per_trial=per_trial, track_seed=a.track_seed,
                                  detector_dir=a.detector_dir if a.detector == "learned" else None,
                                  when_dir=a.when_dir, when_cfg=_when_cfg(a))
    session_s = time.perf_counter() - t0
    lock = _lock(pathlib.Path(a.out))  # another `evaluate multi` may have added rows meanwhile
    old = _read_table(json_path, a.fresh)
    rows = merge_rows(old, rows, settings)
    have = {r["method"] for r in rows}
    skipped = [sk for sk in skipped if sk.split(":")[0] not in have]
    if old:
        kept = [r["method"] for r in rows if r["method"] not in a.methods]
        print(f"kept from {json_path}: {', '.join(kept) or 'no rows'}", flush=True)
    settings["methods"] = [r["method"] for r in rows]
    out = _write_table(a.out, "table2", table2_markdown(rows),
                       ["method", "init", "trials"]
                       # gap_fail_pct, ..., stair_fail_hi: the singular of each kind
                       + [f"{k[:-1]}_fail_{c}" for k in TABLE2_FAIL_ORDER for c in ("pct", "lo", "hi")]
                       + ["switches_per_trial", "wall_s"],
                       [[r["method"], r["init"], r["n"]]
                        + [v for k in TABLE2_FAIL_ORDER for v in (r["fail_on"][k], *r["fail_ci"][k])]
                        + [r["switches_per_trial"], r["wall_s"]] for r in rows],
                       rows)
    # wall_s: the time to make the whole table, the sum of its rows' (each with its setup and
    # compiles), over the sessions that made them; wall_s_session: this command's rollouts
    wall = float(sum(r["wall_s"] for r in rows))
    (out / "table2.json").write_text(json.dumps(
        {"settings": settings, "rows": rows, "skipped": skipped, "wall_s": wall,
         "wall_s_session": session_s,
         "device": str(jax.devices()[0]), "backend": sorted({r["backend"] for r in rows}),
         "track_seed": a.track_seed}, indent=2, default=str))
    save_trials(out / "table2_trials.npz", per_trial, {r["method"] for r in rows})
    claims_md = claims_markdown(paper_claims(rows))  # the paper's claims on the whole table
    (out / "claims.md").write_text(claims_md + "\n")
    print(claims_md, flush=True)
    lock.close()
    # Fig. 5 of each stand-suite estimator method run now: fig5_trial<i>[<suffix>.png]; of each
    # setup method, the first trial from <i> on whose track has a pair a setup policy serves
    for method in a.methods:
        if a.fig5_trial < 0 or method in RANDOM_INIT_METHODS:
            continue
        key = setup_key(method)
        if method.startswith("estimator") and "stand" in setups:
            suffix, s, trial = method.removeprefix("estimator"), setups["stand"], a.fig5_trial
        elif (method in SETUP_METHODS or method in LEARNED_METHODS) and key in setups:
            s, suffix = setups[key], f"_{method}"
            trial = (_setup_trial(s, a.fig5_trial, a.trials) if method in SETUP_METHODS
                     else a.fig5_trial)
        else:
            continue
        trial %= a.trials
        rec = trace_trial(s, method, trial, a.seed)
        rec["policy_names"] = np.asarray(s.policy_names)
        threshold = None
        if method in LEARNED_METHODS:  # its trace holds the score, against the margin
            rec["output_kind"] = np.asarray("score")
            threshold = float(s.variants[method]["threshold"])
            rec["threshold"] = np.asarray(threshold)
        track = trial_track(s, trial)
        path = out / f"fig5_trial{trial}{suffix}.png"
        plot_trial(rec, track, path, f"{method} switching, trial {trial}", threshold)
        np.savez_compressed(path.with_suffix(".npz"), **rec, track_seed=a.track_seed + trial,
                            n_artifacts=a.n_artifacts)
        print(f"wrote {path}")
    print(json.dumps({"table2_wall_s": round(wall, 1), "session_s": round(session_s, 1),
                      "trials": a.trials, "methods_run": len(a.methods), "rows": len(rows)}))
    return 0


if __name__ == "__main__":
    from biped_switch.cli import run

    run(main)

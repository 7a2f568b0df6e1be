"""The command bodies of `evaluate` (biped_switch/evaluate.py parses the flags): run a table's
rows, join them with the rows already in its folder, and write its Markdown, CSV and JSON.

One function per command: `single` (Table I), `multi` (Table II, with Fig. 5 of the rows that
have one), `failures`, `switches` and `retrain_cost` (Table III). Each takes the command's flags
(an argparse Namespace) and returns its exit status. `multi --lineup` other than the paper's
(Table II-4) writes a failure column per target of its line-up and no paper column; the paper's
claims, Fig. 5 and `failures` read the paper's kinds only, so they are left out for it.
"""

from __future__ import annotations

import csv
import json
import pathlib
import sys
import time

import jax
import numpy as np

from biped_switch import paths
from biped_switch.config import LINEUP_TRACK_SEEDS, MULTI_TRACK_SEED, default_when_config
from biped_switch.evaluation.multi import (BASELINES, MultiConfig, evaluate_multi, lineup_meta,
                                           merge_rows, mixed_track)
from biped_switch.evaluation.parts import available_methods, check_detector, lineup_gap, new_names
from biped_switch.evaluation.single import evaluate_single, merge_rows as merge_table1
from biped_switch.products.fig5 import fig5_traces
from biped_switch.learning.runs import find_policy
from biped_switch.kinds import KIND
from biped_switch.lineups import LINEUP, PAPER_LINEUP
from biped_switch.methods import method as method_record
from biped_switch.names import MULTI_METHODS
from biped_switch.paper import TABLE2_FAIL_ORDER
from biped_switch.reports.fig4b import plot_switch_distances
from biped_switch.reports.table1 import table1_markdown
from biped_switch.reports.table2 import (ceiling_markdown, claims_markdown, failures_by_context,
                                         failures_markdown, fall_positions,
                                         fall_positions_markdown, paper_claims, policy_on_falls,
                                         policy_on_falls_markdown, suite_ceiling, switch_outcomes,
                                         switch_summary, switches_markdown, table2_markdown)
from biped_switch.reports.table3 import retrain_cost as table3_doc, table3_markdown
from biped_switch.stats import dist_success_cells, pct_ci


def _print(*s):
    print(*s, flush=True)


def retrain_cost(runs, results, init: str, out, when_dir=paths.WHEN_DIR) -> int:
    """`evaluate retrain-cost`: Table III from the training logs under `runs` and `results`, and
    the learned when rule's record under `when_dir`."""
    doc = table3_doc(pathlib.Path(runs), pathlib.Path(results), init, pathlib.Path(when_dir))
    md = table3_markdown(doc)
    print(md)
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table3.json").write_text(json.dumps(doc, indent=2))
    (out / "table3.md").write_text(md + "\n")
    return 0


def single(a, error) -> int:
    """`evaluate single`: Table I rows for `a.policies` x `a.inits`, joined with the table in
    `a.out` made with the same settings; `a`: the command's flags, `error(msg)`: refuses them."""
    json_path = pathlib.Path(a.out) / "table1.json"
    settings = {**vars(a), "batch": min(a.batch, a.trials)}
    try:  # before the rollouts, not after
        merge_table1(read_table(json_path, a.fresh), [], settings)
    except ValueError as e:
        error(f"{json_path}: {e}")
    rows, missing = [], []
    for init in a.inits:
        for policy in a.policies:
            ckpt = find_policy(policy, init, pathlib.Path(a.runs))
            if ckpt is None:
                missing.append(f"{policy}_{init}")
                continue
            t0 = time.perf_counter()
            print(f"evaluating {policy}/{init} ({ckpt}) on {a.trials} {a.kind or policy} tracks of "
                  f"seeds {a.track_seed:,}.. ({a.backend} backend) ...", flush=True)
            row = evaluate_single(policy, init, ckpt, a.trials, a.seed, a.horizon_s,
                                  min(a.batch, a.trials), a.backend, a.track_seed, a.kind)
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
    lock_file = lock(pathlib.Path(a.out), "table1")  # another `evaluate single` may have added rows
    old = read_table(json_path, a.fresh)
    done = {(r["policy"], r["init"]) for r in rows}
    rows = merge_table1(old, rows, settings)
    if old:
        kept = [f"{r['policy']}_{r['init']}" for r in rows if (r["policy"], r["init"]) not in done]
        print(f"kept from {json_path}: {', '.join(kept) or 'no rows'}", flush=True)
    settings["policies"] = list(dict.fromkeys(r["policy"] for r in rows))  # the table's, not this run's
    settings["inits"] = list(dict.fromkeys(r["init"] for r in rows))
    out = write_table(a.out, "table1", table1_markdown(rows),
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
    lock_file.close()
    return 0



def read_table(path: pathlib.Path, fresh: bool) -> dict | None:
    """A saved table's JSON, or None when there is none or `--fresh` replaces it."""
    return None if fresh or not path.exists() else json.loads(path.read_text())


def write_table(out_dir, name: str, md: str, head: list, cols: list, rows: list) -> pathlib.Path:
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


def lock(out: pathlib.Path, name: str = "table2"):
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


def failures(out) -> int:
    """`evaluate failures`: Table II's falls by artifact and the artifact before it, the policy
    acting at each fall and the suite's ceiling, from the per-trial outcomes of `evaluate multi`."""
    out = pathlib.Path(out)
    trials_path = out / "table2_trials.npz"
    if not trials_path.exists():
        print(f"error: {trials_path} missing: run `python -m biped_switch.evaluate multi` first",
              file=sys.stderr)
        return 2
    settings = json.loads((out / "table2.json").read_text())["settings"]
    lineup = LINEUP[settings.get("lineup", PAPER_LINEUP.name)]
    if new_names(lineup):
        print(f"error: {out / 'table2.json'} is line-up {lineup.name}'s; `evaluate failures` "
              f"reports the paper's kinds only, not {', '.join(new_names(lineup))}", file=sys.stderr)
        return 2
    seed0 = settings.get("track_seed", MULTI_TRACK_SEED)
    tracks = [mixed_track(seed0 + i, settings["n_artifacts"]) for i in range(settings["trials"])]
    by_method, on_falls, where = {}, {}, {}
    with np.load(trials_path) as z:
        for m in dict.fromkeys(k.split("/")[0] for k in z.files):
            by_method[m] = failures_by_context(tracks, z[f"{m}/progress_frac"], z[f"{m}/fell"],
                                               z[f"{m}/fail_kind"])
            where[m] = fall_positions(tracks, z[f"{m}/progress_frac"], z[f"{m}/fell"],
                                      z[f"{m}/fail_kind"])
            if f"{m}/active_at_start" in z.files:
                on_falls[m] = policy_on_falls(tracks, z[f"{m}/progress_frac"], z[f"{m}/fell"],
                                              z[f"{m}/fail_kind"], z[f"{m}/active_at_start"])
    md = failures_markdown(by_method)
    if on_falls:
        md += "\n\n" + policy_on_falls_markdown(on_falls)
    md += "\n\n" + fall_positions_markdown(where)
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
    (out / "fall_positions.json").write_text(json.dumps(where, indent=1))
    return 0


def switches(a) -> int:
    """`evaluate switches`: Table II's rollouts (the same first `a.trials` tracks and seeds) with
    every switch logged: its distance before the artifact and whether that artifact was lost;
    `a`: the command's flags."""
    methods, skipped = available_methods(a.methods, a.runs, a.estimators, a.lookup)
    for sk in skipped:
        print(f"skipped {sk}", file=sys.stderr)
    if not methods:
        return 1
    t0, per_trial, n_art = time.perf_counter(), {}, a.n_artifacts
    cfg = MultiConfig(a.trials, min(a.batch, a.trials), a.horizon_s, a.runs, est_dir=a.estimators,
                      lookup_dir=a.lookup, n_artifacts=n_art, backend=a.backend)
    evaluate_multi(methods, cfg, a.seed, _print, per_trial)
    tracks = [mixed_track(MULTI_TRACK_SEED + i, n_art) for i in range(a.trials)]
    # a rule with a model logs its output at each switch; the others have none to show
    model = {m for m in per_trial if method_record(m).reads_model}
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
    plot_switch_distances(by_method, out / "switch_distances_gaps.png", "gaps")  # the worst kind
    print(f"wrote {out / 'switch_distances.md'}, .json and switch_distances_gaps.png "
          f"({wall:.0f} s)")
    return 0


def when_cfg(margin=None, persist_steps=None, later_from=None):
    """The learned rule's config with a command's overrides (None: the config's)."""
    cfg = default_when_config()
    for key, value in (("margin", margin), ("persist_steps", persist_steps),
                       ("later_from", later_from)):
        if value is not None:
            cfg[key] = value
    return cfg


def resolve_lineup(a, error):
    """The line-up of `evaluate multi`'s flags, once: its reporting tracks unless --track-seed,
    the rows it can have unless --methods (a row it cannot have is refused, naming its part);
    a learned detector must name its every target."""
    lineup = LINEUP[a.lineup]
    if a.track_seed is None:
        if lineup.name not in LINEUP_TRACK_SEEDS:
            error(f"--lineup {lineup.name}: no reporting tracks in config.LINEUP_TRACK_SEEDS; "
                  f"give --track-seed")
        a.track_seed = LINEUP_TRACK_SEEDS[lineup.name][0]
    if a.methods is None:
        a.methods = [m for m in MULTI_METHODS if lineup_gap(method_record(m), lineup) is None]
    bad = [f"row {m}: line-up {lineup.name} has no {gap}" for m in a.methods
           if (gap := lineup_gap(method_record(m), lineup))]
    if bad:
        error("; ".join(bad))
    try:
        check_detector(a.detector_dir if a.detector == "learned" else None, lineup)
    except ValueError as e:
        error(str(e))
    return lineup


def fail_order(lineup) -> tuple[str, ...]:
    """Table II's failure columns for `lineup`: the paper's order, then its other targets."""
    return (tuple(k for k in TABLE2_FAIL_ORDER if k in lineup.targets)
            + tuple(k for k in lineup.targets if k not in TABLE2_FAIL_ORDER))


def lineup_markdown(rows: list[dict], lineup) -> str:
    """Table II's Markdown for a line-up the paper has no numbers for (Table II-4): a failure
    column per target of the line-up, switches per trial, no paper column."""
    order = fail_order(lineup)
    head = (f"Line-up {lineup.name}: {', '.join(lineup.policies)} switching into "
            f"{', '.join(lineup.targets)} on {lineup.tracks} tracks\n\n")
    lines = ["| method | trials | % total dist. (95% CI) | % success (95% CI) | "
             + "".join(f"% {KIND[k].singular} fail (CI) | " for k in order) + "switches/trial |",
             "|---" * (5 + len(order)) + "|"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['n']} | {dist_success_cells(r)} | "
                     + " | ".join(pct_ci(r["fail_on"][k], r["fail_ci"][k]) for k in order)
                     + f" | {r['switches_per_trial']:.2f} |")
    return head + "\n".join(lines)


def multi(a, error) -> int:
    """`evaluate multi`: Table II rows for `a.methods`, joined with the table in `a.out` made with
    the same settings (TRIAL_KEYS), saved with the per-trial outcomes, the claims and Fig. 5 of
    each row that has one; `a`: the command's flags, `error(msg)`: refuses them (argparse's)."""
    batch = min(a.batch, a.trials)
    t0 = time.perf_counter()
    json_path = pathlib.Path(a.out) / "table2.json"
    old = read_table(json_path, a.fresh)
    lineup = resolve_lineup(a, error)
    settings = {**vars(a), "batch": batch}
    if a.detector == "oracle":
        settings.pop("detector_dir")
    if lineup == PAPER_LINEUP:  # the paper's table records no line-up (its files stay as they were)
        settings.pop("lineup")
    try:  # before an hour of rollouts, not after
        merge_rows(old, [], settings)
    except ValueError as e:
        error(f"{json_path}: {e}")
    a.methods, skipped = available_methods(a.methods, a.runs, a.estimators, a.lookup, a.dqn,
                                           a.stand_in, a.when_dir, lineup=lineup)
    for s in skipped:
        print(f"skipped {s}", file=sys.stderr)
    if not a.methods:
        print("evaluate multi: no method has its trained parts", file=sys.stderr)
        return 1
    print(f"Table II: {len(a.methods)} methods x {a.trials} trials of {lineup.tracks} tracks (batch "
          f"{batch}, {jax.local_device_count()} {jax.devices()[0].platform} device(s))", flush=True)
    per_trial = {}
    cfg = MultiConfig(a.trials, batch, a.horizon_s, a.runs, a.stand_in, a.estimators, a.lookup,
                      a.dqn, a.guide_scale, a.n_artifacts, a.backend, a.track_seed,
                      a.detector_dir if a.detector == "learned" else None, a.when_dir,
                      when_cfg(a.when_margin, a.when_persist, a.when_later), lineup)
    rows, setups = evaluate_multi(a.methods, cfg, a.seed, _print, per_trial)
    session_s = time.perf_counter() - t0
    lock_file = lock(pathlib.Path(a.out))  # another `evaluate multi` may have added rows meanwhile
    old = read_table(json_path, a.fresh)
    rows = merge_rows(old, rows, settings)
    have = {r["method"] for r in rows}
    skipped = [sk for sk in skipped if sk.split(":")[0] not in have]
    if old:
        kept = [r["method"] for r in rows if r["method"] not in a.methods]
        print(f"kept from {json_path}: {', '.join(kept) or 'no rows'}", flush=True)
    settings["methods"] = [r["method"] for r in rows]
    fails, paper_kinds = fail_order(lineup), not new_names(lineup)
    out = write_table(a.out, "table2",
                       table2_markdown(rows) if paper_kinds else lineup_markdown(rows, lineup),
                       ["method", "init", "trials"]
                       + [f"{KIND[k].singular}_fail_{c}" for k in fails for c in ("pct", "lo", "hi")]
                       + ["switches_per_trial", "wall_s"],
                       [[r["method"], r["init"], r["n"]]
                        + [v for k in fails for v in (r["fail_on"][k], *r["fail_ci"][k])]
                        + [r["switches_per_trial"], r["wall_s"]] for r in rows],
                       rows)
    # wall_s: the time to make the whole table, the sum of its rows' (each with its setup and
    # compiles), over the sessions that made them; wall_s_session: this command's rollouts
    wall = float(sum(r["wall_s"] for r in rows))
    (out / "table2.json").write_text(json.dumps(
        {"settings": settings, "rows": rows, "skipped": skipped, "wall_s": wall,
         "wall_s_session": session_s,
         "device": str(jax.devices()[0]), "backend": sorted({r["backend"] for r in rows}),
         "track_seed": a.track_seed, **lineup_meta(lineup)}, indent=2, default=str))
    save_trials(out / "table2_trials.npz", per_trial, {r["method"] for r in rows})
    if paper_kinds:
        claims_md = claims_markdown(paper_claims(rows))  # the paper's claims on the whole table
        (out / "claims.md").write_text(claims_md + "\n")
        print(claims_md, flush=True)
    lock_file.close()
    if a.fig5_trial >= 0 and not paper_kinds:
        print(f"no Fig. 5 or claims for line-up {lineup.name}: they read the paper's kinds only",
              flush=True)
    elif a.fig5_trial >= 0:
        fig5_traces(setups, a.methods, a.fig5_trial, a.trials, a.seed, a.track_seed,
                    a.n_artifacts, out)
    print(json.dumps({"table2_wall_s": round(wall, 1), "session_s": round(session_s, 1),
                      "trials": a.trials, "methods_run": len(a.methods), "rows": len(rows)}))
    return 0

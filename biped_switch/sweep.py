"""Switch-point sweeps (paper Sec. III-C): estimator data and lookup tables.

The command line of `biped_switch.switching.sweep`: `python -m biped_switch.sweep` or `biped-switch sweep`.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import jax
import numpy as np
from biped_switch import cli
from biped_switch.simulation import env as env_lib
from biped_switch.learning import policies as pol
from biped_switch.simulation import terrain
from biped_switch.config import default_sweep_config
from biped_switch.switching.estimator import load_data, sweep_name
from biped_switch.reports import fig4b
from biped_switch.switching import lookup
from biped_switch.switching import sweep as sweep_lib


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.sweep", description=__doc__.split("\n")[0])
    cli.add_init(p)
    p.add_argument("--targets", nargs="+", default=list(terrain.ARTIFACT_KINDS),
                   choices=terrain.ARTIFACT_KINDS)
    p.add_argument("--points", type=int, default=None, help="data points per target (default 100,000)")
    p.add_argument("--batch", type=int, default=None, help="episodes per jitted batch")
    p.add_argument("--tracks", type=int, default=512, help="single-artifact tracks in the bank")
    p.add_argument("--seed", type=int, default=0)
    cli.add_runs(p, "where the trained policies are (then models/policies/)")
    cli.add_out(p, "runs/sweeps", "the sweep data, one part per batch (large; not committed)")
    p.add_argument("--results", default="experiments/results/lookup")
    p.add_argument("--stand-in", default=None, choices=pol.POLICY_NAMES,
                   help="use this policy for any that is not trained yet (pipeline checks only)")
    p.add_argument("--guide-scale", type=float, default=0.0,
                   help="scripted guide forces on (pipeline checks with untrained policies only)")
    p.add_argument("--difficulty", type=float, default=None, help="terrain difficulty (default 1)")
    cli.add_backend(p)
    p.add_argument("--context", action="store_true",
                   help="switch after the source policy has crossed its own artifact, as on mixed "
                        "tracks (two-artifact tracks; data and lookup named <init>_context)")
    p.add_argument("--lead-in", action="store_true",
                   help="a context sweep whose episodes all start with walk, the controller handing "
                        "over along the track by the context lookup, as on Table II (up to three-"
                        "artifact tracks; data and lookup named <init>_leadin)")
    p.add_argument("--switch-min", type=float, default=None,
                   help="switch at U(this, 0.9) m before the artifact (default 0: the paper's); "
                        "a floor puts the data where the rules decide")
    p.add_argument("--replay", type=int, default=0, metavar="N",
                   help="instead of sweeping: replay N recorded switches (0.3-0.9 m) of each "
                        "target's sweep in a program of another batch size, and report how often "
                        "the label agrees (RESULTS/label_noise.json)")
    p.add_argument("--replay-batch", type=int, default=128)
    a = p.parse_args(argv)
    name = sweep_name(a.init, a.context, a.lead_in)
    cfg = default_sweep_config()
    if a.points is not None:
        cfg.n_points = a.points
    if a.batch is not None:
        cfg.batch = a.batch
    if a.switch_min is not None:
        if not 0.0 <= a.switch_min < cfg.switch_max_m:
            p.error(f"--switch-min must lie in [0, {cfg.switch_max_m}) m, got {a.switch_min}")
        cfg.switch_min_m = a.switch_min
    if a.difficulty is not None:
        terrain.check_difficulty(a.difficulty)
        cfg.difficulty = a.difficulty
    if cfg.n_points < 1 or cfg.batch < 1:
        p.error("--points and --batch must be >= 1")
    out = pathlib.Path(a.out)
    if a.replay:
        if a.replay < 1 or a.replay_batch < 1:
            p.error(f"--replay and --replay-batch must be >= 1, got {a.replay}, {a.replay_batch}")
        return _main_replay(a, out / name, pathlib.Path(a.results))
    lookup_path = pathlib.Path(a.results) / f"lookup_{name}.json"

    def read_stored() -> tuple[dict, dict]:
        # Read when needed, never at the start: a sweep of another target of this init, run
        # beside this one, may write the lookup while this one runs.
        doc = json.loads(lookup_path.read_text()) if lookup_path.exists() else {}
        return doc, doc.get("meta", {}).get("sweeps", {})

    data, stats = {}, {}
    for target in a.targets:
        print(f"sweep {name}/{target}: {cfg.n_points:,} points, batch {cfg.batch} on "
              f"{jax.local_device_count()} {jax.devices()[0].platform} device(s)", flush=True)
        run = sweep_lib.run_sweep(a.init, target, cfg, out, a.runs, a.seed, a.tracks, a.stand_in,
                        a.guide_scale, print_fn=lambda *s: print(*s, flush=True),
                        backend=a.backend, context=a.context, lead_in=a.lead_in,
                        lookup_results=a.results)
        data[target] = load_data(run.path)
        stats[target] = {**sweep_lib.data_stats(data[target], run.path, run.wall_s_total),
                         "points_new": run.points_new, "session_s": round(run.session_s, 1),
                         "loop_s": round(run.loop_s, 1),
                         "points_per_s": sweep_lib.rate_or_none(run.points_new, run.loop_s),
                         "points_per_s_steady": sweep_lib.rate_or_none(run.steady_points, run.steady_s),
                         "device": str(jax.devices()[0]),
                         "backend": env_lib.resolve_backend(a.backend)}
        # nothing to make: keep its recorded speed
        if run.points_new == 0 and (kept := read_stored()[1].get(target)):
            stats[target] = {**kept, **sweep_lib.data_stats(data[target], run.path, run.wall_s_total)}
        print(json.dumps({"sweep": f"{name}/{target}", **stats[target]}), flush=True)
    stored_doc, stored = read_stored()
    for target in terrain.ARTIFACT_KINDS:  # the lookup table covers every target swept so far
        path = out / name / f"{target}.npz"
        if target not in data and path.exists():
            data[target] = load_data(path)
            st = sweep_lib.stored_stats(data[target], path, stored.get(target, {}))
            if st is None:
                print(f"no sweep time recorded for {name}/{target}: left out of meta.sweeps",
                      file=sys.stderr)
            else:
                stats[target] = st
    tables = lookup.tables_from_data(data, cfg)
    policies = {k: d["meta"]["policies"] for k, d in data.items()}
    for target in terrain.ARTIFACT_KINDS:  # swept before, its data gone: keep its stored table
        t = stored_doc.get("tables", {}).get(target)
        if target not in tables and t is not None:
            rate = [[np.nan if v is None else v for v in r] for r in t["rate"]]
            tables[target] = lookup.table_from_rates(rate, t["count"], target, cfg.lookup_bin_m)
            stats[target] = stored.get(target, {})
            policies[target] = stored_doc["meta"].get("policies", {}).get(target)
            print(f"lookup {name}/{target}: kept from {lookup_path} (its sweep data is not under "
                  f"{out}/)", flush=True)
    tables = {k: tables[k] for k in terrain.ARTIFACT_KINDS if k in tables}
    meta = {"sweeps": stats, "policies": policies}
    doc = lookup.save_lookup(tables, name, pathlib.Path(a.results), meta)
    fig4b.draw_lookup(tables, name, pathlib.Path(a.results))
    print("lookup table (best switch distance [m], active -> target):")
    for k, v in doc["best_m"].items():
        if v is not None:
            print(f"  {k:16s} {v:.2f}")
    return 0


def _main_replay(a, sweep_dir: pathlib.Path, results: pathlib.Path) -> int:
    rows = []
    for target in a.targets:
        path = sweep_dir / f"{target}.npz"
        if not path.exists():
            raise FileNotFoundError(f"no sweep data at {path} to replay")
        r = sweep_lib.replay_labels(load_data(path), a.replay, a.replay_batch, a.runs,
                                    a.stand_in, a.backend, seed=a.seed,
                                    print_fn=lambda *s: print(*s, flush=True))
        rows.append({**r, "data": str(path), "device": str(jax.devices()[0]),
                     "backend": env_lib.resolve_backend(a.backend)})
        print(json.dumps(rows[-1]), flush=True)
    results.mkdir(parents=True, exist_ok=True)
    dst = results / "label_noise.json"
    old = json.loads(dst.read_text()) if dst.exists() else []
    keep = [r for r in old if r["target"] not in a.targets]
    dst.write_text(json.dumps(keep + rows, indent=1))
    print(f"wrote {dst}")
    return 0


if __name__ == "__main__":
    from biped_switch.cli import run

    run(main)

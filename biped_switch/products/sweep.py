"""The body of `sweep` (biped_switch/sweep.py parses its flags): the switch-point sweeps of each
target, then the lookup table over every target swept so far, and its figure; sized by the
line-up swept (`lineups.Lineup`, the paper's by default)."""

from __future__ import annotations

import json
import pathlib
import sys

import jax
import numpy as np

from biped_switch.lineups import PAPER_LINEUP, Lineup
from biped_switch.reports import fig4b
from biped_switch.simulation import env as env_lib
from biped_switch.switching import lookup
from biped_switch.switching import sweep as sweep_lib
from biped_switch.switching.estimator import load_data


def sweeps_and_lookup(a, cfg, name: str, out: pathlib.Path, lineup: Lineup = PAPER_LINEUP) -> int:
    """`sweep`: sweeps `a.targets` into `out`/`name`, then writes the lookup table `name` of every
    target of `lineup` swept so far (a target whose data is gone keeps its stored table); `a`:
    the flags."""
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
                        lookup_results=a.results, lineup=lineup)
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
    for target in lineup.targets:  # the lookup table covers every target swept so far
        path = out / name / f"{target}.npz"
        if target not in data and path.exists():
            data[target] = load_data(path)
            st = sweep_lib.stored_stats(data[target], path, stored.get(target, {}))
            if st is None:
                print(f"no sweep time recorded for {name}/{target}: left out of meta.sweeps",
                      file=sys.stderr)
            else:
                stats[target] = st
    tables = lookup.tables_from_data(data, cfg, lineup)
    policies = {k: d["meta"]["policies"] for k, d in data.items()}
    for target in lineup.targets:  # swept before, its data gone: keep its stored table
        t = stored_doc.get("tables", {}).get(target)
        if target not in tables and t is not None:
            rate = [[np.nan if v is None else v for v in r] for r in t["rate"]]
            tables[target] = lookup.table_from_rates(rate, t["count"], target, cfg.lookup_bin_m,
                                                     lineup=lineup)
            stats[target] = stored.get(target, {})
            policies[target] = stored_doc["meta"].get("policies", {}).get(target)
            print(f"lookup {name}/{target}: kept from {lookup_path} (its sweep data is not under "
                  f"{out}/)", flush=True)
    tables = {k: tables[k] for k in lineup.targets if k in tables}
    meta = {"sweeps": stats, "policies": policies}
    doc = lookup.save_lookup(tables, name, pathlib.Path(a.results), meta, lineup)
    if lineup.policies == fig4b.POLICY_NAMES:
        fig4b.draw_lookup(tables, name, pathlib.Path(a.results))
    else:  # its panels draw the paper's policies' rows only
        print(f"no fig4b for line-up {lineup.name}: reports/fig4b.py draws the paper's policies "
              f"{fig4b.POLICY_NAMES} only", flush=True)
    print("lookup table (best switch distance [m], active -> target):")
    for k, v in doc["best_m"].items():
        if v is not None:
            print(f"  {k:16s} {v:.2f}")
    return 0


def replay(a, sweep_dir: pathlib.Path, results: pathlib.Path, lineup: Lineup = PAPER_LINEUP) -> int:
    """`sweep --replay N`: N recorded switches of each target's sweep replayed in a program of
    another batch size; how often the label agrees (<results>/label_noise.json, a row per target
    and line-up: rows of a line-up other than the paper's name it, so none replaces another's)."""
    named = {} if lineup == PAPER_LINEUP else {"lineup": lineup.name}  # the paper's rows as before
    rows = []
    for target in a.targets:
        path = sweep_dir / f"{target}.npz"
        if not path.exists():
            raise FileNotFoundError(f"no sweep data at {path} to replay")
        r = sweep_lib.replay_labels(load_data(path), a.replay, a.replay_batch, a.runs,
                                    a.stand_in, a.backend, seed=a.seed,
                                    print_fn=lambda *s: print(*s, flush=True))
        rows.append({**r, **named, "data": str(path), "device": str(jax.devices()[0]),
                     "backend": env_lib.resolve_backend(a.backend)})
        print(json.dumps(rows[-1]), flush=True)
    results.mkdir(parents=True, exist_ok=True)
    dst = results / "label_noise.json"
    old = json.loads(dst.read_text()) if dst.exists() else []
    keep = [r for r in old if r["target"] not in a.targets
            or r.get("lineup", PAPER_LINEUP.name) != lineup.name]
    dst.write_text(json.dumps(keep + rows, indent=1))
    print(f"wrote {dst}")
    return 0

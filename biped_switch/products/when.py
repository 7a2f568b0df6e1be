"""The learned when rule's products (biped_switch/when.py parses the flags): its training with
the offline check, the margin and run-length tuning on tuning tracks, and the timing ceiling."""

from __future__ import annotations

import json
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np

from biped_switch import paths
from biped_switch.config import (MULTI_TRACK_SEED, TUNE_TRACK_SEED, default_env_config,
                                 default_when_config)
from biped_switch.evaluation import multi
from biped_switch.names import ARTIFACT_KINDS, POLICY_NAMES
from biped_switch.reports import when as when_report
from biped_switch.simulation.observation import layout
from biped_switch.stats import episode_table, reliability, wilson_ci
from biped_switch.switching import estimator as est_lib
from biped_switch.switching import when


def train_rule(a, cfg) -> int:
    """`when`: trains the rule of `cfg` on the context sweeps (and lead-in sweeps, `a.lead_in`),
    saves it to <a.out>/<a.init> and scores it offline beside the paper's estimator and the prior
    table (<a.results>/offline.md); `a`: the command's flags."""
    grid = layout(default_env_config()).grid
    name, lead = est_lib.sweep_name(a.init, True), est_lib.sweep_name(a.init, True, True)
    t0 = time.perf_counter()
    rows, est_p, sweeps = [], [], {}
    for target in ARTIFACT_KINDS:
        path = pathlib.Path(a.data) / name / f"{target}.npz"
        lead_path = pathlib.Path(a.data) / lead / f"{target}.npz"
        use = [path] + ([lead_path] if a.lead_in != "skip" and lead_path.exists() else [])
        if a.lead_in == "only" and lead_path.exists():
            use = [lead_path]
        if not use[0].exists():
            raise FileNotFoundError(f"no sweep at {path}: python -m biped_switch.sweep --init "
                                    f"{a.init} --context --switch-min 0.2 --targets {target} "
                                    f"--out {a.data}")
        for path in use:
            _read_sweep(path, target, grid, a.init, a.estimators, rows, est_p, sweeps)
    rows, est_p = when.concat_rows(rows), np.concatenate(est_p)
    data_s = time.perf_counter() - t0
    params, metrics = when.train(rows, cfg, print_fn=lambda *s: print(*s, flush=True))
    val = when.is_val(rows.track, cfg)
    tr, va = when.take(rows, ~val), when.take(rows, val)
    preds = {"learned": when.predict_rows(params, va), "table": when.table_predict(tr, va),
             "paper_estimator": est_p[val]}
    scores = when.offline_scores(preds, va)
    out = pathlib.Path(a.out) / a.init
    meta = {"init": a.init, "config": cfg.to_dict(), "sweeps": sweeps, "lead_in": a.lead_in,
            "grid": list(grid),
            "parts": list(when.PARTS), "widths": when.part_widths(grid),
            **{k: v for k, v in metrics.items() if k != "history"},
            "data_s": round(data_s, 1), "device": str(jax.devices()[0])}
    est_lib.save_estimator(out, params, meta)
    res = pathlib.Path(a.results)
    res.mkdir(parents=True, exist_ok=True)
    rel = {}
    for k, pk in preds.items():
        m = va.now & ~np.isnan(pk) & (va.d_now >= when.OFFLINE_BAND_M[0])
        rel[k] = {kk: np.asarray(v).tolist() for kk, v in reliability(pk[m], va.label[m]).items()}
    doc = {"model": str(out), "scores": scores, "reliability": rel, "train": meta,
           "history": metrics["history"], "band_m": list(when.OFFLINE_BAND_M)}
    (res / "offline.json").write_text(json.dumps(doc, indent=1, default=float))
    when_report.write(doc, res)
    print(f"saved {out}; offline check in {res}/offline.md "
          f"({time.perf_counter() - t0:.0f} s in all, training {metrics['train_s']:.0f} s)")
    return 0



def _read_sweep(path: pathlib.Path, target: str, grid, init: str, estimators, rows: list,
                est_p: list, sweeps: dict) -> None:
    """Appends one sweep's rows, and the paper's estimator's output on its switch rows (NaN on the
    wait rows, which it has no prediction for), to `rows` and `est_p`; its record to `sweeps`."""
    data = est_lib.load_data(path)
    r = when.rows_from_sweep(data, target, grid)
    rows.append(r)
    sweeps[f"{path.parent.name}/{target}"] = {
        "data": str(path), "samples": int((data["offset"] == 0).sum()),
        "wall_s": (data["meta"] or {}).get("wall_s_total"),
        "switch_min_m": data["meta"]["config"].get("switch_min_m")}
    est_params, _ = est_lib.load_estimator(pathlib.Path(estimators) / f"{init}_{target}")
    at0 = data["offset"] == 0
    x = np.concatenate([data["state"][at0], data["heightmap"][at0].astype(np.float32)], -1)
    f = jax.jit(lambda x: est_lib.predict(est_params, x))
    pe = np.concatenate([np.asarray(f(jnp.asarray(x[i:i + 4096])))
                         for i in range(0, len(x), 4096)])
    est_p.append(np.concatenate([pe, np.full(len(r.label) - len(pe), np.nan)]))
    print(f"{path.parent.name}/{target}: {len(r.label):,} rows ({int(r.now.sum()):,} switches), "
          f"{100 * r.label[r.now].mean():.1f}% success", flush=True)


def _implied_pct(rows: list[dict], methods, n_tracks: int) -> dict:
    """What `ceiling`'s per-pair rates imply for Table II's first `n_tracks` tracks, each artifact
    crossed independently; the same product of Table II's own per-pair rates checks how well
    independence holds."""
    seqs = []
    for i in range(n_tracks):
        kinds = [ARTIFACT_KINDS[c] for c in multi.mixed_track(MULTI_TRACK_SEED + i).artifact_codes]
        seqs.append([(k, "start" if n == 0 else kinds[n - 1]) for n, k in enumerate(kinds)])

    def implied(pick):
        rate = {(r["target"], r["source"]): v for r in rows if (v := pick(r)) is not None}
        v = when_report.implied_success(seqs, rate)
        return None if v is None else round(100 * v, 1)

    def best(r):  # the lead-in sweep's best bin where there is one, else the context sweep's
        s = r["sweeps"].get("lead-in sweep") or r["sweeps"].get("context sweep")
        return None if s is None else s["pct"] / 100

    implied_pct = {"best bins": implied(best)}
    for m in methods:
        implied_pct[f"Table II {m}"] = implied(
            lambda r: r["table2"][m]["pct"] / 100 if m in r["table2"] else None)
    return implied_pct


def ceiling(a, cfg) -> int:
    """Per (target, source): the best switch-distance bin of the context and lead-in sweeps, and
    what Table II's `learned` and `lookup_context` rows reached there (read, never tuned on)."""
    sweeps = {"context sweep": est_lib.sweep_name(a.init, True),
              "lead-in sweep": est_lib.sweep_name(a.init, True, True)}
    methods = ("learned", "lookup_context") if a.init == "stand" else ("learned_no_overlap",)
    t2_path = pathlib.Path(a.table2) / "failures_by_context.json"
    t2 = json.loads(t2_path.read_text()) if t2_path.exists() else {}
    data = {(s, t): np.load(pathlib.Path(a.data) / name / f"{t}.npz")
            for s, name in sweeps.items() for t in ARTIFACT_KINDS
            if (pathlib.Path(a.data) / name / f"{t}.npz").exists()}
    rows, half_m, phase_bins = [], float(cfg.ceiling_bin_m), int(cfg.ceiling_phase_bins)
    phase_sweep = "lead-in sweep"
    for target in ARTIFACT_KINDS:
        for j, src in enumerate(POLICY_NAMES):
            if src == target:
                continue
            after = "start" if src == "walk" else src  # walk acts only before the 1st artifact
            row = {"target": target, "source": after, "sweeps": {}, "table2": {}}
            for s in sweeps:
                d = data.get((s, target))
                if d is None:
                    continue
                at0 = d["offset"] == 0
                mine = d["source"][at0] == j
                lost = (d["lost_switch_at_m"][d["lost_source"] == j] if "lost_source" in d.files
                        else np.zeros(0))
                b = when_report.best_bin(d["switch_dist_m"][at0][mine], d["label"][at0][mine],
                                         lost, cfg.ceiling_bin_m, tuple(cfg.ceiling_band_m),
                                         int(cfg.ceiling_min_n))
                if b is not None:
                    ci = wilson_ci(b[1], b[2])
                    row["sweeps"][s] = {"bin_m": b[0], "k": b[1], "n": b[2],
                                        "pct": 100 * b[1] / b[2], "ci": [100 * c for c in ci]}
                if b is not None and s == phase_sweep:  # the phase clock around the best distance
                    near = mine & (np.abs(d["switch_dist_m"][at0] - b[0] - cfg.ceiling_bin_m / 2)
                                   <= cfg.ceiling_bin_m / 2 + half_m)
                    ph = when_report.phase_spread(d["phase"][at0][near], d["label"][at0][near],
                                                  phase_bins)
                    if ph is not None:
                        row["phase"] = {"min_pct": ph[0], "max_pct": ph[1], "min_n": ph[2],
                                        "p": ph[3]}
            for m in methods:
                reached, fell = t2.get(m, {}).get(target, {}).get(after, (0, 0))
                if reached:
                    ci = wilson_ci(reached - fell, reached)
                    row["table2"][m] = {"pct": 100 * (1 - fell / reached),
                                        "ci": [100 * c for c in ci], "n": reached}
            rows.append(row)
    implied_pct = _implied_pct(rows, methods, a.trials_ceiling)
    doc = {"init": a.init, "bin_m": float(cfg.ceiling_bin_m), "implied_pct": implied_pct,
           "phase_sweep": phase_sweep, "phase_halfwidth_m": half_m, "phase_bins": phase_bins,
           "tracks": a.trials_ceiling, "track_seed": MULTI_TRACK_SEED,
           "band_m": list(cfg.ceiling_band_m), "min_n": int(cfg.ceiling_min_n),
           "sweeps": [s for s in sweeps if any((s, t) in data for t in ARTIFACT_KINDS)],
           "methods": list(methods), "rows": rows, "table2": str(t2_path)}
    res = pathlib.Path(a.results)
    res.mkdir(parents=True, exist_ok=True)
    (res / "ceiling.json").write_text(json.dumps(doc, indent=1))
    (res / "ceiling.md").write_text(when_report.ceiling_markdown(doc))
    print(when_report.ceiling_markdown(doc))
    return 0


def tune(a) -> int:
    """Success on the tuning tracks for each (margin, run length): one compiled rollout, the
    margin and run length being traced values of the rules."""
    t0 = time.perf_counter()
    method = "learned" if a.init == "stand" else "learned_no_overlap"
    rows, setups = [], {}

    res = pathlib.Path(a.results)
    name = "tuning" if a.init == "stand" else f"tuning_{a.init}"
    model = str(pathlib.Path(a.out) / a.init)
    old = json.loads((res / f"{name}.json").read_text()) if (res / f"{name}.json").exists() else {}
    if old and (old.get("model"), old.get("trials")) == (model, a.trials):
        # a tuning in steps: this command's settings join the earlier ones (band 1: none)
        rows = [{"band_tol": 1.0, **r} for r in old["rows"]]
    keys = ("later_from", "band_tol", "margin", "persist_steps")

    def best():
        return max(rows, key=lambda r: r["success_pct"])

    def run(later_from, band_tol, margin, persist):
        if any(tuple(r.get(k) for k in keys) == (later_from, band_tol, margin, persist)
               for r in rows):
            return  # measured by an earlier step
        if (later_from, band_tol) not in setups:  # a compiled rollout per pair: they set the program
            cfg = default_when_config()
            cfg.later_from, cfg.band_tol = later_from, band_tol
            setups[later_from, band_tol] = multi.MultiSetup([method], multi.MultiConfig(
                a.trials, min(250, a.trials), 60.0, a.runs, est_dir=a.estimators,
                lookup_dir=paths.LOOKUP, track_seed=TUNE_TRACK_SEED, when_dir=a.out, when_cfg=cfg))
        r = episode_table(setups[later_from, band_tol].evaluate(
            method, a.trials, 0, margin=float(margin), persist_steps=int(persist)))
        rows.append({"later_from": later_from, "band_tol": float(band_tol), "margin": float(margin),
                     "persist_steps": int(persist), "trials": a.trials,
                     "success_pct": r["success_pct"], "success_ci": r["success_ci"],
                     "fail_on": r["fail_on"]})
        print(f"later from the {later_from}, band {band_tol:g}, margin {margin:+.2f}, {persist} "
              f"step(s): success {r['success_pct']:.1f}% ({r['success_ci'][0]:.1f}-"
              f"{r['success_ci'][1]:.1f})", flush=True)

    for later_from in a.later:  # 1. the margin, anywhere in range
        for m in a.margins:
            run(later_from, 1.0, float(m), 1)
    for b in a.band:  # 2. the band, at the best margin
        run(best()["later_from"], float(b), best()["margin"], 1)
    for k in a.persist:  # 3. the run length, at the best of those
        run(best()["later_from"], best()["band_tol"], best()["margin"], k)
    chosen = best()
    res.mkdir(parents=True, exist_ok=True)
    doc = {"init": a.init, "track_seed": TUNE_TRACK_SEED, "trials": a.trials, "rows": rows,
           "chosen": {k: chosen[k] for k in keys},
           "wall_s": round(time.perf_counter() - t0 + (old.get("wall_s", 0) if old else 0), 1),
           "device": str(jax.devices()[0]), "model": model}
    (res / f"{name}.json").write_text(json.dumps(doc, indent=1))
    (res / f"{name}.md").write_text(when_report.tuning_markdown(doc))
    print(f"chosen: later from the {chosen['later_from']}, band {chosen['band_tol']:g}, "
          f"margin {chosen['margin']:g}, "
          f"{chosen['persist_steps']} step(s) "
          f"(set them in config.default_when_config); {res / name}.md")
    return 0

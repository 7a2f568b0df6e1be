"""The body of `detector` (biped_switch/detector.py parses its flags): each stand policy's
heightmap profiles and oracle labels (or the cached ones), the detector trained on them, its filter
chosen on the validation tracks, and the detector and its report written."""

from __future__ import annotations

import json
import pathlib
import time

import jax
import numpy as np

from biped_switch.config import (DETECTOR_KIND_STRIDE, DETECTOR_MIXED_OFFSET, DETECTOR_TRACK_SEED,
                                 DETECTOR_VAL_OFFSET)
from biped_switch.kinds import CODE_OF_CLASS, POLICY_NAMES
from biped_switch.learning import runs as runs_lib
from biped_switch.learning.policies import load_policy
from biped_switch.reports import detector as report
from biped_switch.simulation import env as env_lib
from biped_switch.switching import detector as det

SETS = ("train", "val", "mixed")


def _collect(kind: str, ckpt: pathlib.Path, seed: int, n_envs: int, horizon_s: float, every: int,
             backend: str, rng_seed: int, n_artifacts=None) -> dict:
    overrides = runs_lib.policy_env_overrides(ckpt)
    env = env_lib.make_env(kind, "stand", n_tracks=n_envs, seed=seed, backend=backend,
                           n_artifacts=n_artifacts, **overrides)
    act, _ = load_policy(ckpt, env)
    return det.collect(env, act, jax.random.PRNGKey(rng_seed), n_envs,
                       int(round(horizon_s / env.dt)), every)


def _collect_all(a, cfg, n_envs: int, e2e: pathlib.Path) -> tuple[dict, float]:
    """Training data (every `cfg.every`-th step) and validation data (every step, for the
    debounce) of each stand policy on its own kind, and the mixed validation tracks."""
    t0 = time.time()
    train_parts, val_parts = [], []
    for k, kind in enumerate(POLICY_NAMES):
        ckpt = runs_lib.find_policy(kind, "stand", pathlib.Path(a.runs))
        if ckpt is None:
            raise SystemExit(f"error: no trained {kind}_stand policy under {a.runs}/ or "
                             f"models/policies/")
        base = DETECTOR_TRACK_SEED + DETECTOR_KIND_STRIDE * k
        for seed, n, every, parts, tag in (
                (base, n_envs, cfg.every, train_parts, "train"),
                (base + DETECTOR_VAL_OFFSET, cfg.val_envs, 1, val_parts, "val")):
            ts = time.time()
            d = _collect(kind, ckpt, seed, n, cfg.horizon_s, every, a.backend, k)
            parts.append(d)
            counts = {c: int(np.sum(d["kind"] == CODE_OF_CLASS[i]))
                      for i, c in enumerate(det.CLASSES)}
            print(f"{tag} {kind}: {len(d['kind']):,} steps of {n} episodes on tracks {seed:,}.. "
                  f"{counts} ({time.time() - ts:.0f} s)", flush=True)
    ts = time.time()
    mixed_seed = DETECTOR_TRACK_SEED + DETECTOR_MIXED_OFFSET
    mixed = _collect("mixed", e2e, mixed_seed, cfg.val_envs, cfg.horizon_s * 2, 1, a.backend, 99,
                     n_artifacts=7)
    print(f"val mixed: {len(mixed['kind']):,} steps ({e2e} on 7-artifact tracks "
          f"{mixed_seed:,}..; {time.time() - ts:.0f} s)", flush=True)
    sets = {"train": det.concat(train_parts), "val": det.concat(val_parts), "mixed": mixed}
    return sets, time.time() - t0


def _data(a, cfg, n_envs: int, e2e: pathlib.Path) -> tuple[dict, float]:
    """(the sets of `_collect_all`, the seconds they took): read from `a.data` when it was made
    with the same settings, else collected and written there."""
    cache = pathlib.Path(a.data)
    key = {"n_envs": n_envs, "val_envs": cfg.val_envs, "horizon_s": cfg.horizon_s,
           "every": cfg.every, "track_seed": DETECTOR_TRACK_SEED, "e2e": str(e2e),
           "fields": list(det.DATA_FIELDS),
           "profile": {"statistic": det.PROFILE_STATISTIC, "lateral_cols": list(cfg.lateral_cols),
                       "feet_rows": list(cfg.feet_rows)}}
    if cache.is_file() and json.loads(str(np.load(cache)["key"])) == key:
        with np.load(cache) as z:
            sets = {s: {f: z[f"{s}/{f}"] for f in det.DATA_FIELDS} for s in SETS}
            data_s = float(z["data_s"])
        print(f"data: {cache} (made in {data_s:.0f} s)")
        return sets, data_s
    sets, data_s = _collect_all(a, cfg, n_envs, e2e)
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(cache, key=json.dumps(key), data_s=data_s,
                        **{f"{s}/{f}": d[f] for s, d in sets.items() for f in det.DATA_FIELDS})
    return sets, data_s


def _choose_filter(val: dict, mixed: dict, pred: dict, cfg) -> dict:
    """Sets `cfg`'s debounce to the filter with the fewest wrong switches on the validation tracks
    (a third kind named first, a kind the oracle is not naming, an artifact missed) among those
    that name artifacts on the mixed tracks at most `cfg.choice_max_late_cm` late on average;
    returns each one's counts."""
    choice = {}
    for via in cfg.via_none_choices:
        for n in cfg.debounce_choices:
            m = [report.detector_metrics(d, report.debounce(d, pred[name][0], n, via),
                                         pred[name][1])
                 for name, d in (("val_single", val), ("val_mixed", mixed))]
            bad = sum(x["wrong_first"] + x["missed"] + x["wrong_onsets"] for x in m)
            # lateness on the mixed tracks only: on a single-kind track the kind just crossed is
            # the next one's too, so a held kind reads as an early onset there
            late = float(m[1]["onset_error_cm"]["mean"])
            choice[f"{n}{'/via_none' if via else ''}"] = {
                "steps": n, "via_none": bool(via), "wrong": bad, "onset_error_cm_mean": late}
            print(f"debounce {n}{', via none' if via else ''}: {bad} wrong switches (a third kind "
                  f"first, a wrong kind named, missed), mean onset error {late:+.1f} cm")
    ok = ([c for c in choice.values() if c["onset_error_cm_mean"] >= -cfg.choice_max_late_cm]
          or list(choice.values()))
    best = min(ok, key=lambda c: (c["wrong"], c["steps"], not c["via_none"]))
    cfg.debounce_steps, cfg.debounce_via_none = best["steps"], best["via_none"]
    print(f"debounce: {cfg.debounce_steps} control steps"
          f"{', a new kind only after none' if cfg.debounce_via_none else ''}")
    return choice


def train_and_report(a, cfg, n_envs: int, e2e: pathlib.Path) -> int:
    """`detector`: trains the detector on `n_envs` episodes per kind (`e2e` crosses the mixed
    validation tracks), writes it to `a.out` and its report to `a.results`; `a`: the flags."""
    sets, data_s = _data(a, cfg, n_envs, e2e)
    train, val, mixed = (sets[s] for s in SETS)
    ts = time.time()
    params, hist = det.train(train, val, cfg)
    train_s = time.time() - ts
    rows = det.row_m()
    pred = {name: det.predict(params, d["profile"], d["yaw"], rows, cfg) for name, d in
            (("val_single", val), ("val_mixed", mixed))}
    choice = _choose_filter(val, mixed, pred, cfg)
    metrics = {}
    for name, d in (("val_single", val), ("val_mixed", mixed)):
        kind, dist = pred[name]
        metrics[f"{name}/learned, per step"] = report.detector_metrics(d, kind, dist)
        metrics[f"{name}/learned"] = report.detector_metrics(
            d, report.debounce(d, kind, cfg.debounce_steps, cfg.debounce_via_none), dist)
        metrics[f"{name}/hand_rule"] = report.detector_metrics(
            d, *det.hand_rule(d["profile"], d["yaw"], rows, cfg))
    meta = {"config": cfg.to_dict(), "history": hist, "debounce_choice": choice,
            "data": {"train_steps": int(len(train["kind"])), "val_steps": int(len(val["kind"])),
                     "mixed_steps": int(len(mixed["kind"])), "episodes_per_kind": n_envs,
                     "track_seed": DETECTOR_TRACK_SEED, "e2e": str(e2e)},
            "cost_s": {"data": round(data_s, 1), "train": round(train_s, 1)},
            "metrics": metrics, "device": str(jax.devices()[0])}
    out = det.save(pathlib.Path(a.out), params, meta)
    res = pathlib.Path(a.results)
    res.mkdir(parents=True, exist_ok=True)
    md = report.detector_markdown(meta)
    (res / "detector.json").write_text(json.dumps(meta, indent=1, default=float))
    (res / "detector.md").write_text(md + "\n")
    kind, dist = pred["val_mixed"]
    report.plot_trial(mixed, report.debounce(mixed, kind, cfg.debounce_steps,
                                             cfg.debounce_via_none), dist, 0,
                      res / "detector_trial.png")
    print(md)
    print(f"detector: {out}; report: {res}/detector.md; data {data_s:.0f} s, training "
          f"{train_s:.0f} s on {jax.devices()[0]}")
    return 0

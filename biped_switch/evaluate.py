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
Policies load from `<runs>/<policy>_<init>/checkpoints/<latest>` (or models/policies/).

    python -m biped_switch.evaluate multi [--trials 2500] [--methods random detection ...]

`multi` (Table II): every method on the same `mixed` tracks (7 artifacts, no kind twice in a
row, >= 0.9 m of flat before each; trial i uses track i and rng seed + batch start), each trial
starting with the walk policy; the methods differ only in when they switch (switching.py). The
stand-init suite is used for every method but `estimator_no_overlap`, which uses the random-init
policies and their estimators and starts from random joints with no pause, as they were trained.
Every env runs on the physics `--backend`, with the env overrides its policy suite was trained with.
Reports % distance, % success and % of trials failing on gaps / jumps / stairs, with 95% CIs;
saves Markdown, CSV and JSON under experiments/results/table2/, plus the paper's Fig. 5 (one
trial of the estimator method over time) as fig5_trial<i>.png.
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
import warnings

import jax
import numpy as np

from biped_switch import env as env_lib
from biped_switch import train as train_lib
from biped_switch.model import MODELS_DIR
from biped_switch.rollout import rollout

PAPER_TABLE1 = {  # % total distance, % success: stand init / random init (Tidd et al., Table I)
    "jumps": (93.1, 87.8, 86.2, 77.5),
    "gaps": (76.0, 56.3, 87.4, 75.5),
    "stairs": (71.4, 52.1, 78.7, 59.0),
}

BACKEND_CHOICES = ("auto",) + env_lib.BACKENDS
BACKEND_HELP = "physics backend (auto: mujoco on a CPU, mjx on an accelerator)"


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
    kinds = ("jumps", "gaps", "stairs")
    return {"n": n, "distance_pct": d, "distance_ci": [d_lo, d_hi],
            "success_pct": 100.0 * succ.mean(), "success_ci": [100 * s_lo, 100 * s_hi],
            "fell_pct": 100.0 * float((np.asarray(result["fell"]) > 0.5).mean()),
            "fail_on": {k: 100.0 * float((fail == i).mean()) for i, k in enumerate(kinds)},
            "fail_ci": {k: [100 * v for v in wilson_ci(float((fail == i).sum()), n)]
                        for i, k in enumerate(kinds)}}


def find_policy(policy: str, init: str, runs: pathlib.Path) -> pathlib.Path | None:
    for base in (runs, POLICY_DIR):
        ckpt = train_lib.latest_checkpoint(base / f"{policy}_{init}")
        if ckpt is not None:
            return ckpt
    return None


HORIZON_SPEED_MPS = 0.6  # Table I's acceptance speed: the derived horizon lets a walker this
HORIZON_MARGIN = 1.2  # fast finish the longest track with this margin on the walking time


def single_horizon_s(finish_m: float, pause_s: float, speed_mps: float = HORIZON_SPEED_MPS,
                     margin: float = HORIZON_MARGIN) -> float:
    """Episode time limit [s] of Table I: the standing pause, then `margin` times the time to walk
    to the farthest finish line `finish_m` [m] (the episode starts near x = 0) at `speed_mps`."""
    return float(np.ceil(pause_s + margin * finish_m / speed_mps))


def speed_table(result: dict, dt_s: float, pause_s: float) -> dict:
    """Mean forward speed [m/s] over episodes (with its 95% CI): distance / time alive after the
    standing pause (`speed_mps`, the policy's own speed), also over successful episodes only, and
    distance / time alive with the pause (`speed_alive_mps`)."""
    dist = np.asarray(result["distance_m"], float)
    alive_s = np.asarray(result["length"], float) * dt_s
    walking = np.maximum(alive_s - pause_s, dt_s)
    speed = dist / walking
    succ = np.asarray(result["success"]) > 0.5
    m, lo, hi = mean_ci(speed)
    return {"speed_mps": m, "speed_ci": [lo, hi],
            "speed_success_mps": float(speed[succ].mean()) if succ.any() else math.nan,
            "speed_alive_mps": float(np.mean(dist / np.maximum(alive_s, dt_s)))}


def evaluate_single(policy: str, init: str, ckpt: pathlib.Path, trials: int, seed: int,
                    horizon_s: float | None, batch: int, backend: str = "auto",
                    track_seed: int | None = None) -> dict:
    """Table I row: `trials` episodes of `policy` on its own terrain kind, trial i on track
    `track_seed + i` (default EVAL_TRACK_SEED: tracks training never saw), in an env made with
    the env overrides the policy was trained with. `horizon_s` None: `single_horizon_s` of the
    farthest finish line of these tracks."""
    track_seed = EVAL_TRACK_SEED if track_seed is None else int(track_seed)
    # difficulty 1, no guides, no pushes (the config's defaults)
    env = env_lib.make_env(policy, init, n_tracks=trials, seed=track_seed, backend=backend,
                           **train_lib.policy_env_overrides(ckpt))
    act, progress = train_lib.load_policy(ckpt, env)
    finish = jax.vmap(lambda i: env.track_arrays(i, env.cfg.difficulty)[4])(
        jax.numpy.arange(env.bank.size))
    finish_m = float(jax.numpy.max(finish))
    pause_s = float(env.cfg.pause_s) if init == "stand" else 0.0
    if horizon_s is None:
        horizon_s = single_horizon_s(finish_m, pause_s)
        horizon_from = (f"derived: {pause_s:g} s pause + {HORIZON_MARGIN:g} x farthest finish "
                        f"{finish_m:.1f} m / {HORIZON_SPEED_MPS:g} m/s")
    else:
        horizon_from = "--horizon-s"
    run = jax.jit(functools.partial(rollout, env, act, n_envs=batch,
                                    horizon=int(round(horizon_s / env.dt))))
    results = []
    for start in range(0, trials, batch):
        ids = jax.numpy.arange(start, start + batch) % trials
        results.append(jax.device_get(run(jax.random.PRNGKey(seed + start), track_ids=ids)))
    merged = {k: np.concatenate([r[k] for r in results])[:trials] for k in results[0]}
    out = episode_table(merged)
    out.update(speed_table(merged, env.dt, pause_s))
    out.update(policy=policy, init=init, checkpoint=str(ckpt), train_step=progress["step"],
               curriculum=progress["curriculum"], backend=env.backend, track_seed=track_seed,
               env_overrides=train_lib.policy_env_overrides(ckpt), horizon_s=horizon_s,
               horizon_from=horizon_from, finish_m_max=finish_m,
               timed_out_pct=100.0 * float((np.asarray(merged["done"]) < 0.5).mean()))
    return out


def _dist_success_cells(r: dict) -> str:
    """The "% distance (CI) | % success (CI)" cells of a Table I or II row."""
    return f"{_pct_ci(r['distance_pct'], r['distance_ci'])} | {_pct_ci(r['success_pct'], r['success_ci'])}"


def _pct_ci(v: float, ci) -> str:
    return f"{v:.1f} ({ci[0]:.1f}-{ci[1]:.1f})"


def table1_markdown(rows: list[dict]) -> str:
    lines = ["| policy | init | trials | % total dist. (95% CI) | % success (95% CI) | paper dist. | "
             "paper success | trained steps | curriculum | speed m/s (95% CI) | horizon s | "
             "track seed | backend |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        paper = PAPER_TABLE1.get(r["policy"])
        pd, ps = ((paper[0], paper[1]) if r["init"] == "stand" else (paper[2], paper[3])) if paper \
            else ("-", "-")
        c = r["curriculum"]
        speed = (f"{r['speed_mps']:.2f} ({r['speed_ci'][0]:.2f}-{r['speed_ci'][1]:.2f})"
                 if "speed_mps" in r else "-")
        horizon = f"{r['horizon_s']:g}" if r.get("horizon_s") is not None else "-"
        lines.append(
            f"| {r['policy']} | {r['init']} | {r['n']} | {_dist_success_cells(r)} | {pd} | {ps} | "
            f"{r['train_step']:,} | {c['stage_name']} d={c['difficulty']:.1f} g={c['guide_scale']:.1f} | "
            f"{speed} | {horizon} | {r.get('track_seed', '-')} | {r.get('backend', '-')} |")
    return "\n".join(lines)


EVAL_TRACK_SEED = 10_000  # evaluation tracks never overlap training tracks (seeds 0..n_tracks-1)
MULTI_TRACK_SEED = 30_000  # Table II tracks (sweeps use 20,000..)

PAPER_TABLE2 = {  # % total dist., % success, % gap / jump / stair fail (Tidd et al., Table II)
    "random": (42.7, 10.1, 70.6, 11.6, 7.6),
    "detection": (75.6, 60.1, 21.4, 3.3, 15.2),
    "lookup": (76.3, 59.0, 21.2, 4.7, 14.9),
    "com_over_feet": (79.1, 66.8, 17.6, 2.7, 12.9),
    "estimator": (82.4, 71.4, 16.7, 2.4, 9.4),
    "estimator_no_overlap": (17.5, 0.7, 58.6, 12.9, 27.7),
    "dqn": (83.2, 72.4, 15.1, 3.7, 8.8),
    "end_to_end": (92.7, 90.2, 4.2, 1.8, 3.7),
}
SWITCH_METHODS = ("random", "detection", "lookup", "com_over_feet", "estimator",
                  "estimator_no_overlap")
BASELINES = ("dqn", "end_to_end")  # trained on the whole mixed domain (issue 5)
MULTI_METHODS = SWITCH_METHODS + BASELINES
POLICY_DIR = MODELS_DIR / "policies"  # committed trained policies, searched after <runs>/
BASELINE_DIR = MODELS_DIR / "baselines"  # committed DQN runs, as models/policies/ for PPO


def find_dqn(runs, init: str = "stand", dqn_dir=None) -> pathlib.Path | None:
    """The DQN run directory with a checkpoint: `dqn_dir` if given, else <runs>/dqn_<init>, then
    models/baselines/dqn_<init> (find_policy's search, for the selector)."""
    dirs = [dqn_dir] if dqn_dir else [pathlib.Path(runs) / f"dqn_{init}", BASELINE_DIR / f"dqn_{init}"]
    return next((pathlib.Path(d) for d in dirs
                 if train_lib.latest_checkpoint(pathlib.Path(d)) is not None), None)


def available_methods(methods, runs, est_dir, lookup_dir, dqn_dir=None,
                      stand_in: str | None = None) -> tuple[list, list]:
    """(methods whose trained parts exist, ["method: what is missing", ...])."""
    from biped_switch import terrain

    runs, ok, skipped = pathlib.Path(runs), [], []
    for m in methods:
        init = "random" if m == "estimator_no_overlap" else "stand"
        first = stand_in or "walk"
        if m == "end_to_end":
            if find_policy("mixed", "stand", runs) is None:
                skipped.append(f"{m}: no end-to-end policy (python -m biped_switch.train --policy mixed)")
                continue
        elif find_policy("walk", init, runs) is None and find_policy(first, init, runs) is None:
            skipped.append(f"{m}: no {init}-init walk policy under {runs}/ or models/policies/")
            continue
        if m.startswith("estimator") and not all(
                (pathlib.Path(est_dir) / f"{init}_{k}").exists() for k in terrain.ARTIFACT_KINDS):
            skipped.append(f"{m}: no {init}-init estimators in {est_dir} (make train-estimators)")
            continue
        if m == "lookup" and not (pathlib.Path(lookup_dir) / "lookup_stand.json").exists():
            skipped.append(f"{m}: no lookup table in {lookup_dir} (python -m biped_switch.sweep)")
            continue
        if m == "dqn" and find_dqn(runs, "stand", dqn_dir) is None:
            skipped.append(f"{m}: no DQN checkpoint in {dqn_dir or f'{runs}/dqn_stand'} or "
                           f"{BASELINE_DIR}/ (make train-dqn)")
            continue
        ok.append(m)
    return ok, skipped


def _run_batches(run, trials: int, batch: int, seed: int) -> dict:
    """`run(rng, track_ids)` over trials in batches; trial i is track i, rng = seed + batch start."""
    results = []
    for start in range(0, trials, batch):
        ids = jax.numpy.arange(start, start + batch, dtype=jax.numpy.int32) % trials
        results.append(jax.device_get(run(jax.random.PRNGKey(seed + start), ids)))
    return {k: np.concatenate([r[k] for r in results])[:trials] for k in results[0]}


def _multi_terrain_cfg(n_artifacts: int):
    from biped_switch.config import default_terrain_config

    tcfg = default_terrain_config()
    tcfg.n_artifacts = int(n_artifacts)
    return tcfg


def multi_env(init: str, trials: int, n_artifacts: int = 7, **overrides):
    """Table II's env: `mixed` tracks MULTI_TRACK_SEED + i (trial i), `n_artifacts` per track;
    `overrides` (env config: the physics `backend`, the suite's action mode and phase clock, ...)
    go to `env.make_env`."""
    return env_lib.make_env("mixed", init, terrain_cfg=_multi_terrain_cfg(n_artifacts),
                            n_tracks=trials, seed=MULTI_TRACK_SEED, **overrides)


def mixed_track(seed: int, n_artifacts: int = 7):
    """The terrain.Track of seed `seed` as multi_env lays it out (trial i: MULTI_TRACK_SEED + i)."""
    from biped_switch import terrain

    return terrain.generate_track(int(seed), "mixed", 1.0, _multi_terrain_cfg(n_artifacts))


def trial_track(setup, trial: int):
    """The terrain.Track of a trial of `setup` (for plots)."""
    return mixed_track(MULTI_TRACK_SEED + trial, setup.env.terrain_cfg.n_artifacts)


def _estimators(init: str, model_dir: str):
    from biped_switch import estimator as est_lib

    params, metas = est_lib.load_estimator_set(init, model_dir)
    return est_lib.predict, params, metas


class MultiSetup:
    """Env, policy suite, estimators and lookup table of one init mode, and its compiled rollout."""

    def __init__(self, init: str, trials: int, batch: int, horizon_s: float, runs, stand_in,
                 est_dir, lookup_dir, need_estimators: bool, need_lookup: bool,
                 guide_scale: float = 0.0, n_artifacts: int = 7, backend: str = "auto"):
        from biped_switch import policies as pol
        from biped_switch import sweep
        from biped_switch import switching as sw

        self.init = init
        self.env = multi_env(init, trials, n_artifacts, backend=backend,
                             **pol.suite_env_overrides(init, runs, stand_in=stand_in))
        self.suite = pol.load_suite(init, self.env, runs, stand_in=stand_in)
        self.est_apply, self.est_params, self.est_meta = None, None, None
        if need_estimators:
            self.est_apply, self.est_params, self.est_meta = _estimators(init, est_dir)
        self.lookup_m = sweep.load_lookup(init, lookup_dir) if need_lookup else None
        self.horizon = int(round(horizon_s / self.env.dt))
        from biped_switch.rollout import over_devices

        env, apply, est_apply, horizon = self.env, self.suite.apply, self.est_apply, self.horizon

        def one(suite_params, est_params, rules, rng, ids):
            return sw.multi_rollout(env, apply, suite_params, est_apply, est_params, rules, rng,
                                    ids.shape[0], horizon, track_ids=ids, guide_scale=guide_scale)

        self.run = over_devices(one, n_shared=3)
        self.batch = batch
        self.guide_scale = guide_scale

    def evaluate(self, method: str, trials: int, seed: int) -> dict:
        from biped_switch import switching as sw

        rules = sw.make_rules(method, lookup_m=self.lookup_m)
        return _run_batches(lambda rng, ids: self.run(self.suite.params, self.est_params, rules,
                                                      rng, ids), trials, self.batch, seed)


class BaselineSetup:
    """The DQN selector or the end-to-end policy on MultiSetup's tracks, seeds and horizon.

    Both run `dqn.dqn_rollout` (same resets, chunks, early stop and frozen metrics as
    `switching.multi_rollout`); the end-to-end policy is a one-policy suite whose "selector"
    always picks it."""

    def __init__(self, method: str, trials: int, batch: int, horizon_s: float, runs, stand_in,
                 dqn_dir=None, guide_scale: float = 0.0, n_artifacts: int = 7,
                 backend: str = "auto"):
        from biped_switch import dqn as dqn_lib
        from biped_switch import policies as pol
        from biped_switch.rollout import over_devices

        if method not in BASELINES:
            raise ValueError(f"unknown baseline {method!r}; expected one of {BASELINES}")
        if method == "dqn":
            run_dir = find_dqn(runs, "stand", dqn_dir)
            if run_dir is None:
                raise FileNotFoundError(f"no stand-init DQN checkpoint under {dqn_dir or runs}/ or "
                                        f"{BASELINE_DIR}/ (make train-dqn)")
            self.env = multi_env("stand", trials, n_artifacts, detector_one_hot=True,
                                 backend=backend,
                                 **pol.suite_env_overrides("stand", runs, stand_in=stand_in))
            self.suite = pol.load_suite("stand", self.env, runs, stand_in=stand_in)
            q_apply, self.q_params = dqn_lib.load_dqn(run_dir, dqn_lib.q_input_size(self.env))
            ckpt = train_lib.latest_checkpoint(run_dir)
            self.sources = self.suite.sources + (f"selector: {ckpt}",)
            trained_with = json.loads((ckpt / "progress.json").read_text()).get("policies")
            if trained_with is not None and list(trained_with) != list(self.suite.sources):
                # a selector's Q-values are only meaningful for the policies it chose among
                warnings.warn(f"the DQN selector {ckpt} was trained with the policies {trained_with}, "
                              f"not the ones evaluated now {list(self.suite.sources)}; retrain it "
                              f"(make train-dqn) for a Table II row", stacklevel=2)
                self.sources += (f"MISMATCH: selector trained with {trained_with}",)
        else:
            self.env = multi_env("stand", trials, n_artifacts, backend=backend,
                                 **pol.suite_env_overrides("stand", runs, names=("mixed",)))
            self.suite = pol.load_suite("stand", self.env, runs, names=("mixed",))
            self.q_params = jax.numpy.zeros(())

            def q_apply(_, x):  # the only policy of the suite, always
                return jax.numpy.zeros(x.shape[:-1] + (1,))
            self.sources = self.suite.sources
        env, apply, horizon = self.env, self.suite.apply, int(round(horizon_s / self.env.dt))

        def one(suite_params, q_params, rng, ids):
            return dqn_lib.dqn_rollout(env, apply, suite_params, q_apply, q_params, rng,
                                       ids.shape[0], horizon, track_ids=ids, guide_scale=guide_scale)

        self.run = over_devices(one, n_shared=2)
        self.batch = batch

    def evaluate(self, trials: int, seed: int) -> dict:
        return _run_batches(lambda rng, ids: self.run(self.suite.params, self.q_params, rng, ids),
                            trials, self.batch, seed)


def evaluate_multi(methods, trials: int, batch: int, horizon_s: float, seed: int, runs,
                   stand_in=None, est_dir="models/estimators", lookup_dir="experiments/results/lookup",
                   print_fn=print, guide_scale: float = 0.0, dqn_dir=None,
                   n_artifacts: int = 7, backend: str = "auto") -> tuple[list, dict]:
    """Table II rows (dicts) for `methods`, and the setup used per init mode ("stand", "random")
    and per baseline ("dqn", "end_to_end"), every env on the physics `backend` with its policies'
    env overrides. `wall_s` of a row includes its setup and compiles."""
    setups, rows = {}, []
    for method in methods:
        t0 = time.perf_counter()
        init = "random" if method == "estimator_no_overlap" else "stand"
        if method in BASELINES:
            setups[method] = BaselineSetup(method, trials, batch, horizon_s, runs, stand_in, dqn_dir,
                                           guide_scale, n_artifacts, backend)
            merged, sources = setups[method].evaluate(trials, seed), setups[method].sources
        else:
            if init not in setups:
                need_est = ("estimator_no_overlap" if init == "random" else "estimator") in methods
                setups[init] = MultiSetup(init, trials, batch, horizon_s, runs, stand_in, est_dir,
                                          lookup_dir, need_est,
                                          "lookup" in methods and init == "stand", guide_scale,
                                          n_artifacts, backend)
            rule = "estimator" if method == "estimator_no_overlap" else method
            merged, sources = setups[init].evaluate(rule, trials, seed), setups[init].suite.sources
        row = episode_table(merged)
        env = setups[method if method in BASELINES else init].env
        row.update(method=method, init=init, wall_s=time.perf_counter() - t0,
                   switches_per_trial=float(np.mean(merged["n_switches"])),
                   policies=list(sources), backend=env.backend)
        rows.append(row)
        print_fn(f"  {method:22s} distance {row['distance_pct']:5.1f}%  success {row['success_pct']:5.1f}%"
                 f"  ({row['wall_s']:.0f} s)")
    return rows, setups


def table2_markdown(rows: list[dict]) -> str:
    lines = ["| method | trials | % total dist. (95% CI) | % success (95% CI) | % gap fail (CI) | "
             "% jump fail (CI) | % stair fail (CI) | paper (dist. / success / gap / jump / stair) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        paper = PAPER_TABLE2.get(r["method"])
        f = r["fail_on"]
        lines.append(
            f"| {r['method']} | {r['n']} | {_dist_success_cells(r)} | "
            + " | ".join(_pct_ci(f[k], r["fail_ci"][k]) for k in ("gaps", "jumps", "stairs")) + " | "
            + (" / ".join(f"{v}" for v in paper) if paper else "-") + " |")
    return "\n".join(lines)


def trace_trial(setup: "MultiSetup", method: str, trial: int, seed: int) -> dict:
    """Per-step record of trial `trial` (Fig. 5). A stand-init reset on a given track uses no
    randomness, so this is the trial of the table; a random-init trace draws its own start joints
    (key seed + trial), and the `random` rule its own distances."""
    from biped_switch import switching as sw

    rules = sw.make_rules(method, lookup_m=setup.lookup_m)
    f = jax.jit(functools.partial(sw.trace_rollout, setup.env, setup.suite.apply,
                                  est_apply=setup.est_apply, horizon=setup.horizon,
                                  guide_scale=setup.guide_scale))
    rec = jax.device_get(f(suite_params=setup.suite.params, est_params=setup.est_params,
                           rules=rules, rng=jax.random.PRNGKey(seed + trial), track_id=trial))
    return {k: np.asarray(v) for k, v in rec.items()}


def trial_length(rec: dict) -> int:
    live = np.flatnonzero(np.asarray(rec["ended"]) < 0.5)
    return int(live[-1]) + 1 if len(live) else 1


def trial_outcome(rec: dict) -> str:
    n = trial_length(rec)
    if rec["success"][:n].max() > 0.5:
        return "success"
    return "fell" if rec["fell"][:n].max() > 0.5 else "time limit"


def fig5_figure(rec: dict, track, title: str = "", threshold: float | None = None):
    """The paper's Fig. 5 (one drawing for the CLI, the demo and the notebook): estimator outputs
    while an artifact is detected (green lines: detections, red: switches), the active policy, and
    the terrain under the CoM with foot and CoM heights, the periods with the CoM over the feet
    shaded."""
    import matplotlib.pyplot as plt

    from biped_switch.config import default_switching_config
    from biped_switch.policies import POLICY_NAMES
    from biped_switch.terrain import ARTIFACT_KINDS

    if threshold is None:  # the estimator rule's E >= threshold
        threshold = float(default_switching_config().estimator_threshold)

    n = trial_length(rec)
    t = np.arange(n)
    kind = rec["det_kind"][:n].astype(int)
    fig, (ax0, axp, ax1) = plt.subplots(3, 1, figsize=(13, 7.5), sharex=True,
                                        gridspec_kw={"height_ratios": [3, 0.6, 3]})
    colours = {"walk": "tab:blue", "jumps": "tab:orange", "gaps": "tab:purple", "stairs": "tab:brown"}
    for k, name in enumerate(ARTIFACT_KINDS):
        p = rec["est_probs"][:n, k]
        ax0.plot(t, p, color=colours[name], lw=0.5, alpha=0.25)
        ax0.plot(t, np.where(kind == k, p, np.nan), color=colours[name], lw=1.5, label=f"E_{name}")
    new_det = np.flatnonzero((kind >= 0) & (np.r_[-1, kind[:-1]] != kind))
    switches = np.flatnonzero(rec["switched"][:n] > 0.5)
    for ax in (ax0, axp, ax1):
        for i in new_det:
            ax.axvline(i, color="g", lw=1)
        for i in switches:
            ax.axvline(i, color="r", lw=1)
    ax0.axhline(threshold, color="k", ls=":", lw=0.8, label=f"threshold {threshold:g}")
    ax0.set_ylabel("switch estimate E_i(s)")
    ax0.set_ylim(-0.02, 1.02)
    ax0.legend(fontsize=8, loc="lower right", ncol=4)
    ax0.set_title("thick: the detected artifact's estimator; faint: every estimator at every step",
                  fontsize=8)
    # active policy strip
    active = rec["active"][:n].astype(int)
    for j, name in enumerate(POLICY_NAMES):
        on = active == j
        if on.any():
            axp.fill_between(t, 0, 1, where=on, step="mid", color=colours[name], alpha=0.7,
                             label=name, lw=0)
    axp.set_yticks([])
    axp.set_ylabel("active", fontsize=8)
    axp.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    # terrain under the CoM, feet and CoM heights
    boxes = track.boxes
    x = rec["com_x_m"][:n]
    lo, hi = boxes[:, 0] - boxes[:, 3], boxes[:, 0] + boxes[:, 3]
    top = boxes[:, 2] + boxes[:, 5]
    ground = np.array([np.max(np.where((lo <= xi) & (xi <= hi), top, -1.0)) for xi in x])
    com_z = rec["body_com"][:n, 2]
    ymin = min(-0.8, float(ground.min()) - 0.1)
    ok = rec["com_ok"][:n] > 0.5
    ax1.fill_between(t, ymin, com_z.max() + 0.2, where=ok, step="mid", color="gold", alpha=0.25,
                     lw=0, label="CoM over feet")
    ax1.fill_between(t, ymin, ground, color="pink", step="mid", label="terrain under the CoM")
    soles_z = rec["soles"][:n, :, 2]
    ax1.plot(t, soles_z[:, :4].mean(1), color="tab:blue", lw=1, label="left foot")
    ax1.plot(t, soles_z[:, 4:].mean(1), color="tab:green", lw=1, label="right foot")
    ax1.plot(t, np.where(ok, com_z, np.nan), "r.", ms=2, label="CoM (over feet)")
    ax1.plot(t, com_z, color="r", lw=0.3)
    ax1.set_ylim(ymin, com_z.max() + 0.2)
    ax1.set_ylabel("height [m]")
    ax1.set_xlabel("control step (20 ms)")
    ax1.legend(fontsize=8, loc="upper right", ncol=5)
    dt = float(np.median(np.diff(rec["time_s"][:n]))) if n > 1 else 0.02
    sec = ax0.secondary_xaxis("top", functions=(lambda s: s * dt, lambda s: s / max(dt, 1e-9)))
    sec.set_xlabel("time [s]", fontsize=8)
    fig.suptitle(f"{title} ({trial_outcome(rec)})", fontsize=9)
    fig.tight_layout()
    return fig


def plot_trial(rec: dict, track, path: pathlib.Path, title: str = "", threshold: float | None = None) -> None:
    """Fig. 5 (`fig5_figure`) saved as a PNG, off screen."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = fig5_figure(rec, track, title, threshold)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.evaluate", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("single", help="Table I: each policy on its own terrain kind")
    s.add_argument("--policies", nargs="+", default=["jumps", "gaps", "stairs"],
                   choices=train_lib.POLICIES)
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
    s.add_argument("--backend", default="auto", choices=BACKEND_CHOICES, help=BACKEND_HELP)
    s.add_argument("--runs", default="runs")
    s.add_argument("--out", default="experiments/results/table1")
    m = sub.add_parser("multi", help="Table II: switching methods on multi-artifact tracks")
    m.add_argument("--methods", nargs="+", default=list(MULTI_METHODS), choices=MULTI_METHODS)
    m.add_argument("--trials", type=int, default=2500)
    m.add_argument("--batch", type=int, default=250, help="episodes per jitted rollout")
    m.add_argument("--horizon-s", type=float, default=60.0, help="episode time limit [s]")
    m.add_argument("--n-artifacts", type=int, default=7, help="artifacts per track (paper: 7)")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--runs", default="runs")
    m.add_argument("--estimators", default="models/estimators")
    m.add_argument("--lookup", default="experiments/results/lookup")
    m.add_argument("--dqn", default=None,
                   help=f"DQN run directory (default: RUNS/dqn_stand, then {BASELINE_DIR}/dqn_stand)")
    m.add_argument("--stand-in", default=None, choices=train_lib.POLICIES,
                   help="use this policy for any that is not trained yet (pipeline checks only)")
    m.add_argument("--guide-scale", type=float, default=0.0,
                   help="scripted guide forces on (pipeline checks with untrained policies only)")
    m.add_argument("--fig5-trial", type=int, default=0, help="trial drawn as Fig. 5 (-1: none)")
    m.add_argument("--backend", default="auto", choices=BACKEND_CHOICES, help=BACKEND_HELP)
    m.add_argument("--out", default="experiments/results/table2")
    r = sub.add_parser("retrain-cost", help="Table III: hours to add a new terrain, from logs")
    r.add_argument("--runs", default="runs")
    r.add_argument("--results", default="experiments/results")
    r.add_argument("--init", default="stand", choices=env_lib.INITS)
    r.add_argument("--out", default="experiments/results/table3")
    a = p.parse_args(argv)
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
    out = _write_table(a.out, "table1", table1_markdown(rows),
                       ["policy", "init", "trials", "checkpoint", "train_step", "speed_mps",
                        "speed_lo", "speed_hi", "horizon_s", "track_seed", "backend"],
                       [[r["policy"], r["init"], r["n"], r["checkpoint"], r["train_step"],
                         r["speed_mps"], *r["speed_ci"], r["horizon_s"], r["track_seed"],
                         r["backend"]] for r in rows],
                       rows)
    (out / "table1.json").write_text(json.dumps(
        {"settings": vars(a), "rows": rows, "track_seed": a.track_seed,
         "backend": sorted({r["backend"] for r in rows}),
         "horizon_s": {f"{r['policy']}_{r['init']}": r["horizon_s"] for r in rows},
         "speed_note": "speed_mps: distance / time alive after the standing pause, mean over "
                       "episodes; speed_alive_mps: the same with the pause"},
        indent=2, default=str))
    return 0


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


PAPER_TABLE3_H = {"ours": 20.0, "dqn": 25.0, "end_to_end": 34.0}  # hours, CPU (Tidd et al.)


def run_notes(run_dir) -> list[str]:
    """Why a training run (PPO or DQN) is not a finished, real one; [] when nothing says so.

    It lies in a pipeline_check folder; its latest checkpoint is short of the step goal
    (progress.json's total_steps / total_env_steps, else config.json's); its curriculum is
    unfinished (guide forces on or difficulty below 1: progress.json's, else the last logged in
    metrics.csv, for folders of copied logs); a DQN selector chose among stand-in policies."""
    d = pathlib.Path(run_dir)
    notes = ["is a pipeline check"] if "pipeline_check" in d.resolve().parts else []
    ck = train_lib.latest_checkpoint(d)
    prog = json.loads((ck / "progress.json").read_text()) if ck else {}
    cfg = json.loads((d / "config.json").read_text()) if (d / "config.json").is_file() else {}
    total = next((v for v in (prog.get("total_steps"), prog.get("total_env_steps"),
                              cfg.get("total_timesteps"), cfg.get("total_env_steps")) if v), None)
    if "step" in prog and total is not None and int(prog["step"]) < int(total):
        notes.append(f"at step {int(prog['step']):,} of {int(total):,}")
    c = prog.get("curriculum")
    if c is None and (d / "metrics.csv").is_file():
        rows = list(csv.DictReader((d / "metrics.csv").open()))
        last = {k: train_lib.curve_series(rows, k)[-1:, 1] for k in ("difficulty", "guide_scale")}
        if all(len(v) for v in last.values()):
            c = {"stage_name": "last logged", **{k: float(v[0]) for k, v in last.items()}}
    if c is not None and (c["guide_scale"] > 1e-6 or c["difficulty"] < 1 - 1e-6):
        notes.append(f"curriculum unfinished ({c['stage_name']} d={c['difficulty']:.1f} "
                     f"guide={c['guide_scale']:.1f})")
    elif "curriculum_done" in prog and not prog["curriculum_done"]:  # PPO runs since 2026-12-01
        notes.append(f"push stage unfinished (push={c['push_scale']:.1f})")
    stand_in = prog.get("stand_in") or any("stand-in" in str(p) for p in prog.get("policies") or ())
    if stand_in:
        notes.append(f"chose among stand-ins ({prog.get('stand_in') or 'see progress.json'})")
    return notes


def _run_record(ckpt: pathlib.Path | None) -> dict | None:
    """What a run's latest checkpoint recorded for Table III: wall time, device, step, and the
    reasons (`run_notes`, prefixed with the run's name) its hours are not those of a finished,
    real training run."""
    if ckpt is None:
        return None
    prog = json.loads((ckpt / "progress.json").read_text())
    run = ckpt.parent.parent
    return {"wall_s": float(prog["wall_s"]), "step": int(prog.get("step", 0)),
            "notes": [f"{run.name} {n}" for n in run_notes(run)],
            "device": f"{prog.get('device', '?')} x{prog.get('n_devices', 1)}"}


def retrain_cost(runs: pathlib.Path, results: pathlib.Path, init: str = "stand") -> dict:
    """Table III from recorded logs: hours to add a new terrain to a two-behaviour suite.

    ours: one new policy (the mean training wall time of the artifact policies) plus, for each
    of the three policies' switch estimators, its sweep and its training; DQN: the new policy
    plus retraining the selector (the paper's 25 h = 17 h policy + 8 h selector); end-to-end:
    retraining the single policy. A missing log leaves the row's total empty and says what is
    missing; a row built from unfinished, stand-in or pipeline-check runs says so in `status`."""
    rows, missing = [], []
    pol_r = {}
    for p in ("jumps", "gaps", "stairs"):
        r = _run_record(find_policy(p, init, runs))
        if r is None:
            missing.append(f"policy {p}_{init}")
        else:
            pol_r[p] = r
    policy_h = np.mean([v["wall_s"] for v in pol_r.values()]) / 3600 if pol_r else None
    pol_notes = [n for v in pol_r.values() for n in v["notes"]]
    sweep_h, est_h, data_notes = {}, {}, []
    lookup = results / "lookup" / f"lookup_{init}.json"
    lmeta = json.loads(lookup.read_text())["meta"] if lookup.exists() else {}
    sweeps = lmeta.get("sweeps", {})
    for k in ("jumps", "gaps", "stairs"):
        if k in sweeps:
            sweep_h[k] = sweeps[k]["wall_s"] / 3600
            if any("stand-in" in str(v) for v in lmeta.get("policies", {}).get(k, {}).values()):
                data_notes.append(f"sweep {k} ran stand-in policies")
        else:
            missing.append(f"sweep {init}/{k}")
        e = results / "estimators" / f"{init}_{k}.json"
        if e.exists():
            est_h[k] = json.loads(e.read_text())["metrics"]["train_s"] / 3600
        else:
            missing.append(f"estimator {init}_{k}")
    if "PIPELINE_CHECK" in lmeta:
        data_notes.append(f"lookup/sweeps: {lmeta['PIPELINE_CHECK']}")
    ours_parts = {"new policy": policy_h, **{f"sweep {k}": v for k, v in sweep_h.items()},
                  **{f"estimator {k}": v for k, v in est_h.items()}}
    ours_ok = policy_h is not None and len(sweep_h) == 3 and len(est_h) == 3
    devices = sorted({v["device"] for v in pol_r.values()})

    def status(notes, ok):
        return "not measured" if not ok else ("; ".join(notes) if notes else "complete")

    rows.append({"method": "ours", "hours": sum(ours_parts.values()) if ours_ok else None,
                 "parts": ours_parts, "device": ", ".join(devices) or "?",
                 "status": status(pol_notes + data_notes, ours_ok),
                 "paper_hours": PAPER_TABLE3_H["ours"]})
    dqn_dir = find_dqn(runs, init)
    dqn = _run_record(train_lib.latest_checkpoint(dqn_dir) if dqn_dir else None)
    if dqn is None:
        missing.append(f"DQN run dqn_{init}")
    dqn_ok = dqn is not None and policy_h is not None
    rows.append({"method": "dqn", "hours": policy_h + dqn["wall_s"] / 3600 if dqn_ok else None,
                 "parts": {"new policy": policy_h, "selector": dqn["wall_s"] / 3600 if dqn else None},
                 "device": dqn["device"] if dqn else "?",
                 "status": status(pol_notes + (dqn["notes"] if dqn else []), dqn_ok),
                 "paper_hours": PAPER_TABLE3_H["dqn"]})
    e2e = _run_record(find_policy("mixed", init, runs))
    if e2e is None:
        missing.append(f"end-to-end run mixed_{init}")
    rows.append({"method": "end_to_end", "hours": e2e["wall_s"] / 3600 if e2e else None,
                 "parts": {"policy": e2e["wall_s"] / 3600 if e2e else None},
                 "device": e2e["device"] if e2e else "?",
                 "status": status(e2e["notes"] if e2e else [], e2e is not None),
                 "paper_hours": PAPER_TABLE3_H["end_to_end"]})
    return {"rows": rows, "missing": missing, "init": init, "runs": str(runs), "results": str(results),
            "notes": "hours of wall-clock time read from progress.json / sweep and estimator logs"}


def table3_markdown(doc: dict) -> str:
    lines = ["| method | hours (ours) | parts [h] | device | status | paper [h, CPU] |",
             "|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        parts = ", ".join(f"{k} {v:.2f}" if v is not None else f"{k} -" for k, v in r["parts"].items())
        h = f"{r['hours']:.2f}" if r["hours"] is not None else "not measured"
        lines.append(f"| {r['method']} | {h} | {parts} | {r['device']} | {r.get('status', '?')} | "
                     f"{r['paper_hours']:.0f} |")
    if doc["missing"]:
        lines.append("")
        lines.append("missing logs: " + "; ".join(doc["missing"]))
    return "\n".join(lines)


def _main_multi(a, p) -> int:
    if a.trials < 1 or a.batch < 1 or a.n_artifacts < 1:
        p.error(f"--trials, --batch and --n-artifacts must be >= 1 (got {a.trials}, {a.batch}, "
                f"{a.n_artifacts})")
    batch = min(a.batch, a.trials)
    t0 = time.perf_counter()
    a.methods, skipped = available_methods(a.methods, a.runs, a.estimators, a.lookup, a.dqn,
                                           a.stand_in)
    for s in skipped:
        print(f"skipped {s}", file=sys.stderr)
    if not a.methods:
        print("evaluate multi: no method has its trained parts", file=sys.stderr)
        return 1
    print(f"Table II: {len(a.methods)} methods x {a.trials} trials of mixed tracks (batch {batch}, "
          f"{jax.local_device_count()} {jax.devices()[0].platform} device(s))", flush=True)
    rows, setups = evaluate_multi(a.methods, a.trials, batch, a.horizon_s, a.seed, a.runs,
                                  a.stand_in, a.estimators, a.lookup,
                                  print_fn=lambda *s: print(*s, flush=True), guide_scale=a.guide_scale,
                                  dqn_dir=a.dqn, n_artifacts=a.n_artifacts, backend=a.backend)
    out = _write_table(a.out, "table2", table2_markdown(rows),
                       ["method", "init", "trials"]
                       + [f"{k}_fail_{c}" for k in ("gap", "jump", "stair") for c in ("pct", "lo", "hi")]
                       + ["switches_per_trial", "wall_s"],
                       [[r["method"], r["init"], r["n"]]
                        + [v for k in ("gaps", "jumps", "stairs") for v in (r["fail_on"][k], *r["fail_ci"][k])]
                        + [r["switches_per_trial"], r["wall_s"]] for r in rows],
                       rows)
    wall = time.perf_counter() - t0
    (out / "table2.json").write_text(json.dumps(
        {"settings": vars(a), "rows": rows, "skipped": skipped, "wall_s": wall,
         "device": str(jax.devices()[0]), "backend": sorted({r["backend"] for r in rows}),
         "track_seed": MULTI_TRACK_SEED}, indent=2, default=str))
    if a.fig5_trial >= 0 and "stand" in setups and setups["stand"].est_apply is not None:
        s = setups["stand"]
        rec = trace_trial(s, "estimator", a.fig5_trial % a.trials, a.seed)
        track = trial_track(s, a.fig5_trial % a.trials)
        path = out / f"fig5_trial{a.fig5_trial}.png"
        plot_trial(rec, track, path, f"estimator switching, trial {a.fig5_trial}")
        np.savez_compressed(out / f"fig5_trial{a.fig5_trial}.npz", **rec,
                            track_seed=MULTI_TRACK_SEED + a.fig5_trial % a.trials,
                            n_artifacts=a.n_artifacts)
        print(f"wrote {path}")
    print(json.dumps({"table2_wall_s": round(wall, 1), "trials": a.trials,
                      "methods": len(a.methods)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Table II: the switching methods and the baselines on multi-artifact tracks (`evaluate multi`).

Every method runs on the same `mixed` tracks (7 artifacts by default, no kind twice in a row,
>= 0.9 m of flat before each; trial i on track config.MULTI_TRACK_SEED + i with rng seed + batch
start), each trial starting with the walk policy; the switching methods differ only in when they
switch (switching.py). The stand-init suite is used for every method but `estimator_no_overlap`,
which uses the random-init policies and their estimators and starts from random joints with no
pause, as they were trained. The baselines (the DQN selector, the end-to-end policy) run the same
tracks, seeds and horizon (`BaselineSetup`). Every env runs on the chosen physics backend, with the
env overrides its policy suite was trained with. A row reports % distance, % success and % of
trials failing on gaps / jumps / stairs, with 95% CIs (stats.py).
"""

from __future__ import annotations

import math
import pathlib
import time
import warnings
from typing import Sequence

import jax
import numpy as np

from biped_switch import dqn as dqn_lib
from biped_switch import env as env_lib
from biped_switch import estimator as est_lib
from biped_switch import paper
from biped_switch import policies as pol
from biped_switch import provenance as prov
from biped_switch import runs as runs_lib
from biped_switch import sweep
from biped_switch import switching as sw
from biped_switch import terrain
from biped_switch.config import MULTI_TRACK_SEED, default_env_config, default_terrain_config
from biped_switch.rollout import over_devices
from biped_switch.stats import dist_success_cells, episode_table, join_rows, pct_ci, pct_ci_cell

SWITCH_METHODS = ("random", "detection", "lookup", "com_over_feet", "estimator",
                  "estimator_no_overlap")
BASELINES = ("dqn", "end_to_end")  # trained on the whole mixed domain (issue 5)
# Ours, beyond the paper: lookup table and estimators from the context sweeps (`sweep --context`),
# whose switches come after the source policy's own artifact, as on these tracks.
# `estimator_context_persist` also asks for the estimate to hold for PERSIST_STEPS control steps
# in a row (as long as a sweep sample's window) instead of the paper's first confident step.
CONTEXT_METHODS = ("lookup_context", "estimator_context", "estimator_context_persist")
MULTI_METHODS = SWITCH_METHODS + BASELINES + CONTEXT_METHODS
PERSIST_STEPS = sweep.N_WINDOW


def switch_rule(method: str) -> str:
    """The switching.METHODS rule a Table II switching method applies."""
    if method.startswith("estimator"):
        return "estimator"
    return method.removesuffix("_context")


def available_methods(methods, runs, est_dir, lookup_dir, dqn_dir=None,
                      stand_in: str | None = None) -> tuple[list, list]:
    """(methods whose trained parts exist, ["method: what is missing", ...])."""
    runs, ok, skipped = pathlib.Path(runs), [], []
    for m in methods:
        init = "random" if m == "estimator_no_overlap" else "stand"
        first = stand_in or "walk"
        if m == "end_to_end":
            if runs_lib.find_policy("mixed", "stand", runs) is None:
                skipped.append(f"{m}: no end-to-end policy (python -m biped_switch.train --policy mixed)")
                continue
        else:  # the suite: all four policies, or with a stand-in, walk or the stand-in
            missing = [n for n in pol.POLICY_NAMES if runs_lib.find_policy(n, init, runs) is None]
            if stand_in is not None and (runs_lib.find_policy("walk", init, runs) is not None
                                         or runs_lib.find_policy(first, init, runs) is not None):
                missing = []
            if missing:
                skipped.append(f"{m}: no {init}-init {', '.join(missing)} policy under {runs}/ or "
                               f"models/policies/ (python -m biped_switch.train --policy P "
                               f"--init {init})")
                continue
        if m.startswith("estimator_context"):
            if est_lib.context_estimator_paths(init, est_dir) is None:
                skipped.append(f"{m}: no {init}_context estimator in {est_dir} (python -m "
                               f"biped_switch.estimator --init {init} --context), or a target has "
                               f"no estimator at all")
                continue
        elif m.startswith("estimator") and not all(
                (pathlib.Path(est_dir) / f"{init}_{k}").exists() for k in terrain.ARTIFACT_KINDS):
            skipped.append(f"{m}: no {init}-init estimators in {est_dir} (make train-estimators)")
            continue
        if m == "lookup_context":
            missing = sweep.context_lookup_missing("stand", lookup_dir)
            if missing is None or missing:
                skipped.append(f"{m}: no context lookup table covering every target in {lookup_dir}"
                               f" (python -m biped_switch.sweep --init stand --context)")
                continue
        if m == "lookup":
            missing = sweep.lookup_missing("stand", lookup_dir)
            if missing is None:
                skipped.append(f"{m}: no lookup table in {lookup_dir} (python -m biped_switch.sweep)")
                continue
            if missing:  # swept one target at a time, across sessions
                skipped.append(f"{m}: the lookup table in {lookup_dir} has no {', '.join(missing)} "
                               f"(python -m biped_switch.sweep --targets {' '.join(missing)})")
                continue
        if m == "dqn" and runs_lib.find_dqn(runs, "stand", dqn_dir) is None:
            skipped.append(f"{m}: no DQN checkpoint in {dqn_dir or f'{runs}/dqn_stand'} or "
                           f"{runs_lib.BASELINE_DIR}/ (make train-dqn)")
            continue
        ok.append(m)
    return ok, skipped


def _run_batches(run, trials: int, batch: int, seed: int, print_fn=None, label: str = "") -> dict:
    """`run(rng, track_ids)` over trials in batches; trial i is track i, rng = seed + batch start.
    With `print_fn`, a line per batch (trials done, running success, time left), since a full
    Table II row takes tens of minutes on a CPU."""
    results, t0 = [], time.perf_counter()
    for start in range(0, trials, batch):
        ids = jax.numpy.arange(start, start + batch, dtype=jax.numpy.int32) % trials
        results.append(jax.device_get(run(jax.random.PRNGKey(seed + start), ids)))
        if print_fn is not None:
            done = min(start + batch, trials)
            succ = np.concatenate([r["success"] for r in results])[:done]
            el = time.perf_counter() - t0
            print_fn(f"    [{label}] {done:,}/{trials:,} trials, success so far {100 * succ.mean():.1f}%,"
                     f" {el:.0f} s (~{el / done * (trials - done) / 60:.1f} min left)")
    return {k: np.concatenate([r[k] for r in results])[:trials] for k in results[0]}


def multi_env(init: str, trials: int, n_artifacts: int = 7, **overrides):
    """Table II's env (`env.make_env`): `mixed` tracks MULTI_TRACK_SEED + i (trial i),
    `n_artifacts` per track; `overrides` (env config: the physics `backend`, the suite's action
    mode and phase clock, ...) go to `env.make_env`."""
    return env_lib.make_env("mixed", init, n_artifacts=n_artifacts, n_tracks=trials,
                            seed=MULTI_TRACK_SEED, **overrides)


def mixed_track(seed: int, n_artifacts: int = 7):
    """The terrain.Track of seed `seed` as multi_env lays it out (trial i: MULTI_TRACK_SEED + i)."""
    return terrain.generate_track(int(seed), "mixed", 1.0, default_terrain_config(n_artifacts))


def trial_track(setup, trial: int):
    """The terrain.Track of a trial of `setup` (for plots)."""
    return mixed_track(MULTI_TRACK_SEED + trial, setup.env.terrain_cfg.n_artifacts)


class MultiSetup:
    """Env, policy suite, estimators and lookup table of one init mode, and its compiled rollout."""

    def __init__(self, init: str, trials: int, batch: int, horizon_s: float, runs, stand_in,
                 est_dir, lookup_dir, need_estimators: bool, need_lookup: bool,
                 guide_scale: float = 0.0, n_artifacts: int = 7, backend: str = "auto",
                 need_context: Sequence[str] = ()):
        self.init = init
        self.env = multi_env(init, trials, n_artifacts, backend=backend,
                             **pol.suite_env_overrides(init, runs, stand_in=stand_in))
        self.suite = pol.load_suite(init, self.env, runs, stand_in=stand_in)
        self.est_apply, self.est_params, self.est_meta = None, None, None
        if need_estimators:
            self.est_params, self.est_meta = est_lib.load_estimator_set(init, est_dir)
            self.est_apply = est_lib.predict
        self.lookup_m = sweep.load_lookup(init, lookup_dir) if need_lookup else None
        # the context methods' estimators and lookup: same shapes, so the same compiled rollout
        self.variants, self.parts = {}, {}
        if need_estimators:
            self.parts["estimator"] = [f"{k}: {pathlib.Path(est_dir) / f'{init}_{k}'}"
                                       for k in terrain.ARTIFACT_KINDS]
        if need_lookup:
            self.parts["lookup"] = [f"{k}: {pathlib.Path(lookup_dir) / f'lookup_{init}.json'}"
                                    for k in terrain.ARTIFACT_KINDS]
        est_ctx = [m for m in need_context if m.startswith("estimator_context")]
        if est_ctx:
            paths = est_lib.context_estimator_paths(init, est_dir)
            if paths is None:
                raise FileNotFoundError(f"no {init}_context estimators in {est_dir}")
            params, _ = est_lib.load_estimator_paths(paths)
            self.est_apply = est_lib.predict
            if self.est_params is None:  # a compiled rollout needs some set for the other methods
                self.est_params = params
            for m in est_ctx:
                persist = PERSIST_STEPS if m.endswith("_persist") else 1
                self.variants[m] = {"est_params": params, "persist_steps": persist}
                self.parts[m] = ([f"{k}: {p}" for k, p in zip(terrain.ARTIFACT_KINDS, paths)]
                                 + [f"estimate >= threshold on {persist} control step(s) in a row"])
        if "lookup_context" in need_context:
            m, used = sweep.load_context_lookup(init, lookup_dir)
            self.variants["lookup_context"] = {"lookup_m": m}
            self.parts["lookup_context"] = used
        self.horizon = int(round(horizon_s / self.env.dt))

        env, apply, est_apply, horizon = self.env, self.suite.apply, self.est_apply, self.horizon

        def one(suite_params, est_params, rules, rng, ids):
            return sw.multi_rollout(env, apply, suite_params, est_apply, est_params, rules, rng,
                                    ids.shape[0], horizon, track_ids=ids, guide_scale=guide_scale)

        self.run = over_devices(one, n_shared=3)
        self.batch = batch
        self.guide_scale = guide_scale

    def rules_for(self, method: str):
        """(switching rules, estimator params) of Table II method `method` (a switching.METHODS
        rule, or a context variant with its own estimators, lookup or persistence)."""
        var = self.variants.get(method, {})
        rules = sw.make_rules(switch_rule(method), lookup_m=var.get("lookup_m", self.lookup_m),
                              persist_steps=var.get("persist_steps"))
        return rules, var.get("est_params", self.est_params)

    def evaluate(self, method: str, trials: int, seed: int, print_fn=None) -> dict:
        rules, est_params = self.rules_for(method)
        return _run_batches(lambda rng, ids: self.run(self.suite.params, est_params, rules,
                                                      rng, ids), trials, self.batch, seed, print_fn,
                            f"{self.init}/{method}")


class BaselineSetup:
    """The DQN selector or the end-to-end policy on MultiSetup's tracks, seeds and horizon.

    Both run `dqn.dqn_rollout` (same resets, chunks, early stop and frozen metrics as
    `switching.multi_rollout`); the end-to-end policy is a one-policy suite whose "selector"
    always picks it."""

    def __init__(self, method: str, trials: int, batch: int, horizon_s: float, runs, stand_in,
                 dqn_dir=None, guide_scale: float = 0.0, n_artifacts: int = 7,
                 backend: str = "auto"):
        if method not in BASELINES:
            raise ValueError(f"unknown baseline {method!r}; expected one of {BASELINES}")
        self.method = method
        if method == "dqn":
            run_dir = runs_lib.find_dqn(runs, "stand", dqn_dir)
            if run_dir is None:
                raise FileNotFoundError(f"no stand-init DQN checkpoint under {dqn_dir or runs}/ or "
                                        f"{runs_lib.BASELINE_DIR}/ (make train-dqn)")
            self.env = multi_env("stand", trials, n_artifacts, detector_one_hot=True,
                                 backend=backend,
                                 **pol.suite_env_overrides("stand", runs, stand_in=stand_in))
            self.suite = pol.load_suite("stand", self.env, runs, stand_in=stand_in)
            q_apply, self.q_params = dqn_lib.load_dqn(run_dir, dqn_lib.q_input_size(self.env))
            ckpt = runs_lib.latest_checkpoint(run_dir)
            self.sources = self.suite.sources + (f"selector: {ckpt}",)
            trained_with = runs_lib.read_progress(ckpt).get("policies")
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

    def evaluate(self, trials: int, seed: int, print_fn=None) -> dict:
        return _run_batches(lambda rng, ids: self.run(self.suite.params, self.q_params, rng, ids),
                            trials, self.batch, seed, print_fn, self.method)


def evaluate_multi(methods, trials: int, batch: int, horizon_s: float, seed: int, runs,
                   stand_in=None, est_dir="models/estimators", lookup_dir="experiments/results/lookup",
                   print_fn=print, guide_scale: float = 0.0, dqn_dir=None,
                   n_artifacts: int = 7, backend: str = "auto",
                   per_trial: dict | None = None) -> tuple[list, dict]:
    """Table II rows (dicts) for `methods`, and the setup used per init mode ("stand", "random")
    and per baseline ("dqn", "end_to_end"), every env on the physics `backend` with its policies'
    env overrides. `wall_s` of a row includes its setup and compiles. `per_trial`, if given, gets
    each method's per-trial outcomes (TRIAL_FIELDS), to find the trials behind a row's failures."""
    setups, rows = {}, []
    for method in methods:
        t0 = time.perf_counter()
        init = "random" if method == "estimator_no_overlap" else "stand"
        if method in BASELINES:
            setups[method] = BaselineSetup(method, trials, batch, horizon_s, runs, stand_in, dqn_dir,
                                           guide_scale, n_artifacts, backend)
            merged = setups[method].evaluate(trials, seed, print_fn)
            sources = setups[method].sources
        else:
            if init not in setups:
                need_est = ("estimator_no_overlap" if init == "random" else "estimator") in methods
                need_ctx = [m for m in CONTEXT_METHODS if m in methods] if init == "stand" else []
                setups[init] = MultiSetup(init, trials, batch, horizon_s, runs, stand_in, est_dir,
                                          lookup_dir, need_est,
                                          "lookup" in methods and init == "stand", guide_scale,
                                          n_artifacts, backend, need_context=need_ctx)
            merged = setups[init].evaluate(method, trials, seed, print_fn)
            sources = setups[init].suite.sources
        if per_trial is not None:
            per_trial[method] = {k: np.asarray(merged[k]) for k in TRIAL_FIELDS if k in merged}
        row = episode_table(merged)
        env = setups[method if method in BASELINES else init].env
        row.update(method=method, init=init, wall_s=time.perf_counter() - t0,
                   switches_per_trial=float(np.mean(merged["n_switches"])),
                   policies=list(sources), backend=env.backend)
        if method not in BASELINES:
            parts = setups[init].parts
            parts = parts.get(method, parts.get(switch_rule(method)))
            if parts:
                row["switch_parts"] = parts  # the estimators or lookup file per target
        rows.append(row)
        print_fn(f"  {method:22s} distance {row['distance_pct']:5.1f}%  success {row['success_pct']:5.1f}%"
                 f"  ({row['wall_s']:.0f} s)")
    return rows, setups


# Per-trial outcomes `evaluate multi` keeps beside the table (table2_trials.npz): trial i ran on
# track MULTI_TRACK_SEED + i; fail_kind is the ARTIFACT_KINDS code of the artifact fallen on (-1: none)
TRIAL_FIELDS = ("success", "fell", "fail_kind", "progress_frac", "n_switches", "switch_ahead_m")


# The settings that fix what a Table II row measured: rows made with equal values of these are
# rows of one table (the batch too: a policy's matmuls round differently at another batch size, and
# a trajectory is chaotic), so `evaluate multi` may add rows to a table across sessions.
TRIAL_KEYS = ("trials", "batch", "seed", "horizon_s", "n_artifacts", "stand_in", "guide_scale")


def merge_rows(old: dict | None, rows: list[dict], settings: dict) -> list[dict]:
    """`rows` joined with the rows of `old` (a table2.json) for the methods not among them, in
    MULTI_METHODS order (`stats.join_rows`): the methods' inputs (sweeps, estimators, DQN,
    end-to-end policy) are ready at different times, and each row's `policies` keeps where it
    came from."""
    return join_rows(old, rows, settings, TRIAL_KEYS, key=lambda r: r["method"],
                     order=MULTI_METHODS)


def _reached(track, progress_frac: float, detect_range_m: float) -> tuple[float, list[int]]:
    """(x [m] of the trial's end, the indices of the artifacts whose detection zone it entered).
    Positions come from `progress_frac` along start -> finish line (the start taken at x = 0:
    a few cm off)."""
    x = float(progress_frac) * track.finish_x_m
    return x, [k for k, (_, a0, _) in enumerate(track.artifacts) if a0 - detect_range_m <= x]


def failures_by_context(tracks, progress_frac, fell, fail_kind,
                        detect_range_m: float | None = None) -> dict:
    """{kind: {previous kind or "start": [reached, fell on it]}} over trials on `tracks`.

    Why a row fails, by where: an artifact is reached when the body came within `detect_range_m`
    of its start; a trial that fell is charged to the last artifact it reached if the env blamed
    that artifact's kind (`fail_kind`, env.blame_kind). `detect_range_m` defaults to the env's
    detection range."""
    if detect_range_m is None:
        detect_range_m = float(default_env_config().detect_range_m)
    out = {k: {} for k in terrain.ARTIFACT_KINDS}
    for i, t in enumerate(tracks):
        arts = t.artifacts
        _, reached = _reached(t, progress_frac[i], detect_range_m)
        for k in reached:
            kind, prev = arts[k][0], ("start" if k == 0 else arts[k - 1][0])
            cell = out[kind].setdefault(prev, [0, 0])
            cell[0] += 1
            cell[1] += int(k == reached[-1] and fell[i] > 0.5
                           and int(fail_kind[i]) == terrain.ARTIFACT_KINDS.index(kind))
    return out


def switch_outcomes(tracks, switch_ahead_m, progress_frac, fell, fail_kind,
                    detect_range_m: float | None = None) -> list[dict]:
    """One record per switch into an artifact's policy: {"kind", "prev" (the artifact before it, or
    "start"), "ahead_m" (CoM to its start when switched), "outcome": "fell" (the trial fell on
    this artifact, as `failures_by_context` charges it), "crossed" (the CoM passed its end) or
    "open" (time ran out first)}. Trials are `tracks` (terrain.Track, trial order)."""
    if detect_range_m is None:
        detect_range_m = float(default_env_config().detect_range_m)
    out = []
    for i, t in enumerate(tracks):
        arts = t.artifacts
        x, reached = _reached(t, progress_frac[i], detect_range_m)
        last = reached[-1] if reached else -1
        for k, (kind, _, a1) in enumerate(arts):
            ahead = float(switch_ahead_m[i][k])
            if np.isnan(ahead):
                continue
            fell_here = (k == last and fell[i] > 0.5
                         and int(fail_kind[i]) == terrain.ARTIFACT_KINDS.index(kind))
            out.append({"kind": kind, "prev": "start" if k == 0 else arts[k - 1][0],
                        "ahead_m": ahead,
                        "outcome": "fell" if fell_here else ("crossed" if x > a1 else "open")})
    return out


def switch_summary(records: list[dict], forced_m: float = 0.01) -> dict:
    """{kind: {prev: {"n", "ahead_m_q" (quartiles [m]), "forced_pct" (switched within
    `forced_m`: the rule never fired), "lost_pct" (fell on it), "lost_by_ahead": [[bin lo, bin hi,
    n, fell], ...] (0.1 m bins)}}."""
    out = {}
    for kind in terrain.ARTIFACT_KINDS:
        for prev in sorted({r["prev"] for r in records if r["kind"] == kind},
                           key=lambda q: (q != "start", q)):
            rs = [r for r in records if r["kind"] == kind and r["prev"] == prev]
            ahead = np.array([r["ahead_m"] for r in rs])
            lost = np.array([r["outcome"] == "fell" for r in rs])
            edges = np.round(np.arange(0.0, 1.0, 0.1), 2)
            # the first bin takes the forced switches a step past the start too (ahead < 0)
            bins = [[float(lo), round(float(lo) + 0.1, 2), int(m.sum()), int(lost[m].sum())]
                    for lo in edges for m in [((ahead >= lo) | (lo == 0)) & (ahead < lo + 0.1)]
                    if m.any()]
            out.setdefault(kind, {})[prev] = {
                "n": len(rs), "ahead_m_q": [float(q) for q in np.quantile(ahead, (0.25, 0.5, 0.75))],
                "forced_pct": float(100 * np.mean(ahead <= forced_m)),
                "lost_pct": float(100 * lost.mean()), "lost_by_ahead": bins}
    return out


def switches_markdown(by_method: dict) -> str:
    """One table per artifact kind: where each method switched into its policy, by the artifact
    before it, and how often that artifact was then lost."""
    lines = []
    for kind in terrain.ARTIFACT_KINDS:
        lines += [f"**into {kind}**: switch distance before it, median (quartiles) [m]; % forced "
                  f"(within 1 cm); % lost (fell on it)", "",
                  "| method | after | switches | distance [m] | % forced | % lost |",
                  "|---|---|---|---|---|---|"]
        for m, d in by_method.items():
            for prev, c in d.get(kind, {}).items():
                q1, q2, q3 = c["ahead_m_q"]
                lines.append(f"| {m} | {prev} | {c['n']:,} | {q2:.2f} ({q1:.2f}-{q3:.2f}) | "
                             f"{c['forced_pct']:.1f} | {c['lost_pct']:.1f} |")
        lines.append("")
    return "\n".join(lines)


def failures_markdown(by_method: dict) -> str:
    """One table per artifact kind: % fell on it (fell / reached) by the artifact before it."""
    lines = []
    for kind in terrain.ARTIFACT_KINDS:
        prevs = sorted({p for d in by_method.values() for p in d[kind]},
                       key=lambda p: (p != "start", p))
        lines += [f"**{kind}**, fell on it / reached, by the artifact before it", "",
                  "| method | " + " | ".join(f"after {p}" for p in prevs) + " |",
                  "|---|" + "---|" * len(prevs)]
        for m, d in by_method.items():
            cells = [(f"{f:,} / {n:,} ({100 * f / n:.1f}%)" if n else "-")
                     for n, f in (d[kind].get(p, [0, 0]) for p in prevs)]
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


HEURISTICS = ("random", "detection", "lookup", "com_over_feet")  # the paper's heuristic rows


def compare(a: dict, b: dict, key: str = "success") -> int:
    """+1 when row a's 95% CI on `key` ("success" or "distance") lies wholly above b's, -1 wholly
    below, 0 when they overlap (no difference claimed)."""
    (alo, ahi), (blo, bhi) = a[f"{key}_ci"], b[f"{key}_ci"]
    return 1 if alo > bhi else (-1 if ahi < blo else 0)


def _cell(r: dict) -> str:
    return f"{r['method']} {pct_ci(r['success_pct'], r['success_ci'])}"


def paper_claims(rows: list[dict]) -> list[dict]:
    """The paper's four Table II claims, tested on our rows by their 95% CIs on % success
    (`compare`): {claim, verdict, evidence}. verdict: "holds", "fails" (with the rows that break
    it) or "not tested" (a row it needs was not run). "Comparable" means overlapping CIs."""
    by = {r["method"]: r for r in rows}

    def beats_all(m, others, show_all: bool):
        """(verdict, evidence) of "row m beats each of `others`": every row's cell and the names
        not beaten (`show_all`, a few rows), else the cells of those not beaten only."""
        if not others:
            return "not tested", f"{_cell(by[m])}; no other rows"
        lost = [o for o in others if compare(by[m], by[o]) < 1]
        if show_all:
            ev = "; ".join(_cell(by[r]) for r in (m, *others))
            return ("fails", f"{ev}; not beaten: {', '.join(lost)}") if lost else ("holds", ev)
        if lost:
            return "fails", f"{_cell(by[m])}; not beaten: " + "; ".join(_cell(by[o]) for o in lost)
        return "holds", f"{_cell(by[m])}; above all {len(others)} other rows"

    def dqn_vs_estimator():
        c = compare(by["dqn"], by["estimator"])
        return ("holds" if c == 0 else "fails", f"{_cell(by['dqn'])}; {_cell(by['estimator'])}"
                + ("" if c == 0 else f"; the DQN is {'better' if c > 0 else 'worse'}"))

    claims = (  # (claim, rows it needs, test)
        ("the estimator beats every heuristic (success)", ("estimator", *HEURISTICS),
         lambda: beats_all("estimator", HEURISTICS, show_all=True)),
        ("without overlap the estimator collapses (success)", ("estimator", "estimator_no_overlap"),
         lambda: ("holds" if compare(by["estimator_no_overlap"], by["estimator"]) < 0 else "fails",
                  f"{_cell(by['estimator_no_overlap'])}; {_cell(by['estimator'])}")),
        ("the DQN is comparable to the estimator (overlapping success CIs)", ("dqn", "estimator"),
         dqn_vs_estimator),
        ("end-to-end is best (success)", ("end_to_end",),
         lambda: beats_all("end_to_end", [m for m in by if m != "end_to_end"], show_all=False)),
    )
    out = []
    for claim, need, test in claims:
        missing = [m for m in need if m not in by]
        verdict, evidence = (("not tested", "missing rows: " + ", ".join(missing)) if missing
                             else test())
        out.append({"claim": claim, "verdict": verdict, "evidence": evidence})
    return out


def claims_markdown(claims: list[dict]) -> str:
    lines = ["| the paper's claim | on our system | evidence: % success (95% CI) |", "|---|---|---|"]
    lines += [f"| {c['claim']} | {c['verdict']} | {c['evidence']} |" for c in claims]
    return "\n".join(lines)


def table2_markdown(rows: list[dict]) -> str:
    lines = ["| method | trials | % total dist. (95% CI) | % success (95% CI) | % gap fail (CI) | "
             "% jump fail (CI) | % stair fail (CI) | paper (dist. / success / gap / jump / stair) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ref = paper.TABLE2.get(r["method"])
        f = r["fail_on"]
        lines.append(
            f"| {r['method']} | {r['n']} | {dist_success_cells(r)} | "
            + " | ".join(pct_ci(f[k], r["fail_ci"][k]) for k in paper.TABLE2_FAIL_ORDER) + " | "
            + (" / ".join(f"{v}" for v in ref) if ref else "-") + " |")
    return "\n".join(lines)


def table2_rows(doc: dict, with_paper_only: bool = True):
    """(headers, rows) of a table2.json as the notebook prints it, each method beside the paper's
    row; with `with_paper_only`, the paper's methods not run here as "not run" rows."""
    headers = ["method", "init", "trials", "% dist. (95% CI)", "% success (95% CI)", "% gap fail",
               "% jump fail", "% stair fail", "switches/trial",
               "paper dist. / success / gap / jump / stair"]
    rows, seen = [], set()
    for r in doc["rows"]:
        f, p = r["fail_on"], paper.TABLE2.get(r["method"])
        seen.add(r["method"])
        rows.append([r["method"], r["init"], r["n"], pct_ci_cell(r["distance_pct"], r.get("distance_ci")),
                     pct_ci_cell(r["success_pct"], r.get("success_ci")), f"{f['gaps']:.1f}",
                     f"{f['jumps']:.1f}", f"{f['stairs']:.1f}",
                     f"{r.get('switches_per_trial', math.nan):.2f}",
                     " / ".join(f"{v}" for v in p) if p else "-"])
    if with_paper_only:
        for m, p in paper.TABLE2.items():
            if m not in seen:
                rows.append([m, "-", "not run", "-", "-", "-", "-", "-", "-",
                             " / ".join(f"{v}" for v in p)])
    return headers, rows


def table2_provenance(doc: dict, path, print_fn=print) -> list[str]:
    """Prints where a table2.json's rows come from (settings, methods not run, each init's
    policies) and its verdict; returns the reasons it is a pipeline check ([] if none)."""
    s, rows = doc.get("settings", {}), doc["rows"]
    fmt = prov.fmt
    print_fn(f"file: {prov.rel(path)}")
    for k in ("trials", "seed", "horizon_s", "n_artifacts", "stand_in", "guide_scale", "runs",
              "estimators", "dqn", "lookup"):
        print_fn(f"  {k}: {fmt(s.get(k))}")
    for sk in doc.get("skipped") or []:
        print_fn(f"  not run: {sk}")
    print_fn(f"  device: {fmt(doc.get('device'))}   track_seed: {fmt(doc.get('track_seed'))}   "
             f"wall: {fmt(round(doc['wall_s'])) if doc.get('wall_s') is not None else 'not recorded'} s")
    reasons, seen, subs = [], set(), {}
    for r in rows:
        srcs = tuple(r.get("policies") or ())
        if srcs and (r["init"], srcs) not in seen:
            seen.add((r["init"], srcs))
            print_fn(f"  policies ({r['init']} init), walk/jumps/gaps/stairs:")
            for src in srcs:
                print_fn(f"    {src}")
            subs[r["init"]] = [x.split(":")[0].removeprefix("stand-in for ")
                               for x in prov.stand_ins(srcs)]
    for r in rows:
        if r.get("switch_parts"):
            print_fn(f"  {r['method']} switches with: " + "; ".join(r["switch_parts"]))
    subs = {k: v for k, v in subs.items() if v}
    if subs:
        reasons.append("stand-in policies: " + "; ".join(f"{k} init {', '.join(v)}"
                                                         for k, v in subs.items()))
    if s.get("stand_in"):
        reasons.append(f"--stand-in {s['stand_in']}")
    if (s.get("guide_scale") or 0) > 0:
        reasons.append(f"scripted guide forces on (guide_scale {s['guide_scale']:g})")
    if s.get("n_artifacts") not in (None, paper.ARTIFACTS):
        reasons.append(f"{s['n_artifacts']} artifacts per track (paper: {paper.ARTIFACTS})")
    mismatch = sorted({x for r in rows for x in (r.get("policies") or ()) if "MISMATCH" in str(x)})
    if mismatch:
        reasons.append("DQN selector trained with other policies than those evaluated")
    return prov.conclude(doc, reasons, rows, paper.TRIALS["table2"], "method", print_fn=print_fn)

"""Table II: the switching methods and the baselines on multi-artifact tracks (`evaluate multi`).

Every method runs on the same `mixed` tracks (7 artifacts by default, no kind twice in a row,
>= 0.9 m of flat before each; trial i on track config.MULTI_TRACK_SEED + i with rng seed + batch
start), each trial starting with the walk policy; the switching methods differ only in when they
switch (switching.py). The stand-init suite is used for every method but `estimator_no_overlap`
and `learned_no_overlap` (RANDOM_INIT_METHODS), which use the random-init policies and their
estimators or learned rule and start from random joints with no pause, as they were trained. The
baselines (the DQN selector, the end-to-end policy) run the same tracks, seeds and horizon
(`BaselineSetup`). Every env runs on the chosen physics backend, with the
env overrides its policy suite was trained with. A row reports % distance, % success and % of
trials failing on gaps / jumps / stairs, with 95% CIs (stats.py).
"""

from __future__ import annotations

import pathlib
import time
import warnings
from typing import Sequence

import jax
import numpy as np

from biped_switch.learning import dqn as dqn_lib
from biped_switch.learning import dqn_train as dqn_train
from biped_switch.simulation import env as env_lib
from biped_switch.switching import estimator as est_lib
from biped_switch.learning import policies as pol
from biped_switch.learning import runs as runs_lib
from biped_switch.switching import labels
from biped_switch.switching import detector as det_lib
from biped_switch.switching import lookup
from biped_switch.switching import rules as sw
from biped_switch.simulation import terrain
from biped_switch.config import (MULTI_TRACK_SEED, SETUP_SUITE, SETUP_WALK_ON,
                                 default_switching_config, default_terrain_config,
                                 default_when_config)
from biped_switch.paths import WHEN_DIR
from biped_switch.simulation.rollout import over_devices
from biped_switch.stats import episode_table, join_rows

from biped_switch.names import (BASELINES, CONTEXT_METHODS, LEARNED_METHODS,  # noqa: E402,F401
                                MULTI_METHODS, RANDOM_INIT_METHODS, SETUP_METHODS, SWITCH_METHODS)
from biped_switch.switching import when as when_lib
PERSIST_STEPS = labels.N_WINDOW


def switch_rule(method: str) -> str:
    """The switching.METHODS rule a Table II switching method applies."""
    if method.startswith("estimator") or method in LEARNED_METHODS:
        return "estimator"  # a model's output against a threshold
    return base_method(method).removesuffix("_context")


def base_method(method: str) -> str:
    """The Table II method a setup method (SETUP_METHODS) adds setup policies to."""
    return method.removesuffix("_setup") if method in SETUP_METHODS else method


def setup_key(method: str) -> str:
    """The MultiSetup (one compiled rollout) of `evaluate_multi` that runs a switching method:
    its init, with setup policies or not, with the learned rule's model or not."""
    init = "random" if method in RANDOM_INIT_METHODS else "stand"
    return (init + ("+setup" if method in SETUP_METHODS else "")
            + ("+learned" if method in LEARNED_METHODS else ""))


def find_setup_policies(init: str, runs, names=SETUP_SUITE) -> dict:
    """{setup policy name: (target kind, source policy names, hand-over distance [m])} of the
    trained setup policies `names` of an init mode (`train --policy setup_<target>`; default: the
    controller's, config.SETUP_SUITE), each as its run's config says it was trained: the sources
    it takes over from and the distance it hands over at."""
    found = {}
    for name in names:
        ckpt = runs_lib.find_policy(name, init, runs)
        if ckpt is None:
            continue
        s = runs_lib.read_config(ckpt.parent.parent).get("setup")
        if not s:
            raise ValueError(f"{ckpt}: a setup policy's run config.json without a setup section")
        found[name] = (s["target"], tuple(s["sources"]), float(s["handover_m"]))
    return found


def available_methods(methods, runs, est_dir, lookup_dir, dqn_dir=None,
                      stand_in: str | None = None, when_dir=WHEN_DIR) -> tuple[list, list]:
    """(methods whose trained parts exist, ["method: what is missing", ...])."""
    runs, ok, skipped = pathlib.Path(runs), [], []
    for m in methods:
        init = "random" if m in RANDOM_INIT_METHODS else "stand"
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
        if m in SETUP_METHODS and not find_setup_policies(init, runs):
            skipped.append(f"{m}: no {init}-init setup policy under {runs}/ or models/policies/ "
                           f"(python -m biped_switch.train --policy setup_gaps --init {init})")
            continue
        if m in LEARNED_METHODS and not (pathlib.Path(when_dir) / init / "meta.json").exists():
            skipped.append(f"{m}: no learned when rule in {when_dir}/{init} (python -m "
                           f"biped_switch.when --init {init})")
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
        if base_method(m) == "lookup_context":
            missing = lookup.context_lookup_missing("stand", lookup_dir)
            if missing is None or missing:
                skipped.append(f"{m}: no context lookup table covering every target in {lookup_dir}"
                               f" (python -m biped_switch.sweep --init stand --context)")
                continue
        if m == "lookup":
            missing = lookup.lookup_missing("stand", lookup_dir)
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


def multi_env(init: str, trials: int, n_artifacts: int = 7, track_seed: int = MULTI_TRACK_SEED,
              **overrides):
    """Table II's env (`env.make_env`): `mixed` tracks track_seed + i (trial i; Table II's are
    MULTI_TRACK_SEED + i, tuning uses others), `n_artifacts` per track; `overrides` (env config:
    the physics `backend`, the suite's action mode and phase clock, ...) go to `env.make_env`."""
    return env_lib.make_env("mixed", init, n_artifacts=n_artifacts, n_tracks=trials,
                            seed=int(track_seed), **overrides)


def mixed_track(seed: int, n_artifacts: int = 7):
    """The terrain.Track of seed `seed` as multi_env lays it out (trial i: MULTI_TRACK_SEED + i)."""
    return terrain.generate_track(int(seed), "mixed", 1.0, default_terrain_config(n_artifacts))


def trial_track(setup, trial: int):
    """The terrain.Track of a trial of `setup` (for plots)."""
    return mixed_track(setup.env.cfg.seed + trial, setup.env.terrain_cfg.n_artifacts)


def load_detector(detector_dir, env):
    """(det_apply, det_params, source) of the learned terrain detector for `env`, or (None, None,
    "oracle") when `detector_dir` is None (the paper's oracle)."""
    if detector_dir is None:
        return None, None, "oracle"
    params, meta = det_lib.load(detector_dir)
    return det_lib.detect_fn(meta, env), params, f"detector: {pathlib.Path(detector_dir)}"


class MultiSetup:
    """Env, policy suite, estimators and lookup table of one init mode, and its compiled rollout."""

    def __init__(self, init: str, trials: int, batch: int, horizon_s: float, runs, stand_in,
                 est_dir, lookup_dir, need_estimators: bool, need_lookup: bool,
                 guide_scale: float = 0.0, n_artifacts: int = 7, backend: str = "auto",
                 need_context: Sequence[str] = (), track_seed: int = MULTI_TRACK_SEED,
                 detector_dir=None, with_setup: bool = False, when_dir=None, when_cfg=None):
        self.init = init
        # the setup methods' suite: the four policies, then every trained setup policy
        setups = find_setup_policies(init, runs) if with_setup else {}
        if with_setup and not setups:
            raise FileNotFoundError(f"no {init}-init setup policy under {runs}/ or models/policies/")
        names = pol.POLICY_NAMES + tuple(setups)
        self.env = multi_env(init, trials, n_artifacts, track_seed, backend=backend,
                             **pol.suite_env_overrides(init, runs, stand_in=stand_in, names=names))
        det_apply, self.det_params, self.detector = load_detector(detector_dir, self.env)
        self.suite = pol.load_suite(init, self.env, runs, stand_in=stand_in, names=names)
        self.policy_names = names
        self.walk_on = {k: (tuple(v["sources"]), float(v["handover_m"]))
                        for k, v in SETUP_WALK_ON.items()} if with_setup else {}
        self.setup = sw.setup_slots(names, setups) if setups else None
        self.est_apply, self.est_params, self.est_meta = None, None, None
        if need_estimators:
            self.est_params, self.est_meta = est_lib.load_estimator_set(init, est_dir)
            self.est_apply = est_lib.predict
        self.lookup_m = lookup.load_lookup(init, lookup_dir) if need_lookup else None
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
        if when_dir is not None:  # the learned rule: its own model, read with the context
            path = pathlib.Path(when_dir) / init
            self.est_params, self.when_meta = est_lib.load_estimator(path)
            wcfg = when_cfg or default_when_config()
            self.est_apply = when_lib.rule_fn(self.env, wcfg)
            margin, persist = float(wcfg.margin), int(wcfg.persist_steps)
            for m in LEARNED_METHODS:  # each init's learned row reads its own model
                self.variants[m] = {"threshold": margin, "persist_steps": persist}
                self.parts[m] = [f"model: {path}",
                                 f"switch once P(now) >= best later P ({wcfg.later_from}) + "
                                 f"{margin:g} on {persist} control step(s) in a row"]
        if "lookup_context" in need_context:
            m, used = lookup.load_context_lookup(init, lookup_dir)
            self.variants["lookup_context"] = {"lookup_m": m}
            self.parts["lookup_context"] = used
        for name, (target, sources, handover_m) in setups.items():
            self.parts.setdefault("setup", []).append(
                f"{name}: {sources} -> {target}, hand-over at {handover_m:g} m: "
                f"{self.suite.sources[names.index(name)]}")
        for target, (sources, handover_m) in self.walk_on.items():
            self.parts.setdefault("setup", []).append(
                f"walk on: {sources} -> {target}, the source acts to {handover_m:g} m")
        self.horizon = int(round(horizon_s / self.env.dt))

        env, apply, est_apply, horizon = self.env, self.suite.apply, self.est_apply, self.horizon

        def one(suite_params, est_params, det_params, rules, rng, ids):
            return sw.multi_rollout(env, apply, suite_params, est_apply, est_params, rules, rng,
                                    ids.shape[0], horizon, track_ids=ids, guide_scale=guide_scale,
                                    det_apply=det_apply, det_params=det_params)

        self.det_apply = det_apply
        self.run = over_devices(one, n_shared=4)
        self.batch = batch
        self.guide_scale = guide_scale

    def rules_for(self, method: str):
        """(switching rules, estimator params) of Table II method `method` (a switching.METHODS
        rule, or a context variant with its own estimators, lookup or persistence)."""
        var = self.variants.get(base_method(method), {})
        lookup_m, setup = var.get("lookup_m", self.lookup_m), None
        if method in SETUP_METHODS:
            setup = self.setup
            lookup_m = sw.walk_on_lookup(lookup_m, self.walk_on, setup)
        cfg = default_switching_config()
        if "threshold" in var:
            cfg.estimator_threshold = var["threshold"]
        rules = sw.make_rules(switch_rule(method), lookup_m=lookup_m, cfg=cfg,
                              persist_steps=var.get("persist_steps"), setup=setup)
        return rules, var.get("est_params", self.est_params)

    def evaluate(self, method: str, trials: int, seed: int, print_fn=None) -> dict:
        rules, est_params = self.rules_for(method)
        return _run_batches(lambda rng, ids: self.run(self.suite.params, est_params,
                                                      self.det_params, rules, rng, ids),
                            trials, self.batch, seed, print_fn,
                            f"{self.init}/{method}")


class BaselineSetup:
    """The DQN selector or the end-to-end policy on MultiSetup's tracks, seeds and horizon.

    Both run `dqn.dqn_rollout` (same resets, chunks, early stop and frozen metrics as
    `switching.multi_rollout`); the end-to-end policy is a one-policy suite whose "selector"
    always picks it."""

    def __init__(self, method: str, trials: int, batch: int, horizon_s: float, runs, stand_in,
                 dqn_dir=None, guide_scale: float = 0.0, n_artifacts: int = 7,
                 backend: str = "auto", track_seed: int = MULTI_TRACK_SEED, detector_dir=None):
        if method not in BASELINES:
            raise ValueError(f"unknown baseline {method!r}; expected one of {BASELINES}")
        self.method = method
        if method == "dqn":
            run_dir = runs_lib.find_dqn(runs, "stand", dqn_dir)
            if run_dir is None:
                raise FileNotFoundError(f"no stand-init DQN checkpoint under {dqn_dir or runs}/ or "
                                        f"{runs_lib.BASELINE_DIR}/ (make train-dqn)")
            self.env = multi_env("stand", trials, n_artifacts, track_seed, detector_one_hot=True,
                                 backend=backend,
                                 **pol.suite_env_overrides("stand", runs, stand_in=stand_in))
            self.suite = pol.load_suite("stand", self.env, runs, stand_in=stand_in)
            q_apply, self.q_params = dqn_train.load_dqn(run_dir, dqn_lib.q_input_size(self.env))
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
            self.env = multi_env("stand", trials, n_artifacts, track_seed, backend=backend,
                                 **pol.suite_env_overrides("stand", runs, names=("mixed",)))
            self.suite = pol.load_suite("stand", self.env, runs, names=("mixed",))
            self.q_params = jax.numpy.zeros(())

            def q_apply(_, x):  # the only policy of the suite, always
                return jax.numpy.zeros(x.shape[:-1] + (1,))
            self.sources = self.suite.sources
        env, apply, horizon = self.env, self.suite.apply, int(round(horizon_s / self.env.dt))
        # the end-to-end policy reads no detector (only its heightmap); the DQN reads the detected
        # kind, the oracle's or the learned one's
        det_apply, self.det_params, self.detector = load_detector(
            detector_dir if method == "dqn" else None, env)
        if method != "dqn" and detector_dir is not None:
            self.detector = "none: the end-to-end policy reads no detector"

        def one(suite_params, q_params, det_params, rng, ids):
            return dqn_train.dqn_rollout(env, apply, suite_params, q_apply, q_params, rng,
                                         ids.shape[0], horizon, track_ids=ids,
                                         guide_scale=guide_scale, det_apply=det_apply,
                                         det_params=det_params)

        self.run = over_devices(one, n_shared=3)
        self.batch = batch

    def evaluate(self, trials: int, seed: int, print_fn=None) -> dict:
        return _run_batches(lambda rng, ids: self.run(self.suite.params, self.q_params,
                                                      self.det_params, rng, ids),
                            trials, self.batch, seed, print_fn, self.method)


def evaluate_multi(methods, trials: int, batch: int, horizon_s: float, seed: int, runs,
                   stand_in=None, est_dir="models/estimators", lookup_dir="experiments/results/lookup",
                   print_fn=print, guide_scale: float = 0.0, dqn_dir=None,
                   n_artifacts: int = 7, backend: str = "auto",
                   per_trial: dict | None = None, track_seed: int = MULTI_TRACK_SEED,
                   detector_dir=None, when_dir=WHEN_DIR, when_cfg=None) -> tuple[list, dict]:
    """Table II rows (dicts) for `methods`, and the setup used per init mode ("stand", "random")
    and per baseline ("dqn", "end_to_end"), every env on the physics `backend` with its policies'
    env overrides. `wall_s` of a row includes its setup and compiles. `per_trial`, if given, gets
    each method's per-trial outcomes (TRIAL_FIELDS), to find the trials behind a row's failures.
    Trial i runs on track `track_seed` + i; `detector_dir`: a learned terrain detector in place of
    the oracle (switching.detector), for the switching methods and the DQN."""
    setups, rows = {}, []
    for method in methods:
        t0 = time.perf_counter()
        init = "random" if method in RANDOM_INIT_METHODS else "stand"
        if method in BASELINES:
            setups[method] = BaselineSetup(method, trials, batch, horizon_s, runs, stand_in, dqn_dir,
                                           guide_scale, n_artifacts, backend, track_seed,
                                           detector_dir)
            merged = setups[method].evaluate(trials, seed, print_fn)
            sources = setups[method].sources
        else:
            # the setup methods run a suite with the setup policies, the learned rule its own
            # model: each in a rollout of its own
            learned, key = method in LEARNED_METHODS, setup_key(method)
            if key not in setups:
                group = [m for m in methods if setup_key(m) == key]
                bases = {base_method(m) for m in group}
                need_est = ("estimator_no_overlap" if init == "random" else "estimator") in bases
                need_ctx = [m for m in CONTEXT_METHODS if m in bases] if init == "stand" else []
                setups[key] = MultiSetup(init, trials, batch, horizon_s, runs, stand_in, est_dir,
                                         lookup_dir, need_est,
                                         "lookup" in bases and init == "stand", guide_scale,
                                         n_artifacts, backend, need_context=need_ctx,
                                         track_seed=track_seed, detector_dir=detector_dir,
                                         with_setup=method in SETUP_METHODS,
                                         when_dir=when_dir if learned else None,
                                         when_cfg=when_cfg)
            merged = setups[key].evaluate(method, trials, seed, print_fn)
            sources = setups[key].suite.sources
        if per_trial is not None:
            per_trial[method] = {k: np.asarray(merged[k]) for k in TRIAL_FIELDS if k in merged}
        row = episode_table(merged)
        used = setups[method if method in BASELINES else key]
        row.update(method=method, init=init, wall_s=time.perf_counter() - t0,
                   switches_per_trial=float(np.mean(merged["n_switches"])),
                   policies=list(sources), backend=used.env.backend, detector=used.detector)
        if method not in BASELINES:
            base = base_method(method)
            parts = list(used.parts.get(base, used.parts.get(switch_rule(base), [])))
            if method in SETUP_METHODS:
                parts += used.parts["setup"]
                row["policy_names"] = list(used.policy_names)
            if parts:
                row["switch_parts"] = parts  # the estimators or lookup file per target
        rows.append(row)
        print_fn(f"  {method:22s} distance {row['distance_pct']:5.1f}%  success {row['success_pct']:5.1f}%"
                 f"  ({row['wall_s']:.0f} s)")
    return rows, setups


# Per-trial outcomes `evaluate multi` keeps beside the table (table2_trials.npz): trial i ran on
# track MULTI_TRACK_SEED + i; fail_kind is the ARTIFACT_KINDS code of the artifact fallen on (-1: none)
TRIAL_FIELDS = ("success", "fell", "fail_kind", "progress_frac", "n_switches", "switch_ahead_m",
                "active_at_start", "switch_from", "switch_forced", "switch_output")


# The settings that fix what a Table II row measured: rows made with equal values of these are
# rows of one table (the batch too: a policy's matmuls round differently at another batch size, and
# a trajectory is chaotic), so `evaluate multi` may add rows to a table across sessions.
TRIAL_KEYS = ("trials", "batch", "seed", "horizon_s", "n_artifacts", "stand_in", "guide_scale",
              "track_seed", "detector")
# what a table made before these settings existed was made with
TRIAL_DEFAULTS = {"track_seed": MULTI_TRACK_SEED, "detector": "oracle"}


def merge_rows(old: dict | None, rows: list[dict], settings: dict) -> list[dict]:
    """`rows` joined with the rows of `old` (a table2.json) for the methods not among them, in
    MULTI_METHODS order (`stats.join_rows`): the methods' inputs (sweeps, estimators, DQN,
    end-to-end policy) are ready at different times, and each row's `policies` keeps where it
    came from."""
    if old:
        old = {**old, "settings": {**TRIAL_DEFAULTS, **old.get("settings", {})}}
    return join_rows(old, rows, settings, TRIAL_KEYS, key=lambda r: r["method"],
                     order=MULTI_METHODS)

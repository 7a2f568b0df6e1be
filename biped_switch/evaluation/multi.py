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

Another line-up (`MultiConfig.lineup`, `lineups.Lineup`; Table II-4: stones) runs the same way on
its own track kind (`mixed4`) with its suite (`lineup.policies`) and rules sized by it; the rows
it cannot have are refused up front (evaluation/parts.py), and each row reports a failure rate
per target of the line-up.
"""

from __future__ import annotations

import pathlib
import time
import warnings
from dataclasses import dataclass
from typing import Sequence

import jax
import numpy as np

from biped_switch.learning import dqn as dqn_lib
from biped_switch.learning import dqn_train as dqn_train
from biped_switch.simulation import env as env_lib
from biped_switch.switching import estimator as est_lib
from biped_switch.learning import policies as pol
from biped_switch.learning import runs as runs_lib
from biped_switch.switching import detector as det_lib
from biped_switch.switching import lookup
from biped_switch.switching import rules as sw
from biped_switch.simulation import terrain
from biped_switch.config import (MULTI_TRACK_SEED, SETUP_WALK_ON,
                                 default_switching_config, default_terrain_config,
                                 default_when_config)
from biped_switch.paths import WHEN_DIR
from biped_switch.simulation.rollout import over_devices
from biped_switch.stats import episode_table, join_rows

from biped_switch import kinds, lineups
from biped_switch.evaluation import parts as parts_lib
from biped_switch.evaluation.parts import find_setup_policies
from biped_switch.methods import Method, method as method_record
from biped_switch.names import BASELINES, MULTI_METHODS
from biped_switch.switching import when as when_lib


@dataclass(frozen=True)
class MultiConfig:
    """What every row of one `evaluate multi` shares: the trials, where the trained parts are, the
    tracks and the backend. Trial i runs on track `track_seed` + i; `detector_dir`: a learned
    terrain detector in place of the oracle; `when_cfg`: the learned rule's (None: config's);
    `lineup`: whose policies switch into which targets, on which track kind (lineups.LINEUPS)."""

    trials: int
    batch: int
    horizon_s: float = 60.0
    runs: str = "runs"
    stand_in: str | None = None
    est_dir: str = "models/estimators"
    lookup_dir: str = "experiments/results/lookup"
    dqn_dir: str | None = None
    guide_scale: float = 0.0
    n_artifacts: int = 7
    backend: str = "auto"
    track_seed: int = MULTI_TRACK_SEED
    detector_dir: str | None = None
    when_dir: str = WHEN_DIR
    when_cfg: object = None
    lineup: lineups.Lineup = lineups.PAPER_LINEUP


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
              kind: str = "mixed", **overrides):
    """Table II's env (`env.make_env`): `kind` tracks (a line-up's `tracks`; the paper's: mixed)
    track_seed + i (trial i; Table II's are MULTI_TRACK_SEED + i, tuning uses others),
    `n_artifacts` per track; `overrides` (env config: the physics `backend`, the suite's action
    mode and phase clock, ...) go to `env.make_env`."""
    return env_lib.make_env(kind, init, n_artifacts=n_artifacts, n_tracks=trials,
                            seed=int(track_seed), **overrides)


def mixed_track(seed: int, n_artifacts: int = 7, kind: str = "mixed"):
    """The terrain.Track of seed `seed` as multi_env lays it out (trial i: MULTI_TRACK_SEED + i)."""
    return terrain.generate_track(int(seed), kind, 1.0, default_terrain_config(n_artifacts))


def trial_track(setup, trial: int):
    """The terrain.Track of a trial of `setup` (for plots)."""
    return mixed_track(setup.env.cfg.seed + trial, setup.env.terrain_cfg.n_artifacts,
                       setup.env.cfg.kind)


def load_detector(detector_dir, env):
    """(det_apply, det_params, source) of the learned terrain detector for `env`, or (None, None,
    "oracle") when `detector_dir` is None (the paper's oracle)."""
    if detector_dir is None:
        return None, None, "oracle"
    params, meta = det_lib.load(detector_dir)
    return det_lib.detect_fn(meta, env), params, f"detector: {pathlib.Path(detector_dir)}"


class MultiSetup:
    """Env, policy suite and the switching parts (estimators, lookup tables, the learned rule's
    model) of the rows `methods` (records sharing one `Method.rollout`), and their compiled
    rollout."""

    def __init__(self, methods: Sequence[Method | str], cfg: MultiConfig):
        recs = [method_record(m) if isinstance(m, str) else m for m in methods]
        if not recs or recs[0].baseline or len({r.rollout for r in recs}) != 1:
            raise ValueError(f"one MultiSetup runs switching methods of one rollout, got "
                             f"{[r.name for r in recs]}")
        first, runs = recs[0], cfg.runs
        self.init = init = first.suite
        self.lineup = lineup = cfg.lineup
        parts_lib.check_rows(recs, lineup)
        parts_lib.check_detector(cfg.detector_dir, lineup)
        # the setup methods' suite: the line-up's policies, then every trained setup policy
        setups = find_setup_policies(init, runs) if first.setup else {}
        if first.setup and not setups:
            raise FileNotFoundError(f"no {init}-init setup policy under {runs}/ or models/policies/")
        names = lineup.policies + tuple(setups)
        self.env = multi_env(init, cfg.trials, cfg.n_artifacts, cfg.track_seed, lineup.tracks,
                             backend=cfg.backend,
                             **pol.suite_env_overrides(init, runs, stand_in=cfg.stand_in, names=names))
        det_apply, self.det_params, self.detector = load_detector(cfg.detector_dir, self.env)
        self.suite = pol.load_suite(init, self.env, runs, stand_in=cfg.stand_in, names=names)
        self.policy_names = names
        self.walk_on = {k: (tuple(v["sources"]), float(v["handover_m"]))
                        for k, v in SETUP_WALK_ON.items()} if first.setup else {}
        self.setup = sw.setup_slots(names, setups, lineup=lineup) if setups else None
        self._load_parts(recs, cfg)
        for name, (target, sources, handover_m) in setups.items():
            self.parts.setdefault("setup", []).append(
                f"{name}: {sources} -> {target}, hand-over at {handover_m:g} m: "
                f"{self.suite.sources[names.index(name)]}")
        for target, (sources, handover_m) in self.walk_on.items():
            self.parts.setdefault("setup", []).append(
                f"walk on: {sources} -> {target}, the source acts to {handover_m:g} m")
        unserved = [n for n in parts_lib.new_names(lineup)  # a kind no setup policy serves
                    if not any(n == t or n in src for t, src, _ in setups.values())]
        if setups and unserved:
            self.parts["setup"].append(f"line-up {lineup.name}: no setup policy into or out of "
                                       f"{', '.join(unserved)}; those pairs switch by the rule")
        self.horizon = int(round(cfg.horizon_s / self.env.dt))

        env, apply, est_apply, horizon = self.env, self.suite.apply, self.est_apply, self.horizon
        guide_scale = cfg.guide_scale

        def one(suite_params, est_params, det_params, rules, rng, ids):
            return sw.multi_rollout(env, apply, suite_params, est_apply, est_params, rules, rng,
                                    ids.shape[0], horizon, track_ids=ids, guide_scale=guide_scale,
                                    det_apply=det_apply, det_params=det_params)

        self.det_apply = det_apply
        self.run = over_devices(one, n_shared=4)
        self.batch = min(cfg.batch, cfg.trials)
        self.guide_scale = guide_scale

    def _load_parts(self, recs: list[Method], cfg: MultiConfig) -> None:
        """The estimators, lookup tables and learned rule the rows `recs` read; the context
        parts have the plain ones' shapes, so the rows share one compiled rollout. `parts`: what
        each row switches with, for its table row."""
        init, est_dir, lookup_dir = self.init, cfg.est_dir, cfg.lookup_dir
        self.est_apply, self.est_params, self.est_meta, self.context_est_params = (None,) * 4
        self.lookup_m, self.context_lookup_m, self.when_cfg, self.parts = None, None, None, {}
        if any(r.estimators == "sweep" for r in recs):
            self.est_params, self.est_meta = est_lib.load_estimator_set(init, est_dir)
            self.est_apply = est_lib.predict
            self.parts["estimator"] = [f"{k}: {pathlib.Path(est_dir) / f'{init}_{k}'}"
                                       for k in self.lineup.targets]
        if any(r.lookup == "sweep" for r in recs):
            self.lookup_m = lookup.load_lookup(init, lookup_dir)
            self.parts["lookup"] = [f"{k}: {pathlib.Path(lookup_dir) / f'lookup_{init}.json'}"
                                    for k in self.lineup.targets]
        est_ctx = [r for r in recs if r.estimators == "context"]
        if est_ctx:
            paths = est_lib.context_estimator_paths(init, est_dir)
            if paths is None:
                raise FileNotFoundError(f"no {init}_context estimators in {est_dir}")
            self.context_est_params, _ = est_lib.load_estimator_paths(paths)
            self.est_apply = est_lib.predict
            if self.est_params is None:  # a compiled rollout needs some set for the other methods
                self.est_params = self.context_est_params
            for r in est_ctx:
                self.parts[r.name] = ([f"{k}: {p}" for k, p in zip(self.lineup.targets, paths)]
                                      + [f"estimate >= threshold on {r.persist_steps} control "
                                         f"step(s) in a row"])
        if recs[0].when:  # the learned rule: its own model, read with the context
            path = pathlib.Path(cfg.when_dir) / init
            self.est_params, self.when_meta = est_lib.load_estimator(path)
            self.when_cfg = wcfg = cfg.when_cfg or default_when_config()
            self.est_apply = when_lib.rule_fn(self.env, wcfg)
            for r in recs:
                self.parts[r.setup_of or r.name] = [
                    f"model: {path}", f"switch once P(now) >= best later P ({wcfg.later_from}) + "
                    f"{float(wcfg.margin):g} on {int(wcfg.persist_steps)} control step(s) in a row"]
        if any(r.lookup == "context" for r in recs):
            self.context_lookup_m, used = lookup.load_context_lookup(init, lookup_dir,
                                                                     lineup=self.lineup)
            for r in recs:
                if r.lookup == "context":
                    self.parts[r.setup_of or r.name] = used

    def parts_for(self, method: Method | str) -> list[str]:
        """What row `method` switches with (its estimators, lookup file or model per target, and
        its setup policies), for its table row."""
        rec = method_record(method) if isinstance(method, str) else method
        plain = "estimator" if rec.estimators == "sweep" else "lookup" if rec.lookup == "sweep" else ""
        parts = list(self.parts.get(rec.setup_of or rec.name, self.parts.get(plain, [])))
        return parts + (self.parts["setup"] if rec.setup else [])

    def rules_for(self, method: Method | str, margin: float | None = None,
                  persist_steps: int | None = None):
        """(switching rules, estimator params) of Table II row `method`, from its record; the
        learned rule's `margin` and `persist_steps` default to its config's (`when --tune` tries
        others in the same compiled rollout)."""
        rec = method_record(method) if isinstance(method, str) else method
        lookup_m = self.context_lookup_m if rec.lookup == "context" else self.lookup_m
        est_params = (self.context_est_params if rec.estimators == "context"
                      else self.est_params)
        cfg, persist = default_switching_config(), rec.persist_steps
        if rec.when:  # its score P(now) - best later P against the margin
            cfg.estimator_threshold = float(self.when_cfg.margin if margin is None else margin)
            persist = int(self.when_cfg.persist_steps if persist_steps is None else persist_steps)
        setup = None
        if rec.setup:
            setup = self.setup
            lookup_m = sw.walk_on_lookup(lookup_m, self.walk_on, setup, lineup=self.lineup)
        rules = sw.make_rules(rec.rule, lookup_m=lookup_m, cfg=cfg, persist_steps=persist,
                              setup=setup, lineup=self.lineup)
        return rules, est_params

    def evaluate(self, method: str, trials: int, seed: int, print_fn=None, **rule) -> dict:
        """Per-trial outcomes of row `method` (`rule`: rules_for's overrides)."""
        rules, est_params = self.rules_for(method, **rule)
        return _run_batches(lambda rng, ids: self.run(self.suite.params, est_params,
                                                      self.det_params, rules, rng, ids),
                            trials, self.batch, seed, print_fn,
                            f"{self.init}/{method}")


class BaselineSetup:
    """The DQN selector or a one-policy row (the end-to-end policy, the distilled student) on
    MultiSetup's tracks, seeds and horizon.

    All run `dqn.dqn_rollout` (same resets, chunks, early stop and frozen metrics as
    `switching.multi_rollout`); a one-policy row is a suite of its record's `policy` whose
    "selector" always picks it. On another line-up's tracks they run as they are: the DQN chooses
    among the paper's policies and its one-hot shows a kind it lacks as nothing detected."""

    def __init__(self, method: str, cfg: MultiConfig):
        trials, runs, stand_in, n_artifacts = cfg.trials, cfg.runs, cfg.stand_in, cfg.n_artifacts
        track_seed, backend, dqn_dir = cfg.track_seed, cfg.backend, cfg.dqn_dir
        if method not in BASELINES:
            raise ValueError(f"unknown baseline {method!r}; expected one of {BASELINES}")
        self.method, rec = method, method_record(method)
        kind = cfg.lineup.tracks
        if method == "dqn":
            run_dir = runs_lib.find_dqn(runs, "stand", dqn_dir)
            if run_dir is None:
                raise FileNotFoundError(f"no stand-init DQN checkpoint under {dqn_dir or runs}/ or "
                                        f"{runs_lib.BASELINE_DIR}/ (make train-dqn)")
            self.env = multi_env("stand", trials, n_artifacts, track_seed, kind,
                                 detector_one_hot=True, backend=backend,
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
            self.env = multi_env("stand", trials, n_artifacts, track_seed, kind, backend=backend,
                                 **pol.suite_env_overrides("stand", runs, names=(rec.policy,)))
            self.suite = pol.load_suite("stand", self.env, runs, names=(rec.policy,))
            self.q_params = jax.numpy.zeros(())

            def q_apply(_, x):  # the only policy of the suite, always
                return jax.numpy.zeros(x.shape[:-1] + (1,))
            self.sources = self.suite.sources
        env, apply = self.env, self.suite.apply
        horizon, guide_scale = int(round(cfg.horizon_s / self.env.dt)), cfg.guide_scale
        # the end-to-end policy reads no detector (only its heightmap); the DQN reads the detected
        # kind, the oracle's or the learned one's
        reads = method_record(method).reads_detector
        parts_lib.check_detector(cfg.detector_dir if reads else None, cfg.lineup)
        det_apply, self.det_params, self.detector = load_detector(
            cfg.detector_dir if reads else None, env)
        if not reads and cfg.detector_dir is not None:
            self.detector = "none: the end-to-end policy reads no detector"

        def one(suite_params, q_params, det_params, rng, ids):
            return dqn_train.dqn_rollout(env, apply, suite_params, q_apply, q_params, rng,
                                         ids.shape[0], horizon, track_ids=ids,
                                         guide_scale=guide_scale, det_apply=det_apply,
                                         det_params=det_params)

        self.run = over_devices(one, n_shared=3)
        self.batch = min(cfg.batch, trials)

    def evaluate(self, trials: int, seed: int, print_fn=None) -> dict:
        return _run_batches(lambda rng, ids: self.run(self.suite.params, self.q_params,
                                                      self.det_params, rng, ids),
                            trials, self.batch, seed, print_fn, self.method)


def make_setup(rec: Method, recs: Sequence[Method], cfg: MultiConfig):
    """The set-up that runs row `rec` in a table of the rows `recs`: a baseline's own, or the
    MultiSetup of its rollout, whose parts are loaded for every row of `recs` sharing it."""
    if rec.baseline:
        return BaselineSetup(rec.name, cfg)
    return MultiSetup([r for r in recs if r.rollout == rec.rollout], cfg)


def evaluate_multi(methods, cfg: MultiConfig, seed: int, print_fn=print,
                   per_trial: dict | None = None) -> tuple[list, dict]:
    """Table II rows (dicts) for `methods`, and the set-ups that ran them by `Method.rollout`
    (a baseline: its name), every env on the physics `cfg.backend` with its policies' env
    overrides. `wall_s` of a row includes its setup and compiles. `per_trial`, if given, gets
    each method's per-trial outcomes (TRIAL_FIELDS), to find the trials behind a row's failures."""
    setups, rows = {}, []
    recs = [method_record(m) for m in methods]
    for rec in recs:
        t0, key = time.perf_counter(), rec.rollout
        if key not in setups:
            setups[key] = make_setup(rec, recs, cfg)
        used = setups[key]
        merged = (used.evaluate(cfg.trials, seed, print_fn) if rec.baseline
                  else used.evaluate(rec.name, cfg.trials, seed, print_fn))
        if per_trial is not None:
            per_trial[rec.name] = {k: np.asarray(merged[k]) for k in TRIAL_FIELDS if k in merged}
        row = episode_table(merged, cfg.lineup.targets)
        row.update(method=rec.name, init=rec.suite, wall_s=time.perf_counter() - t0,
                   switches_per_trial=float(np.mean(merged["n_switches"])),
                   policies=list(used.sources if rec.baseline else used.suite.sources),
                   backend=used.env.backend, detector=used.detector, **lineup_meta(cfg.lineup))
        if not rec.baseline:
            if rec.setup:
                row["policy_names"] = list(used.policy_names)
            parts = used.parts_for(rec)
            if parts:
                row["switch_parts"] = parts  # the estimators or lookup file per target
        rows.append(row)
        print_fn(f"  {rec.name:22s} distance {row['distance_pct']:5.1f}%  success "
                 f"{row['success_pct']:5.1f}%  ({row['wall_s']:.0f} s)")
    return rows, setups


def lineup_meta(lineup: lineups.Lineup) -> dict:
    """What a row and a table record of their line-up: nothing for the paper's (its files stay
    as they were), else its name, policies, targets and track kind."""
    if lineup == lineups.PAPER_LINEUP:
        return {}
    return {"lineup": lineup.name, "lineup_policies": list(lineup.policies),
            "lineup_targets": list(lineup.targets), "tracks": lineup.tracks}


# Per-trial outcomes `evaluate multi` keeps beside the table (table2_trials.npz): trial i ran on
# track MULTI_TRACK_SEED + i; fail_kind is the ARTIFACT_KINDS code of the artifact fallen on (-1: none)
TRIAL_FIELDS = ("success", "fell", "fail_kind", "progress_frac", "n_switches", "switch_ahead_m",
                "active_at_start", "switch_from", "switch_forced", "switch_output")


# The settings that fix what a Table II row measured: rows made with equal values of these are
# rows of one table (the batch too: a policy's matmuls round differently at another batch size, and
# a trajectory is chaotic), so `evaluate multi` may add rows to a table across sessions.
TRIAL_KEYS = ("trials", "batch", "seed", "horizon_s", "n_artifacts", "stand_in", "guide_scale",
              "track_seed", "detector", "lineup")
# what a table made before these settings existed was made with (a paper line-up table records
# no line-up)
TRIAL_DEFAULTS = {"track_seed": MULTI_TRACK_SEED, "detector": "oracle",
                  "lineup": lineups.PAPER_LINEUP.name}


def merge_rows(old: dict | None, rows: list[dict], settings: dict) -> list[dict]:
    """`rows` joined with the rows of `old` (a table2.json) for the methods not among them, in
    MULTI_METHODS order (`stats.join_rows`): the methods' inputs (sweeps, estimators, DQN,
    end-to-end policy) are ready at different times, and each row's `policies` keeps where it
    came from."""
    if old:
        old = {**old, "settings": {**TRIAL_DEFAULTS, **old.get("settings", {})}}
    return join_rows(old, rows, {**TRIAL_DEFAULTS, **settings}, TRIAL_KEYS,
                     key=lambda r: r["method"], order=MULTI_METHODS)

"""Switch-point sweeps (paper Sec. III-C): estimator data and lookup tables.

    python -m biped_switch.sweep --init stand [--targets jumps gaps stairs] [--points 100000]

For a target policy i and every other policy j, pi_j walks up to a single artifact of kind i; the
artifact is detected 0.9 m ahead and pi_i takes over at a distance U(0, 0.9) m before it. The five
observations (robot state + heightmap) at control steps t-2 .. t+2 around the switch step t form
one sample, labelled 1 when the robot then makes `steps_past` (2) steps with the foot centre past
the artifact's end without falling (a step: a landing of the other foot than the last step's, so
two steps need each foot; see `count_steps_past`), or reaches the finish line, else 0 (a fall, or
neither within `horizon_s`).
Episodes that fall before the switch, or never reach the switch point, give no sample. Sources
cycle j over the other three policies, so every pair gets a third of the samples.

One jitted rollout runs a batch of episodes (split over every local device with pmap) until all
have a label; batches are saved as parts under runs/sweeps/<init>/<target>/ and a rerun resumes
after the last part; the parts are merged into runs/sweeps/<init>/<target>.npz (the estimator's
input, see estimator.py for the fields). The lookup table (success rate per 1 cm of switch
distance for each pair j -> i, and its argmax) and the success-against-distance figure (the
paper's Fig. 4b) go to experiments/results/lookup/.

    python -m biped_switch.sweep --init stand --context [--targets gaps]

A *context* sweep (ours, not the paper's) switches where the switching controller does on a
`mixed` track: an artifact policy j first crosses its own artifact and hands over before the next
one, of kind i (two-artifact tracks [j, i]); walk, which only ever acts before the first artifact,
switches before an [i, other] track's first. The paper's sweep starts every source on flat ground,
so its data never hold the states just after an artifact, where Table II's switches happen. Data,
lookup table and figure are named `<init>_context`.

    python -m biped_switch.sweep --init stand --lead-in --switch-min 0.2 [--targets gaps]

A *lead-in* sweep (ours) goes one step further: every episode starts with walk, and the earlier
hand-overs follow the context lookup table, as on Table II's tracks (`sweep_tracks.leadin_plan`);
named `<init>_leadin`. The tracks and plans are in `sweep_tracks.py`.

A context sweep of another line-up (`--lineup stones`: a `lineups.Lineup`'s policies, targets and
track kind) is named `<init>_context_stones`; plain and lead-in sweeps are the paper's only.
"""

from __future__ import annotations

import functools
import json
import pathlib
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from biped_switch.simulation import env as env_lib
from biped_switch.learning import policies as pol
from biped_switch.config import SWEEP_TRACK_SEED, default_sweep_config, default_switching_config
from biped_switch.kinds import POLICY_OF_CODE, policy_for
from biped_switch.lineups import PAPER_LINEUP, Lineup
from biped_switch.paths import LOOKUP
from biped_switch.switching.estimator import sweep_name
from biped_switch.switching.lookup import load_context_lookup
from biped_switch.simulation.observation import layout
from biped_switch.simulation.rollout import episode_keys, over_devices, reset_by_track, run_episodes
from biped_switch.switching.labels import (label_step, labelling_init, window_fill, window_init,
                                           window_update)
from biped_switch.switching.sweep_tracks import (context_plan, leadin_plan, make_context_env,
                                                 check_sweep_kind, make_env, others,
                                                 sweep_lineup)


# ----------------------------------------------------------------------- the rollout
def sweep_rollout(env, apply, params, rng, track_ids, sources, target: int, switch_max_m: float,
                  steps_past: int, horizon: int, chunk: int = 50, guide_scale=0.0,
                  end_offset_m: float = 0.0, target_index=None, window=None,
                  switch_min_m: float = 0.0, approach_queries: int = 0, switch_at_m=None,
                  reset_keys=None, lead_m=None, lead_jitter_m: float = 0.0,
                  force_m: float = 0.01) -> dict:
    """A batch of switch episodes (one env per track id), switching before artifact
    `target_index` (B,) of each track (default 0: the first; context sweeps switch before the 2nd).

    `sources` (B,) policy index acting before the switch, `target` the index switched to;
    `guide_scale` > 0 turns the scripted gait's guide forces on and `end_offset_m` moves the line
    past which steps count from the artifact's end (tests only: the guided robot never crosses an
    artifact, so only a line moved back gives it labels of 1). `window`: the step offsets of the
    observations recorded around the switch (default: the sweep config's).

    The switch distance is U(`switch_min_m`, `switch_max_m`) [m], or `switch_at_m` (B,) where
    given (a replay of recorded switches, with their episodes' `reset_keys` (B, 2)).
    `approach_queries` K > 0 also records, per episode, the
    observation at the first step within each of K distances U(switch distance, switch_max_m)
    of the target (before or at the switch: the source policy still acts), and the distance
    there: what a rule deciding *when* to switch sees earlier on the same approach.

    `lead_m` (P, N_TARGETS) [m] (a lead-in sweep): walk starts every episode, and before each
    artifact ahead of the target's the active policy hands over to that artifact's at
    lead_m[active, kind] - U(0, `lead_jitter_m`) (one draw per episode; at `force_m` at the
    latest), as the switching controller does along a track; `sources` then names the policy
    the lead-in leaves acting before the target.

    One function: `act` and `record` close over the episode draws the compiled rollout reads."""
    n = track_ids.shape[0]
    keys, k_u = episode_keys(rng, n)
    reset_keys = keys if reset_keys is None else reset_keys
    state = reset_by_track(env, reset_keys, track_ids, guide_scale=guide_scale)
    k_q = jax.random.fold_in(k_u, 1)  # k_u itself draws the paper's switch distances, as before
    if switch_at_m is None:
        switch_at = jax.random.uniform(k_u, (n,), minval=switch_min_m, maxval=switch_max_m)
    else:
        switch_at = jnp.asarray(switch_at_m, jnp.float32)
    q_at = switch_at[:, None] + jax.random.uniform(k_q, (n, approach_queries)) * (
        switch_max_m - switch_at[:, None])
    tidx = (jnp.zeros(n, jnp.int32) if target_index is None
            else jnp.asarray(target_index, jnp.int32))
    lead_u = jax.random.uniform(jax.random.fold_in(k_u, 2), (n,)) * lead_jitter_m
    start = sources if lead_m is None else jnp.full(n, pol.POLICY_INDEX["walk"])
    carry = {"active": start.astype(jnp.int32), "switched": jnp.zeros(n, bool),
             "dist_m": jnp.full(n, jnp.nan), "lab": labelling_init((n,)),
             "win": jax.vmap(lambda o: window_init(o, window))(state.obs),
             "q_obs": jnp.zeros((n, approach_queries) + state.obs.shape[1:], state.obs.dtype),
             "q_dist_m": jnp.full((n, approach_queries), jnp.nan),
             "q_done": jnp.zeros((n, approach_queries), bool),
             "lead_dist_m": jnp.full(n, jnp.nan), "left": jnp.full(n, -1, jnp.int32)}
    label_steps = jax.vmap(functools.partial(label_step, steps_past=steps_past))

    def act(c, state, live, _):
        si = jax.vmap(env.switch_inputs)(state)
        det = si["detect"]
        near = live & ~c["switched"] & (det["kind"] >= 0) & (det["index"] == tidx)
        now = near & (det["dist_m"] <= switch_at)
        active = c["active"]
        if lead_m is not None:  # the lead-in: hand over into each earlier artifact's policy
            code = jnp.maximum(det["kind"], 0)
            at_m = jnp.nan_to_num(lead_m[active, code], nan=force_m) - lead_u
            code_pol = jnp.asarray(_POLICY_OF_CODE)[code]
            lead = (live & (det["kind"] >= 0) & (det["index"] < tidx) & (code_pol != active)
                    & (det["dist_m"] <= jnp.maximum(at_m, force_m)))
            active = jnp.where(lead, code_pol, active)
            c = {**c, "lead_dist_m": jnp.where(lead, det["dist_m"], c["lead_dist_m"])}
        left = jnp.where(now, active, c["left"])  # the policy the switch leaves
        active = jnp.where(now, target, active)
        win = jax.vmap(window_update)(c["win"], state.obs, now, c["switched"] & live)
        q_hit = near[:, None] & ~c["q_done"] & (det["dist_m"][:, None] <= q_at)
        q_obs = jnp.where(q_hit[..., None], state.obs[:, None], c["q_obs"])
        q_dist = jnp.where(q_hit, det["dist_m"][:, None], c["q_dist_m"])
        action = pol.select(pol.all_actions(apply, params, state.obs), active)
        before = c["switched"]
        c = {**c, "active": active, "switched": before | now, "win": win, "left": left,
             "dist_m": jnp.where(now, det["dist_m"], c["dist_m"]), "q_obs": q_obs,
             "q_dist_m": q_dist, "q_done": c["q_done"] | q_hit}
        return action, c, (si, before)

    def record(c, aux, state, nxt, live):
        si, switched_before = aux
        # touchdowns counted on the observation's own contact flags (this step vs the last)
        lab = label_steps(c["lab"], live, switched_before, c["switched"], si["contact"],
                          si["contact_prev"], si["soles"][..., 0],
                          jnp.take_along_axis(state.info["art_x1"], tidx[:, None], 1)[:, 0]
                          + end_offset_m,
                          nxt.metrics["fell"] > 0.5, nxt.metrics["success"] > 0.5, nxt.done > 0.5)
        return {**c, "lab": lab}, lab.ended  # a label (or a fall) ends the episode

    # Ended episodes are frozen (`freeze_state`). Not needed for the record (it reads only live
    # steps), but it keeps the compiled step bit-identical to the env's own: the window test
    # compares observations to 1e-4 after ~200 chaotic contact steps, and a regrouped program
    # drifts.
    ep = run_episodes(env, state, horizon, act, carry, record=record, chunk=chunk,
                      freeze_state=True)
    c, lab = ep.carry, ep.carry["lab"]
    # the window is complete two steps after the switch; a label needs >= 2 steps, so later
    valid = c["switched"] & ~lab.fell_before
    return {"window": jax.vmap(window_fill)(c["win"]), "label": lab.label, "valid": valid,
            "switch_dist_m": c["dist_m"], "switch_at_m": switch_at, "source": sources,
            "track_id": track_ids, "fell": lab.fell, "steps": ep.length.astype(jnp.int32),
            "steps_past": lab.steps, "approach_obs": c["q_obs"], "approach_dist_m": c["q_dist_m"],
            "approach_valid": c["q_done"], "approach_at_m": q_at, "switch_left": c["left"],
            "fell_before": lab.fell_before,
            "lead_dist_m": c["lead_dist_m"]}


def make_runner(env, apply, target: str, cfg, guide_scale: float = 0.0, target_index=None,
                replay: bool = False, lead_m=None):
    """(params, rng, track_ids, sources) -> batch results, split over all local devices;
    `target_index` (n_tracks,) the artifact switched before on each track (default: the first);
    `lead_m` the lead-in's switch table (a lead-in sweep). With `replay`: (params, rng,
    track_ids, sources, switch_at_m, reset_keys)."""
    horizon = int(round(cfg.horizon_s / env.dt))
    tgt = policy_for(target)  # its slot in any line-up's suite (slot = Behaviour.index)
    tidx_of = None if target_index is None else jnp.asarray(target_index, jnp.int32)

    def one(params, rng, ids, src, switch_at_m=None, reset_keys=None):
        return sweep_rollout(env, apply, params, rng, ids, src, tgt, cfg.switch_max_m,
                             cfg.steps_past, horizon, guide_scale=guide_scale,
                             target_index=None if tidx_of is None else tidx_of[ids],
                             window=tuple(cfg.window), switch_min_m=cfg.switch_min_m,
                             approach_queries=0 if replay else int(cfg.approach_queries),
                             switch_at_m=switch_at_m, reset_keys=reset_keys,
                             lead_m=None if lead_m is None else jnp.asarray(lead_m, jnp.float32),
                             lead_jitter_m=float(cfg.lead_jitter_m),
                             force_m=float(default_switching_config().force_switch_m))

    return over_devices(one, n_shared=1)


def sweep_env(init: str, target: str, cfg, runs, n_tracks: int, stand_in=None,
              backend: str = "auto", context: bool = False, lead_in: bool = False,
              lineup: Lineup = PAPER_LINEUP):
    """(env, policy suite, source per track, target artifact index per track) of a sweep; the
    last two are None for the paper's sweep (sources cycle, the first artifact). A `lead_in`
    sweep (a kind of context sweep) lays out `leadin_plan`'s tracks. The suite is `lineup`'s
    policies in slot order, and a context sweep's tracks its plan on its track kind."""
    overrides = pol.suite_env_overrides(init, runs, stand_in=stand_in, names=lineup.policies)
    if context or lead_in:
        plan = leadin_plan if lead_in else context_plan
        kinds, track_src, track_tidx = plan(target, n_tracks, lineup)
        env = make_context_env(kinds, init, cfg.difficulty, lineup=lineup, backend=backend,
                               **overrides)
    else:
        track_src = track_tidx = None
        env = make_env(target, init, n_tracks, cfg.difficulty, backend=backend, **overrides)
    suite = pol.load_suite(init, env, runs, stand_in=stand_in, names=lineup.policies)
    return env, suite, track_src, track_tidx


def replay_labels(data: dict, n: int, batch: int, runs="runs", stand_in=None, backend="auto",
                  tol_m: float = 1e-4, band_m=(0.3, 0.9), seed: int = 0, print_fn=print) -> dict:
    """Label noise: `n` recorded switches of a sweep (`data`, its merged npz) within `band_m`,
    replayed from their own starts at their own switch distances (+ `tol_m`, so a last-bit
    difference in the distance picks the same control step) in a program compiled for another
    batch size. A trajectory is chaotic, so float rounding that differs with the batch can flip a
    label; the agreement rate is the labels' noise floor."""
    meta = data["meta"]
    cfg = default_sweep_config()
    for k, v in meta["config"].items():  # the sweep's own settings (JSON lists back to tuples)
        if k in cfg:
            cfg[k] = tuple(v) if isinstance(cfg[k], tuple) else v
    if batch == int(cfg.batch):
        raise ValueError(f"replay batch {batch} equals the sweep's: choose another, so that the "
                         f"program differs")
    lead_in = bool(meta.get("lead_in"))
    env, suite, track_src, track_tidx = sweep_env(
        meta["init"], meta["target"], cfg, runs, int(meta["n_tracks"]), stand_in, backend,
        bool(meta.get("context")), lead_in, sweep_lineup(meta))
    sample_idx = np.unique(data["sample"])  # global episode index: batch b * sweep batch + i
    first = np.searchsorted(data["sample"], sample_idx)
    dist = data["switch_dist_m"][first]
    pick = np.flatnonzero((dist >= band_m[0]) & (dist <= band_m[1]))
    pick = np.sort(np.random.default_rng(seed).choice(pick, min(n, len(pick)), replace=False))
    g = sample_idx[pick]
    b_orig, i_orig = g // int(cfg.batch), g % int(cfg.batch)
    batch_keys = {int(b): np.asarray(episode_keys(jax.random.fold_in(  # as run_sweep drew them
        jax.random.PRNGKey(int(meta["seed"])), int(b)), int(cfg.batch))[0]) for b in set(b_orig)}
    keys = np.stack([batch_keys[int(b)][int(i)] for b, i in zip(b_orig, i_orig)])
    runner = make_runner(env, suite.apply, meta["target"], cfg, target_index=track_tidx,
                         replay=True,
                         lead_m=np.asarray(meta["lead_m"], float) if lead_in else None)
    labels, dists, t0 = [], [], time.perf_counter()
    for s in range(0, len(g), batch):
        idx = np.arange(s, s + batch) % len(g)  # the last batch wraps; its extra rows are dropped
        out = jax.device_get(runner(suite.params, jax.random.PRNGKey(0),
                                    jnp.asarray(data["track_id"][first[pick[idx]]], jnp.int32),
                                    jnp.asarray(data["source"][first[pick[idx]]], jnp.int32),
                                    jnp.asarray(dist[pick[idx]] + tol_m, jnp.float32),
                                    jnp.asarray(keys[idx])))
        labels.append(np.asarray(out["label"])[: min(batch, len(g) - s)])
        dists.append(np.asarray(out["switch_dist_m"])[: min(batch, len(g) - s)])
        print_fn(f"[replay {meta['target']}] {min(s + batch, len(g))}/{len(g)} switches "
                 f"({time.perf_counter() - t0:.0f} s)")
    new = np.concatenate(labels).astype(int)
    old = data["label"][first[pick]].astype(int)
    # the same start and the same approach switch at the same control step (a check of the replay)
    same_step = np.abs(np.concatenate(dists) - dist[pick]) < 1e-3
    return {"target": meta["target"], "n": int(len(g)), "batch": batch,
            "same_switch_step_pct": round(100 * float(same_step.mean()), 2),
            "sweep_batch": int(cfg.batch), "band_m": list(band_m),
            "agree_pct": round(100 * float((new == old).mean()), 2),
            "flips_1_to_0": int(((old == 1) & (new == 0)).sum()),
            "flips_0_to_1": int(((old == 0) & (new == 1)).sum()),
            "success_pct_recorded": round(100 * float(old.mean()), 2),
            "success_pct_replayed": round(100 * float(new.mean()), 2),
            "wall_s": round(time.perf_counter() - t0, 1)}


# ----------------------------------------------------------------------- the sweep driver
def _split(window: np.ndarray, lay):
    """(robot state, heightmap, phase clock) of observations: the estimator's inputs (the
    `ObsLayout` `lay`'s state and heightmap) and the gait clock the policies act on, without the
    one-hot after them."""
    state = window[..., lay.state].astype(np.float32)
    hm = window[..., lay.heightmap].astype(np.float16)
    return state, hm, window[..., lay.phase].astype(np.float32)


def _part(out: dict, first_sample: int, window, lay) -> tuple[dict, int]:
    """A batch's valid samples as len(window) rows each (the estimator's fields and the phase
    clock), and their count. Per sample, not per row (in the order of the samples' offset-0
    rows, which carry the sample's label, source, track and switch distance): the `approach_*`
    records (K queries each: state, heightmap, phase, distance [m], valid) and `lead_dist_m`,
    where the lead-in last handed over (NaN: no lead-in).

    An episode that fell before its switch has no sample, but its approach records still say
    something true: waiting from there for the switch distance (`lost_switch_at_m`) failed.
    Without them a "when" rule would count only the waits that survived, and wait too long. They
    are kept as `lost_*` (approach records, source, track, the intended switch distance)."""
    v = np.asarray(out["valid"])
    state, hm, phase = _split(np.asarray(out["window"])[v], lay)
    a_state, a_hm, a_phase = _split(np.asarray(out["approach_obs"])[v], lay)
    n_s, n_w = int(v.sum()), len(window)
    k = np.repeat(np.arange(n_s), n_w)

    def rows(x, dtype):
        return np.repeat(np.asarray(x)[v], n_w).astype(dtype)

    lost = np.asarray(out["fell_before"]) & np.asarray(out["approach_valid"]).any(-1)
    l_state, l_hm, l_phase = _split(np.asarray(out["approach_obs"])[lost], lay)
    lost_part = {"lost_approach_state": l_state, "lost_approach_heightmap": l_hm,
                 "lost_approach_phase": l_phase,
                 "lost_approach_dist_m": np.asarray(out["approach_dist_m"])[lost].astype(np.float32),
                 "lost_approach_valid": np.asarray(out["approach_valid"])[lost],
                 "lost_source": np.asarray(out["source"])[lost].astype(np.int8),
                 "lost_track_id": np.asarray(out["track_id"])[lost].astype(np.int32),
                 "lost_switch_at_m": np.asarray(out["switch_at_m"])[lost].astype(np.float32)}
    return {**lost_part,
            "state": state.reshape(-1, state.shape[-1]), "heightmap": hm.reshape(-1, hm.shape[-1]),
            "phase": phase.reshape(n_s * n_w, phase.shape[-1]),
            "approach_state": a_state, "approach_heightmap": a_hm, "approach_phase": a_phase,
            "approach_dist_m": np.asarray(out["approach_dist_m"])[v].astype(np.float32),
            "approach_valid": np.asarray(out["approach_valid"])[v],
            "lead_dist_m": np.asarray(out["lead_dist_m"])[v].astype(np.float32),
            "label": rows(out["label"], np.int8),
            "sample": (first_sample + np.flatnonzero(v)[k]).astype(np.int32),
            "offset": np.tile(np.asarray(window, np.int8), n_s),
            "source": rows(out["source"], np.int8),
            "switch_dist_m": rows(out["switch_dist_m"], np.float32),
            "track_id": rows(out["track_id"], np.int32)}, n_s


# Every session adding parts to a sweep must share these; of the config only the keys below may
# differ (more points extend a sweep; the lookup bin applies to the merged data only).
_POLICY_OF_CODE = np.asarray(POLICY_OF_CODE, np.int32)  # the policy that crosses each artifact code
RESUME_KEYS = ("policies", "seed", "config", "guide_scale", "n_tracks", "track_seed", "context",
               "lead_in", "lead_m")
PROGRESS_CONFIG_KEYS = ("n_points", "lookup_bin_m", "approach_queries")  # extra records only
CONFIG_KEY_DEFAULTS = {"switch_min_m": 0.0, "lead_jitter_m": 0.2}  # what sweeps made before a key existed used


def resume_key(meta: dict) -> dict:
    """The part of a sweep's meta (as JSON) that the parts already made depend on."""
    key = json.loads(json.dumps({k: meta.get(k) for k in RESUME_KEYS}, default=str))
    key["context"] = bool(key["context"])  # absent in sweeps made before context sweeps existed
    key["lead_in"] = bool(key["lead_in"])
    key["config"] = {k: v for k, v in {**CONFIG_KEY_DEFAULTS, **(key["config"] or {})}.items()
                     if k not in PROGRESS_CONFIG_KEYS}
    return key


class SweepRun(NamedTuple):
    """One run_sweep call: the merged data, this session's own figures and the sweep's total."""

    path: pathlib.Path  # the merged npz
    points_new: int  # points made by this session
    loop_s: float  # this session's batch loop (its first batch includes the compile)
    steady_points: int  # points of this session's batches after the first
    steady_s: float  # their time: the rate without the compile
    session_s: float  # this session's wall time: setup, compile, loop, merge
    wall_s_total: float  # the sweep's wall time summed over the sessions that made points


def run_sweep(init: str, target: str, cfg, out_dir: pathlib.Path, runs="runs", seed: int = 0,
              n_tracks: int = 512, stand_in: str | None = None, guide_scale: float = 0.0,
              print_fn=print, backend: str = "auto", context: bool = False,
              lead_in: bool = False, lookup_results=LOOKUP,
              lineup: Lineup = PAPER_LINEUP) -> SweepRun:
    """Runs (or resumes, or extends to `cfg.n_points`) the sweep of one target kind, on the
    physics `backend`, in an env with the policy suite's env overrides. With `context`, the
    tracks are `context_plan`'s two-artifact tracks and the data go to `<init>_context/`; with
    `lead_in`, `leadin_plan`'s, walk leading in by the context lookup (under `lookup_results`),
    to `<init>_leadin/`. Another `lineup` than the paper's: context only, `<init>_context_<it>/`.

    part_dir/meta.json keeps `wall_s_total`, the sum of the wall times of the sessions that ran
    batches; it is updated after every part and on an exception, so an interrupted session's time
    counts too (all but its last batch's if the process is killed).

    One function: one resumable session top to bottom, `write_meta` closing over its wall time."""
    t_start = time.perf_counter()
    if target not in lineup.targets:
        raise ValueError(f"target must be one of line-up {lineup.name}'s {lineup.targets}, "
                         f"got {target!r}")
    check_sweep_kind(lineup, context, lead_in)
    name = sweep_name(init, context, lead_in, lineup=lineup)
    part_dir = out_dir / name / target
    part_dir.mkdir(parents=True, exist_ok=True)
    env, suite, track_src, track_tidx = sweep_env(init, target, cfg, runs, n_tracks, stand_in,
                                                  backend, context, lead_in, lineup)
    lead_m = load_context_lookup(init, lookup_results, lineup)[0] if lead_in else None  # (P, T)
    # no line-up named: the paper's (its meta as before line-ups existed; see `sweep_lineup`)
    named = {} if lineup == PAPER_LINEUP else {"lineup": lineup.name}
    meta = {"init": init, "target": target, **named, "seed": seed, "n_tracks": n_tracks,
            "track_seed": SWEEP_TRACK_SEED, "policies": dict(zip(lineup.policies, suite.sources)),
            "config": cfg.to_dict(), "window": list(cfg.window), "guide_scale": guide_scale,
            "env_overrides": dict(suite.env_overrides),
            "backend": env_lib.resolve_backend(backend), "context": bool(context or lead_in),
            "lead_in": bool(lead_in),
            "lead_m": None if lead_m is None else [[None if np.isnan(v) else round(float(v), 4)
                                                    for v in row] for row in lead_m]}
    meta_path = part_dir / "meta.json"
    wall0 = 0.0
    if meta_path.exists():
        old = json.loads(meta_path.read_text())
        k_old, k_new = resume_key(old), resume_key(meta)
        if k_old != k_new:
            diff = [k for k in RESUME_KEYS if k_old[k] != k_new[k]]
            diff += [f"config.{k}" for k in sorted(set(k_old["config"]) | set(k_new["config"]))
                     if "config" in diff and k_old["config"].get(k) != k_new["config"].get(k)]
            raise RuntimeError(f"{part_dir} holds parts of a sweep with other {', '.join(diff)}; "
                               f"move it away or pass another --out")
        wall0 = float(old.get("wall_s_total", 0.0))

    def write_meta(wall_s_total):
        meta["wall_s_total"] = round(wall_s_total, 3)
        meta_path.write_text(json.dumps(meta, indent=2, default=str))

    write_meta(wall0)
    srcs = np.array(others(target, lineup))
    runner = make_runner(env, suite.apply, target, cfg, guide_scale, track_tidx, lead_m=lead_m)
    parts = sorted(part_dir.glob("part_*.npz"))
    have = sum(int(np.load(p)["label"].shape[0]) for p in parts)
    b = len(parts)
    if have:
        print_fn(f"[sweep {name}/{target}] resuming: {len(parts)} parts, {have:,} points")
    t0, pts0 = time.perf_counter(), have
    steady_points, steady_s = 0, 0.0
    batch = cfg.batch
    ran = False  # whether this session ran a batch (a session that runs none adds no time)
    try:
        while have < cfg.n_points:
            ran = True
            t_b = time.perf_counter()
            idx = np.arange(b * batch, (b + 1) * batch)
            ids = jnp.asarray(idx % n_tracks, jnp.int32)
            src = jnp.asarray(srcs[idx % len(srcs)] if track_src is None
                              else track_src[idx % n_tracks], jnp.int32)
            rng = jax.random.fold_in(jax.random.PRNGKey(seed), b)
            out = jax.device_get(runner(suite.params, rng, ids, src))
            part, n_s = _part(out, b * batch, cfg.window, layout(env))
            tmp = part_dir / f"tmp_{b:05d}.npz"
            np.savez_compressed(tmp, **part)
            tmp.rename(part_dir / f"part_{b:05d}.npz")
            write_meta(wall0 + time.perf_counter() - t_start)
            n_p, dt = len(part["label"]), time.perf_counter() - t_b
            if b > len(parts):  # not this session's first batch (the compile)
                steady_points, steady_s = steady_points + n_p, steady_s + dt
            have += n_p
            b += 1
            left_min = max(cfg.n_points - have, 0) / max(
                (have - pts0) / max(time.perf_counter() - t0, 1e-9), 1e-9) / 60
            print_fn(f"[sweep {name}/{target}] batch {b}: {n_s}/{batch} valid samples, "
                     f"{100 * part['label'].mean() if n_s else float('nan'):.0f}% success; "
                     f"{have:,}/{cfg.n_points:,} points, {n_p / max(dt, 1e-9):,.0f} points/s this "
                     f"batch ({dt:.1f} s), ~{left_min:.1f} min left")
            if n_s == 0 and b >= 3 and have == 0:
                raise RuntimeError(f"no valid switch sample in {b} batches: the source policies "
                                   f"fall before the switch point (untrained policies?)")
        loop_s = time.perf_counter() - t0
        path = merge_parts(part_dir, out_dir / name / f"{target}.npz", meta)
    finally:  # the session's time, an interrupted one's too
        session_s = time.perf_counter() - t_start
        if ran:
            write_meta(wall0 + session_s)
    return SweepRun(path, have - pts0, loop_s, steady_points, steady_s, session_s,
                    meta["wall_s_total"])


def merge_parts(part_dir: pathlib.Path, path: pathlib.Path, meta: dict) -> pathlib.Path:
    parts = [dict(np.load(p)) for p in sorted(part_dir.glob("part_*.npz"))]
    # parts made before a field was recorded lack it: the merge keeps the fields all parts have
    keys = [k for k in parts[0] if all(k in p for p in parts)]
    merged = {k: np.concatenate([p[k] for p in parts]) for k in keys}
    merged["meta"] = np.array(json.dumps(meta, default=str))
    np.savez_compressed(path, **merged)
    return path


def rate_or_none(points: int, seconds: float):
    return round(points / seconds, 1) if points > 0 and seconds > 0 else None


def data_stats(data: dict, path: pathlib.Path, wall_s_total: float) -> dict:
    """A target's entry in the lookup's meta["sweeps"]; `wall_s` is the sweep's total wall time
    over all its sessions (Table III's sweep cost)."""
    return {"points": int(len(data["label"])), "wall_s": round(float(wall_s_total), 1),
            "success_pct": round(100 * float(data["label"].mean()), 2), "data": str(path)}


def stored_stats(data: dict, path: pathlib.Path, stored: dict) -> dict | None:
    """The entry of a target not swept by this command: its entry in the existing lookup (the
    speed of the session that made it) with points and total wall time from its data and part
    dir (newer, if the data was extended elsewhere); None where no wall time is known."""
    meta_path = path.with_suffix("") / "meta.json"
    part_meta = json.loads(meta_path.read_text()) if meta_path.exists() else data["meta"]
    wall = part_meta.get("wall_s_total", stored.get("wall_s"))
    return None if wall is None else {**stored, **data_stats(data, path, wall)}

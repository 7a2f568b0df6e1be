"""When to switch: the paper's switching rules (Sec. IV-B) as one pure, per-env decision function,
and the multi-policy rollout that applies them on multi-artifact tracks.

Every method differs only in *when* it switches. The oracle detector names the next artifact once
its start is within 0.9 m of the body; the policy of the line-up that crosses it
(`lineups.Lineup.policy_of_code`) becomes the target, and the rule decides at each control step
whether the active policy hands over now:
  random         at a distance U(0, 0.9) m before the artifact, drawn at detection (the same
                 thing as a random distance travelled after detection)
  detection      at once
  lookup         at the lookup table's best distance for (active policy -> target)
  com_over_feet  when the whole-body CoM is over the support polygon of the touching soles and the
                 feet are within `feet_tol_m` of each other fore-aft
  estimator      when the target's switch estimator gives E(s) >= `estimator_threshold`, on
                 `persist_steps` control steps in a row (1, the paper's rule: the first such step);
                 Table II's `learned` row runs this rule on the learned when rule's score
                 (switching/when.py: P(now) - best later P) against its margin
With setup policies (ours: switching/setup.py), a pair (active -> target) that has one switches
into it as soon as the target is detected, and the setup policy hands over to the target's policy
at its own hand-over distance (the one it was trained with), whatever the method. A walk-on pair
(its source is its own best setup) is only a lookup entry: the source acts to that distance.
Every method is forced to switch once the artifact is `force_switch_m` (1 cm) away, so a rule
that never fires (and a distance stepped over between control steps) still switches in time.
While nothing is detected the active policy keeps control; an artifact policy also walks the
flat after its artifact (>= 1.08 m) until the next artifact comes into range and its switch. The method is a traced integer and the rules' numbers are traced arrays, so
all methods and both policy suites run through one compiled rollout.

The rules are sized by a line-up (`lineups.Lineup`, default the paper's: 4 policies, 3 targets):
`make_rules(..., lineup=)` puts its policy per artifact code, walk slot and policy count in
`Rules` as arrays, so `decide` reads no module constant. A code the line-up does not switch into
(a kind added after it) makes its walk policy the target; the lookup and estimator rules have no
entry for it and switch at the forced distance.
"""

from __future__ import annotations

import itertools
import warnings
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from biped_switch.learning import policies as pol
from biped_switch.config import default_switching_config
from biped_switch.simulation.detection import debounce_step
from biped_switch.simulation.rollout import episode_keys, reset_by_track, run_episodes
from biped_switch.lineups import PAPER_LINEUP, Lineup
from biped_switch.methods import RULES

METHODS = RULES  # the rules a Table II row (methods.py) can name
METHOD_INDEX = {m: i for i, m in enumerate(METHODS)}
# the paper line-up's sizes (the default line-up; other line-ups: Lineup.n_policies, .n_targets)
N_POLICIES = PAPER_LINEUP.n_policies
N_TARGETS = PAPER_LINEUP.n_targets  # the switch targets: jumps, gaps, stairs


class Rules(NamedTuple):
    """Traced parameters of a switching method."""

    method: jax.Array  # int32 index into METHODS
    lookup_m: jax.Array  # (P, T) switch distance [m] for active -> target (P: suite, T: targets)
    threshold: jax.Array  # estimator threshold
    force_m: jax.Array  # forced switch distance [m]
    feet_tol_m: jax.Array
    margin_m: jax.Array  # CoM may be this far outside the support polygon [m]
    switch_max_m: jax.Array  # random method: U(0, switch_max_m)
    persist_steps: jax.Array  # int32: estimator: E >= threshold this many control steps in a row
    setup_of: jax.Array  # (P, T) int32: the setup policy for active -> target (-1: none);
    # policies from index n_policies on are setup policies
    handover_m: jax.Array  # (T,) a setup policy hands over this far before the target [m]
    policy_of_code: jax.Array  # (T,) int32: the line-up's policy that crosses each artifact code
    walk_policy: jax.Array  # int32: the line-up's flat-ground policy (target of an unknown code)
    n_policies: jax.Array  # int32: the line-up's behaviour policies (slots 0..n-1; then setup)


class SetupSlots(NamedTuple):
    """Where setup policies sit in a suite (host-side, resolved once): `setup_of` (P, T) the suite
    index of the setup policy for (active policy, target kind), -1 where the pair has none;
    `handover_m` (T,) each target's hand-over distance [m] (NaN: no setup policy); T: the
    line-up's targets."""

    setup_of: np.ndarray
    handover_m: np.ndarray


def _check_handover(what: str, handover_m) -> None:
    if not 0.0 < float(handover_m) < 0.9:
        raise ValueError(f"{what}: hand-over distance {handover_m!r} m is outside (0, 0.9) m, the "
                         f"detection range")


def setup_slots(names, setups: dict, lineup: Lineup = PAPER_LINEUP) -> SetupSlots:
    """SetupSlots of a suite whose policies are `names` (`lineup.policies`, then setup policies),
    from `setups` {setup policy name: (target kind, source policy names, hand-over distance [m])};
    a setup policy serves its pairs in any line-up that has its target and sources."""
    names = list(names)
    if names[:lineup.n_policies] != list(lineup.policies):
        raise ValueError(f"a suite of line-up {lineup.name} with setup policies starts with "
                         f"{lineup.policies}, got {names}")
    setup_of = np.full((len(names), lineup.n_targets), -1, np.int32)
    handover = np.full(lineup.n_targets, np.nan, np.float32)
    for name, (target, sources, handover_m) in setups.items():
        if name not in names:
            raise ValueError(f"setup policy {name!r} is not in the suite {names}")
        k = _named(name, lineup.target_index, target)
        _check_handover(name, handover_m)
        for src in sources:
            setup_of[_named(name, lineup.source_slot, src), k] = names.index(name)
        handover[k] = float(handover_m)
    return SetupSlots(setup_of, handover)


def _named(what: str, fn, name: str) -> int:
    """`fn(name)` (a line-up's target index or source slot), its ValueError prefixed by `what`."""
    try:
        return fn(name)
    except ValueError as e:
        raise ValueError(f"{what}: {e}") from None


def walk_on_lookup(lookup_m, walk_on: dict, setup: SetupSlots | None = None,
                   lineup: Lineup = PAPER_LINEUP) -> np.ndarray:
    """The (n_policies, n_targets) lookup table of `lineup` with each walk-on pair's entry set to
    its hand-over distance: `walk_on` {target kind: (source policy names, hand-over distance
    [m])}, pairs whose source is its own best setup and acts on to that distance. A pair that
    also has a setup policy in `setup` is an error (which of the two would act?)."""
    shape = (lineup.n_policies, lineup.n_targets)
    out = (np.zeros(shape, np.float32) if lookup_m is None
           else np.array(lookup_m, np.float32, copy=True))
    if out.shape != shape:
        raise ValueError(f"lookup table of line-up {lineup.name} must be {shape}, got {out.shape}")
    for target, (sources, handover_m) in walk_on.items():
        _check_handover(f"walk-on into {target}", handover_m)
        k = _named("walk-on", lineup.target_index, target)
        for src in sources:
            j = _named(f"walk-on into {target}", lineup.source_slot, src)
            if setup is not None and setup.setup_of[j, k] >= 0:
                raise ValueError(f"walk-on pair {src} -> {target} also has a setup policy")
            out[j, k] = float(handover_m)
    return out


def make_rules(method: str, lookup_m=None, cfg=None, switch_max_m: float = 0.9,
               persist_steps: int | None = None, setup: SetupSlots | None = None,
               lineup: Lineup = PAPER_LINEUP) -> Rules:
    """Traced rules of `method` for `lineup`'s policies and targets (the lookup table is
    (n_policies, n_targets)); `setup`: the suite's setup policies (None: a suite of the line-up's
    behaviour policies, no setup)."""
    if method not in METHOD_INDEX:
        raise ValueError(f"unknown switching method {method!r}; expected one of {METHODS}")
    cfg = cfg or default_switching_config()
    n_pol, n_tgt = lineup.n_policies, lineup.n_targets
    if lookup_m is None:
        if method == "lookup":
            raise ValueError("the lookup method needs a lookup table (python -m biped_switch.sweep)")
        lookup_m = np.zeros((n_pol, n_tgt))
    lookup_m = np.asarray(lookup_m, np.float32)
    if lookup_m.shape != (n_pol, n_tgt):
        raise ValueError(f"lookup table must be {(n_pol, n_tgt)} (line-up {lineup.name}: "
                         f"{lineup.policies} x {lineup.targets}), got {lookup_m.shape}")
    if method == "lookup":
        own = np.zeros_like(lookup_m, bool)
        own[list(lineup.policy_of_code), np.arange(n_tgt)] = True  # a target's own policy: unused
        missing = np.argwhere(np.isnan(lookup_m) & ~own)
        if len(missing):
            warnings.warn(f"lookup table has no data for {len(missing)} pair(s) (active, target) "
                          f"{[tuple(int(v) for v in m) for m in missing]}: those switch only at the "
                          f"forced distance ({(cfg.force_switch_m):g} m)", stacklevel=2)
    persist = int(cfg.estimator_persist_steps if persist_steps is None else persist_steps)
    if persist < 1:
        raise ValueError(f"persist_steps must be >= 1 (1: the paper's rule), got {persist}")
    if setup is None:
        setup = SetupSlots(np.full((n_pol, n_tgt), -1, np.int32), np.full(n_tgt, np.nan, np.float32))
    if setup.setup_of.shape[1] != n_tgt or setup.setup_of.shape[0] < n_pol:
        raise ValueError(f"setup slots {setup.setup_of.shape} do not fit line-up {lineup.name} "
                         f"({n_pol} policies, {n_tgt} targets): setup_slots(..., lineup=)")
    # a setup policy's row of the lookup is never read (it hands over at its own distance)
    lookup_m = np.concatenate([lookup_m, np.zeros((setup.setup_of.shape[0] - n_pol, n_tgt),
                                                  np.float32)])
    f32 = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    i32 = lambda v: jnp.asarray(v, jnp.int32)  # noqa: E731
    return Rules(i32(METHOD_INDEX[method]), jnp.asarray(np.nan_to_num(lookup_m)),
                 f32(cfg.estimator_threshold), f32(cfg.force_switch_m), f32(cfg.feet_tol_m),
                 f32(cfg.support_margin_m), f32(switch_max_m), i32(persist),
                 i32(setup.setup_of), f32(np.nan_to_num(setup.handover_m)),
                 i32(lineup.policy_of_code), i32(lineup.walk_policy), i32(n_pol))


class SwitchState(NamedTuple):
    """Per-env controller state."""

    active: jax.Array  # int32 policy index acting now
    art_index: jax.Array  # int32 index of the artifact last detected (-1: none yet)
    random_m: jax.Array  # random method: this artifact's switch distance [m]
    n_switches: jax.Array  # int32
    est_run: jax.Array  # int32: control steps in a row the detected target's E >= threshold
    det_count: jax.Array = np.int32(0)  # artifacts the learned detector has named so far
    det_kind: jax.Array = np.int32(-1)  # the learned detector's kind as reported (debounced)
    det_cand: jax.Array = np.int32(-1)  # a new kind it names, not yet reported
    det_run: jax.Array = np.int32(0)  # control steps in a row it has named det_cand


def init_state(n_envs: int) -> SwitchState:
    zi, mi = jnp.zeros(n_envs, jnp.int32), jnp.full(n_envs, -1, jnp.int32)
    return SwitchState(zi, mi, jnp.zeros(n_envs, jnp.float32), zi, zi, zi, mi, mi, zi)


def learned_detection(ss: SwitchState, kind: jax.Array, steps: int, via_none: bool = False):
    """One control step of a learned detector's output as the rules read it: (new state, kind,
    index). A change of kind is held back until it has been named `steps` control steps in a row
    (a one-step misreading never switches policies). The oracle indexes artifacts by their slot
    on the track; a learned detector sees no track, so an artifact is a new one whenever the
    reported kind starts naming something after nothing (index: those onsets counted, -1 while
    nothing is named). `via_none`: a new kind only after none (`detection.debounce_step`)."""
    rep, cand, run = debounce_step(ss.det_kind, ss.det_cand, ss.det_run, kind, steps, via_none)
    count = ss.det_count + ((rep >= 0) & (ss.det_kind < 0)).astype(jnp.int32)
    ss = ss._replace(det_kind=rep, det_cand=cand, det_run=run, det_count=count)
    return ss, rep, jnp.where(rep >= 0, count, -1)


# ----------------------------------------------------------------------- CoM over feet
_TRI = np.array(list(itertools.combinations(range(8), 3)), np.int32)  # 56 triangles of 8 soles
_SEG = np.array(list(itertools.combinations(range(8), 2)), np.int32)  # 28 segments


def in_support(p: jax.Array, pts: jax.Array, mask: jax.Array, margin_m) -> jax.Array:
    """Whether 2D point `p` lies within `margin_m` of the convex hull of the masked `pts` (8, 2).

    In 2D a point is in the hull iff it is in a triangle of three of the points (Caratheodory),
    so test all 56 triangles, plus the 28 segments and 8 points for hulls that are degenerate
    (one or two touching soles, or soles in a line). Pure and jittable."""
    a, b, c = pts[_TRI[:, 0]], pts[_TRI[:, 1]], pts[_TRI[:, 2]]

    def cross(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    area2 = cross(b - a, c - a)
    sgn = jnp.where(area2 >= 0, 1.0, -1.0)
    ok_tri = mask[_TRI].all(axis=1) & (jnp.abs(area2) > 1e-8)
    inside = jnp.ones(len(_TRI), bool)
    for s, e in ((a, b), (b, c), (c, a)):  # signed distance of p from each edge, inward positive
        edge = e - s
        dist = sgn * cross(edge, p - s) / jnp.maximum(jnp.linalg.norm(edge, axis=-1), 1e-9)
        inside &= dist >= -margin_m
    s, e = pts[_SEG[:, 0]], pts[_SEG[:, 1]]
    d = e - s
    t = jnp.clip(jnp.sum((p - s) * d, -1) / jnp.maximum(jnp.sum(d * d, -1), 1e-12), 0.0, 1.0)
    near_seg = jnp.linalg.norm(s + t[:, None] * d - p, axis=-1) <= margin_m
    near_pt = jnp.linalg.norm(pts - p, axis=-1) <= margin_m
    return (jnp.any(inside & ok_tri) | jnp.any(near_seg & mask[_SEG].all(axis=1))
            | jnp.any(near_pt & mask))


def com_over_feet(body_com, soles, contact, yaw, feet_tol_m, margin_m) -> jax.Array:
    """The paper's heuristic: CoM over the support polygon and both feet close together.

    `soles` (8, 3) sole centres (left four, right four), `contact` (8,) 1 where touching;
    "close" = fore-aft distance (along the heading `yaw`) of the feet's centres <= feet_tol_m."""
    heading = jnp.array([jnp.cos(yaw), jnp.sin(yaw)])
    left, right = soles[:4, :2].mean(0), soles[4:, :2].mean(0)
    feet_close = jnp.abs(jnp.dot(left - right, heading)) <= feet_tol_m
    return feet_close & in_support(body_com[:2], soles[:, :2], contact > 0.5, margin_m)


# ----------------------------------------------------------------------- the decision
def decide(ss: SwitchState, det_kind, det_index, det_dist_m, com_ok, est_probs, u01,
           rules: Rules) -> tuple[SwitchState, jax.Array]:
    """One env, one control step: (new controller state, switched now?).

    det_*: the oracle detection (kind -1 when nothing is in range), com_ok: com_over_feet,
    est_probs (T,): every estimator's output on the current observation (a model that
    reads the context, the learned when rule: its score for the detected target in every slot;
    the estimator rule then compares that score with the threshold, its margin), u01: a uniform
    draw in [0, 1) used when a new artifact is detected (random method). Sized by `rules` (its
    line-up): a detected code it has no target for makes its walk policy the target, with no
    lookup entry, estimate or setup policy (switched at the forced distance by those rules)."""
    seen = det_kind >= 0
    known = seen & (det_kind < rules.policy_of_code.shape[0])  # a target of the line-up
    kind = jnp.clip(det_kind, 0, rules.policy_of_code.shape[0] - 1)
    new_art = seen & (det_index != ss.art_index)
    random_m = jnp.where(new_art, u01 * rules.switch_max_m, ss.random_m)
    target = jnp.where(seen, jnp.where(known, rules.policy_of_code[kind], rules.walk_policy),
                       ss.active)
    pending = target != ss.active
    lookup_m = jnp.where(known, rules.lookup_m[ss.active, kind], 0.0)
    # a run of confident estimates, counted afresh for each artifact
    est_run = jnp.where(known & (est_probs[kind] >= rules.threshold),
                        jnp.where(new_art, 0, ss.est_run) + 1, 0).astype(jnp.int32)
    fire = jnp.stack([
        det_dist_m <= random_m,
        jnp.asarray(True),
        det_dist_m <= lookup_m,
        com_ok,
        est_run >= rules.persist_steps,
    ])[rules.method]
    # setup policies: into one at detection (unless already inside its hand-over distance), out
    # of one into the target's policy at the hand-over distance
    setup = jnp.where(known, rules.setup_of[ss.active, kind], -1)
    handover_m = rules.handover_m[kind]
    into_setup = pending & (setup >= 0) & (det_dist_m > handover_m)
    fire = jnp.where(ss.active >= rules.n_policies, det_dist_m <= handover_m, fire)
    switch = pending & (into_setup | fire | (det_dist_m <= rules.force_m))
    target = jnp.where(into_setup, setup, target)
    new = ss._replace(active=jnp.where(switch, target, ss.active).astype(jnp.int32),
                      art_index=jnp.where(seen, det_index, ss.art_index).astype(jnp.int32),
                      random_m=random_m, n_switches=ss.n_switches + switch.astype(jnp.int32),
                      est_run=est_run)
    return new, switch


# ----------------------------------------------------------------------- multi-policy rollout
def controller_inputs(env, state, est_apply, est_params, rules: Rules, det_apply=None,
                      det_params=None) -> dict:
    """Batched rule inputs for a batch of env states (detection, CoM over feet, estimators).
    "detect" is what the rules act on: the oracle's, or with `det_apply` (switching.detector's
    `detect_fn`) the learned detector's on the observation; "truth" is always the oracle's (for
    the record of where each switch happened)."""
    si = jax.vmap(env.switch_inputs)(state)
    si["truth"] = si["detect"]
    if det_apply is not None:
        si["detect"] = det_apply(det_params, state.obs, si["yaw"])
    com_ok = jax.vmap(com_over_feet, in_axes=(0, 0, 0, 0, None, None))(
        si["body_com"], si["soles"], si["contact"], si["yaw"], rules.feet_tol_m, rules.margin_m)
    n_targets = rules.lookup_m.shape[1]
    if est_apply is None or reads_context(est_apply):  # none, or computed after the detection
        probs = jnp.zeros((state.obs.shape[0], n_targets))
    else:
        probs = jax.vmap(est_apply, in_axes=(0, None))(est_params, state.obs).T  # (B, T)
        if probs.shape[1] != n_targets:
            raise ValueError(f"{probs.shape[1]} switch estimators for rules of {n_targets} targets: "
                             f"the estimators were made for another line-up")
    return {**si, "com_ok": com_ok, "est_probs": probs}


def reads_context(est_apply) -> bool:
    """Whether a rule's model reads the active policy and the detection besides the observation
    (`switching.when.RuleFn`: called as (params, obs, active, kind, dist_m) -> (B,) scores)."""
    return bool(getattr(est_apply, "reads_context", False))


def switch_and_act(env, suite_apply, suite_params, est_apply, est_params, rules: Rules,
                    det_apply=None, det_params=None):
    """(ss, state, live, u01) -> (action, ss, controller inputs, switched now): one control step
    of the switching controller for a batch; switches of ended episodes are not counted."""
    def act(ss, state, live, u01):
        ci = controller_inputs(env, state, est_apply, est_params, rules, det_apply, det_params)
        det = ci["detect"]
        if det_apply is None:
            index = det["index"]
        else:
            ss, kind, index = learned_detection(ss, det["kind"],
                                                getattr(det_apply, "debounce_steps", 1),
                                                getattr(det_apply, "via_none", False))
            det = ci["detect"] = {**det, "kind": kind,
                                  "dist_m": jnp.where(kind >= 0, det["dist_m"], jnp.inf)}
        if reads_context(est_apply):  # its score for the detected target, in every slot
            sc = est_apply(est_params, state.obs, ss.active, det["kind"], det["dist_m"])
            ci["est_probs"] = jnp.broadcast_to(sc[:, None], (sc.shape[0], rules.lookup_m.shape[1]))
        n_before = ss.n_switches
        ss, switched = jax.vmap(decide, in_axes=(0, 0, 0, 0, 0, 0, 0, None))(
            ss, det["kind"], index, det["dist_m"], ci["com_ok"], ci["est_probs"], u01, rules)
        ss = ss._replace(n_switches=jnp.where(live, ss.n_switches, n_before))
        action = pol.select(pol.all_actions(suite_apply, suite_params, state.obs), ss.active)
        return action, ss, ci, switched

    return act


def multi_rollout(env, suite_apply, suite_params, est_apply, est_params, rules: Rules,
                  rng: jax.Array, n_envs: int, horizon: int, track_ids=None,
                  chunk: int = 50, guide_scale=0.0, det_apply=None, det_params=None) -> dict:
    """Episodes on the env's tracks, each starting with the walk policy and switching by `rules`.

    Runs in chunks of `chunk` steps and stops early once every episode has ended
    (`rollout.run_episodes`; ended episodes step on unread). Returns the per-episode final env
    metrics, `length` (live steps), `done` and `n_switches`. `guide_scale` > 0 turns the scripted
    gait's guide forces on (tests and diagnostics only).

    Also `switch_ahead_m` (n_envs, A): for each of the track's A artifact slots (sorted by x, as
    the detector indexes them), the distance [m] from the CoM to its start when the controller
    switched into its policy; NaN where it never did. Which rule switches where, and what that
    cost (`table2.switch_distances`). `active_at_start` (n_envs, A): the policy index acting when
    the CoM came over each artifact's start (-1: never reached), so a fall with the wrong policy
    on an artifact shows a missed or wrong detection. `det_apply`, `det_params`: a learned detector in place of
    the oracle (switching.detector); the switch distances stay the oracle's measure.
    Per slot, the last switch there is also logged: `switch_from` (the policy it left),
    `switch_forced` (made at the forced distance) and `switch_output` (the rule's model output
    for the target there: the estimator's E(s), the learned rule's score; 0 for rules without
    a model)."""
    reset_keys, k_run = episode_keys(rng, n_envs)
    if track_ids is None:
        track_ids = jax.random.randint(k_run, (n_envs,), 0, env.bank.size)
    state = reset_by_track(env, reset_keys, track_ids,
                           guide_scale=guide_scale)
    switch_act = switch_and_act(env, suite_apply, suite_params, est_apply, est_params, rules,
                                 det_apply, det_params)
    slots = jnp.arange(state.info["art_x0"].shape[-1])

    def act(c, state, live, _):
        ss, key, ahead, on, log = c
        key, k_u = jax.random.split(key)  # a carried key, split per step (the random rule's draws)
        before = ss.active
        action, ss, ci, switched = switch_act(ss, state, live, jax.random.uniform(k_u, (n_envs,)))
        truth, det = ci["truth"], ci["detect"]
        at = slots[None, :] == truth["index"][:, None]
        hit = (switched & live)[:, None] & at
        ahead = jnp.where(hit, truth["dist_m"][:, None], ahead)
        # every switch's record: from which policy, forced or not, the rule's output there
        k_out = jnp.clip(det["kind"], 0, ci["est_probs"].shape[1] - 1)  # the rules' target slot
        output = jnp.take_along_axis(ci["est_probs"], k_out[:, None], 1)[:, 0]
        forced = det["dist_m"] <= rules.force_m
        log = {"switch_from": jnp.where(hit, before[:, None], log["switch_from"]),
               "switch_forced": jnp.where(hit, forced[:, None], log["switch_forced"]),
               "switch_output": jnp.where(hit, output[:, None], log["switch_output"])}
        # the policy acting as the CoM comes over the artifact's start (the oracle's measure)
        first = (live & (truth["dist_m"] <= 0.0))[:, None] & at & (on < 0)
        on = jnp.where(first, ss.active[:, None], on)
        return action, (ss, key, ahead, on, log), None

    shape = (n_envs, slots.shape[0])
    ahead0 = jnp.full(shape, jnp.nan, jnp.float32)
    on0 = jnp.full(shape, -1, jnp.int32)
    log0 = {"switch_from": on0, "switch_forced": jnp.zeros(shape, bool), "switch_output": ahead0}
    ep = run_episodes(env, state, horizon, act, (init_state(n_envs), k_run, ahead0, on0, log0),
                      chunk=chunk)
    return {**ep.metrics, "length": ep.length, "done": ep.done,
            "n_switches": ep.carry[0].n_switches, "switch_ahead_m": ep.carry[2],
            "active_at_start": ep.carry[3], **ep.carry[4]}


def trace_rollout(env, suite_apply, suite_params, est_apply, est_params, rules: Rules,
                  rng: jax.Array, track_id, horizon: int, guide_scale=0.0, det_apply=None,
                  det_params=None) -> dict:
    """One episode with a per-step record (for the paper's Fig. 5): time, CoM, soles, contacts,
    detection, every estimator's output, CoM-over-feet, active policy, switch events. The episode
    is frozen (its whole state) once it ends and the record runs to the horizon (`ended` = 1)."""
    state = reset_by_track(env, rng[None], jnp.reshape(jnp.asarray(track_id), (1,)),
                           guide_scale=guide_scale)
    switch_act = switch_and_act(env, suite_apply, suite_params, est_apply, est_params, rules,
                                 det_apply, det_params)

    def act(ss, state, live, key):
        action, ss, ci, switched = switch_act(ss, state, live, jax.random.uniform(key, (1,)))
        return action, ss, (ci, switched)

    def trace(ss, aux, state, nxt, live):
        ci, switched = aux
        det = ci["detect"]
        return {"time_s": state.info["time_s"][0], "qpos": state.pipeline_state.qpos[0],
                "com_x_m": ci["com_x_m"][0],
                "body_com": ci["body_com"][0], "soles": ci["soles"][0], "contact": ci["contact"][0],
                "det_kind": det["kind"][0], "det_dist_m": det["dist_m"][0],
                "est_probs": ci["est_probs"][0], "com_ok": ci["com_ok"][0], "active": ss.active[0],
                "switched": switched[0], "ended": (~live[0]).astype(jnp.float32),
                "fell": nxt.metrics["fell"][0], "success": nxt.metrics["success"][0]}

    return run_episodes(env, state, horizon, act, init_state(1), trace=trace, rng=rng,
                        freeze_state=True).trace

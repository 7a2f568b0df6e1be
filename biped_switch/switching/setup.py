"""Setup policies (the paper's future work): a short policy that takes the robot from a
source behaviour's exit into the target behaviour's region of attraction, then hands over.

The composite env `SetupEnv` wraps a BipedEnv on two-artifact tracks [source kind, target kind]
and runs three phases, kept in `state.info["phase"]` (the phase of the policy that acts on this
state):

  SOURCE  the frozen source policy acts, until its artifact is passed and the target is
          detected (the oracle detector's next artifact is the target, within `detect_range_m`,
          0.9 m): the moment a switching controller would switch;
  SETUP   the learner acts (the action given to `step`), until the target artifact's start is
          `handover_m` away (a fixed hand-over distance);
  TARGET  the frozen target policy acts, until the episode ends: success = the CoM crosses the
          success line `finish_after_m` past the target artifact, or a fall.

`state.info["learner_acts"]` is 1 where the next action is the learner's (phase SETUP): PPO
(learning/ppo.py) weights its policy loss by it, while values and GAE run over every step (the
frozen phases are part of the learner's environment).

Reward: the BipedEnv's walking reward (times `setup_reward_scale`) on SETUP steps; on a fall in
SETUP or TARGET, `fall_penalty` once; on success, `success_bonus` once; nothing on SOURCE steps
(a source fall is not the learner's). The frozen policies' actions come from the stacked suite
(learning/policies.py) evaluated inside the jitted step.

Reset pool: the source phase is deterministic given the track (stand init, no pushes, a
deterministic source policy), and it is most of an episode's steps. `build_pool` runs it once per
track (one jitted rollout) and keeps each track's state at the start of SETUP; with a pool,
`reset` draws one of those states, so training simulates only the SETUP and TARGET phases.

Tracks: `setup_track` lays [source, target] as terrain.sequence_track does, but with short
artifacts (`source_segments`, `target_segments`: the source's exit and the target's first holes
are what the setup phase is about).

    python -m biped_switch.switching.setup baseline [--n 512]    # walk as the setup policy
    python -m biped_switch.train --policy setup_gaps --init stand    # train (resumable)
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np

from biped_switch import stats
from biped_switch.config import SETUP_TARGETS, default_setup_config, default_terrain_config
from biped_switch.learning import policies as pol
from biped_switch.simulation import env as env_lib
from biped_switch.simulation import terrain
from biped_switch.simulation.rollout import episode_keys, reset_by_track, rollout, run_episodes

SOURCE, SETUP, TARGET = 0, 1, 2
PHASES = ("source", "setup", "target")
TARGET_INDEX = 1  # the target is the track's second artifact
SETUP_TERMS = ("setup", "bonus", "penalty")  # reward/<term> metrics of the composite env


# ----------------------------------------------------------------------- tracks
def setup_track(seed: int, source: str, target: str, cfg=None, source_segments=(4, 5),
                target_segments=(2, 3)) -> terrain.Track:
    """A two-artifact track [source, target] laid as `terrain._build_track` lays one (run-up,
    >= flat_before_m of flats before each artifact, goal flat), with the source artifact's
    segment count drawn from `source_segments` (min, max) and the target's from
    `target_segments`."""
    cfg = cfg or default_terrain_config(2)
    codes = [terrain.ARTIFACT_KINDS.index(source), terrain.ARTIFACT_KINDS.index(target)]
    rng = np.random.default_rng([int(seed), 45, *codes])
    segs = terrain._flats(rng, cfg, cfg.start_back_m + cfg.runup_m)
    spans = []
    for kind, (lo, hi) in ((source, source_segments), (target, target_segments)):
        segs += terrain._flats(rng, cfg, cfg.flat_before_m)
        acfg = ml_collections.ConfigDict(cfg.to_dict())
        acfg.segments_min, acfg.segments_max = int(lo), int(hi)
        first = len(segs)
        segs += terrain._artifact(rng, acfg, kind)
        spans.append((first, len(segs) - 1))
    segs += terrain._flats(rng, cfg, cfg.goal_flat_m)
    return terrain.Track(
        kind="mixed", seed=int(seed), difficulty=1.0, width_m=float(rng.uniform(cfg.width_min_m,
                                                                                   cfg.width_max_m)),
        x_origin_m=-float(cfg.start_back_m), thickness_m=float(cfg.slab_thickness_m),
        segments=np.asarray(segs, dtype=np.float64), artifact_codes=np.asarray(codes, np.int32),
        artifact_segments=np.asarray(spans, np.int32), finish_after_m=float(cfg.finish_after_m))


def track_plan(sources, target: str, n_tracks: int, seed0: int, scfg):
    """(tracks, source name per track): sources alternate over the tracks."""
    tcfg = default_terrain_config(2)
    tcfg.finish_after_m = float(scfg.finish_after_m)
    src = [sources[i % len(sources)] for i in range(n_tracks)]
    tracks = [setup_track(seed0 + i, s, target, tcfg, tuple(scfg.source_segments),
                          tuple(scfg.target_segments)) for i, s in enumerate(src)]
    return tracks, src


# ----------------------------------------------------------------------- phase logic (pure)
def advance_phase(phase, det_index, det_kind, det_dist_m, handover_m, target_index=TARGET_INDEX):
    """The phase after a step, from the detection at the new state: SOURCE -> SETUP once the
    target artifact is detected (the detector's next artifact, within range: kind >= 0), SETUP
    -> TARGET once its start is `handover_m` or less away (both may happen in one step)."""
    is_target = det_index == target_index
    phase = jnp.where((phase == SOURCE) & is_target & (det_kind >= 0), SETUP, phase)
    return jnp.where((phase == SETUP) & is_target & (det_dist_m <= handover_m), TARGET, phase)


def phase_reward(phase, env_reward, fell, success, scfg):
    """(reward, terms) of a step taken in `phase` (see the module doc)."""
    fell, success = jnp.asarray(fell, jnp.float32), jnp.asarray(success, jnp.float32)
    setup = jnp.where(phase == SETUP, scfg.setup_reward_scale * env_reward, 0.0)
    bonus = jnp.where(phase == TARGET, scfg.success_bonus * success, 0.0)
    penalty = jnp.where(phase == SOURCE, 0.0, -scfg.fall_penalty * fell)
    terms = {"setup": setup, "bonus": bonus, "penalty": penalty}
    terms = {k: jnp.asarray(v, jnp.float32) for k, v in terms.items()}
    return sum(terms.values()).astype(jnp.float32), terms


# ----------------------------------------------------------------------- the composite env
class SetupEnv:
    """See the module doc. `apply`/`params`: a stacked suite of the frozen policies `names`;
    `source_of_track` (n_tracks,) the index into `names` of each bank track's source policy,
    `target` the target policy's index. reset(rng, difficulty, track_id, guide_scale,
    push_scale) ignores the curriculum's levels: full difficulty, no guides, no pushes."""

    def __init__(self, base: env_lib.BipedEnv, apply, params, names, source_of_track, target: int,
                 scfg):
        self.base, self.apply, self.params, self.names = base, apply, params, tuple(names)
        self.cfg = base.cfg
        self.scfg = scfg
        self._src = jnp.asarray(np.asarray(source_of_track, np.int32))
        self._tgt = int(target)
        self._handover = float(scfg.handover_m)
        self.pool = None  # {"state": State without obs/metrics, "prev": (N, 9)}, from build_pool
        self.source_in_setup = False  # True: the source policy acts on in SETUP (no setup policy:
        # the plain switch from source to target at the hand-over distance, a baseline)

    observation_size = property(lambda self: self.base.observation_size)
    policy_observation_size = property(lambda self: self.base.policy_observation_size)
    action_size = property(lambda self: self.base.action_size)
    backend = property(lambda self: self.base.backend)
    dt = property(lambda self: self.base.dt)
    bank = property(lambda self: self.base.bank)
    obs_layout = property(lambda self: self.base.obs_layout)

    def _detect(self, state):
        com_x = self.base._pose(state.pipeline_state.qpos)[2][0]
        return self.base.detect(state.info, com_x)

    def _wrap(self, s, phase, fell, success, terms, setup_steps):
        info = dict(s.info)
        info["phase"] = jnp.asarray(phase, jnp.int32)
        info["learner_acts"] = (info["phase"] == SETUP).astype(jnp.float32)
        info["setup_steps"] = jnp.asarray(setup_steps, jnp.int32)
        m = {k: v for k, v in s.metrics.items() if not k.startswith("reward/")}
        m.update(success=jnp.asarray(success, jnp.float32), fell=jnp.asarray(fell, jnp.float32),
                 phase=info["phase"].astype(jnp.float32),
                 source=self._src[info["track_id"]].astype(jnp.float32),
                 setup_steps=info["setup_steps"].astype(jnp.float32))
        m.update({f"reward/{k}": terms[k] for k in SETUP_TERMS})
        return s.replace(info=info, metrics=m)

    def reset(self, rng, difficulty=None, track_id=None, guide_scale=None, push_scale=None):
        if self.pool is not None and track_id is None:
            return self._pool_reset(rng)
        s = self.base.reset(rng, 1.0, track_id, 0.0, 0.0)
        det = self._detect(s)
        phase = advance_phase(jnp.int32(SOURCE), det["index"], det["kind"], det["dist_m"],
                              self._handover)
        zero = jnp.zeros((), jnp.float32)
        return self._wrap(s, phase, zero, zero, {k: zero for k in SETUP_TERMS}, 0)

    def _pool_reset(self, rng):
        k_i, k_env = jax.random.split(rng)
        i = jax.random.randint(k_i, (), 0, self.pool["prev"].shape[0])
        st = jax.tree.map(lambda x: x[i], self.pool["state"])
        info = dict(st["info"])
        info["rng"] = k_env
        data = st["pipeline_state"]
        obs, feat = self.base._observe(data, info, info["contact_prev"], prev=self.pool["prev"][i])
        zero = jnp.zeros((), jnp.float32)
        metrics = self.base._metrics(feat, info, fell=zero, success=zero,
                                     terms={k: zero for k in env_lib.REWARD_TERMS})
        s = env_lib.State(pipeline_state=data, obs=obs, reward=zero, done=zero, metrics=metrics,
                          info=info)
        return self._wrap(s, info["phase"], zero, zero, {k: zero for k in SETUP_TERMS},
                          info["setup_steps"])

    def frozen_action(self, state):
        """The frozen policy's action on `state` (the source's in SOURCE, else the target's)."""
        acts = pol.all_actions(self.apply, self.params, state.obs[None])[:, 0]  # (P, 12)
        src = self._src[state.info["track_id"]]
        src_acts = (state.info["phase"] == SOURCE) | (
            self.source_in_setup & (state.info["phase"] == SETUP))
        return jnp.where(src_acts, acts[src], acts[self._tgt])

    def step(self, state, action):
        phase = state.info["phase"]
        learner = (phase == SETUP) & (not self.source_in_setup)
        a = jnp.where(learner, jnp.clip(action, -1.0, 1.0), self.frozen_action(state))
        nxt = self.base.step(state, a)
        det = self._detect(nxt)
        new_phase = advance_phase(phase, det["index"], det["kind"], det["dist_m"], self._handover)
        fell, success = nxt.metrics["fell"], nxt.metrics["success"]
        reward, terms = phase_reward(phase, nxt.reward, fell, success, self.scfg)
        steps = state.info["setup_steps"] + (phase == SETUP).astype(jnp.int32)
        out = self._wrap(nxt, new_phase, fell, success, terms, steps)
        return out.replace(reward=reward)


# ----------------------------------------------------------------------- the reset pool
def source_phase(senv: SetupEnv, track_ids, horizon: int, chunk: int = 50):
    """Every track's source phase (the frozen source policy from the stand start), ended at the
    state that enters SETUP (or a fall, or the horizon): (Episodes' state, ok (B,) bool: entered
    SETUP without falling)."""
    keys, _ = episode_keys(jax.random.PRNGKey(0), track_ids.shape[0])
    state = reset_by_track(senv, keys, track_ids)

    def act(c, state, live, key):
        return jnp.zeros(state.obs.shape[:1] + (senv.action_size,)), c, None

    def record(c, aux, state, nxt, live):
        return c, nxt.info["phase"] != SOURCE

    ep = run_episodes(senv, state, horizon, act, None, record=record, chunk=chunk,
                      freeze_state=True)
    ok = (ep.state.info["phase"] == SETUP) & (ep.state.metrics["fell"] < 0.5)
    return ep.state, ok


def build_pool(senv: SetupEnv, horizon: int, batch: int = 256, print_fn=print) -> dict:
    """Runs `source_phase` on every bank track (batches of `batch`) and installs the pool of
    SETUP-start states (tracks whose source fell or overshot the hand-over are left out)."""
    t0 = time.perf_counter()
    run = jax.jit(lambda ids: source_phase(senv, ids, horizon))
    n = senv.bank.size
    states, prevs, n_ok = [], [], 0
    sl = env_lib.STATE_SLICES["contact_prev"]
    for b0 in range(0, n, batch):
        ids = jnp.arange(b0, min(b0 + batch, n), dtype=jnp.int32)
        st, ok = jax.device_get(run(ids))
        ok = np.asarray(ok)
        keep = {"pipeline_state": st.pipeline_state, "info": st.info}
        states.append(jax.tree.map(lambda x: np.asarray(x)[ok], keep))
        prevs.append(np.asarray(st.obs)[ok][:, sl])
        n_ok += int(ok.sum())
        print_fn(f"[setup pool] tracks {b0}..{b0 + len(ids) - 1}: {int(ok.sum())}/{len(ids)} "
                 f"reached the setup phase ({time.perf_counter() - t0:.0f} s)")
    if n_ok == 0:
        raise RuntimeError("no track's source phase reached the setup phase")
    pool = {"state": jax.tree.map(lambda *x: jnp.asarray(np.concatenate(x)), *states),
            "prev": jnp.asarray(np.concatenate(prevs))}
    senv.pool = pool
    print_fn(f"[setup pool] {n_ok}/{n} tracks in the pool, built in {time.perf_counter() - t0:.0f} s")
    return {"pool_size": n_ok, "pool_tracks": n, "pool_s": time.perf_counter() - t0}


# ----------------------------------------------------------------------- construction
def make_setup_env(scfg, n_tracks: int, seed0: int, runs="runs", backend: str = "auto",
                   env_overrides: dict | None = None) -> SetupEnv:
    """The composite env on `n_tracks` tracks seed0 + i (no pool: see `build_pool`)."""
    names = tuple(dict.fromkeys(list(scfg.sources) + [scfg.target]))
    overrides = dict(env_overrides if env_overrides is not None
                     else pol.suite_env_overrides(scfg.suite_init, runs, names=names))
    tracks, src = track_plan(tuple(scfg.sources), scfg.target, n_tracks, seed0, scfg)
    tcfg = default_terrain_config(2)
    tcfg.finish_after_m = float(scfg.finish_after_m)
    base = env_lib.make_env("mixed", scfg.suite_init, terrain_cfg=tcfg, tracks=tracks,
                            n_tracks=len(tracks), seed=seed0, difficulty=1.0, backend=backend,
                            **overrides)
    suite = pol.load_suite(scfg.suite_init, base, runs, names=names)
    senv = SetupEnv(base, suite.apply, suite.params, names, [names.index(s) for s in src],
                    names.index(scfg.target), scfg)
    senv.sources = suite.sources
    return senv


def setup_env(cfg, print_fn=print) -> SetupEnv:
    """The training env of a setup run config (`default_setup_config`): tracks
    setup.train_track_seed + seed + i, with the reset pool when `setup.pool`. The trainer's
    `env_fn`."""
    s = cfg.setup
    senv = make_setup_env(s, int(cfg.n_tracks), int(s.train_track_seed) + int(cfg.seed),
                          runs=s.get("suite_runs", "runs"), backend=cfg.env.backend)
    wrong = {k: (senv.cfg[k], v) for k, v in cfg.env.items() if k != "backend" and senv.cfg[k] != v}
    if wrong:
        raise ValueError(f"the setup run's env {wrong} (run, suite) differs from the frozen suite's")
    if s.pool:
        build_pool(senv, int(s.pool_horizon), print_fn=print_fn)
    return senv


def is_setup_policy(policy: str) -> bool:
    return policy.startswith("setup_")


def setup_train_config(policy: str):
    """`default_setup_config` of a policy name setup_<target> (it names the targets there are)."""
    return default_setup_config(policy.removeprefix("setup_"))


# ----------------------------------------------------------------------- evaluation
def evaluate(senv: SetupEnv, policy, n: int, rng_seed: int = 0, horizon: int = 1500,
             batch: int = 128) -> dict:
    """`n` full episodes (source phase included unless the env has a pool) on tracks 0..n-1 of
    the env's bank (cycled), with `policy(obs, key)` as the setup policy. Success is counted
    over the episodes that reached the setup phase, per source."""
    run = jax.jit(lambda rng, ids: rollout(senv, policy, rng, ids.shape[0], horizon,
                                           track_ids=ids))
    rows = []
    for b0 in range(0, n, batch):
        ids = jnp.asarray(np.arange(b0, min(b0 + batch, n)) % senv.bank.size, jnp.int32)
        r = jax.device_get(run(jax.random.PRNGKey(rng_seed + b0), ids))
        rows.append({k: np.asarray(r[k]) for k in ("success", "fell", "phase", "source",
                                                    "setup_steps", "length", "fail_kind")})
    r = {k: np.concatenate([x[k] for x in rows]) for k in rows[0]}
    reached = r["phase"] >= SETUP
    out = {"episodes": int(n), "reached_setup": int(reached.sum()),
           "source_fell": int((~reached & (r["fell"] > 0.5)).sum())}
    for j, name in enumerate(senv.names):
        sel = reached & (r["source"] == j)
        if not sel.any():
            continue
        k = int((r["success"][sel] > 0.5).sum())
        lo, hi = stats.wilson_ci(k, int(sel.sum()))
        out[f"{name}->{senv.names[senv._tgt]}"] = {
            "n": int(sel.sum()), "success": k, "success_pct": round(100 * k / sel.sum(), 1),
            "ci95_pct": None if lo is None else [round(100 * lo, 1), round(100 * hi, 1)],
            "fell_in_setup": int(((r["fell"] > 0.5) & (r["phase"] == SETUP) & sel).sum()),
            "fell_in_target": int(((r["fell"] > 0.5) & (r["phase"] == TARGET) & sel).sum()),
            "timeout": int(((r["success"] < 0.5) & (r["fell"] < 0.5) & sel).sum()),
            "mean_setup_steps": round(float(r["setup_steps"][sel].mean()), 1),
            "failed_tracks": [int(i) for i in np.flatnonzero(sel & (r["success"] < 0.5))]}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.switching.setup",
                                description=__doc__.split("\n")[0])
    p.add_argument("what", choices=("baseline", "eval"),
                   help="a setup policy (or a baseline) on held-out tracks (tabulated by `python "
                        "-m biped_switch.reports.setup`)")
    p.add_argument("--target", default="gaps", choices=tuple(SETUP_TARGETS))
    p.add_argument("--setup", default="walk_stand",
                   help="the setup policy: a run name (runs/, models/policies/) or checkpoint; "
                        "'source': none, the source policy walks on to the hand-over")
    p.add_argument("--n", type=int, default=512, help="episodes (held-out tracks)")
    p.add_argument("--handover-m", type=float, default=None)
    p.add_argument("--pool", action="store_true", help="start from the source phase's end states "
                   "(otherwise whole episodes from the stand start)")
    p.add_argument("--full-tracks", action="store_true",
                   help="artifacts of the full size range (4..9 segments each) and the usual "
                        "1 m finish: closer to Table II's tracks than the short training ones")
    p.add_argument("--out", default=None, help="write the result JSON here")
    p.add_argument("--runs", default="runs", help="parent folder of the training runs of the "
                   "frozen policies and of a --setup run name (then the committed models/)")
    a = p.parse_args(argv)
    from biped_switch.learning import runs as runs_lib
    cfg = default_setup_config(a.target)
    if a.handover_m is not None:
        cfg.setup.handover_m = a.handover_m
    if a.full_tracks:
        tc = default_terrain_config(2)
        cfg.setup.source_segments = cfg.setup.target_segments = (tc.segments_min, tc.segments_max)
        cfg.setup.finish_after_m = tc.finish_after_m
    t0 = time.perf_counter()
    senv = make_setup_env(cfg.setup, a.n, int(cfg.setup.eval_track_seed), runs=a.runs)
    if a.pool:
        build_pool(senv, int(cfg.setup.pool_horizon))
    if a.setup == "source":
        senv.source_in_setup = True
        ckpt, prog = "source", {"step": None}

        def policy(obs, key):
            return jnp.zeros(obs.shape[:-1] + (senv.action_size,))
    else:
        ckpt = runs_lib.resolve_checkpoint(a.setup, pathlib.Path(a.runs))
        policy, prog = pol.load_policy(ckpt, senv.base)
    res = evaluate(senv, policy, a.n)
    doc = {"setup_policy": str(ckpt), "setup_policy_step": prog["step"],
           "frozen": list(senv.sources), "handover_m": cfg.setup.handover_m,
           "tracks": f"setup tracks {cfg.setup.eval_track_seed} + i (held out)",
           "setup_config": cfg.setup.to_dict(), "backend": senv.backend, "pool": bool(a.pool),
           "wall_s": round(time.perf_counter() - t0, 1), **res}
    print(json.dumps(doc, indent=2, default=str))
    if a.out:
        pathlib.Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        pathlib.Path(a.out).write_text(json.dumps(doc, indent=2, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())

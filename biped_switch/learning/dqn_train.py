"""Training the DQN selector: the collector over the frozen policy suite, the compiled train step, summaries, checkpoints, the evaluation rollout and the resumable driver."""

from __future__ import annotations

import math
import pathlib
import time
import types
from typing import NamedTuple
import jax
import jax.numpy as jnp
import numpy as np
from ml_collections import config_dict
from biped_switch.simulation import env as env_lib
from biped_switch.learning import policies as pol
from biped_switch.simulation import rollout as rollout_lib
from biped_switch.learning import checkpoints as ckpt_lib
from biped_switch.learning import runs as runs_lib
from biped_switch.config import default_dqn_config
from biped_switch.learning.replay import buffer_add, buffer_init, buffer_rows, buffer_sample
from biped_switch.learning.dqn import epsilon_at, epsilon_greedy, make_optimizer, make_q, make_update, oracle_bonus, q_input, q_input_size, sync_target
from biped_switch.learning.normalizer import frozen_stats
from biped_switch.simulation.observation import layout
from biped_switch.simulation.rollout import tree_where
from biped_switch.simulation.detection import debounce_step


# ----------------------------------------------------------------------- collection
class Collector(NamedTuple):
    """Per-env collection state (leading axis num_envs)."""

    state: object  # brax State
    need_reset: jax.Array  # bool: start a new episode before the next step
    ep_return: jax.Array  # env reward + bonus, unscaled
    ep_env_return: jax.Array
    ep_len: jax.Array  # int32 steps


def reset_pool(env, key, size: int):
    """`size` reset states (a batched State), track i % bank size for state i: the starts that
    collection draws new episodes from. With the `stand` init a reset is a function of the track
    alone (the keyframe; its rng only seeds pushes, which are off), so a pool of one state per bank
    track is exactly a fresh reset on a random track, at the cost of a gather instead of an
    `mjx.forward` per step. With `random` init the pool holds `size` joint draws; the trainer
    redraws it every chunk."""
    ids = jnp.arange(size, dtype=jnp.int32) % env.bank.size
    return jax.vmap(lambda k, i: env.reset(k, track_id=i))(jax.random.split(key, size), ids)


def _from_pool(pool, key, n):
    """n states drawn uniformly from the pool, each with a fresh info["rng"]."""
    k_idx, k_rng = jax.random.split(key)
    size = jax.tree.leaves(pool.obs)[0].shape[0]
    idx = jax.random.randint(k_idx, (n,), 0, size)
    state = jax.tree.map(lambda x: jnp.asarray(x)[idx], pool)
    if "rng" in state.info:
        state = state.replace(info={**state.info, "rng": jax.random.split(k_rng, n).astype(
            state.info["rng"].dtype)})
    return state


def collector_init(pool, n_envs: int) -> Collector:
    """Placeholder states (zeros shaped like the pool's, built on the host: nothing compiles), all
    flagged for reset, so the first `collect_step` starts every episode from the pool."""
    z = lambda x: jnp.asarray(np.zeros((n_envs,) + tuple(x.shape[1:]), x.dtype))  # noqa: E731
    state = jax.tree.map(z, pool)
    return Collector(state, jnp.ones(n_envs, bool), z(np.zeros((1,), np.float32)),
                     z(np.zeros((1,), np.float32)), z(np.zeros((1,), np.int32)))


def collect_act(env, suite_apply, suite_params, q_apply, q_params, col: Collector, pool, key,
                epsilon):
    """The part of a collection step before the physics: envs flagged for reset start a new
    episode from a random `pool` state (a random track), Q picks a policy per env
    (epsilon-greedy), the suite gives that policy's action.

    Returns (collector with the episode counters of reset envs zeroed, choice record, actions);
    step `collector.state` with the actions and hand the result to `collect_record`."""
    k_reset, k_eps = jax.random.split(key)
    n = col.ep_len.shape[0]
    p = layout(env).policy_size
    state = tree_where(col.need_reset, _from_pool(pool, k_reset, n), col.state)
    keep = ~col.need_reset
    col = Collector(state, col.need_reset, jnp.where(keep, col.ep_return, 0.0),
                    jnp.where(keep, col.ep_env_return, 0.0), jnp.where(keep, col.ep_len, 0))
    det = state.metrics["detected_kind"].astype(jnp.int32)
    obs = q_input(state.obs, det, p)
    choice = epsilon_greedy(k_eps, q_apply(q_params, obs), epsilon)
    action = pol.select(pol.all_actions(suite_apply, suite_params, state.obs[:, :p]), choice)
    return col, {"det": det, "obs": obs, "choice": choice}, action


def collect_record(env, col: Collector, rec: dict, nxt, bonus, reward_scale, max_steps):
    """The part after the physics (`nxt` = the stepped states): (collector, transitions for the
    buffer, episode stats of this step). The stored reward is reward_scale * (env reward + oracle
    bonus); done = 1 on a fall or the finish only (a time-out at `max_steps` ends the episode but
    bootstraps); next_obs is the obs the step reached (never a reset's)."""
    b = oracle_bonus(rec["choice"], rec["det"], bonus)
    ep_return = col.ep_return + nxt.reward + b
    ep_env_return = col.ep_env_return + nxt.reward
    ep_len = col.ep_len + 1
    end = (nxt.done > 0.5) | (ep_len >= max_steps)
    trans = {"obs": rec["obs"], "action": rec["choice"], "reward": reward_scale * (nxt.reward + b),
             "next_obs": q_input(nxt.obs, nxt.metrics["detected_kind"], layout(env).policy_size),
             "done": (nxt.done > 0.5).astype(jnp.float32)}
    endf = end.astype(jnp.float32)
    m = nxt.metrics
    stats = {"episodes": jnp.sum(endf), "return": jnp.sum(endf * ep_return),
             "env_return": jnp.sum(endf * ep_env_return), "length": jnp.sum(endf * ep_len),
             "success": jnp.sum(endf * m["success"]), "fell": jnp.sum(endf * m["fell"]),
             "progress": jnp.sum(endf * m["progress_frac"]),
             "correct_choice": jnp.mean((b > 0).astype(jnp.float32)),
             "detected": jnp.mean((rec["det"] >= 0).astype(jnp.float32))}
    return Collector(nxt, end, ep_return, ep_env_return, ep_len), trans, stats


def collect_step(env, suite_apply, suite_params, q_apply, q_params, col: Collector, pool, key,
                 epsilon, bonus, reward_scale, max_steps):
    """One control step of every env: `collect_act`, the batched env step, `collect_record`.
    Returns (collector, transitions for the buffer, episode stats of this step)."""
    col, rec, action = collect_act(env, suite_apply, suite_params, q_apply, q_params, col, pool,
                                   key, epsilon)
    nxt = jax.vmap(env.step)(col.state, action)
    return collect_record(env, col, rec, nxt, bonus, reward_scale, max_steps)


# ----------------------------------------------------------------------- training state and loop
class TrainState(NamedTuple):
    col: Collector
    buf: dict
    params: dict  # online Q params {"net", "norm"}
    target: dict
    opt_state: object
    key: jax.Array
    env_steps: jax.Array  # int32
    n_updates: jax.Array  # int32
    norm_ready: jax.Array  # bool


_FNS_CACHE: dict = {}  # compiled train functions per (env, suite) pair


def make_train_fns(cfg, env, suite_apply) -> types.SimpleNamespace:
    """The jitted pieces of a run, cached per (env, suite apply, config): `reset_pool(key)` the
    pool of episode starts; `init(key, pool)` a fresh TrainState; `run(ts, suite_params, pool)`
    `log_every` iterations (donates `ts`) -> (ts, sums); plus `q_apply`, `q_init`, `optimizer`,
    `max_steps`, `in_size`, `hm_size`. `sums` holds the per-iteration stats summed over the call
    (`epsilon_used`: the epsilons the iterations acted with) and `epsilon`, the schedule's value at
    the returned `ts.env_steps` (what the next call starts with).

    One function: its jitted pieces close over one run's config, env and sizes, cached together."""
    cache_key = (id(env), id(suite_apply), cfg.to_json_best_effort())
    if cache_key in _FNS_CACHE:
        return _FNS_CACHE[cache_key][2]
    if not 1 <= cfg.learning_starts <= cfg.replay_capacity:
        raise ValueError("learning_starts must be in [1, replay_capacity]")
    if cfg.num_envs > cfg.replay_capacity:
        raise ValueError("num_envs must not exceed replay_capacity")
    lay = layout(env)
    in_size = q_input_size(env)
    n_hm = lay.hm_size
    q_init, q_apply = make_q(cfg.network, n_hm, norm_clip=cfg.norm_clip)
    optimizer = make_optimizer(cfg)
    update = make_update(q_apply, optimizer, cfg.gamma, cfg.huber_delta)
    max_steps = int(round(cfg.max_episode_s / env.dt))
    n_envs, eps = cfg.num_envs, cfg.epsilon
    norm_idx = np.unique(np.linspace(0, cfg.learning_starts - 1,
                                     min(cfg.norm_rows, cfg.learning_starts)).astype(np.int32))

    @jax.jit
    def init_learner(key):
        k_q, k_run = jax.random.split(key)
        params = q_init(k_q, in_size)
        return (buffer_init(cfg.replay_capacity, in_size), params, jax.tree.map(jnp.copy, params),
                optimizer.init(params["net"]), k_run, jnp.zeros((), jnp.int32),
                jnp.zeros((), jnp.int32), jnp.zeros((), bool))

    def init(key, pool) -> TrainState:
        """A fresh TrainState; the env part is built on the host (only the learner part compiles:
        the pool's many leaves need no jitted gather here, the first `run` resets every env)."""
        return TrainState(collector_init(pool, n_envs), *init_learner(key))

    def set_norm(params, target, buf):
        norm = frozen_stats(buffer_rows(buf, jnp.asarray(norm_idx))["obs"], cfg.norm_std_floor,
                            n_hm, lay.state_size)
        return {**params, "norm": norm}, {**target, "norm": norm}

    def iteration(ts: TrainState, suite_params, pool):
        key, k_col, k_upd = jax.random.split(ts.key, 3)
        epsilon = epsilon_at(ts.env_steps, eps.start, eps.end, eps.decay_steps)
        col, trans, st = collect_step(env, suite_apply, suite_params, q_apply, ts.params, ts.col,
                                      pool, k_col, epsilon, cfg.oracle_bonus, cfg.reward_scale,
                                      max_steps)
        buf = buffer_add(ts.buf, trans)
        ready = buf["size"] >= cfg.learning_starts
        params, target = jax.lax.cond(ready & ~ts.norm_ready, set_norm, lambda a, b, _: (a, b),
                                      ts.params, ts.target, buf)

        def learn(c):
            def one(c, k):
                params, target, opt_state, n_upd = c
                params, opt_state, m = update(params, target, opt_state,
                                              buffer_sample(buf, k, cfg.batch_size))
                n_upd = n_upd + 1
                target = sync_target(target, params, n_upd % cfg.target_update_period == 0, cfg.tau)
                return (params, target, opt_state, n_upd), m

            c, ms = jax.lax.scan(one, c, jax.random.split(k_upd, cfg.updates_per_collect))
            return c, {"loss": jnp.mean(ms["loss"]), "q": jnp.mean(ms["q"])}

        def skip(c):
            return c, {"loss": jnp.zeros(()), "q": jnp.zeros(())}

        (params, target, opt_state, n_upd), m = jax.lax.cond(
            ready, learn, skip, (params, target, ts.opt_state, ts.n_updates))
        st = {**st, "loss": m["loss"], "q": m["q"], "learned": ready.astype(jnp.float32),
              "epsilon_used": epsilon}
        ts = TrainState(col, buf, params, target, opt_state, key, ts.env_steps + n_envs, n_upd,
                        ts.norm_ready | ready)
        return ts, st

    def run(ts: TrainState, suite_params, pool):
        ts, st = jax.lax.scan(lambda c, _: iteration(c, suite_params, pool), ts, None,
                              length=cfg.log_every)
        sums = {k: jnp.sum(v) for k, v in st.items()}
        sums["epsilon"] = epsilon_at(ts.env_steps, eps.start, eps.end, eps.decay_steps)
        return ts, sums

    pool_size = cfg.reset_pool or env.bank.size
    n_eval = int(cfg.get("eval_envs", 0))
    eval_ids = jnp.asarray((np.arange(n_eval) * env.bank.size) // max(n_eval, 1), jnp.int32)

    @jax.jit
    def greedy_eval(suite_params, q_params):
        """The greedy selector on `eval_envs` fixed training tracks (spread over the bank, the
        same starts every chunk), as `dqn_rollout` plays it: a learning curve free of epsilon."""
        return dqn_rollout(env, suite_apply, suite_params, q_apply, q_params,
                           jax.random.PRNGKey(cfg.seed + 2), n_eval, max_steps, track_ids=eval_ids)

    fns = types.SimpleNamespace(init=init, run=jax.jit(run, donate_argnums=0),
                                greedy_eval=greedy_eval if n_eval > 0 else None,
                                reset_pool=jax.jit(lambda key: reset_pool(env, key, pool_size)),
                                q_apply=q_apply,
                                q_init=q_init, optimizer=optimizer, max_steps=max_steps,
                                in_size=in_size, hm_size=n_hm)
    _FNS_CACHE[cache_key] = (env, suite_apply, fns)  # keep both alive: their ids stay unique
    return fns


def summarize_run(sums: dict, iterations: int) -> dict:
    """Per-call means from `run`'s sums (episode means over the episodes that ended)."""
    s = {k: float(v) for k, v in jax.device_get(sums).items()}
    n_ep, learned = s["episodes"], s["learned"]
    ep = lambda k: s[k] / n_ep if n_ep > 0 else math.nan  # noqa: E731
    return {"episodes": int(n_ep), "episode_return": ep("return"),
            "episode_env_return": ep("env_return"), "episode_length": ep("length"),
            "episode_success": ep("success"), "episode_fell": ep("fell"),
            "episode_progress": ep("progress"),
            "loss": s["loss"] / learned if learned > 0 else math.nan,
            "q_mean": s["q"] / learned if learned > 0 else math.nan,
            "correct_choice_frac": s["correct_choice"] / iterations,
            "detected_frac": s["detected"] / iterations, "epsilon": s["epsilon"]}


def summarize_eval(ep: dict) -> dict:
    """Means over the greedy episodes of `greedy_eval` (the `eval_` keys of metrics.csv)."""
    ep = jax.device_get(ep)
    return {"eval_success": float(np.mean(ep["success"])), "eval_fell": float(np.mean(ep["fell"])),
            "eval_progress": float(np.mean(ep["progress_frac"])),
            "eval_switches": float(np.mean(ep["n_switches"])),
            "eval_episodes": int(np.size(ep["success"]))}


# ----------------------------------------------------------------------- checkpoints
def _opt_to_dict(opt_state) -> dict:
    return {f"{i:04d}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(opt_state))}


def _opt_from_dict(d: dict, template):
    leaves, treedef = jax.tree.flatten(template)
    restored = [np.asarray(d[k]) for k in sorted(d)]
    if len(restored) != len(leaves):
        raise ValueError(f"optimiser state has {len(restored)} leaves, expected {len(leaves)}")
    return jax.tree.unflatten(treedef, [jnp.asarray(np.asarray(r, t.dtype).reshape(t.shape))
                                        for r, t in zip(restored, leaves)])


def _as_template(tree, template):
    """`tree` as device arrays of exactly `template`'s dtypes and shapes (no recompilation)."""
    return jax.tree.map(lambda x, t: jnp.asarray(np.asarray(x, t.dtype).reshape(t.shape)), tree,
                        template)


def _restore(path: pathlib.Path) -> dict:
    return ckpt_lib.load_checkpoint(pathlib.Path(path))[0]


def load_dqn(run_dir, in_size: int | None = None):
    """(q_apply, q_params) of the latest checkpoint of a DQN run (online net, with its normaliser).
    `in_size`: the Q-input size of the env it will run on (`q_input_size(env)`), checked against
    the checkpoint's (a selector trained without the phase clock cannot read one with it)."""
    run_dir = pathlib.Path(run_dir)
    ckpt = runs_lib.latest_checkpoint(run_dir)
    if ckpt is None:
        raise FileNotFoundError(f"no DQN checkpoint under {run_dir}/checkpoints "
                                f"(train with `python -m biped_switch.dqn`)")
    cfg = config_dict.ConfigDict(runs_lib.read_config(run_dir))
    prog = runs_lib.read_progress(ckpt)
    saved_in = prog.get("q_input_size")
    if in_size is not None and saved_in is not None and int(saved_in) != int(in_size):
        raise ValueError(f"{ckpt}: the DQN selector reads {saved_in} input columns, the env gives "
                         f"{in_size} (policy observation + one-hot); retrain it for this policy "
                         f"suite (make train-dqn)")
    net_cfg = config_dict.create(hidden=tuple(cfg.network.hidden), hm_hidden=tuple(cfg.network.hm_hidden))
    # a run that predates the `norm_clip` key ran with the default
    _, q_apply = make_q(net_cfg, prog["hm_size"],
                        norm_clip=cfg.get("norm_clip", default_dqn_config().norm_clip))
    params = jax.tree.map(jnp.asarray, _restore(ckpt)["online"])
    return q_apply, params


# ----------------------------------------------------------------------- evaluation
def dqn_rollout(env, suite_apply, suite_params, q_apply, q_params, rng: jax.Array, n_envs: int,
                horizon: int, track_ids=None, chunk: int = 50, guide_scale=0.0, det_apply=None,
                det_params=None) -> dict:
    """Episodes on the env's tracks with the greedy Q choice of policy at every step.

    Same protocol and keys as `switching.multi_rollout` (`rollout.run_episodes`: episodes frozen
    at their end, chunks of `chunk` steps under a while loop that stops once all have ended):
    every final env metric, `length` (live steps), `done` and `n_switches` (changes of the chosen
    policy, counted from walk, as multi_rollout's episodes start with walk active). The same rng
    gives the same start states as multi_rollout; `guide_scale` > 0 turns the scripted guides on
    (pipeline checks). `det_apply`, `det_params`: a learned terrain detector's kind in place of the
    oracle's (switching.detector)."""
    p = layout(env).policy_size
    reset_keys, k_run = rollout_lib.episode_keys(rng, n_envs)
    if track_ids is None:
        track_ids = jax.random.randint(k_run, (n_envs,), 0, env.bank.size)
    state = rollout_lib.reset_by_track(env, reset_keys, track_ids,
                                       guide_scale=guide_scale)

    steps = getattr(det_apply, "debounce_steps", 1)

    def act(c, state, live, _):
        prev, n_sw, det = c
        if det_apply is None:  # the oracle's
            kind = state.metrics["detected_kind"]
        else:  # the learned detector's, through the switching rollout's filter
            yaw = jax.vmap(env.switch_inputs)(state)["yaw"]
            det = debounce_step(*det, det_apply(det_params, state.obs, yaw)["kind"], steps)
            kind = det[0].astype(jnp.float32)
        obs = q_input(state.obs, kind, p)
        choice = jnp.argmax(q_apply(q_params, obs), axis=-1).astype(jnp.int32)
        action = pol.select(pol.all_actions(suite_apply, suite_params, state.obs[:, :p]), choice)
        n_sw = n_sw + (live & (choice != prev)).astype(jnp.int32)
        return action, (jnp.where(live, choice, prev), n_sw, det), None

    zi, mi = jnp.zeros(n_envs, jnp.int32), jnp.full(n_envs, -1, jnp.int32)
    ep = rollout_lib.run_episodes(env, state, horizon, act, (zi, zi, (mi, mi, zi)), chunk=chunk)
    return {**ep.metrics, "length": ep.length, "done": ep.done, "n_switches": ep.carry[1]}


# ----------------------------------------------------------------------- training driver
def make_dqn_env(cfg, backend: str = "auto", **overrides):
    """The DQN's training env: `mixed` tracks with the detector one-hot, on the physics `backend`;
    `overrides` are the policy suite's env overrides (`policies.suite_env_overrides`)."""

    return env_lib.make_env("mixed", cfg.init, detector_one_hot=True, n_tracks=cfg.n_tracks,
                            seed=cfg.seed, difficulty=cfg.difficulty, backend=backend, **overrides)


def train_dqn(cfg, run_dir, runs="runs", stand_in: str | None = None, max_chunks: int | None = None,
              print_fn=print, env=None, suite: pol.PolicySuite | None = None, pool=None,
              backend: str = "auto") -> dict:
    """Trains (or resumes) until `total_env_steps` (or `max_chunks` chunks); returns the last
    progress record of this session, {} when it saved none (the run had already reached the total).

    `env` (default: `make_dqn_env` on `backend` with the suite's env overrides), `suite` (default:
    the `cfg.init` policies under `runs`, missing ones replaced by `stand_in`) and `pool` (the
    episode starts; default: `reset_pool` of one state per bank track) may be passed in (tests).

    One function: one session top to bottom, its resume state carried through every chunk."""

    t_session = time.perf_counter()
    run_dir = pathlib.Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(cfg.to_json_best_effort(indent=2))
    if env is None:
        overrides = (suite.env_overrides if suite is not None
                     else pol.suite_env_overrides(cfg.init, runs, stand_in=stand_in))
        env = make_dqn_env(cfg, backend, **overrides)
    if suite is None:
        suite = pol.load_suite(cfg.init, env, runs, stand_in=stand_in)
    fns = make_train_fns(cfg, env, suite.apply)
    logger = runs_lib.Logger(run_dir)
    ckpt = runs_lib.latest_checkpoint(run_dir)
    step, wall_s, n_updates, norm_ready, setup_total = 0, 0.0, 0, False, 0.0
    own_pool = pool is None
    if own_pool:
        pool = fns.reset_pool(jax.random.PRNGKey(cfg.seed + 1))
    ts = fns.init(jax.random.PRNGKey(cfg.seed), pool)
    if ckpt is not None:
        saved = _restore(ckpt)
        prog = runs_lib.read_progress(ckpt)
        step, wall_s = int(prog["step"]), float(prog["wall_s"])
        n_updates, norm_ready = int(prog["n_updates"]), bool(prog["norm_ready"])
        setup_total = prog.get("setup_s_total")  # None: an older checkpoint, the sum is unknown
        ts = ts._replace(params=_as_template(saved["online"], ts.params),
                         target=_as_template(saved["target"], ts.target),
                         opt_state=_opt_from_dict(saved["opt"], ts.opt_state),
                         key=jax.random.PRNGKey(cfg.seed + step),
                         env_steps=jnp.asarray(step, jnp.int32),
                         n_updates=jnp.asarray(n_updates, jnp.int32),
                         norm_ready=jnp.asarray(norm_ready))
        logger.drop_after(step)
        print_fn(f"resuming {run_dir} at step {step:,} ({ckpt.name}); the replay buffer refills "
                 f"({cfg.learning_starts:,} transitions) before updates resume")
    per_call = cfg.log_every * cfg.num_envs
    calls_per_chunk = max(1, math.ceil(cfg.chunk_env_steps / per_call))
    progress, chunks, last = {}, 0, {}
    setup_s = time.perf_counter() - t_session  # env, policies, pool: counted in the first chunk
    while step < cfg.total_env_steps and (max_chunks is None or chunks < max_chunks):
        t_chunk, step0 = time.perf_counter(), step
        if own_pool and cfg.init == "random" and chunks > 0:  # new joint draws (stand: no need)
            pool = fns.reset_pool(jax.random.PRNGKey(cfg.seed + 1 + step))
        for _ in range(calls_per_chunk):
            if step >= cfg.total_env_steps:
                break
            t0 = time.perf_counter()
            ts, sums = fns.run(ts, suite.params, pool)
            last = summarize_run(sums, cfg.log_every)  # device_get: waits for the call
            dt = time.perf_counter() - t0
            step += per_call
            sps = per_call / max(dt, 1e-9)
            left = max(cfg.total_env_steps - step, 0) / sps
            elapsed = wall_s + time.perf_counter() - t_chunk + (setup_s if chunks == 0 else 0.0)
            print_fn(f"[dqn/{cfg.init}] step {step:,}/{cfg.total_env_steps:,}  episodes "
                     f"{last['episodes']}  return {last['episode_return']:.1f} (env "
                     f"{last['episode_env_return']:.1f})  success {last['episode_success']:.2f}  "
                     f"correct {last['correct_choice_frac']:.2f}  loss {last['loss']:.4f}  "
                     f"q {last['q_mean']:.2f}  eps {last['epsilon']:.3f}  {sps:,.0f} steps/s  "
                     f"elapsed {elapsed / 60:.1f} min  "
                     f"left ~{left / 60:.1f} min")
            logger.log(step, {k: v for k, v in {**last, "steps_per_s": sps}.items()
                              if not (isinstance(v, float) and math.isnan(v))})
        ev = {}
        if fns.greedy_eval is not None:  # part of the chunk's time (as PPO's milestone rollout)
            t_ev = time.perf_counter()
            ev = summarize_eval(fns.greedy_eval(suite.params, ts.params))
            print_fn(f"[dqn/{cfg.init}] greedy, {ev['eval_episodes']} training tracks: success "
                     f"{ev['eval_success']:.2f}  progress {ev['eval_progress']:.2f}  fell "
                     f"{ev['eval_fell']:.2f}  switches {ev['eval_switches']:.1f}  "
                     f"({time.perf_counter() - t_ev:.0f} s)")
        chunk_s = time.perf_counter() - t_chunk
        wall_s += chunk_s + (setup_s if chunks == 0 else 0.0)
        if chunks == 0 and setup_total is not None:
            setup_total += setup_s
        n_updates, norm_ready = int(ts.n_updates), bool(ts.norm_ready)
        progress = {"step": step, "total_env_steps": cfg.total_env_steps, "wall_s": wall_s,
                    "chunk_s": chunk_s, "session_setup_s": setup_s if chunks == 0 else 0.0,
                    "setup_s_total": setup_total, "epsilon": last["epsilon"],
                    "n_updates": n_updates, "norm_ready": norm_ready,
                    "env_steps_per_s": (step - step0) / chunk_s, "last": last, "eval": ev,
                    "hm_size": fns.hm_size, "q_input_size": fns.in_size, "init": cfg.init,
                    "stand_in": stand_in, "policies": list(suite.sources),
                    "env_overrides": dict(suite.env_overrides), "backend": env.backend,
                    "oracle_bonus": cfg.oracle_bonus, "device": str(jax.devices()[0]),
                    "buffer_saved": False}
        tree = {"online": jax.tree.map(np.asarray, jax.device_get(ts.params)),
                "target": jax.tree.map(np.asarray, jax.device_get(ts.target)),
                "opt": _opt_to_dict(jax.device_get(ts.opt_state))}
        path = ckpt_lib.save_tree(run_dir, step, tree, progress)
        logger.log(step, {"wall_s": wall_s, "chunk_env_steps_per_s": progress["env_steps_per_s"],
                          **ev})
        print_fn(f"[dqn/{cfg.init}] chunk done at step {step:,} ({n_updates:,} updates, "
                 f"{chunk_s:.0f} s); saved {path}")
        chunks += 1
    return progress

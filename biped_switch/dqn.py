"""The DQN selector baseline (paper Sec. IV-C, Table II "DQN", Table III): a discrete Q-network
that picks, at every control step, which pre-trained policy of the suite acts.

    python -m biped_switch.dqn --preset cpu|gpu [--total-steps N] [--chunk-steps N] [--runs runs]
                               [--out runs/dqn_stand] [--stand-in walk]

Unlike the switch estimators, the DQN is trained on the test domain: `mixed` tracks (7 artifacts of
every kind; training tracks have seeds `seed .. seed + n_tracks - 1`, evaluation tracks 30,000..).

Input: the Q-network sees what the behaviour policies see -- the robot state (51), the heightmap
(2400) and, when the suite was trained with it, the gait phase clock (2): the first
`env.policy_observation_size` columns -- and the oracle detector's artifact kind as a one-hot (3):
`q_input(obs, detected_kind, n_policy_obs)`. The one-hot is rebuilt from
`state.metrics["detected_kind"]` (the very value the env's `detector_one_hot` appends), so the
DQN runs on an env made with or without `detector_one_hot`; `make_dqn_env` (the suite's env
overrides, `detector_one_hot=True`) is what the CLI uses. The behaviour policies always get the
first `env.policy_observation_size` columns (they were trained without the one-hot).
Output: Q-values of the 4 policies (index = policies.POLICY_INDEX: walk, jumps, gaps, stairs).

Reward per step: the env's reward (the one each policy was trained on) plus an oracle bonus
`oracle_bonus` for choosing the policy of the detected artifact (walk while nothing is detected),
both multiplied by `reward_scale`. The paper found that the DQN fails to learn without the bonus,
and gives no value; ours is 1.0 per step (before scaling), about a fifth of the best env reward per
step (5.4), so the bonus leads at first and the env reward still separates good from bad timing.

Learning: Double DQN (van Hasselt et al.): target r + gamma (1 - done) Q_target(s', argmax_a
Q_online(s', a)), Huber loss on the chosen action, Adam (Optax) with gradient clipping, a target
network synced every `target_update_period` updates (tau = 1: hard copy; tau < 1: Polyak step),
epsilon-greedy exploration with epsilon linear in env steps from `epsilon.start` to `epsilon.end`
over `epsilon.decay_steps`. Collection is vectorised over `num_envs` envs (either physics
backend, `--backend`): per iteration each env takes one step (Q picks a policy, the suite gives
the actions), the `num_envs` transitions go into the replay buffer, then `updates_per_collect`
gradient updates on uniform samples of `batch_size`. Episodes end on a fall or the finish
(done = 1: no bootstrap) or after `max_episode_s` (a time-out: bootstrapped); an ended env starts
its next episode, at the start of the next iteration, from a random state of a pool of reset
states (`reset_pool`: one per bank track, so a random track; with the `stand` init a reset
depends on the track alone, so this is exactly a fresh reset, for the price of a gather instead
of a forward pass of every env whenever any env ends). `log_every` iterations run as one jitted
`lax.scan` (one progress line). Training runs on one device (the first); `dqn_rollout` can be
split over devices with `rollout.over_devices` as `evaluate multi` does.

Input scaling: the Q-network normalises its input with statistics frozen when the buffer first
holds `learning_starts` transitions (the state per column, the heightmap with one shared mean and
std, the phase clock and the one-hot untouched; std floored at `norm_std_floor`; the normalised
input clipped to +-10). They are part of the params (`params["norm"]`), so a checkpoint (with the
run's `config.json` for the layer sizes) is enough to run the network.

Replay buffer: a pytree of fixed-size arrays (a ring). Observations are stored split: the 51 state
columns as float32, the heightmap, phase clock and one-hot as float16 (heightmap values lie in
[0, 1], the clock's in [-1, 1]; float16 keeps them to 5e-4), about 5 kB per observation and
10 kB per transition (obs and next obs): the GPU preset's 500,000 transitions take about 5 GB.

Greedy evaluation: after each chunk the greedy selector (no epsilon) runs `eval_envs` episodes of
`max_episode_s` on fixed training tracks spread over the bank, the same starts every time
(`greedy_eval`, `dqn_rollout`); their mean success, progress, falls and switches go to the progress
line, `metrics.csv` (`eval_*`), progress.json (`eval`) and the fourth panel of `curves.png`. Its
time counts in the chunk's (`wall_s`, `env_steps_per_s`), as PPO's milestone rollout does.

Checkpoints: every `chunk_env_steps` env steps, an Orbax checkpoint `checkpoints/<step>/` of the
online and target params and the optimiser state, with `progress.json` (step, `total_env_steps`:
the target this session was asked to reach, so step < total_env_steps marks an unfinished run;
epsilon: the schedule's value at `step`, the one the next iteration acts with; n_updates, wall_s,
env steps/s, the policies used incl. any stand-in, their env overrides and the physics
backend); a rerun resumes from the latest one.
NOT saved: the replay buffer and the envs' states. After a resume the envs start new episodes and
the buffer refills: no gradient update happens until it again holds `learning_starts` transitions
(those env steps count towards the total). Step counts are rounded up to whole jitted calls
(`log_every * num_envs` env steps). Metrics go to stdout, `metrics.csv` and TensorBoard (`tb/`).

`wall_s` is what a retraining-cost table (Table III) reads. Summed over all sessions, it counts
each session's setup (from the `train_dqn` call: config, env and bank build, policy loading,
reset-pool draw, learner init, checkpoint restore: `session_setup_s`, summed over sessions in
`setup_s_total`, None when a session predates that key) and every saved chunk's collection and
updates, compiles included. It does NOT count process start and imports, checkpoint writing, or a
chunk cut off before its checkpoint (its steps are lost too). The PPO trainer's `wall_s` leaves
session setup out: subtract `setup_s_total` to compare the two.

Evaluation: `load_dqn(run_dir)` -> (q_apply, q_params); `dqn_rollout(...)` plays the greedy
choice on given tracks and returns the same per-episode keys as `switching.multi_rollout`.
"""

from __future__ import annotations

import argparse
import csv
import functools
import math
import pathlib
import sys
import time
import types
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from ml_collections import config_dict

from biped_switch import env as env_lib
from biped_switch import policies as pol
from biped_switch import rollout as rollout_lib
from biped_switch import runs as runs_lib
from biped_switch.config import default_dqn_config
from biped_switch.env import STATE_SIZE
from biped_switch.networks import EncodedMLP
from biped_switch.terrain import ARTIFACT_KINDS

N_KINDS = len(ARTIFACT_KINDS)  # artifact kinds the detector names (jumps, gaps, stairs)
N_ACTIONS = len(pol.POLICY_NAMES)  # 4 policies: walk, jumps, gaps, stairs
NORM_CLIP = 10.0
NORM_ROWS = 16_384  # rows (strided over the warm-up transitions) the input statistics come from


# ----------------------------------------------------------------------- pure pieces
def policy_obs_size(env) -> int:
    """Observation columns the behaviour policies read: robot state + heightmap (2451), + the
    phase clock (2) when the env has one (`env.policy_observation_size`)."""
    return env.policy_observation_size


def hm_size(env) -> int:
    """The heightmap's columns (2400), right after the robot state."""
    return env.cfg.shape.grid_forward * env.cfg.shape.grid_lateral


def q_input_size(env) -> int:
    """Q-network input columns: the policies' observation and the detector one-hot."""
    return policy_obs_size(env) + N_KINDS


def q_input(obs: jax.Array, detected_kind: jax.Array, n_policy_obs: int) -> jax.Array:
    """(..., n_policy_obs + 3): the policies' observation (state, heightmap, phase clock if any),
    and the one-hot of the detected kind (-1: none)."""
    one_hot = jax.nn.one_hot(jnp.asarray(detected_kind).astype(jnp.int32), N_KINDS, dtype=obs.dtype)
    return jnp.concatenate([obs[..., :n_policy_obs], one_hot], axis=-1)


def oracle_bonus(choice: jax.Array, detected_kind: jax.Array, bonus) -> jax.Array:
    """`bonus` where the chosen policy is the detected artifact's (kind + 1; walk = 0 when nothing
    is detected, kind -1), else 0."""
    match = jnp.asarray(choice).astype(jnp.int32) == jnp.asarray(detected_kind).astype(jnp.int32) + 1
    return jnp.where(match, jnp.asarray(bonus, jnp.float32), 0.0)


def double_dqn_targets(q_next_online, q_next_target, reward, done, gamma) -> jax.Array:
    """r + gamma (1 - done) Q_target(s', argmax_a Q_online(s', a)) for (B, A) Q-values."""
    a_star = jnp.argmax(q_next_online, axis=-1)
    v = jnp.take_along_axis(q_next_target, a_star[..., None], axis=-1)[..., 0]
    return reward + gamma * (1.0 - done) * v


def epsilon_at(step, start: float, end: float, decay_steps: int) -> jax.Array:
    """Linear from `start` at step 0 to `end` at `decay_steps` env steps, then constant."""
    frac = jnp.clip(jnp.asarray(step, jnp.float32) / max(decay_steps, 1), 0.0, 1.0)
    return jnp.asarray(start + frac * (end - start), jnp.float32)


def epsilon_greedy(key: jax.Array, q: jax.Array, epsilon) -> jax.Array:
    """(B,) int32: argmax of q (B, A), or with probability epsilon a uniform random action."""
    k_explore, k_action = jax.random.split(key)
    n, a = q.shape
    explore = jax.random.uniform(k_explore, (n,)) < epsilon
    rand = jax.random.randint(k_action, (n,), 0, a)
    return jnp.where(explore, rand, jnp.argmax(q, axis=-1)).astype(jnp.int32)


# ----------------------------------------------------------------------- replay buffer
def buffer_init(capacity: int, obs_size: int, split: int = STATE_SIZE) -> dict:
    """An empty ring buffer of `capacity` transitions (obs, action, reward, next_obs, done).

    Observation columns [0, split) are stored as float32, the rest (heightmap, one-hot) as
    float16. `ptr` is the next row to write, `size` the number of filled rows ([0, size))."""
    if not 0 <= split <= obs_size:
        raise ValueError(f"split {split} outside [0, {obs_size}]")
    z = functools.partial(jnp.zeros, dtype=jnp.float32)
    return {
        "obs_f32": z((capacity, split)), "obs_f16": jnp.zeros((capacity, obs_size - split), jnp.float16),
        "next_f32": z((capacity, split)),
        "next_f16": jnp.zeros((capacity, obs_size - split), jnp.float16),
        "action": jnp.zeros(capacity, jnp.int32), "reward": z(capacity), "done": z(capacity),
        "ptr": jnp.zeros((), jnp.int32), "size": jnp.zeros((), jnp.int32),
    }


def buffer_capacity(buf: dict) -> int:
    return buf["action"].shape[0]


def buffer_add(buf: dict, batch: dict) -> dict:
    """`buf` with the n transitions of `batch` (obs, action, reward, next_obs, done; leading axis n)
    written at the ring pointer; past the end it wraps to row 0, overwriting the oldest."""
    cap, split = buffer_capacity(buf), buf["obs_f32"].shape[1]
    n = batch["action"].shape[0]
    if n > cap:
        raise ValueError(f"cannot add {n} transitions to a buffer of capacity {cap}")
    idx = (buf["ptr"] + jnp.arange(n, dtype=jnp.int32)) % cap
    put = lambda name, x: buf[name].at[idx].set(x.astype(buf[name].dtype), unique_indices=True)  # noqa: E731
    return {
        "obs_f32": put("obs_f32", batch["obs"][:, :split]),
        "obs_f16": put("obs_f16", batch["obs"][:, split:]),
        "next_f32": put("next_f32", batch["next_obs"][:, :split]),
        "next_f16": put("next_f16", batch["next_obs"][:, split:]),
        "action": put("action", batch["action"]), "reward": put("reward", batch["reward"]),
        "done": put("done", batch["done"]),
        "ptr": ((buf["ptr"] + n) % cap).astype(jnp.int32),
        "size": jnp.minimum(buf["size"] + n, cap).astype(jnp.int32),
    }


def buffer_rows(buf: dict, idx: jax.Array) -> dict:
    """The transitions at rows `idx`, observations back as float32."""
    cat = lambda a, b: jnp.concatenate([buf[a][idx], buf[b][idx].astype(jnp.float32)], axis=-1)  # noqa: E731
    return {"obs": cat("obs_f32", "obs_f16"), "next_obs": cat("next_f32", "next_f16"),
            "action": buf["action"][idx], "reward": buf["reward"][idx], "done": buf["done"][idx]}


def buffer_sample(buf: dict, key: jax.Array, n: int) -> dict:
    """n transitions drawn uniformly (with replacement) from the filled rows only."""
    idx = jax.random.randint(key, (n,), 0, jnp.maximum(buf["size"], 1))
    return buffer_rows(buf, idx)


# ----------------------------------------------------------------------- Q-network
def make_q(net_cfg, hm_size: int, n_actions: int = N_ACTIONS):
    """(init(key, in_size) -> params, apply(params, x (B, in_size)) -> (B, n_actions)).

    The network is the policies' EncodedMLP (heightmap encoder `hm_hidden`, joined with the state
    and the one-hot, MLP `hidden`, swish) behind a frozen input normaliser `params["norm"]`."""

    module = EncodedMLP(out_size=n_actions, hidden=tuple(net_cfg.hidden),
                        hm_hidden=tuple(net_cfg.hm_hidden), hm_size=hm_size)

    def init(key, in_size: int) -> dict:
        return {"net": module.init(key, jnp.zeros((1, in_size))),
                "norm": {"mean": jnp.zeros(in_size), "std": jnp.ones(in_size)}}

    def apply(params, x):
        norm = params["norm"]
        x = jnp.clip((x - norm["mean"]) / norm["std"], -NORM_CLIP, NORM_CLIP)
        return module.apply(params["net"], x)

    return init, apply


def input_norm(x: jax.Array, n_policy_obs: int, std_floor: float, n_hm: int | None = None) -> dict:
    """Normaliser of Q inputs `x` (N, in_size): state columns each their own mean/std, the `n_hm`
    heightmap columns after them (default: all up to `n_policy_obs`) one shared mean/std, the
    rest (phase clock, one-hot; already in [-1, 1]) mean 0, std 1."""
    x = x.astype(jnp.float32)
    n_hm = n_policy_obs - STATE_SIZE if n_hm is None else n_hm
    s, h = x[:, :STATE_SIZE], x[:, STATE_SIZE:STATE_SIZE + n_hm]
    n_extra = x.shape[1] - STATE_SIZE - n_hm
    hm_mean, hm_std = jnp.mean(h), jnp.std(h)
    mean = jnp.concatenate([jnp.mean(s, 0), jnp.full(h.shape[1], hm_mean), jnp.zeros(n_extra)])
    std = jnp.concatenate([jnp.std(s, 0), jnp.full(h.shape[1], hm_std), jnp.ones(n_extra)])
    return {"mean": mean, "std": jnp.maximum(std, std_floor)}


def dqn_loss(net_params, params, target, batch, q_apply, gamma, huber_delta):
    """Huber loss of Q(s, a) against the Double-DQN target; (loss, mean Q(s, a)).

    One online forward pass serves s and s' (the online Q(s') only picks the argmax, which has no
    gradient); the target's values are computed from `target` and get no gradient either."""
    online = {**params, "net": net_params}
    n = batch["obs"].shape[0]
    q_both = q_apply(online, jnp.concatenate([batch["obs"], batch["next_obs"]], axis=0))
    q, q_next_online = q_both[:n], jax.lax.stop_gradient(q_both[n:])
    q_a = jnp.take_along_axis(q, batch["action"][:, None], axis=-1)[:, 0]
    y = double_dqn_targets(q_next_online, q_apply(target, batch["next_obs"]), batch["reward"],
                           batch["done"], gamma)
    loss = jnp.mean(optax.huber_loss(q_a, jax.lax.stop_gradient(y), delta=huber_delta))
    return loss, jnp.mean(q_a)


def make_optimizer(cfg) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), optax.adam(cfg.learning_rate))


def make_update(q_apply, optimizer, gamma: float, huber_delta: float):
    """One gradient step: (params, target, opt_state, batch) -> (params, opt_state, metrics)."""

    def update(params, target, opt_state, batch):
        (loss, q_mean), grads = jax.value_and_grad(dqn_loss, has_aux=True)(
            params["net"], params, target, batch, q_apply, gamma, huber_delta)
        updates, opt_state = optimizer.update(grads, opt_state, params["net"])
        net = optax.apply_updates(params["net"], updates)
        return {**params, "net": net}, opt_state, {"loss": loss, "q": q_mean}

    return update


def sync_target(target, online, do_sync, tau: float):
    """target <- tau * online + (1 - tau) * target where `do_sync` (traced bool), else unchanged."""
    return jax.tree.map(lambda t, o: jnp.where(do_sync, tau * o + (1.0 - tau) * t, t), target, online)


# ----------------------------------------------------------------------- collection
class Collector(NamedTuple):
    """Per-env collection state (leading axis num_envs)."""

    state: object  # brax State
    need_reset: jax.Array  # bool: start a new episode before the next step
    ep_return: jax.Array  # env reward + bonus, unscaled
    ep_env_return: jax.Array
    ep_len: jax.Array  # int32 steps


def _where(mask, new, old):
    return jax.tree.map(lambda n, o: jnp.where(mask.reshape((-1,) + (1,) * (n.ndim - 1)), n, o),
                        new, old)


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
    p = policy_obs_size(env)
    state = _where(col.need_reset, _from_pool(pool, k_reset, n), col.state)
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
             "next_obs": q_input(nxt.obs, nxt.metrics["detected_kind"], policy_obs_size(env)),
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


_FNS_CACHE: dict = {}


def make_train_fns(cfg, env, suite_apply) -> types.SimpleNamespace:
    """The jitted pieces of a run, cached per (env, suite apply, config): `reset_pool(key)` the
    pool of episode starts; `init(key, pool)` a fresh TrainState; `run(ts, suite_params, pool)`
    `log_every` iterations (donates `ts`) -> (ts, sums); plus `q_apply`, `q_init`, `optimizer`,
    `max_steps`, `in_size`, `hm_size`. `sums` holds the per-iteration stats summed over the call
    (`epsilon_used`: the epsilons the iterations acted with) and `epsilon`, the schedule's value at
    the returned `ts.env_steps` (what the next call starts with)."""
    cache_key = (id(env), id(suite_apply), cfg.to_json_best_effort())
    if cache_key in _FNS_CACHE:
        return _FNS_CACHE[cache_key][2]
    if not 1 <= cfg.learning_starts <= cfg.replay_capacity:
        raise ValueError("learning_starts must be in [1, replay_capacity]")
    if cfg.num_envs > cfg.replay_capacity:
        raise ValueError("num_envs must not exceed replay_capacity")
    p = policy_obs_size(env)
    in_size = q_input_size(env)
    n_hm = hm_size(env)
    q_init, q_apply = make_q(cfg.network, n_hm)
    optimizer = make_optimizer(cfg)
    update = make_update(q_apply, optimizer, cfg.gamma, cfg.huber_delta)
    max_steps = int(round(cfg.max_episode_s / env.dt))
    n_envs, eps = cfg.num_envs, cfg.epsilon
    norm_idx = np.unique(np.linspace(0, cfg.learning_starts - 1, min(NORM_ROWS, cfg.learning_starts))
                         .astype(np.int32))

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
        norm = input_norm(buffer_rows(buf, jnp.asarray(norm_idx))["obs"], p, cfg.norm_std_floor,
                          n_hm)
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


def plot_curves(run_dir, out_png) -> None:
    """The DQN's learning curves (metrics.csv, one row per jitted call): episode return and
    success, the share of steps on the oracle's policy, and the TD loss, Q and epsilon."""
    import matplotlib  # lazy, as runs.plot_curves

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with (pathlib.Path(run_dir) / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    ep_rows = [r for r in rows if float(r.get("episodes") or 0) > 0]

    def series(key, src=rows):
        return runs_lib.curve_series(src, key)

    eval_rows = [r for r in rows if r.get("eval_success") not in (None, "")]
    fig, axes = plt.subplots(1, 4 if eval_rows else 3, figsize=(20 if eval_rows else 15, 3.6))
    for key, ax, style in (("episode_env_return", axes[0], "-"),
                           ("episode_success", axes[0].twinx(), "g:")):
        xy = series(key, ep_rows)
        ax.plot(xy[:, 0], xy[:, 1], style, label=key)
        ax.set_ylabel(key)
    axes[0].set_title("training episodes (epsilon-greedy)")
    for key in ("correct_choice_frac", "epsilon"):
        xy = series(key)
        axes[1].plot(xy[:, 0], xy[:, 1], label=key)
    axes[1].set_ylim(-0.02, 1.02)
    axes[1].legend(fontsize=8)
    axes[1].set_title("choice = the oracle's policy; exploration")
    xy = series("loss")
    axes[2].plot(xy[:, 0], xy[:, 1], label="TD loss (Huber)")
    axes[2].set_ylabel("loss")
    q_ax = axes[2].twinx()
    xy = series("q_mean")
    q_ax.plot(xy[:, 0], xy[:, 1], "r:", label="mean Q")
    q_ax.set_ylabel("mean Q", color="r")
    axes[2].set_title("learning")
    if eval_rows:
        n_ep = int(float(eval_rows[-1].get("eval_episodes") or 0))
        for key in ("eval_success", "eval_progress", "eval_fell"):
            xy = series(key, eval_rows)
            axes[3].plot(xy[:, 0], xy[:, 1], "o-", ms=3, label=key.removeprefix("eval_"))
        axes[3].set_ylim(-0.02, 1.02)
        axes[3].set_xlim(axes[0].get_xlim())  # the same steps as the others (it may start late)
        axes[3].legend(fontsize=8)
        axes[3].set_title(f"greedy selector, {n_ep} fixed training tracks (each chunk)")
    runs_lib.save_curves(fig, axes, run_dir, out_png)


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
    return runs_lib.load_checkpoint(pathlib.Path(path))[0]


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
    _, q_apply = make_q(net_cfg, prog["hm_size"])
    params = jax.tree.map(jnp.asarray, _restore(ckpt)["online"])
    return q_apply, params


# ----------------------------------------------------------------------- evaluation
def dqn_rollout(env, suite_apply, suite_params, q_apply, q_params, rng: jax.Array, n_envs: int,
                horizon: int, track_ids=None, chunk: int = 50, guide_scale=0.0) -> dict:
    """Episodes on the env's tracks with the greedy Q choice of policy at every step.

    Same protocol and keys as `switching.multi_rollout` (`rollout.run_episodes`: episodes frozen
    at their end, chunks of `chunk` steps under a while loop that stops once all have ended):
    every final env metric, `length` (live steps), `done` and `n_switches` (changes of the chosen
    policy, counted from walk, as multi_rollout's episodes start with walk active). The same rng
    gives the same start states as multi_rollout; `guide_scale` > 0 turns the scripted guides on
    (pipeline checks)."""
    p = policy_obs_size(env)
    reset_keys, k_run = rollout_lib.episode_keys(rng, n_envs)
    if track_ids is None:
        track_ids = jax.random.randint(k_run, (n_envs,), 0, env.bank.size)
    state = rollout_lib.reset_by_track(env, reset_keys, track_ids,
                                       guide_scale=guide_scale)

    def act(c, state, live, _):
        prev, n_sw = c
        obs = q_input(state.obs, state.metrics["detected_kind"], p)
        choice = jnp.argmax(q_apply(q_params, obs), axis=-1).astype(jnp.int32)
        action = pol.select(pol.all_actions(suite_apply, suite_params, state.obs[:, :p]), choice)
        n_sw = n_sw + (live & (choice != prev)).astype(jnp.int32)
        return action, (jnp.where(live, choice, prev), n_sw), None

    zi = jnp.zeros(n_envs, jnp.int32)
    ep = rollout_lib.run_episodes(env, state, horizon, act, (zi, zi), chunk=chunk)
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
    episode starts; default: `reset_pool` of one state per bank track) may be passed in (tests)."""

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
        path = runs_lib.save_tree(run_dir, step, tree, progress)
        logger.log(step, {"wall_s": wall_s, "chunk_env_steps_per_s": progress["env_steps_per_s"],
                          **ev})
        print_fn(f"[dqn/{cfg.init}] chunk done at step {step:,} ({n_updates:,} updates, "
                 f"{chunk_s:.0f} s); saved {path}")
        chunks += 1
    return progress


def main(argv=None) -> int:

    p = argparse.ArgumentParser(prog="python -m biped_switch.dqn", description=__doc__.split("\n")[0])
    p.add_argument("--preset", default=None, choices=("gpu", "cpu"),
                   help="default: cpu on a CPU host, else gpu")
    p.add_argument("--init", default="stand", choices=env_lib.INITS)
    p.add_argument("--total-steps", type=int, default=None)
    p.add_argument("--chunk-steps", type=int, default=None)
    p.add_argument("--num-envs", type=int, default=None)
    p.add_argument("--max-chunks", type=int, default=None, help="stop after this many chunks")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--oracle-bonus", type=float, default=None)
    p.add_argument("--runs", default="runs", help="where the behaviour policies are")
    p.add_argument("--out", default=None, help="run directory (default RUNS/dqn_<init>)")
    p.add_argument("--stand-in", default=None, choices=pol.POLICY_NAMES,
                   help="use this policy for any that is not trained yet (pipeline checks only)")
    p.add_argument("--backend", default="auto", choices=env_lib.BACKEND_CHOICES,
                   help="physics backend (auto: mujoco on a CPU, mjx on an accelerator)")
    p.add_argument("--commit", action="store_true",
                   help=f"copy the run's latest checkpoint, config, metrics and curves to "
                        f"{runs_lib.BASELINE_DIR}/<run>/ (then git-commit that folder) and exit")
    a = p.parse_args(argv)
    run_dir = pathlib.Path(a.out or pathlib.Path(a.runs) / f"dqn_{a.init}")
    if a.commit:
        out = runs_lib.commit_run(run_dir, runs_lib.BASELINE_DIR / run_dir.name, plot_curves)
        print(f"committed copy: {out}")
        return 0
    preset = a.preset or ("cpu" if jax.default_backend() == "cpu" else "gpu")
    cfg = default_dqn_config(preset)
    cfg.init, cfg.seed = a.init, a.seed
    for attr, val in (("total_env_steps", a.total_steps), ("chunk_env_steps", a.chunk_steps),
                      ("num_envs", a.num_envs), ("oracle_bonus", a.oracle_bonus)):
        if val is not None:
            cfg[attr] = val
    runs_lib.restore_committed(run_dir, print, runs_lib.BASELINE_DIR)
    say = runs_lib.train_log(run_dir, functools.partial(print, flush=True), runs_lib.BASELINE_DIR)
    say(f"training the DQN selector ({a.init} policies) on {jax.devices()[0].platform}: "
          f"{cfg.total_env_steps:,} env steps, {cfg.num_envs} envs, checkpoints every "
          f"{cfg.chunk_env_steps:,} ({preset} preset) -> {run_dir}")
    train_dqn(cfg, run_dir, a.runs, a.stand_in, a.max_chunks, print_fn=say, backend=a.backend)
    return 0


if __name__ == "__main__":
    sys.exit(main())

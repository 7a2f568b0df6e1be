"""PPO compiled once per run (purejaxrl style): `make_train(cfg, env) -> Trainer`.

Brax's `ppo.train` recompiles on every call (about 3 minutes on the 2-core CPU) and cannot take
the curriculum's values as traced inputs, and a jitted computation with a host callback (the
`mujoco` backend) is never put in JAX's persistent compilation cache. So this trainer jits one
`iteration(state, curriculum) -> (state, metrics)` and calls it for the whole run: a curriculum
notch, a resume or a new chunk never compiles again.

One iteration is `collect` then `update`. `collect`: `unroll_length` steps of `num_envs` envs
(auto-reset to fresh episodes drawn at the current curriculum values; an episode that reaches
`episode_length` steps is truncated, and its last step is masked out of the advantages, as Brax
does). `update`: GAE, then `num_updates_per_batch` epochs of `num_minibatches` minibatch steps of
`ppo_loss` (the clipped surrogate, Adam, global-norm clipping). Policy: a Gaussian with a
state-independent log std; the env clips actions to [-1, 1]. `max_action_std` (0: none) holds
each joint's std at or under a cap by projecting the log std after every update and before every
rollout: the entropy bonus otherwise drives up the std of joints whose noise the guides absorb
(README, Training).

What the rollout stores is the networks' input, not the observation: with the pooled heightmap
encoding (the default) the 2,400 heightmap cells are mean-pooled to 150 values once, at
collection (`policy_input`), and the networks run on that with a 1 x 1 pool, which is the same
function of the observation (pooling has no parameters, and the heightmap is fed un-normalised).
The inputs are normalised once per step, and the stored normalised input is what the updates
read, since the normaliser only moves after them. This keeps the rollout 12x smaller than the
observation (203 against 2,453 columns), which is most of what the update costs on a CPU.

Observation normalisation (normalizer.py): running mean/std of the robot state and the phase
clock (the heightmap, already in [0, 1], is fed raw so that a policy trained on flat ground meets
steps without exploding inputs; its entries in the normaliser are carried but never updated or
read); the statistics are updated after each iteration's updates.

Everything that a resume needs is in `TrainState` (parameters, optimiser moments, normaliser);
the env state is not saved (a resume starts fresh episodes).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from biped_switch.learning import networks
from biped_switch.learning.normalizer import Normalizer, normalize, update_normalizer  # noqa: F401  (Normalizer re-exported)
from biped_switch.simulation.observation import layout
from biped_switch.simulation.rollout import tree_where


class TrainState(NamedTuple):
    params: dict  # {"policy": ..., "value": ..., "log_std": (12,)}
    opt_state: object
    norm: Normalizer


class Trainer(NamedTuple):
    init: object  # rng -> TrainState
    reset_envs: object  # (rng, curriculum (3,)) -> env state batch
    iteration: object  # (TrainState, env state, rng, curriculum (3,)) -> (TrainState, env state, metrics)
    policy: object  # (params, norm, obs, rng, deterministic) -> action; obs may carry more
    # columns after the policy observation (a detector one-hot), which it ignores
    steps_per_iteration: int
    collect: object = None  # (TrainState, env state, rng, curriculum) -> (env state, Rollout)
    update: object = None  # (TrainState, Rollout, rng) -> (TrainState, metrics)
    forward: object = None  # (TrainState, obs, rng) -> the collection's per-step network pass


class LossParams(NamedTuple):
    """The clipped surrogate's constants (cfg.ppo)."""

    clipping_epsilon: float
    value_cost: float
    entropy_cost: float


def norm_mask(env) -> np.ndarray:
    """Over the policy observation: 1 for the columns that are normalised (robot state, phase
    clock), 0 for the heightmap."""
    lay = layout(env)
    mask = np.ones(lay.policy_size, np.float32)
    mask[lay.heightmap] = 0.0
    return mask


def make_networks(net_cfg, env, pooled_input: bool = False):
    """Policy and value networks on the policy observation, or, with `pooled_input`, on its
    `policy_input` (heightmap already pooled): the same parameters either way."""
    lay = layout(env)
    grid, pool = lay.grid, tuple(net_cfg.pool)
    if pooled_input:
        grid, pool = (lay.grid[0] // pool[0], lay.grid[1] // pool[1]), (1, 1)
    kw = dict(state_size=lay.state_size, grid=grid, encoding=net_cfg.encoding,
              pool=pool, hm_hidden=tuple(net_cfg.hm_hidden))
    pi = networks.PolicyValueMLP(env.action_size, tuple(net_cfg.policy_hidden), **kw)
    vf = networks.PolicyValueMLP(1, tuple(net_cfg.value_hidden), **kw)
    return pi, vf


def make_policy(net_cfg, env):
    """(params, norm, obs (B, >= policy obs), rng, deterministic) -> actions (B, 12), unclipped."""
    pi, _ = make_networks(net_cfg, env)
    mask = jnp.asarray(norm_mask(env))
    cols = layout(env).policy

    def policy(params, norm, obs, rng, deterministic=True):
        mean = pi.apply(params["policy"], normalize(norm, obs[..., cols], mask))
        if deterministic:
            return mean
        return mean + jnp.exp(params["log_std"]) * jax.random.normal(rng, mean.shape)

    return policy


def policy_input_fn(net_cfg, env):
    """(obs (..., policy obs) -> network input, its column map into the observation (I,), its
    normalisation mask (I,)). With the pooled encoding the heightmap is pooled here (150 values
    for 2,400): the heightmap columns' map entries point at the first heightmap column, whose
    statistics are never used (mask 0). With the MLP encoding, the observation itself."""
    lay = layout(env)
    mask = norm_mask(env)
    if net_cfg.encoding != "pool":
        return (lambda obs: obs), np.arange(lay.policy_size), mask
    pr, pc = net_cfg.pool
    n_pool = (lay.grid[0] // pr) * (lay.grid[1] // pc)
    hm0 = lay.heightmap.start
    cols = np.concatenate([np.arange(lay.state_size), np.full(n_pool, hm0),
                           np.arange(lay.phase.start, lay.phase.stop)])
    in_mask = np.concatenate([mask[:lay.state_size], np.zeros(n_pool, np.float32),
                              mask[lay.phase]]).astype(np.float32)

    def policy_input(obs):
        s, h, rest = lay.split(obs[..., :lay.policy_size])
        return jnp.concatenate([s, networks.encode_heightmap(h, lay.grid, (pr, pc)), rest], -1)

    return policy_input, cols, in_mask


def input_normalizer(norm: Normalizer, cols) -> Normalizer:
    """The normaliser's entries of the network input's columns `cols` (`policy_input_fn`'s map;
    gathered once per rollout, not at every step)."""
    return Normalizer(norm.mean[cols], norm.var[cols], norm.count)


def _gaussian_logp(x, mean, log_std):
    return jnp.sum(-0.5 * ((x - mean) / jnp.exp(log_std)) ** 2 - log_std - 0.5 * jnp.log(2 * jnp.pi),
                   axis=-1)


def gae(reward, value, value_next, term, trunc, discount, lam):
    """Advantages (T, ...) by generalised advantage estimation over time-major arrays. A
    termination cuts the bootstrap; a truncated step (episode cut at its length limit, its next
    value being that of a fresh episode) has its delta and the recursion through it masked, as
    Brax does."""

    def body(acc, x):
        r, v, vn, te, tr = x
        keep = 1.0 - tr
        delta = (r + discount * (1.0 - te) * vn - v) * keep
        acc = delta + discount * lam * (1.0 - te) * keep * acc
        return acc, acc

    _, adv = jax.lax.scan(body, jnp.zeros_like(reward[0]), (reward, value, value_next, term, trunc),
                          reverse=True)
    return adv


def ppo_loss(params, mb, pi_apply, vf_apply, hp: LossParams):
    """PPO's loss on one minibatch: (total, info).

    mb: "x" the networks' normalised inputs (N, I), "action" (N, 12), "logp" its log-likelihood
    when it was sampled, "adv" advantages, "target" value targets, "mask" 0 on truncated steps,
    "learner" 1 on the steps where the learner's own action acted (all, but in a setup env).
    Advantages are standardised over the learner's steps; the surrogate is averaged over the steps
    that are both the learner's and not truncated; the value loss over every step."""
    mean = pi_apply(params["policy"], mb["x"])
    logp = _gaussian_logp(mb["action"], mean, params["log_std"])
    ratio = jnp.exp(logp - mb["logp"])
    lm = mb["learner"]
    n_l = jnp.maximum(jnp.sum(lm), 1.0)
    a = mb["adv"]
    a_mean = jnp.sum(a * lm) / n_l  # = jnp.mean and jnp.std when every step is the learner's
    a = (a - a_mean) / (jnp.sqrt(jnp.sum(lm * (a - a_mean) ** 2) / n_l) + 1e-8)
    eps = hp.clipping_epsilon
    surr = jnp.minimum(ratio * a, jnp.clip(ratio, 1 - eps, 1 + eps) * a)
    w = mb["mask"] * lm
    pg = -jnp.sum(surr * w) / jnp.maximum(jnp.sum(w), 1.0)
    v = vf_apply(params["value"], mb["x"])[..., 0]
    v_loss = 0.5 * jnp.mean((v - mb["target"]) ** 2)
    entropy = jnp.sum(params["log_std"] + 0.5 * jnp.log(2 * jnp.pi * jnp.e))
    total = pg + hp.value_cost * v_loss - hp.entropy_cost * entropy
    return total, {"loss/policy": pg, "loss/value": v_loss, "loss/entropy": entropy,
                   "loss/approx_kl": jnp.mean((ratio - 1) - jnp.log(ratio)),
                   "loss/clip_frac": jnp.mean(jnp.abs(ratio - 1) > eps)}


def update_normalizer_cols(norm: Normalizer, batch, cols, mask, axis_name=None) -> Normalizer:
    """`update_normalizer` of the entries `cols` (I,) where `mask` > 0, from a batch (N, I) of
    those columns; every other entry of `norm` is left as it is (the count moves for all)."""
    sel = np.flatnonzero(np.asarray(mask) > 0)
    idx = np.asarray(cols)[sel]
    part = Normalizer(norm.mean[idx], norm.var[idx], norm.count)
    new = update_normalizer(part, batch[:, sel], axis_name)
    return Normalizer(norm.mean.at[idx].set(new.mean), norm.var.at[idx].set(new.var), new.count)


def make_train(cfg, env) -> Trainer:
    """The PPO of `cfg.ppo` with the networks of `cfg.network` on `env` (a BipedEnv or any env
    with reset(rng, difficulty, guide_scale=, push_scale=) and step(state, action)).
    One function: its inner `forward`, `collect` and `update` close over the networks, shapes
    and devices they are compiled for; the math is in `ppo_loss`, `gae` and the normaliser."""
    p = cfg.ppo
    n_dev = jax.local_device_count()
    if p.num_envs % n_dev:
        raise ValueError(f"num_envs {p.num_envs} does not split over {n_dev} local devices")
    n_envs, T = int(p.num_envs) // n_dev, int(p.unroll_length)  # per device
    n_batch = n_envs * T
    if n_batch % p.num_minibatches:
        raise ValueError(f"num_envs * unroll_length = {n_batch * n_dev} does not split into "
                         f"{p.num_minibatches} minibatches on each of {n_dev} device(s)")
    axis = "devices" if n_dev > 1 else None

    def pmean(x):
        return x if axis is None else jax.lax.pmean(x, axis)

    def psum(x):
        return x if axis is None else jax.lax.psum(x, axis)
    pi, vf = make_networks(cfg.network, env, pooled_input=cfg.network.encoding == "pool")
    pi_full, vf_full = make_networks(cfg.network, env)
    policy_input, in_cols, in_mask = policy_input_fn(cfg.network, env)
    in_cols_j, in_mask_j = jnp.asarray(in_cols), jnp.asarray(in_mask)
    policy = make_policy(cfg.network, env)
    hp = LossParams(float(p.clipping_epsilon), float(p.value_cost), float(p.entropy_cost))
    tx = optax.chain(optax.clip_by_global_norm(p.max_grad_norm),
                     optax.adam(p.learning_rate, eps=1e-5))
    obs_size = layout(env).policy_size
    if obs_size != env.observation_size:
        raise ValueError(f"the training env's observation ({env.observation_size}) must be the "
                         f"policy observation ({obs_size}): train without detector_one_hot")
    ep_len = int(cfg.episode_length)
    max_log_std = float(np.log(p.max_action_std)) if p.get("max_action_std", 0.0) > 0 else None

    def cap_std(params):
        """`params` with the log std projected under the cap (the optimiser's step can cross it)."""
        if max_log_std is None:
            return params
        return {**params, "log_std": jnp.minimum(params["log_std"], max_log_std)}

    def init(rng) -> TrainState:
        k_pi, k_vf = jax.random.split(rng)
        dummy = jnp.zeros((1, obs_size))
        params = {"policy": pi_full.init(k_pi, dummy), "value": vf_full.init(k_vf, dummy),
                  "log_std": jnp.full((env.action_size,), np.log(p.init_action_std), jnp.float32)}
        return TrainState(cap_std(params), tx.init(params), Normalizer.fresh(obs_size))

    def reset_envs(rng, curr):
        keys = jax.random.split(rng, n_envs)
        d, g, push = curr[0], curr[1], curr[2]
        state = jax.vmap(lambda k: env.reset(k, d, guide_scale=g, push_scale=push))(keys)
        return state, jnp.zeros(n_envs, jnp.int32), jnp.zeros(n_envs)

    def net_input(norm_in, obs):
        """(raw, normalised) network inputs of `obs` under `input_normalizer`'s normaliser."""
        x = policy_input(obs)
        return x, normalize(norm_in, x, in_mask_j)

    def forward(ts: TrainState, obs, key, norm_in=None):
        """The collection's network pass on a batch of observations: the sampled action, its
        log-likelihood, the value, and the raw and normalised network inputs."""
        x, xn = net_input(input_normalizer(ts.norm, in_cols_j) if norm_in is None else norm_in, obs)
        mean = pi.apply(ts.params["policy"], xn)
        action = mean + jnp.exp(ts.params["log_std"]) * jax.random.normal(key, mean.shape)
        return {"x_raw": x, "x": xn, "action": action,
                "logp": _gaussian_logp(action, mean, ts.params["log_std"]),
                "value": vf.apply(ts.params["value"], xn)[..., 0]}

    def collect(ts: TrainState, envs, keys, curr):
        """`unroll_length` steps of every env; `keys` (2, 2): the fresh episodes' and the
        actions' keys."""
        params = cap_std(ts.params)  # a run resumed under a new cap
        env_state, ep_t, ep_ret = envs
        k_fresh, k_roll = keys[0], keys[1]
        fresh, _, _ = reset_envs(k_fresh, curr)
        norm_in = input_normalizer(ts.norm, in_cols_j)

        def step(carry, key):
            state, t, ret = carry
            act = forward(ts._replace(params=params), state.obs, key, norm_in)
            action = act["action"]
            nxt = jax.vmap(env.step)(state, action)
            t = t + 1
            term = nxt.done > 0
            trunc = (t >= ep_len) & ~term
            end = term | trunc
            ret = ret + nxt.reward
            m = nxt.metrics
            # 1 where the env uses this action (a setup env's frozen phases: 0); the policy
            # loss is weighted by it, values and GAE run over every step (switching/setup.py)
            learner = state.info.get("learner_acts", jnp.ones_like(nxt.reward))
            out = {**act, "learner": learner, "reward": nxt.reward, "term": term.astype(jnp.float32),
                   "trunc": trunc.astype(jnp.float32),
                   "ep_end": end.astype(jnp.float32), "ep_return": ret, "ep_length": t,
                   "ep_success": m["success"], "ep_fell": m["fell"],
                   "ep_distance_m": m["distance_m"], "ep_progress": m["progress_frac"],
                   "terms": {k: v for k, v in m.items() if k.startswith("reward/")}}
            state = tree_where(end, fresh, nxt)
            return (state, jnp.where(end, 0, t), jnp.where(end, 0.0, ret)), out

        (env_state, ep_t, ep_ret), tr = jax.lax.scan(step, (env_state, ep_t, ep_ret),
                                                    jax.random.split(k_roll, T))
        tr["last_value"] = vf.apply(params["value"], net_input(norm_in, env_state.obs)[1])[..., 0]
        return (env_state, ep_t, ep_ret), tr

    def update(ts: TrainState, tr, k_sgd):
        v_next = jnp.concatenate([tr["value"][1:], tr["last_value"][None]], axis=0)
        adv = gae(tr["reward"] * p.reward_scaling, tr["value"], v_next, tr["term"], tr["trunc"],
                  p.discounting, p.gae_lambda)
        target = adv + tr["value"]
        flat = {k: tr[k].reshape((n_batch,) + tr[k].shape[2:])
                for k in ("x", "action", "logp", "learner")}
        flat["adv"], flat["target"] = adv.reshape(-1), target.reshape(-1)
        flat["mask"] = 1.0 - tr["trunc"].reshape(-1)

        def sgd_epoch(carry, key):
            params, opt_state = carry
            perm = jax.random.permutation(key, n_batch)
            mbs = jax.tree.map(lambda x: x[perm].reshape((p.num_minibatches, -1) + x.shape[1:]),
                               flat)

            def mb_step(c, mb):
                params, opt_state = c
                (_, info), grads = jax.value_and_grad(ppo_loss, has_aux=True)(
                    params, mb, pi.apply, vf.apply, hp)
                grads = pmean(grads)  # one update from every device's minibatch: params stay equal
                upd, opt_state = tx.update(grads, opt_state, params)
                return (cap_std(optax.apply_updates(params, upd)), opt_state), info

            return jax.lax.scan(mb_step, (params, opt_state), mbs)

        (params, opt_state), info = jax.lax.scan(
            sgd_epoch, (cap_std(ts.params), ts.opt_state),
            jax.random.split(k_sgd, p.num_updates_per_batch))
        norm = update_normalizer_cols(ts.norm, tr["x_raw"].reshape(n_batch, -1), in_cols, in_mask,
                                      axis)
        ends = tr["ep_end"]
        n_end = psum(jnp.sum(ends))

        def ep_mean(x):
            return psum(jnp.sum(x * ends)) / jnp.maximum(n_end, 1.0)

        metrics = {k: pmean(jnp.mean(v)) for k, v in info.items()}
        metrics.update({
            "train/reward_per_step": pmean(jnp.mean(tr["reward"])),
            "train/learner_frac": pmean(jnp.mean(tr["learner"])),  # steps the learner acted
            "train/action_std": jnp.mean(jnp.exp(params["log_std"])),
            "train/action_std_max": jnp.max(jnp.exp(params["log_std"])),  # the noisiest joint
            "episode/count": n_end,
            "episode/sum_reward": ep_mean(tr["ep_return"]),
            "episode/length": ep_mean(tr["ep_length"].astype(jnp.float32)),
            "episode/success": ep_mean(tr["ep_success"]),
            "episode/fell": ep_mean(tr["ep_fell"]),
            "episode/distance_m": ep_mean(tr["ep_distance_m"]),
            "episode/progress_frac": ep_mean(tr["ep_progress"]),
        })
        metrics.update({k: pmean(jnp.mean(v)) for k, v in tr["terms"].items()})  # per step
        return TrainState(params, opt_state, norm), metrics

    def split_keys(rng):
        k_fresh, k_roll, k_sgd = jax.random.split(rng, 3)
        return jnp.stack([k_fresh, k_roll]), k_sgd

    def collect_keys(ts, envs, rng, curr):
        """`collect` with the iteration's own key stream (for timing the phases apart)."""
        k2, _ = split_keys(rng)
        return collect(ts, envs, k2, curr)

    def iteration(ts: TrainState, envs, rng, curr):
        k2, k_sgd = split_keys(rng)
        envs, tr = collect(ts, envs, k2, curr)
        ts, metrics = update(ts, tr, k_sgd)
        return ts, envs, metrics

    if axis is None:
        return Trainer(init, jax.jit(reset_envs), jax.jit(iteration), policy, n_batch,
                       jax.jit(collect_keys), jax.jit(update), forward)
    # Every local device runs its share of the envs; the train state is the same on all of them
    # (gradients and normaliser statistics are averaged), so it leaves pmap unreplicated.
    reset_p = jax.pmap(reset_envs, in_axes=(0, None))
    iter_p = jax.pmap(iteration, axis_name=axis, in_axes=(None, 0, 0, None),
                      out_axes=(None, 0, None))

    def reset_all(rng, curr):
        return reset_p(jax.random.split(rng, n_dev), curr)

    def iteration_all(ts, envs, rng, curr):
        return iter_p(ts, envs, jax.random.split(rng, n_dev), curr)

    return Trainer(init, reset_all, iteration_all, policy, n_batch * n_dev)

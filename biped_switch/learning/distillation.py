"""DAgger distillation (rsl_rl's `Distillation` beside PPO): one student policy regresses a frozen
teacher's actions on the states the student itself visits.

`make_dagger(cfg, env, teacher) -> Dagger`, compiled once per run (as ppo.make_train). One
`iteration(state, envs, rng, mix)`:
  - collect `unroll_length` control steps of `num_envs` envs. In each env and step the teacher's
    action is executed with probability `mix` (a traced scalar: the schedule lives on the host,
    `mix_at`), else the student's deterministic one. The teacher labels every visited state with
    its action. Its own state (a switching controller's: the active policy, the artifact last
    seen) is carried along the student's trajectory and starts afresh with each episode;
  - append (student network input, label) to the aggregate buffer, a ring of `buffer_size` rows;
  - `updates_per_iteration` Adam steps of `distill_loss` on minibatches drawn from the whole
    buffer (DAgger's aggregate: early, teacher-driven states stay in the data).

The student is the behaviour policies' network (ppo.make_networks) with its own observation
normaliser, saved in the PPO checkpoint layout ({"params": {"policy", "log_std"}, "norm"}), so
that every tool that loads a policy (`policies.load_suite`, Table II, render) loads it as is.
The rollout stores the pooled network input (203 columns), as PPO's does.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from biped_switch.learning import ppo
from biped_switch.learning.normalizer import Normalizer, normalize
from biped_switch.simulation.observation import layout
from biped_switch.simulation.rollout import tree_where


class Teacher(NamedTuple):
    """A frozen controller as pure functions over a batch: `init(n)` its per-env state;
    `act(tstate, env_state, key) -> (actions (B, A) in [-1, 1], new tstate, active (B,) int32:
    which of its `n_policies` policies acted, for the logs)`."""

    init: Callable
    act: Callable
    n_policies: int


class Buffer(NamedTuple):
    """The aggregate dataset: a ring of (network input, label) rows."""

    x: jax.Array  # (capacity, I) raw (un-normalised) student network inputs
    y: jax.Array  # (capacity, A) the teacher's actions
    ptr: jax.Array  # int32: the next row to write
    count: jax.Array  # int32: rows filled


class DaggerState(NamedTuple):
    params: dict  # {"policy": the student network's Flax variables}
    opt_state: object
    norm: Normalizer  # over the policy observation, as PPO's (heightmap entries unused)
    buffer: Buffer


class Envs(NamedTuple):
    """The collection's carry between iterations."""

    state: object  # env states (B,)
    teacher: object  # the teacher's per-env state
    t: jax.Array  # (B,) int32 control steps into each episode


class Dagger(NamedTuple):
    init: Callable  # rng -> DaggerState (empty buffer)
    reset_envs: Callable  # rng -> Envs
    iteration: Callable  # (DaggerState, Envs, rng, mix) -> (DaggerState, Envs, metrics)
    collect: Callable  # (DaggerState, Envs, rng, mix, fresh Envs) -> (Envs, rollout dict)
    steps_per_iteration: int


def distill_loss(policy_params, x_norm, label, pi_apply) -> tuple[jax.Array, dict]:
    """Mean squared error between the student's action mean on normalised inputs `x_norm` (N, I)
    and the teacher's actions `label` (N, A), over samples and joints."""
    mean = pi_apply(policy_params, x_norm)
    err = jnp.mean((mean - label) ** 2)
    return err, {"loss/action_mse": err}


def mix_at(step: int, start: float, end: float, decay_steps: int) -> float:
    """The probability that the teacher acts at env step `step`: linear from `start` at step 0 to
    `end` at `decay_steps`, then `end` (DAgger's decaying beta)."""
    if decay_steps <= 0:
        return float(end)
    frac = min(max(step, 0) / decay_steps, 1.0)
    return float(start + (end - start) * frac)


def buffer_append(buf: Buffer, x: jax.Array, y: jax.Array) -> Buffer:
    """`buf` with the rows x (n, I), y (n, A) written at its pointer, wrapping round."""
    cap, n = buf.x.shape[0], x.shape[0]
    idx = (buf.ptr + jnp.arange(n)) % cap
    return Buffer(buf.x.at[idx].set(x), buf.y.at[idx].set(y), (buf.ptr + n) % cap,
                  jnp.minimum(buf.count + n, cap).astype(jnp.int32))


def make_dagger(cfg, env, teacher: Teacher) -> Dagger:
    """The DAgger of `cfg.distill` with the student network of `cfg.network` on `env` (whose
    observation is the policy observation), labelled by `teacher`."""
    d = cfg.distill
    n_envs, T = int(d.num_envs), int(d.unroll_length)
    n_batch, cap = n_envs * T, int(d.buffer_size)
    if cap < n_batch:
        raise ValueError(f"distill.buffer_size {cap:,} is smaller than one collection "
                         f"(num_envs x unroll_length = {n_batch:,})")
    horizon = int(round(float(d.horizon_s) / env.dt))
    pi, _ = ppo.make_networks(cfg.network, env, pooled_input=cfg.network.encoding == "pool")
    pi_full, _ = ppo.make_networks(cfg.network, env)
    policy_input, in_cols, in_mask = ppo.policy_input_fn(cfg.network, env)
    in_cols_j, in_mask_j = jnp.asarray(in_cols), jnp.asarray(in_mask)
    obs_size = layout(env).policy_size
    if obs_size != env.observation_size:
        raise ValueError(f"the student's env observation ({env.observation_size}) must be the "
                         f"policy observation ({obs_size}): no detector one-hot")
    tx = optax.chain(optax.clip_by_global_norm(float(d.max_grad_norm)),
                     optax.adam(float(d.learning_rate)))
    noise_std = float(d.action_noise_std)

    def init(rng) -> DaggerState:
        params = {"policy": pi_full.init(rng, jnp.zeros((1, obs_size)))}
        buf = Buffer(jnp.zeros((cap, len(in_cols)), jnp.float32),
                     jnp.zeros((cap, env.action_size), jnp.float32),
                     jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))
        return DaggerState(params, tx.init(params), Normalizer.fresh(obs_size), buf)

    def reset_envs(rng) -> Envs:
        state = jax.vmap(lambda k: env.reset(k, guide_scale=0.0, push_scale=0.0))(
            jax.random.split(rng, n_envs))
        return Envs(state, teacher.init(n_envs), jnp.zeros(n_envs, jnp.int32))

    def student_action(params, norm_in, x, key):
        a = jnp.clip(pi.apply(params["policy"], normalize(norm_in, x, in_mask_j)), -1.0, 1.0)
        if noise_std > 0:
            a = jnp.clip(a + noise_std * jax.random.normal(key, a.shape), -1.0, 1.0)
        return a

    def collect(ds: DaggerState, envs: Envs, rng, mix, fresh: Envs):
        """`unroll_length` steps; ended episodes restart from `fresh` (the teacher's state too)."""
        norm_in = ppo.input_normalizer(ds.norm, in_cols_j)

        def step(c, key):
            k_t, k_mix, k_s = jax.random.split(key, 3)
            x = policy_input(c.state.obs)
            label, tstate, active = teacher.act(c.teacher, c.state, k_t)
            own = student_action(ds.params, norm_in, x, k_s)
            by_teacher = jax.random.uniform(k_mix, (n_envs,)) < mix
            action = jnp.where(by_teacher[:, None], label, own)
            nxt = jax.vmap(env.step)(c.state, action)
            t = c.t + 1
            end = (nxt.done > 0.5) | (t >= horizon)
            m = nxt.metrics
            out = {"x": x, "label": label, "action": action, "student": own,
                   "by_teacher": by_teacher, "active": active, "end": end,
                   "success": m["success"], "fell": m["fell"], "progress": m["progress_frac"]}
            nc = Envs(tree_where(end, fresh.state, nxt), tree_where(end, fresh.teacher, tstate),
                      jnp.where(end, 0, t))
            return nc, out

        return jax.lax.scan(step, envs, jax.random.split(rng, T))

    def update(ds: DaggerState, tr, rng):
        x = tr["x"].reshape(n_batch, -1)
        buf = buffer_append(ds.buffer, x, tr["label"].reshape(n_batch, -1))
        norm = ppo.update_normalizer_cols(ds.norm, x, in_cols, in_mask)
        norm_in = ppo.input_normalizer(norm, in_cols_j)
        n_mb = int(d.updates_per_iteration)
        idx = jax.random.randint(rng, (n_mb, int(d.batch_size)), 0, jnp.maximum(buf.count, 1))

        def mb_step(c, i):
            params, opt_state = c
            xn = normalize(norm_in, buf.x[i], in_mask_j)
            (_, info), g = jax.value_and_grad(distill_loss, has_aux=True)(
                params["policy"], xn, buf.y[i], pi.apply)
            upd, opt_state = tx.update({"policy": g}, opt_state, params)
            return (optax.apply_updates(params, upd), opt_state), info

        (params, opt_state), info = jax.lax.scan(mb_step, (ds.params, ds.opt_state), idx)
        return DaggerState(params, opt_state, norm, buf), {k: v[-1] for k, v in info.items()}

    def iteration(ds: DaggerState, envs: Envs, rng, mix):
        k_fresh, k_roll, k_upd = jax.random.split(rng, 3)
        envs, tr = collect(ds, envs, k_roll, mix, reset_envs(k_fresh))
        ds, info = update(ds, tr, k_upd)
        ends = tr["end"].astype(jnp.float32)
        n_end = jnp.sum(ends)

        def ep_mean(v):
            return jnp.sum(v * ends) / jnp.maximum(n_end, 1.0)

        metrics = {**info, "dagger/mix": jnp.asarray(mix, jnp.float32),
                   "dagger/teacher_frac": jnp.mean(tr["by_teacher"].astype(jnp.float32)),
                   # the student's error on the states just visited, before this update
                   "dagger/onpolicy_mse": jnp.mean((tr["student"] - tr["label"]) ** 2),
                   "dagger/buffer_rows": ds.buffer.count.astype(jnp.float32),
                   "episode/count": n_end, "episode/success": ep_mean(tr["success"]),
                   "episode/fell": ep_mean(tr["fell"]), "episode/progress_frac": ep_mean(tr["progress"])}
        for i in range(teacher.n_policies):  # which teacher policy labelled the steps
            metrics[f"teacher/active_{i}"] = jnp.mean((tr["active"] == i).astype(jnp.float32))
        return ds, envs, metrics

    # the state is donated: the buffer is updated in place, not copied every iteration
    return Dagger(init, jax.jit(reset_envs), jax.jit(iteration, donate_argnums=0), collect, n_batch)


def checkpoint_tree(ds: DaggerState, log_std: float) -> dict:
    """The student's checkpoint tree in the PPO layout (what `policies.load_suite` reads), with
    the optimiser state for a resume; `log_std` a fixed action std [log] for a PPO fine-tune."""
    a = jax.tree.leaves(ds.params["policy"])[-1].shape[-1]
    return {"params": {"policy": ds.params["policy"],
                       "log_std": jnp.full((a,), log_std, jnp.float32)},
            "opt_state": ds.opt_state, "norm": ds.norm._asdict()}


def buffer_arrays(buf: Buffer) -> dict:
    """The buffer's filled rows, in ring order from the oldest, as numpy (for its file)."""
    n, cap, ptr = int(buf.count), buf.x.shape[0], int(buf.ptr)
    order = (np.arange(n) + (ptr - n)) % cap
    return {"x": np.asarray(buf.x)[order], "y": np.asarray(buf.y)[order]}


def buffer_from_arrays(template: Buffer, x: np.ndarray, y: np.ndarray) -> Buffer:
    """A buffer shaped as `template` holding rows x, y (oldest first; the newest kept if more)."""
    cap = template.x.shape[0]
    if x.shape[1:] != template.x.shape[1:] or y.shape[1:] != template.y.shape[1:]:
        raise ValueError(f"buffer rows of shape {x.shape[1:]}/{y.shape[1:]}, expected "
                         f"{template.x.shape[1:]}/{template.y.shape[1:]}")
    x, y = x[-cap:], y[-cap:]
    return buffer_append(template, jnp.asarray(x), jnp.asarray(y)) if len(x) else template

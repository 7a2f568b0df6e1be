"""Batched fixed-horizon rollouts of a policy, with each episode frozen once it ends.

One pure function serves the curriculum's milestone checks during training and the evaluations:
`rollout(env, policy, rng, n_envs, horizon)` runs `n_envs` episodes for `horizon` control steps
under `jax.lax.scan` and returns per-episode totals and final metrics. An episode that ends (fall or
finish) stops accumulating reward and keeps the metrics of its last live step.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

PolicyFn = Callable[[jax.Array, jax.Array], jax.Array]  # (obs batch, rng) -> action batch


def rollout(env, policy: PolicyFn, rng: jax.Array, n_envs: int, horizon: int,
            track_ids: jax.Array | None = None, reset_args: dict | None = None) -> dict:
    """Per-episode `reward` (sum), `length` (live steps), `done`, and every final metric.

    `track_ids` (n_envs,) picks each episode's track from the env's bank; default: random.
    `reset_args` (e.g. the curriculum's difficulty, guide_scale, push_scale; traced ok) go to
    every `env.reset`."""
    k_reset, k_run = jax.random.split(rng)
    keys = jax.random.split(k_reset, n_envs)
    kw = reset_args or {}
    if track_ids is None:
        state = jax.vmap(lambda k: env.reset(k, **kw))(keys)
    else:
        state = jax.vmap(lambda k, i: env.reset(k, track_id=i, **kw))(keys, track_ids)

    def body(carry, key):
        state, total, length, ended, metrics = carry
        action = policy(state.obs, key)
        nxt = jax.vmap(env.step)(state, action)
        live = 1.0 - ended
        total = total + jnp.where(ended > 0, 0.0, nxt.reward)  # never 0 * a frozen episode's
        length = length + live
        metrics = jax.tree.map(lambda new, old: jnp.where(ended > 0, old, new), nxt.metrics, metrics)
        ended = jnp.maximum(ended, nxt.done)
        return (nxt, total, length, ended, metrics), None

    zeros = jnp.zeros(n_envs)
    carry = (state, zeros, zeros, zeros, state.metrics)
    (state, total, length, ended, metrics), _ = jax.lax.scan(
        body, carry, jax.random.split(k_run, horizon))
    return {"reward": total, "length": length, "done": ended, **metrics}


def summarize(result: dict, horizon: int) -> dict:
    """Means over episodes; `reward_per_step` divides by the full horizon (a fall scores 0 after)."""
    out = {k: float(jnp.mean(v)) for k, v in result.items()}
    out["reward_per_step"] = float(jnp.mean(result["reward"]) / horizon)
    return out


def over_devices(fn: Callable, n_shared: int) -> Callable:
    """`fn(*shared, rng, *batched)` run with the batch split over every local device (pmap).

    `shared` arguments (parameters) are broadcast; `rng` is split per device; each `batched`
    array's leading axis is split evenly. With one device this is plain jit."""
    n_dev = jax.local_device_count()
    if n_dev == 1:
        return jax.jit(fn)
    cache = {}

    def run(*args):
        shared, rng, batched = args[:n_shared], args[n_shared], args[n_shared + 1:]
        if len(args) not in cache:
            cache[len(args)] = jax.pmap(fn, in_axes=(None,) * n_shared + (0,) * (1 + len(batched)))
        pf = cache[len(args)]
        n = batched[0].shape[0]
        if n % n_dev:
            raise ValueError(f"batch {n} must divide evenly over {n_dev} devices")
        split = [x.reshape((n_dev, n // n_dev) + x.shape[1:]) for x in batched]
        out = pf(*shared, jax.random.split(rng, n_dev), *split)
        return jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), out)

    return run

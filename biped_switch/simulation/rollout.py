"""Batched episodes, each frozen once it ends: the one episode loop every rollout is built on.

`run_episodes(env, state, horizon, act, ...)` steps a batch of episodes from `state` with an
acting function and an optional per-step record function. The protocol lives here only:
  - live mask: an episode is live at control step t while it has not ended and t < horizon;
  - freeze at the end: an episode ends when the env says `done` (or `record` says it ended) at a
    live step; its metrics keep the values of that last live step, `length` stops counting, and
    with `freeze_state` its whole env state stops too (otherwise the batch's ended episodes step
    on unread: cheaper than masking the physics state every step);
  - chunks: `jax.lax.while_loop` over `jax.lax.scan` chunks of `chunk` steps, stopping once every
    episode has ended or the horizon is reached (the last chunk's steps past the horizon are not
    live); with a per-step `trace` (or `chunk=None`) the loop is instead one scan over the full
    horizon;
  - starts: `reset_by_track` resets a batch on given tracks (or the env's own random ones);
  - devices: `over_devices` splits a batch over every local device (pmap).

`rollout(env, policy, rng, n_envs, horizon)` (the curriculum's milestone checks during training
and Table I) returns per-episode totals and final metrics; `switching.multi_rollout`,
`switching.trace_rollout`, `dqn.dqn_rollout` and `sweep.sweep_rollout` are the others.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from biped_switch.kinds import ALL_ARTIFACT_KINDS

PolicyFn = Callable[[jax.Array, jax.Array], jax.Array]  # (obs batch, rng) -> action batch
# act(carry, state, live, key) -> (action batch, carry, aux): `state` the batch's env states
# (leading axis B), `live` (B,) bool, `key` this step's key (None without `rng`); `aux` (anything)
# goes to `record` / `trace` of the same step.
ActFn = Callable[[Any, Any, jax.Array, Any], tuple]
# record(carry, aux, state, nxt, live) -> (carry, end): `nxt` the stepped states; `end` (B,) bool
# ends episodes besides the env's `done` (applied at live steps only), or None.
RecordFn = Callable[[Any, Any, Any, Any, jax.Array], tuple]
# trace(carry, aux, state, nxt, live) -> a pytree recorded for every step (leading axis horizon);
# `carry` is the one after `record`.
TraceFn = Callable[[Any, Any, Any, Any, jax.Array], Any]


class Episodes(NamedTuple):
    state: Any  # the batch's states after the last step run (frozen at each end with freeze_state)
    carry: Any  # the acting carry after the last step run
    metrics: dict  # every env metric of each episode's last live step (the reset's if none)
    length: jax.Array  # (B,) float32: live steps
    done: jax.Array  # (B,) float32: 1 where the episode ended within the horizon
    trace: Any  # the per-step records (horizon, ...) of `trace`, else None


def episode_keys(rng: jax.Array, n_envs: int) -> tuple[jax.Array, jax.Array]:
    """(one reset key per env (n_envs, 2), the key left for the run): how every batch rollout
    splits its rng, so that one episode's start can be drawn again (table1.trial_reset_key)."""
    k_reset, k_run = jax.random.split(rng)
    return jax.random.split(k_reset, n_envs), k_run


def reset_by_track(env, keys: jax.Array, track_ids: jax.Array | None = None, **reset_args):
    """A batch of `env.reset(key, track_id=id, **reset_args)`, one per key; `track_ids` None: the
    env draws each track. `reset_args` (difficulty, guide_scale, ...; traced ok) go to every one."""
    if track_ids is None:
        return jax.vmap(lambda k: env.reset(k, **reset_args))(keys)
    return jax.vmap(lambda k, i: env.reset(k, track_id=i, **reset_args))(keys, track_ids)


def tree_where(mask, new, old):
    """Per-episode select over batched pytrees: `new` where `mask` (B,) is true, else `old` (every
    leaf has the leading batch axis B)."""
    return jax.tree.map(
        lambda n, o: jnp.where(mask.reshape((-1,) + (1,) * (jnp.ndim(n) - 1)), n, o), new, old)


def run_episodes(env, state, horizon: int, act: ActFn, carry: Any = None, *,
                 record: RecordFn | None = None, trace: TraceFn | None = None,
                 rng: jax.Array | None = None, chunk: int | None = 50,
                 freeze_state: bool = False) -> Episodes:
    """Step the batch `state` (leading axis B) for at most `horizon` control steps.

    Each step: `act` gives the actions (and its new carry), the env steps the whole batch,
    `record` may update the carry and end episodes, then the live mask freezes what has ended
    (see the module doc). With `rng`, step t's key is `jax.random.split(rng, horizon)[t]`.
    `chunk` None (or a `trace`): one scan over the whole horizon, no early stop. Pure and
    jittable (`horizon` and `chunk` static)."""
    n = jax.tree.leaves(state.obs)[0].shape[0]
    keys = None if rng is None else jax.random.split(rng, horizon)

    def step(c, _):
        state, ucarry, metrics, length, ended, t = c
        live = (ended < 0.5) & (t < horizon)  # the last chunk may run past the horizon
        key = None if keys is None else keys[jnp.minimum(t, horizon - 1)]
        action, ucarry, aux = act(ucarry, state, live, key)
        nxt = jax.vmap(env.step)(state, action)
        end = nxt.done > 0.5
        if record is not None:
            ucarry, more = record(ucarry, aux, state, nxt, live)
            if more is not None:
                end = end | more
        rec = None if trace is None else trace(ucarry, aux, state, nxt, live)
        metrics = tree_where(live, nxt.metrics, metrics)
        length = length + live
        ended = jnp.maximum(ended, (end & live).astype(jnp.float32))
        state = tree_where(live, nxt, state) if freeze_state else nxt
        return (state, ucarry, metrics, length, ended, t + 1), rec

    zeros = jnp.zeros(n)
    c = (state, carry, state.metrics, zeros, zeros, jnp.zeros((), jnp.int32))
    if trace is not None or chunk is None:  # a per-step record has a fixed length
        c, recs = jax.lax.scan(step, c, None, length=horizon)
    else:
        def run_chunk(c):
            return jax.lax.scan(step, c, None, length=min(chunk, horizon))[0]

        def not_finished(c):
            return (c[5] < horizon) & jnp.any(c[4] < 0.5)

        c, recs = jax.lax.while_loop(not_finished, run_chunk, c), None
    state, carry, metrics, length, ended, _ = c
    return Episodes(state, carry, metrics, length, ended, recs)


def rollout(env, policy: PolicyFn, rng: jax.Array, n_envs: int, horizon: int,
            track_ids: jax.Array | None = None, reset_args: dict | None = None,
            chunk: int | None = 50) -> dict:
    """Per-episode `reward` and each `reward/<term>` (sums over live steps), `length` (live
    steps), `done`, and every other metric of the last live step, of `n_envs` episodes of
    `policy(obs batch, key)`.

    `track_ids` (n_envs,) picks each episode's track from the env's bank; default: random.
    `reset_args` (e.g. the curriculum's difficulty, guide_scale, push_scale; traced ok) go to
    every `env.reset`. Runs in chunks of `chunk` steps and stops early once every episode has
    ended; `chunk=None` runs one scan over the horizon."""
    reset_keys, k_run = episode_keys(rng, n_envs)
    state = reset_by_track(env, reset_keys, track_ids, **(reset_args or {}))

    terms = [k for k in state.metrics if k.startswith("reward/")]

    def act(sums, state, live, key):
        return policy(state.obs, key), sums, None

    def record(sums, _, state, nxt, live):
        step = {"reward": nxt.reward} | {k: nxt.metrics[k] for k in terms}
        # never 0 * a frozen episode's value
        return {k: sums[k] + jnp.where(live, v, 0.0) for k, v in step.items()}, None

    sums = {k: jnp.zeros(n_envs) for k in ["reward", *terms]}
    ep = run_episodes(env, state, horizon, act, sums, record=record, rng=k_run, chunk=chunk)
    # a reward term's last-step value says little of the episode: its sum replaces it
    return {"length": ep.length, "done": ep.done, **ep.metrics, **ep.carry}


def summarize(result: dict, horizon: int) -> dict:
    """Means over episodes; `reward_per_step` and each `reward/<term>` (then per step, summing to
    it) divide by the full horizon (a fall scores 0 after)."""
    out = {k: float(jnp.mean(v)) / (horizon if k.startswith("reward/") else 1)
           for k, v in result.items()}
    out["reward_per_step"] = float(jnp.mean(result["reward"]) / horizon)
    if "fail_kind" in result:  # a mean of kind codes says nothing: the share of episodes that
        fail, fell = jnp.asarray(result["fail_kind"]), jnp.asarray(result["fell"]) > 0
        for code, kind in enumerate(ALL_ARTIFACT_KINDS):  # fell at each kind, and on plain ground
            out[f"fell_at/{kind}"] = float(jnp.mean(fell & (fail == code)))
        out["fell_at/flat"] = float(jnp.mean(fell & (fail == -1)))
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

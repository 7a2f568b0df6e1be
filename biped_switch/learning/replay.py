"""The DQN's replay buffer: a fixed-capacity ring of transitions in arrays, jittable."""

from __future__ import annotations

import functools
import jax
import jax.numpy as jnp
from biped_switch.simulation.observation import STATE_SIZE


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

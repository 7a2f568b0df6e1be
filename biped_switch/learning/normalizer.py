"""Input normalisation, for every network of the project: z = (x - mean) / std, optionally clipped.

`standardize` is the one formula. Where its statistics come from differs by learner:
  - PPO: running statistics (`Normalizer`, `update_normalizer`: Chan et al.'s parallel update after
    every iteration), applied to the robot state and the phase clock only (`normalize`'s mask; the
    heightmap, already in [0, 1], is fed raw);
  - the DQN selector: statistics frozen once when its replay buffer first fills (`frozen_stats`:
    per state column, one shared mean and std for the whole heightmap, the phase clock and the
    one-hot left as they are), stored in its params as {"mean", "std"};
  - switch estimators: per-column statistics of the training split in float64 (`column_stats`),
    stored in the params as "mean" and "std".
The DQN's statistics are computed on the device inside its jitted train step, the estimators' on
the host before training: each keeps its own reduction, so that a run gives the numbers it gave.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from biped_switch.simulation.observation import STATE_SIZE


def standardize(x, mean, std, clip=None):
    """(x - mean) / std, clipped to [-clip, clip] when `clip` is given."""
    z = (x - mean) / std
    return z if clip is None else jnp.clip(z, -clip, clip)


# ----------------------------------------------------------------------------- running (PPO)
class Normalizer(NamedTuple):
    mean: jax.Array  # (O,)
    var: jax.Array  # (O,)
    count: jax.Array  # ()

    @classmethod
    def from_tree(cls, tree: dict) -> "Normalizer":
        """From a checkpoint's {"mean", "var", "count"}."""
        return cls(**{k: jnp.asarray(tree[k]) for k in cls._fields})

    @classmethod
    def fresh(cls, size: int) -> "Normalizer":
        """Mean 0, variance 1, a tiny count: the first batch sets the statistics."""
        return cls(jnp.zeros(size), jnp.ones(size), jnp.asarray(1e-4))


def normalize(norm: Normalizer, obs, mask, clip=10.0):
    """`obs` standardised by the running statistics where `mask` > 0, left raw elsewhere."""
    z = standardize(obs, norm.mean, jnp.sqrt(norm.var + 1e-6), clip)
    return jnp.where(mask > 0, z, obs)


def update_normalizer(norm: Normalizer, batch, axis_name=None) -> Normalizer:
    """Chan et al.'s parallel update of a running mean/variance with a batch (N, O); with
    `axis_name`, the batch is the union of every device's (inside pmap)."""
    n = batch.shape[0]
    mean_b = jnp.mean(batch, axis=0)
    var_b = jnp.var(batch, axis=0)
    if axis_name is not None:
        mean_l = mean_b
        mean_b = jax.lax.pmean(mean_l, axis_name)
        var_b = jax.lax.pmean(var_b + (mean_l - mean_b) ** 2, axis_name)
        n = n * jax.lax.psum(1, axis_name)
    tot = norm.count + n
    delta = mean_b - norm.mean
    mean = norm.mean + delta * n / tot
    m2 = norm.var * norm.count + var_b * n + delta ** 2 * norm.count * n / tot
    return Normalizer(mean, m2 / tot, tot)


# ----------------------------------------------------------------------------- frozen statistics
def frozen_stats(x: jax.Array, std_floor: float, hm_size: int, state_size: int = STATE_SIZE
                 ) -> dict:
    """{"mean", "std"} of inputs `x` (N, columns) that start state | heightmap: each state column
    its own mean and std, the `hm_size` heightmap columns one shared mean and std, every column
    after them (phase clock, one-hot; already in [-1, 1]) mean 0 and std 1; std floored at
    `std_floor`. Jittable (the DQN's, on the device)."""
    x = x.astype(jnp.float32)
    s, h = x[:, :state_size], x[:, state_size:state_size + hm_size]
    n_extra = x.shape[1] - state_size - hm_size
    hm_mean, hm_std = jnp.mean(h), jnp.std(h)
    mean = jnp.concatenate([jnp.mean(s, 0), jnp.full(h.shape[1], hm_mean), jnp.zeros(n_extra)])
    std = jnp.concatenate([jnp.std(s, 0), jnp.full(h.shape[1], hm_std), jnp.ones(n_extra)])
    return {"mean": mean, "std": jnp.maximum(std, std_floor)}


def column_stats(x: np.ndarray, std_floor: float) -> tuple[np.ndarray, np.ndarray]:
    """(mean, std) float32 of every column of `x` (N, columns), accumulated in float64 on the host,
    std floored at `std_floor` (the switch estimators')."""
    mean = x.mean(0, dtype=np.float64).astype(np.float32)
    std = np.maximum(x.std(0, dtype=np.float64), std_floor).astype(np.float32)
    return mean, std

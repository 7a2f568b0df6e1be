"""Networks on the observation [robot state (51), heightmap (rows*cols), extras] (the column ranges:
`simulation.observation.ObsLayout`), and the one heightmap encoder they share.

`encode`: the state, the heightmap through its own MLP encoder (or mean-pooled), and the extras,
joined into one vector. `PolicyValueMLP`: the PPO policy and value networks (ppo.py), on the lean
pooled heightmap by default or through the encoder. `EncodedMLP`: the encoder and an MLP (the DQN
selector's Q-network). The switch estimators (switching/estimator.py) use the encoder too.

The encoder is a function, not a submodule: it creates its Dense layers in the calling module's
`linen.compact` method, so their parameters sit directly in that module's tree (Dense_<i>, or
<prefix>_<i> with a `prefix`), as in every checkpoint saved so far.
"""

from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp
from flax import linen

from biped_switch.simulation.observation import STATE_SIZE, split_columns


def swish_mlp(x, sizes: Sequence[int], kernel_init=linen.linear.default_kernel_init,
              prefix: str | None = None):
    """Dense + swish layers of `sizes`, named `<prefix>_<i>` (default: Flax's Dense_<n>). Call it
    inside a `linen.compact` method: the layers belong to that module."""
    for i, n in enumerate(sizes):
        name = None if prefix is None else f"{prefix}_{i}"
        x = linen.swish(linen.Dense(n, kernel_init=kernel_init, name=name)(x))
    return x


def layer_sizes(net_variables, prefix: str) -> tuple[int, ...]:
    """The widths of the `swish_mlp` layers `<prefix>_0, <prefix>_1, ...` in Flax variables: a
    saved network's sizes, read back from its params (static shapes under jit and vmap)."""
    p, out = net_variables["params"], []
    while f"{prefix}_{len(out)}" in p:
        out.append(int(p[f"{prefix}_{len(out)}"]["kernel"].shape[-1]))
    return tuple(out)


def encode(obs, state_size: int, hm_size: int, hm_hidden: Sequence[int],
           kernel_init=linen.linear.default_kernel_init, prefix: str | None = None, pool=None):
    """[state, encoded heightmap, extras] of `obs` (..., state | heightmap | extras): the heightmap
    through `swish_mlp(hm_hidden)` (layers `<prefix>_<i>`), or with `pool` ((grid, block)) mean-
    pooled by `encode_heightmap` instead. Call it inside a `linen.compact` method."""
    s, h, extra = split_columns(obs, state_size, hm_size)
    if pool is None:
        h = swish_mlp(h, hm_hidden, kernel_init, prefix)
    else:
        h = encode_heightmap(h, *pool)
    return jnp.concatenate([s, h, extra], axis=-1)


def encode_heightmap(hm, grid, pool):
    """The lean policy input: the (rows x cols) heightmap mean-pooled in blocks of `pool` cells
    (rows, cols); (2, 8) turns the paper's 60 x 40 grid into 30 x 5 = 150 values, 5 cm forward
    and 20 cm across (legged_gym feeds 187 height samples straight to its MLP)."""
    r, c = grid
    pr, pc = pool
    if r % pr or c % pc:
        raise ValueError(f"heightmap pool {pool} does not divide the {r}x{c} grid")
    h = hm.reshape(hm.shape[:-1] + (r // pr, pr, c // pc, pc))
    return jnp.mean(h, axis=(-3, -1)).reshape(hm.shape[:-1] + (r // pr * (c // pc),))


class EncodedMLP(linen.Module):
    """The heightmap through the encoder `hm_hidden`, joined with the state and the extras, an MLP
    `hidden` (swish), a linear output (the DQN selector's Q-network)."""

    out_size: int
    hidden: Sequence[int]
    hm_hidden: Sequence[int]
    hm_size: int
    state_size: int = STATE_SIZE

    @linen.compact
    def __call__(self, obs):
        init = jax.nn.initializers.lecun_uniform()
        x = encode(obs, self.state_size, self.hm_size, self.hm_hidden, init)
        x = swish_mlp(x, self.hidden, init)
        return linen.Dense(self.out_size, kernel_init=init)(x)


class PolicyValueMLP(linen.Module):
    """One network (policy or value) of the project's PPO, on a normalised observation.

    encoding "pool": state + pooled heightmap (`encode_heightmap`) + extras into one MLP;
    encoding "mlp": the heightmap through its own MLP encoder first (`hm_hidden`, as EncodedMLP)."""

    out_size: int
    hidden: Sequence[int]
    state_size: int
    grid: tuple
    encoding: str = "pool"
    pool: tuple = (2, 8)
    hm_hidden: Sequence[int] = (128, 64)

    @linen.compact
    def __call__(self, obs):
        if self.encoding not in ("pool", "mlp"):
            raise ValueError(f"unknown heightmap encoding {self.encoding!r}; expected pool or mlp")
        init = jax.nn.initializers.lecun_uniform()
        x = encode(obs, self.state_size, self.grid[0] * self.grid[1], self.hm_hidden, init,
                   pool=(self.grid, self.pool) if self.encoding == "pool" else None)
        x = swish_mlp(x, self.hidden, init)
        return linen.Dense(self.out_size, kernel_init=jax.nn.initializers.variance_scaling(
            0.01, "fan_in", "uniform"))(x)

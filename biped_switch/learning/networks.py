"""Networks on the observation [robot state (51), heightmap (rows*cols), extras].

`PolicyValueMLP`: the PPO policy and value networks (ppo.py), on the lean pooled heightmap by
default or through a heightmap MLP encoder. `EncodedMLP`: the heightmap through its own MLP
encoder, joined with the state and the extras (the DQN selector's Q-network).
"""

from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp
from flax import linen

from biped_switch.simulation.env import STATE_SIZE


class EncodedMLP(linen.Module):
    out_size: int
    hidden: Sequence[int]
    hm_hidden: Sequence[int]
    hm_size: int
    state_size: int = STATE_SIZE

    @linen.compact
    def __call__(self, obs):
        s = obs[..., : self.state_size]
        h = obs[..., self.state_size: self.state_size + self.hm_size]
        extra = obs[..., self.state_size + self.hm_size:]
        init = jax.nn.initializers.lecun_uniform()
        for n in self.hm_hidden:
            h = linen.swish(linen.Dense(n, kernel_init=init)(h))
        x = jnp.concatenate([s, h, extra], axis=-1)
        for n in self.hidden:
            x = linen.swish(linen.Dense(n, kernel_init=init)(x))
        return linen.Dense(self.out_size, kernel_init=init)(x)


# ----------------------------------------------------------------------------- the project's PPO
def obs_layout(env) -> dict:
    """Sizes of the policy observation's parts: robot state, heightmap grid (rows, cols), extras
    (the phase clock); "size" = all of it, the leading columns of the env's observation (a
    detector one-hot after them is the DQN selector's, never a behaviour policy's)."""
    sh = env.cfg.shape
    hm = sh.grid_forward * sh.grid_lateral
    size = getattr(env, "policy_observation_size", env.observation_size)
    return {"state": STATE_SIZE, "grid": (sh.grid_forward, sh.grid_lateral),
            "extra": size - STATE_SIZE - hm, "size": size}


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
        hm_size = self.grid[0] * self.grid[1]
        s = obs[..., : self.state_size]
        h = obs[..., self.state_size: self.state_size + hm_size]
        extra = obs[..., self.state_size + hm_size:]
        init = jax.nn.initializers.lecun_uniform()
        if self.encoding == "pool":
            h = encode_heightmap(h, self.grid, self.pool)
        elif self.encoding == "mlp":
            for n in self.hm_hidden:
                h = linen.swish(linen.Dense(n, kernel_init=init)(h))
        else:
            raise ValueError(f"unknown heightmap encoding {self.encoding!r}; expected pool or mlp")
        x = jnp.concatenate([s, h, extra], axis=-1)
        for n in self.hidden:
            x = linen.swish(linen.Dense(n, kernel_init=init)(x))
        return linen.Dense(self.out_size, kernel_init=jax.nn.initializers.variance_scaling(
            0.01, "fan_in", "uniform"))(x)

"""Policy and value networks for Brax PPO: a heightmap encoder joined with the robot state.

The observation is [robot state (51), heightmap (rows*cols), extra (detector one-hot, if any)].
The heightmap goes through its own MLP encoder (2400 -> 128 -> 64 by default), is joined with the
state and the extras, and an MLP maps that to the output. Sizes come from the train config.
"""

from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp
from brax.training import distribution, networks, types
from brax.training.agents.ppo.networks import PPONetworks
from flax import linen

from biped_switch.env import STATE_SIZE


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


def _network(module: linen.Module, obs_size: int, preprocess) -> networks.FeedForwardNetwork:
    def init(key):
        return module.init(key, jnp.zeros((1, obs_size)))

    def apply(processor_params, params, obs):
        return module.apply(params, preprocess(obs, processor_params))

    return networks.FeedForwardNetwork(init=init, apply=apply)


def make_networks_factory(net_cfg, hm_size: int):
    """A Brax `network_factory` for ppo.train, with sizes from `net_cfg`."""

    def factory(observation_size: int, action_size: int,
                preprocess_observations_fn: types.PreprocessObservationFn = types
                .identity_observation_preprocessor) -> PPONetworks:
        if isinstance(observation_size, tuple) and len(observation_size) == 1:
            observation_size = observation_size[0]  # Brax passes the shape of a flat observation
        if not isinstance(observation_size, int):
            raise TypeError(f"expected a flat observation, got shape {observation_size!r}")
        dist = distribution.NormalTanhDistribution(event_size=action_size)
        policy = EncodedMLP(dist.param_size, tuple(net_cfg.policy_hidden), tuple(net_cfg.hm_hidden),
                            hm_size)
        value = EncodedMLP(1, tuple(net_cfg.value_hidden), tuple(net_cfg.hm_hidden), hm_size)
        value_net = _network(value, observation_size, preprocess_observations_fn)
        value_apply = value_net.apply
        value_net = networks.FeedForwardNetwork(
            init=value_net.init, apply=lambda p, v, o: jnp.squeeze(value_apply(p, v, o), axis=-1))
        return PPONetworks(policy_network=_network(policy, observation_size, preprocess_observations_fn),
                           value_network=value_net, parametric_action_distribution=dist)

    return factory


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

"""The behaviour-policy suite as one stacked pytree, so a switching controller is one jitted function.

Every policy of a suite has the same network sizes, so their parameters stack along a leading axis
(index = POLICY_INDEX: walk 0, jumps 1, gaps 2, stairs 3, i.e. artifact code + 1) and
`all_actions(apply, params, obs)` evaluates all of them on a batch with one vmap. A switching
controller then picks each env's action by its active index. Evaluating four small MLPs per step
costs little next to the physics, and it keeps policies and switching rules traced arrays: the
stand-init and random-init suites share one compiled rollout.
"""

from __future__ import annotations

import json
import pathlib
import sys
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from biped_switch import terrain

POLICY_NAMES = ("walk",) + terrain.ARTIFACT_KINDS  # ("walk", "jumps", "gaps", "stairs")
POLICY_INDEX = {n: i for i, n in enumerate(POLICY_NAMES)}

ApplyFn = Callable[[object, jax.Array], jax.Array]  # (one policy's params, obs (B, O)) -> (B, 12)


class PolicySuite(NamedTuple):
    apply: ApplyFn  # deterministic action of one policy
    params: object  # pytree, leading axis = len(POLICY_NAMES)
    sources: tuple  # per policy: the checkpoint it came from (or "stand-in for X: ...")


def all_actions(apply: ApplyFn, params, obs: jax.Array) -> jax.Array:
    """(n_policies, B, 12) actions of every policy of a stacked suite on `obs` (B, O)."""
    return jax.vmap(apply, in_axes=(0, None))(params, obs)


def select(actions: jax.Array, active: jax.Array) -> jax.Array:
    """(B, 12) action of each env's active policy from `all_actions`' (P, B, 12)."""
    return jnp.take_along_axis(actions, active[None, :, None], axis=0)[0]


def stack(params_list: list) -> object:
    return jax.tree.map(lambda *xs: jnp.stack(xs), *params_list)


def brax_apply(train_cfg, env) -> ApplyFn:
    """The deterministic action of a Brax PPO policy (tanh of the Gaussian's mean) as a pure
    function of its (normalizer, policy) parameters, for the network sizes of `train_cfg`."""
    from brax.training.acme import running_statistics

    from biped_switch import networks

    factory = networks.make_networks_factory(
        train_cfg.network, env.cfg.shape.grid_forward * env.cfg.shape.grid_lateral)
    nets = factory(env.observation_size, env.action_size,
                   preprocess_observations_fn=running_statistics.normalize
                   if train_cfg.ppo.normalize_observations else lambda x, _: x)

    def apply(params, obs):
        logits = nets.policy_network.apply(params[0], params[1], obs)
        return nets.parametric_action_distribution.mode(logits)

    return apply


def load_suite(init: str, env, runs: str | pathlib.Path = "runs",
               stand_in: str | None = None, names: tuple = POLICY_NAMES) -> PolicySuite:
    """The four policies of an init mode (latest checkpoints under runs/ or models/policies/), or
    those of `names` in that order (("mixed",): the end-to-end baseline as a one-policy suite).

    A missing policy is an error, unless `stand_in` names a policy to use in its place; that is
    for exercising the pipeline before every policy is trained, and the substitution is recorded in
    `sources` (and so in every result's metadata) and printed."""
    from biped_switch import evaluate
    from biped_switch import train as train_lib

    found = {n: evaluate.find_policy(n, init, pathlib.Path(runs)) for n in names}
    if stand_in is not None and stand_in not in found:
        found[stand_in] = evaluate.find_policy(stand_in, init, pathlib.Path(runs))
    missing = [n for n, c in found.items() if c is None]
    if missing and (stand_in is None or found.get(stand_in) is None):
        raise FileNotFoundError(
            f"no trained {init}-init policy for {', '.join(missing)} under {runs}/ or "
            f"models/policies/ (train with `python -m biped_switch.train --policy P --init {init}`"
            + (f"; the stand-in {stand_in!r} is missing too" if stand_in else "") + ")")
    params, sources, run_cfg = [], [], None
    for n in names:
        ckpt = found[n] if found[n] is not None else found[stand_in]
        p, prog = train_lib.load_checkpoint(ckpt)
        cfg = json.loads((ckpt.parent.parent / "config.json").read_text())
        if run_cfg is None:
            run_cfg = cfg
        elif cfg["network"] != run_cfg["network"]:
            raise ValueError(f"{ckpt}: network sizes differ from the suite's first policy")
        params.append((p[0], p[1]))
        src = f"{ckpt} (step {prog['step']:,}, curriculum {prog['curriculum']['stage_name']})"
        if found[n] is None:
            src = f"stand-in for {n}: {src}"
            print(f"WARNING: no {init}-init {n} policy; using {stand_in} in its place", file=sys.stderr)
        sources.append(src)
    train_cfg = train_lib.default_train_config()
    train_cfg.network.update(**{k: tuple(v) for k, v in run_cfg["network"].items()})
    train_cfg.ppo.normalize_observations = run_cfg["ppo"]["normalize_observations"]
    return PolicySuite(brax_apply(train_cfg, env), stack(params), tuple(sources))

"""Behaviour policies from their checkpoints: one as a function (`load_policy`), or a suite as one
stacked pytree, so a switching controller is one jitted function.

Every policy of a suite has the same network config and the same env overrides (action mode,
phase clock: `suite_env_overrides`, to build the suite's env with), so one env serves them all
and their parameters stack along a leading axis (index = POLICY_INDEX: walk 0, jumps 1, gaps 2,
stairs 3: kinds.py's behaviour records) and `all_actions(apply, params, obs)` evaluates all of them on a
batch with one vmap. A switching controller then picks each env's action by its active index.
Evaluating four small MLPs per step costs little next to the physics, and it keeps policies and
switching rules traced arrays: the stand-init and random-init suites share one compiled rollout.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from biped_switch.learning import ppo
from biped_switch.learning import checkpoints as ckpt_lib
from biped_switch.learning import runs as runs_lib
from biped_switch.names import POLICY_INDEX, POLICY_NAMES  # noqa: F401  (re-exported)
from biped_switch.paths import rel


ApplyFn = Callable[[object, jax.Array], jax.Array]  # (one policy's params, obs (B, O)) -> (B, 12)


class PolicySuite(NamedTuple):
    apply: ApplyFn  # deterministic action of one policy, on any obs with the policy columns first
    params: object  # pytree, leading axis = len(POLICY_NAMES)
    sources: tuple  # per policy: the checkpoint it came from (or "stand-in for X: ...")
    env_overrides: dict = {}  # env-config overrides the policies were trained with (read only)


def all_actions(apply: ApplyFn, params, obs: jax.Array) -> jax.Array:
    """(n_policies, B, 12) actions of every policy of a stacked suite on `obs` (B, O)."""
    return jax.vmap(apply, in_axes=(0, None))(params, obs)


def select(actions: jax.Array, active: jax.Array) -> jax.Array:
    """(B, 12) action of each env's active policy from `all_actions`' (P, B, 12)."""
    return jnp.take_along_axis(actions, active[None, :, None], axis=0)[0]


def stack(params_list: list) -> object:
    return jax.tree.map(lambda *xs: jnp.stack(xs), *params_list)


def policy_apply(cfg, env, deterministic: bool = True):
    """The policy of a run config as a pure function (params, obs (B, >= policy obs), rng) ->
    actions (B, 12) in [-1, 1], params = {"params": ..., "norm": ...} as `runs.load_checkpoint`
    gives them; `deterministic`: the Gaussian's mean (rng unused), else a sample."""
    pol = ppo.make_policy(cfg.network, env)

    def apply(params, obs, rng=None):
        norm = ppo.Normalizer.from_tree(params["norm"])
        return jnp.clip(pol(params["params"], norm, obs, rng, deterministic), -1.0, 1.0)

    return apply


def load_policy(ckpt: pathlib.Path, env, deterministic: bool = True):
    """(batched policy (obs, rng) -> action, progress dict) of a checkpoint, with its run's network.
    `env` must have been made with `runs.policy_env_overrides(ckpt)`."""
    tree, progress = ckpt_lib.load_checkpoint(ckpt)
    cfg = runs_lib.run_config(ckpt.parent.parent)
    need = runs_lib.env_overrides(cfg)
    wrong = {k: (env.cfg[k], v) for k, v in need.items() if env.cfg[k] != v}
    if wrong:
        raise ValueError(f"{ckpt}: the env's {wrong} (env, policy) differ from what the policy "
                         f"was trained with; make the env with runs.policy_env_overrides")
    apply = policy_apply(cfg, env, deterministic)
    params = {"params": tree["params"], "norm": tree["norm"]}
    return (lambda obs, key: apply(params, obs, key)), progress


def find_suite(init: str, runs: str | pathlib.Path = "runs", stand_in: str | None = None,
               names: tuple = POLICY_NAMES) -> dict:
    """{name: checkpoint} of a suite, each name's latest checkpoint under runs/ or
    models/policies/, or the stand-in's where it has none (see `load_suite`)."""
    runs = pathlib.Path(runs)
    found = {n: runs_lib.find_policy(n, init, runs) for n in names}
    missing = [n for n, c in found.items() if c is None]
    if not missing:
        return found
    alt = runs_lib.find_policy(stand_in, init, runs) if stand_in is not None else None
    if alt is None:
        raise FileNotFoundError(
            f"no trained {init}-init policy for {', '.join(missing)} under {runs}/ or "
            f"models/policies/ (train with `python -m biped_switch.train --policy P --init {init}`"
            + (f"; the stand-in {stand_in!r} is missing too" if stand_in else "") + ")")
    return {n: c if c is not None else alt for n, c in found.items()}


def _suite_configs(ckpts: dict) -> tuple:
    """(run config, env overrides) shared by the checkpoints of a suite; a policy whose network or
    env overrides (action mode, phase clock) differ from the first one's is an error: the suite
    runs on one env and stacks its parameters."""
    first, run_cfg, overrides = None, None, None
    for name, ckpt in ckpts.items():
        saved = runs_lib.read_config(ckpt.parent.parent)
        policy, init = saved.get("policy", name), saved.get("init", "stand")
        if "env" not in saved:  # run_config would fill in today's defaults, not what it ran with
            raise ValueError(f"{ckpt} ({name}): its config.json has no env section, so the action "
                             f"mode and phase clock it was trained with are unknown (a Brax PPO run "
                             f"from before biped_switch.ppo?); retrain it (`python -m "
                             f"biped_switch.train --policy {policy} --init {init}`)")
        cfg = runs_lib.run_config(ckpt.parent.parent)
        ov = runs_lib.env_overrides(cfg)
        if first is None:
            first, run_cfg, overrides = (name, ckpt), cfg, ov
            continue
        net, net0 = cfg.network.to_dict(), run_cfg.network.to_dict()
        diff = {k: (net.get(k), net0.get(k)) for k in sorted(set(net) | set(net0))
                if net.get(k) != net0.get(k)}
        if diff:
            raise ValueError(f"{ckpt} ({name}): network config {diff} (this policy, {first[0]}) "
                             f"differs from the suite's first policy {first[1]}")
        diff = {k: (ov.get(k), overrides.get(k)) for k in sorted(set(ov) | set(overrides))
                if ov.get(k) != overrides.get(k)}
        if diff:
            raise ValueError(f"{ckpt} ({name}): env overrides {diff} (this policy, {first[0]}) "
                             f"differ from the suite's first policy {first[1]}; every policy of a "
                             f"suite must be trained with the same action mode and phase clock")
    return run_cfg, overrides


def suite_env_overrides(init: str, runs: str | pathlib.Path = "runs", stand_in: str | None = None,
                        names: tuple = POLICY_NAMES) -> dict:
    """Env-config overrides (action mode, phase clock; never the backend) that the suite
    `load_suite(init, ..., runs, stand_in, names)` needs: build its env with them."""
    return _suite_configs(find_suite(init, runs, stand_in, names))[1]


def load_suite(init: str, env, runs: str | pathlib.Path = "runs",
               stand_in: str | None = None, names: tuple = POLICY_NAMES) -> PolicySuite:
    """The four policies of an init mode (latest checkpoints under runs/ or models/policies/), or
    those of `names` in that order (("mixed",): the end-to-end baseline as a one-policy suite).

    `env` must be made with the suite's env overrides (`suite_env_overrides`, also returned as
    `PolicySuite.env_overrides`); the suite's `apply` reads the first `env.policy_observation_size`
    columns of whatever observation it is given. A missing policy is an error, unless `stand_in`
    names a policy to use in its place; that is for exercising the pipeline before every policy
    is trained, and the substitution is recorded in `sources` (and so in every result's metadata)
    and printed."""
    found = find_suite(init, runs, stand_in, names)
    run_cfg, overrides = _suite_configs(found)
    wrong = {k: (env.cfg[k], v) for k, v in overrides.items() if env.cfg[k] != v}
    if wrong:
        raise ValueError(f"the env's {wrong} (env, policies) differ from what the {init}-init "
                         f"policies ({found[names[0]]}, ...) were trained with; make the env with "
                         f"policies.suite_env_overrides")
    params, sources = [], []
    for n in names:
        ckpt = found[n]
        tree, prog = ckpt_lib.load_checkpoint(ckpt)
        if not (isinstance(tree, dict) and {"params", "norm"} <= set(tree)):
            raise ValueError(f"{ckpt}: not a checkpoint of biped_switch.train (a "
                             f"{type(tree).__name__} without params/norm: Brax's format?)")
        # the deterministic action needs the policy network and the normaliser only
        params.append({"params": {"policy": tree["params"]["policy"]}, "norm": tree["norm"]})
        # repo-relative, so a record (a DQN's progress.json, a results file) names the same
        # checkpoint however the runs folder was given and on whichever machine
        src = f"{rel(ckpt)} (step {prog['step']:,}, curriculum {prog['curriculum']['stage_name']})"
        if ckpt.parent.parent.name != f"{n}_{init}":
            src = f"stand-in for {n}: {src}"
            print(f"WARNING: no {init}-init {n} policy; using {stand_in} in its place", file=sys.stderr)
        sources.append(src)
    # the policy network reads only the first env.policy_observation_size columns (ppo.make_policy)
    return PolicySuite(policy_apply(run_cfg, env), stack(params), tuple(sources),
                       dict(overrides))

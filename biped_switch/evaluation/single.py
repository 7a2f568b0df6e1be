"""Table I: each behaviour policy alone on tracks of its own terrain kind (`evaluate single`).

Trial i of a policy runs on the track of seed `track_seed + i` (default config.EVAL_TRACK_SEED:
tracks training never saw), without switching, in an env made with the env overrides (action mode,
phase clock) the policy was trained with. A row reports % of the total track distance covered
(distance along x from the start to the finish line, capped at 100%) and % success (reached the
finish line without falling), each with a 95% confidence interval (stats.py), and the mean
forward speed (distance / time alive after the standing pause). The time limit, unless given,
lets a walker at 0.6 m/s reach the farthest finish line of the tracks evaluated, with a 20%
margin (`single_horizon_s`); each row says which limit it ran with.
"""

from __future__ import annotations

import functools
import math
import pathlib

import jax
import numpy as np

from biped_switch.simulation import env as env_lib
from biped_switch.learning import runs as runs_lib
from biped_switch.config import EVAL_TRACK_SEED, default_single_config
from biped_switch.kinds import BEHAVIOUR
from biped_switch.learning.policies import POLICY_NAMES, load_policy
from biped_switch.simulation.rollout import episode_keys, rollout
from biped_switch.stats import episode_table, join_rows, mean_ci

# the config's values under their former names (evaluate's help text reads them)
HORIZON_SPEED_MPS = default_single_config().horizon_speed_mps
HORIZON_MARGIN = default_single_config().horizon_margin


def single_horizon_s(finish_m: float, pause_s: float, speed_mps: float | None = None,
                     margin: float | None = None) -> float:
    """Episode time limit [s] of Table I: the standing pause, then `margin` times the time to walk
    to the farthest finish line `finish_m` [m] (the episode starts near x = 0) at `speed_mps`
    (defaults: `default_single_config()`'s)."""
    cfg = default_single_config()
    speed_mps = cfg.horizon_speed_mps if speed_mps is None else speed_mps
    margin = cfg.horizon_margin if margin is None else margin
    return float(np.ceil(pause_s + margin * finish_m / speed_mps))


def speed_table(result: dict, dt_s: float, pause_s: float) -> dict:
    """Mean forward speed [m/s] over episodes (with its 95% CI): distance / time alive after the
    standing pause (`speed_mps`, the policy's own speed), also over successful episodes only, and
    distance / time alive with the pause (`speed_alive_mps`)."""
    dist = np.asarray(result["distance_m"], float)
    alive_s = np.asarray(result["length"], float) * dt_s
    walking = np.maximum(alive_s - pause_s, dt_s)
    speed = dist / walking
    succ = np.asarray(result["success"]) > 0.5
    m, lo, hi = mean_ci(speed)
    return {"speed_mps": m, "speed_ci": [lo, hi],
            "speed_success_mps": float(speed[succ].mean()) if succ.any() else math.nan,
            "speed_alive_mps": float(np.mean(dist / np.maximum(alive_s, dt_s)))}


def evaluate_single(policy: str, init: str, ckpt: pathlib.Path, trials: int, seed: int,
                    horizon_s: float | None, batch: int, backend: str = "auto",
                    track_seed: int | None = None, kind: str | None = None) -> dict:
    """Table I row: `trials` episodes of `policy` on its own terrain kind (or on `kind`'s: how a
    policy fares on a kind it was not trained for, e.g. a new kind's baseline), trial i on track
    `track_seed + i` (default EVAL_TRACK_SEED: tracks training never saw), in an env made with
    the env overrides the policy was trained with. `horizon_s` None: `single_horizon_s` of the
    farthest finish line of these tracks."""
    track_seed = EVAL_TRACK_SEED if track_seed is None else int(track_seed)
    overrides = runs_lib.policy_env_overrides(ckpt)
    # difficulty 1, no guides, no pushes (the config's defaults)
    env = env_lib.make_env(kind or BEHAVIOUR[policy].terrain, init, n_tracks=trials,
                           seed=track_seed, backend=backend, **overrides)
    act, progress = load_policy(ckpt, env)
    finish = jax.vmap(lambda i: env.track_arrays(i, env.cfg.difficulty)[4])(
        jax.numpy.arange(env.bank.size))
    finish_m = float(jax.numpy.max(finish))
    pause_s = float(env.cfg.pause_s) if init == "stand" else 0.0
    if horizon_s is None:
        horizon_s = single_horizon_s(finish_m, pause_s)
        cfg = default_single_config()
        horizon_from = (f"derived: {pause_s:g} s pause + {cfg.horizon_margin:g} x farthest finish "
                        f"{finish_m:.1f} m / {cfg.horizon_speed_mps:g} m/s")
    else:
        horizon_from = "--horizon-s"
    run = jax.jit(functools.partial(rollout, env, act, n_envs=batch,
                                    horizon=int(round(horizon_s / env.dt))))
    results = []
    for start in range(0, trials, batch):
        ids = jax.numpy.arange(start, start + batch) % trials
        results.append(jax.device_get(run(batch_key(seed, start), track_ids=ids)))
    merged = {k: np.concatenate([r[k] for r in results])[:trials] for k in results[0]}
    out = episode_table(merged)
    out.update(speed_table(merged, env.dt, pause_s))
    out.update(policy=policy, kind=env.cfg.kind, init=init, checkpoint=str(ckpt), train_step=progress["step"],
               curriculum=progress["curriculum"], curriculum_done=progress.get("curriculum_done"),
               curriculum_end=progress.get("curriculum_end"), push_held=progress.get("push_held"),
               train_h=float(progress["wall_s"]) / 3600.0 if "wall_s" in progress else None,
               warm_start=progress.get("warm_start") or "",
               full_push=runs_lib.full_push(runs_lib.read_config(pathlib.Path(ckpt).parent.parent)),
               backend=env.backend,
               track_seed=track_seed,
               env_overrides=overrides, horizon_s=horizon_s,
               horizon_from=horizon_from, finish_m_max=finish_m,
               timed_out_pct=100.0 * float((np.asarray(merged["done"]) < 0.5).mean()),
               # the trials to render: `render --policy P --track-seed S`
               success_track_seeds=[track_seed + i for i in np.flatnonzero(
                   np.asarray(merged["success"]) > 0.5).tolist()])
    return out


# The settings that fix what a Table I row measured (the batch too: it splits the rng), so that
# `evaluate single` may add the rows of policies that finish later to a table of the same trials.
TRIAL_KEYS = ("trials", "batch", "seed", "horizon_s", "track_seed", "kind")  # kind: --kind


def merge_rows(old: dict | None, rows: list[dict], settings: dict) -> list[dict]:
    """`rows` joined with the rows of `old` (a table1.json) for the other (policy, init) pairs, in
    the paper's order (stand before random, then POLICY_NAMES): the random-init policies finish
    their curricula sessions after the stand suite (`stats.join_rows`)."""
    order = [(pol, init) for init in env_lib.INITS for pol in POLICY_NAMES]
    return join_rows(old, rows, settings, TRIAL_KEYS, key=lambda r: (r["policy"], r["init"]),
                     order=order)


def batch_key(seed: int, start: int) -> jax.Array:
    """The rng of the batch of trials that begins at trial `start` (`rollout` splits it)."""
    return jax.random.PRNGKey(seed + start)


def trial_reset_key(seed: int, batch: int, trial: int) -> jax.Array:
    """The reset key Table I gave trial `trial` (on track track_seed + trial), drawn as
    `rollout` draws it. The policy is deterministic and pushes are off, so this key, the track
    and Table I's batch size replay the trial exactly (`render --table1 PATH --trial I`)."""
    start = (trial // batch) * batch
    return episode_keys(batch_key(seed, start), batch)[0][trial - start]

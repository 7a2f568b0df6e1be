"""How often a trained policy falls under the push stage's pushes, per push level, on its own
training tracks at full difficulty with no guides (what the push-stage milestone sees).

    python scripts/push_falls.py runs/walk_stand --scales 0 0.5 0.75 1 [--magnitude max]
        [--interval 5]

Prints one JSON line per level: the fall fraction of the curriculum check's episodes
(`train.milestone_rollout`, the run's eval config: 64 of 20 s), their reward per step, and the
fall chance per push it implies (1 - (1 - fell)^(1 / pushes per episode)).
Written to size the push stage (CHANGELOG.md: the push stage).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import jax
import jax.numpy as jnp

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))
from biped_switch.learning import runs as runs_lib  # noqa: E402
from biped_switch.learning import trainer as train_lib  # noqa: E402
from biped_switch.simulation.env import PUSH_MAGNITUDES  # noqa: E402
from biped_switch.learning.policies import load_policy  # noqa: E402
from biped_switch.simulation.rollout import summarize  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("run", help="a run folder (runs/<policy>_<init> or models/policies/...)")
    p.add_argument("--scales", type=float, nargs="+", default=[0.0, 0.5, 0.75, 1.0])
    p.add_argument("--magnitude", default=None, choices=PUSH_MAGNITUDES,
                   help="how each push force is drawn (default: the run's config)")
    p.add_argument("--interval", type=float, default=None,
                   help="mean time between pushes [s] (default: the run's config)")
    p.add_argument("--seed", type=int, default=1)
    a = p.parse_args(argv)
    run = pathlib.Path(a.run)
    cfg = runs_lib.run_config(run)
    if a.magnitude:
        cfg.curriculum.push_magnitude = a.magnitude
    if a.interval is not None:  # the env rejects an interval <= 0
        cfg.curriculum.push_interval_s = a.interval
    env = train_lib.train_env(cfg)
    ckpt = runs_lib.latest_checkpoint(run)
    if ckpt is None:
        raise SystemExit(f"{run}: no checkpoint")
    policy, prog = load_policy(ckpt, env)
    # the push stage's levels: full difficulty, no guides
    go = jax.jit(lambda rng, s: train_lib.milestone_rollout(env, policy, rng, cfg.eval,
                                                            (1.0, 0.0, s)))
    c, horizon = env.curriculum_cfg, cfg.eval.horizon_steps
    # a push starts at rate 1 / interval whenever none runs (the pause too), so one per
    # interval + duration on average
    pushes = horizon * env.dt / (c.push_interval_s + c.push_duration_s)
    for s in a.scales:
        t0 = time.perf_counter()
        out = summarize(go(jax.random.PRNGKey(a.seed), jnp.float32(s)), horizon)
        fell = out["fell"]
        print(json.dumps({"run": run.name, "step": prog["step"], "magnitude": c.push_magnitude,
                          "interval_s": c.push_interval_s,
                          "push_scale": s, "max_push_N": s * c.max_push_N,
                          "episodes": cfg.eval.n_envs, "fell": round(fell, 3),
                          "fall_per_push": round(1 - (1 - fell) ** (1 / pushes), 4) if s else None,
                          "reward_per_step": round(out["reward_per_step"], 3),
                          "distance_m": round(out["distance_m"], 2),
                          "wall_s": round(time.perf_counter() - t0, 1)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

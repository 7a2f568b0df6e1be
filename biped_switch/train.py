"""Train one behaviour policy with PPO (ppo.py) and the guided curriculum, resumable.

The command line of `biped_switch.learning.trainer`: `python -m biped_switch.train` or `biped-switch train`.
"""

from __future__ import annotations

import argparse, functools, pathlib
import jax
from biped_switch import cli
from biped_switch.simulation import env as env_lib
from biped_switch.learning import runs as runs_lib, trainer
from biped_switch.config import SETUP_TARGETS, default_train_config
from biped_switch.reports import curves
from biped_switch.switching import setup as setup_lib


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.train", description=__doc__.split("\n")[0])
    p.add_argument("--policy", default="walk", choices=trainer.TRAIN_KINDS + tuple(f"setup_{k}" for k in SETUP_TARGETS),
                   help="a behaviour policy, mixed: the end-to-end baseline, or setup_<target>: "
                        "a setup policy (switching/setup.py; its recipe: config.default_setup_config)")
    cli.add_init(p)
    p.add_argument("--preset", default=None, choices=("gpu", "cpu"),
                   help="batch sizes; default: cpu on a CPU, gpu on an accelerator")
    p.add_argument("--backend", default=None, choices=env_lib.BACKEND_CHOICES,
                   help="physics backend (default: the config's, auto = mujoco on a CPU)")
    p.add_argument("--action", default=None, choices=env_lib.ACTIONS,
                   help="action mode (default torque: the paper's; pd: joint targets)")
    p.add_argument("--pd-offset", default=None, choices=("gait", "stand"),
                   help="pd actions: offsets from the scripted gait (default) or the standing pose")
    p.add_argument("--no-phase", action="store_true", help="no gait phase clock in the observation")
    p.add_argument("--learning-rate", type=float, default=None,
                   help="PPO's Adam step size (default: a resumed run's own, from its "
                        "config.json, else 3e-4; a resume keeps the optimiser's moments)")
    p.add_argument("--guide-notch", type=float, default=None, metavar="FRAC",
                   help="the fraction of the guide scale each of the curriculum's last guide "
                        "notches takes, in (0, 1) (default: a resumed run's own, else 0.5, "
                        "which halves; mixed trains with 0.25: curriculum.py)")
    p.add_argument("--max-action-std", type=float, default=None, metavar="STD",
                   help="cap each joint's exploration std at STD [fraction of the motor limit] "
                        "(default: a resumed run's own, else 0: no cap; mixed trains with 0.5 "
                        "from 205.7M env steps: its recipe.json)")
    p.add_argument("--push-plateau-steps", type=int, metavar="N", help="curriculum.py (0: no plateau end)")
    p.add_argument("--update-epochs", type=int, metavar="E", help="PPO epochs over each batch (default: "
                   "a resumed run's own, else the preset's; docs/speed.md)")
    p.add_argument("--minibatches", type=int, metavar="M", help="PPO minibatches per epoch (as --update-epochs)")
    p.add_argument("--warm-start", default=None, metavar="CKPT_OR_RUN",
                   help="start a new run from the parameters of a checkpoint folder, a run "
                        "folder's latest checkpoint, or a run name (e.g. walk_stand: runs/, then "
                        "models/policies/); ignored when the run resumes")
    p.add_argument("--total-steps", type=cli.positive_int, default=None)
    p.add_argument("--chunk-steps", type=cli.positive_int, default=None)
    p.add_argument("--max-chunks", type=cli.positive_int, help="stop after this many chunks")
    p.add_argument("--keep-training", action="store_true",
                   help="train on to --total-steps after the curriculum finishes (default: stop)")
    p.add_argument("--seed", type=cli.nonneg_int, default=None,
                   help="training seed (default 0); with --recipe, a second seed of the recipes")
    cli.add_out(p, "runs", "one run folder, <policy>_<init>/ (or --name)")
    p.add_argument("--name", default=None, help="run folder name (default <policy>_<init>)")
    p.add_argument("--distributed", action="store_true", help="jax.distributed.initialize() first")
    p.add_argument("--plot", metavar="PNG", help="only plot the run's training curves to PNG")
    p.add_argument("--probe-guides", metavar="G1,G2,...", help="only run the curriculum check of "
                   "the run's latest checkpoint at these guide levels (its own difficulty and "
                   "pushes), print a table and write probe_guides.json in the run folder")
    p.add_argument("--commit", action="store_true", help="only copy the run's latest checkpoint, "
                   "logs and curves to models/policies/<run>/ (with --recipe and --seed S: each "
                   "replay to models/replay_seedS/<run>/), then git-commit that folder")
    p.add_argument("--recipe", nargs="+", metavar="RUN_DIR",
                   help="only replay committed runs from scratch, each by its recipe.json "
                        "(e.g. models/policies/gaps_stand; sources first), into OUT/replay/<run>/ "
                        "(with --seed S: a second training seed, into OUT/replay_seedS/<run>/); "
                        "the other flags are the recipe's (learning/recipe.py)")
    p.add_argument("--suite-runs", default=None, metavar="DIR",
                   help="a setup policy: where its frozen suite is (default runs/, then models/)")
    p.add_argument("--jobs", type=cli.positive_int, default=1,
                   help="--recipe: replays at a time, each in its own process with one mujoco "
                        "thread, a recipe starting once its sources have replayed far enough")
    a = p.parse_args(argv)
    if a.recipe:
        from biped_switch import distill, dqn
        from biped_switch.learning import recipe as recipe_lib
        try:
            if a.commit and a.seed is not None:
                return print(*recipe_lib.commit_replays(a.recipe, a.out, a.seed), sep="\n") or 0
            mains = {"train": main, "dqn": dqn.main, "distill": distill.main}
            return recipe_lib.replay_all(a.recipe, a.out, functools.partial(print, flush=True),
                                         a.seed, a.jobs, mains)
        except recipe_lib.RecipeError as e:
            p.error(str(e))
    run_dir = pathlib.Path(a.out) / (a.name or f"{a.policy}_{a.init}")
    if a.plot:
        return curves.ppo_curves(run_dir, pathlib.Path(a.plot)) or 0
    if a.probe_guides:
        try:
            print(trainer.probe_guides_report(run_dir, a.probe_guides, a.seed or 0))
        except (ValueError, FileNotFoundError) as e:
            p.error(f"--probe-guides {a.probe_guides}: {e}")
        return 0
    if a.commit:
        print(f"committed copy: {runs_lib.commit_run(run_dir, plot_fn=curves.ppo_curves)}")
        return 0
    if a.distributed:
        jax.distributed.initialize()
    preset = a.preset or ("cpu" if jax.default_backend() == "cpu" else "gpu")
    setup = setup_lib.is_setup_policy(a.policy)
    cfg = setup_lib.setup_train_config(a.policy) if setup else default_train_config(preset)
    cfg.policy, cfg.init, cfg.seed = a.policy, a.init, a.seed or 0
    if setup:
        cfg.setup.suite_init = a.init
        cfg.setup.suite_runs = a.suite_runs or cfg.setup.suite_runs
    for key, value in (("backend", a.backend), ("action", a.action), ("pd_offset", a.pd_offset),
                       ("phase_obs", False if a.no_phase else None)):
        if value is not None:
            cfg.env[key] = value
    if a.warm_start:
        cfg.warm_start = a.warm_start
    cfg.stop_when_done = not a.keep_training
    # a flag's value, else the resumed run's own (config.json), else the default
    for flag, section, key, ok, must in (
            ("--learning-rate", "ppo", "learning_rate", lambda v: v > 0, "> 0"),
            ("--guide-notch", "curriculum", "guide_notch", lambda v: 0 < v < 1, "in (0, 1)"),
            ("--max-action-std", "ppo", "max_action_std", lambda v: v >= 0, ">= 0 (0: no cap)"),
            ("--push-plateau-steps", "curriculum", "push_plateau_steps", lambda v: v >= 0, ">= 0"),
            ("--update-epochs", "ppo", "num_updates_per_batch", lambda v: v >= 1, ">= 1"),
            ("--minibatches", "ppo", "num_minibatches", lambda v: v >= 1, ">= 1"),
            ("--chunk-steps", None, "chunk_timesteps", lambda v: v > 0, "> 0")):
        given, sec = getattr(a, flag[2:].replace("-", "_")), cfg[section] if section else cfg
        if given is not None:
            if not ok(given):
                p.error(f"{flag} must be {must}, got {given}")
            sec[key] = given
        elif (v := trainer.saved_setting(run_dir, section, key)) is not None and v != sec[key]:
            print(f"keeping the run's {key.replace('_', ' ')} {v:,.10g} (config.json; {flag} changes it)")
            sec[key] = type(sec[key])(v)
    cfg.total_timesteps = a.total_steps or cfg.total_timesteps  # not kept: a recipe's segments set it
    print(f"training {a.policy}/{a.init} on {jax.device_count()} {jax.devices()[0].platform} device(s), "
          f"{cfg.total_timesteps:,} steps in chunks of {cfg.chunk_timesteps:,} -> {run_dir}", flush=True)
    print_fn = functools.partial(print, flush=True)
    env_fn = functools.partial(setup_lib.setup_env, print_fn=print_fn) if setup else trainer.train_env
    trainer.train(cfg, run_dir, a.max_chunks, print_fn=print_fn, env_fn=env_fn)
    return 0


if __name__ == "__main__":
    from biped_switch.cli import run

    run(main)

"""Distil the composed controller into one student policy by DAgger (learning/distillation.py).

The student acts, the teacher (a Table II switching row, default lookup_context_setup: the stand
suite, its setup policy, the context lookup table, the oracle detector) labels each visited state
with the action of its active policy, and the student regresses those labels. A run resumes from
its newest checkpoint; `--commit` copies it to models/policies/student_stand/.
Evaluate it as Table II's `student` row: `python -m biped_switch.evaluate multi --methods student`.
"""

from __future__ import annotations

import argparse
import functools
import pathlib

from biped_switch import cli
from biped_switch.config import MULTI_TRACK_SEED, default_distill_config
from biped_switch.learning import runs as runs_lib
from biped_switch.methods import method as method_record
from biped_switch.reports import curves

# flag -> (section or None, config key)
_SETTINGS = {"total_steps": ("distill", "total_env_steps"), "chunk_steps": ("distill", "chunk_env_steps"),
             "num_envs": ("distill", "num_envs"), "n_tracks": (None, "n_tracks"),
             "mix_decay_steps": ("distill", "mix_decay_steps"),
             "action_noise": ("distill", "action_noise_std"), "buffer_size": ("distill", "buffer_size"),
             "updates": ("distill", "updates_per_iteration"), "batch_size": ("distill", "batch_size"),
             "learning_rate": ("distill", "learning_rate")}


def _teacher(name: str) -> str:
    rec = method_record(name)  # an unknown name: an error that lists the rows
    if rec.baseline:
        raise argparse.ArgumentTypeError(f"{name!r} is a baseline row, not a switching controller")
    return name


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.distill",
                                description=__doc__.split("\n")[0])
    p.add_argument("--teacher", type=_teacher, default=None,
                   help="the Table II row distilled (default: the config's, lookup_context_setup)")
    p.add_argument("--seed", type=cli.nonneg_int, default=0,
                   help="the student's init and its training tracks' offset")
    p.add_argument("--total-steps", type=cli.positive_int, default=None)
    p.add_argument("--chunk-steps", type=cli.positive_int, default=None,
                   help="env steps between checkpoints")
    p.add_argument("--max-chunks", type=cli.positive_int, default=None, help="stop after this many chunks")
    p.add_argument("--num-envs", type=cli.positive_int, default=None)
    p.add_argument("--n-tracks", type=cli.positive_int, default=None, help="training tracks")
    p.add_argument("--mix-decay-steps", type=cli.nonneg_int, default=None,
                   help="env steps over which P(the teacher acts) falls from 1 to 0")
    p.add_argument("--action-noise", type=cli.nonneg_float, default=None,
                   help="std of Gaussian noise on the student's executed action")
    p.add_argument("--buffer-size", type=cli.positive_int, default=None, help="aggregate rows")
    p.add_argument("--updates", type=cli.positive_int, default=None, help="Adam steps per collection")
    p.add_argument("--batch-size", type=cli.positive_int, default=None)
    p.add_argument("--learning-rate", type=cli.positive_float, default=None)
    p.add_argument("--hidden", type=cli.positive_int, nargs="+", default=None,
                   help="the student's hidden layer widths (default: the policies' 256 256)")
    p.add_argument("--teacher-runs", default=None,
                   help="where the teacher's policies are (default runs/, then models/policies/)")
    cli.add_out(p, "runs", "the run folder student_stand/ (or --name)")
    p.add_argument("--name", default="student_stand", help="the run folder's name")
    cli.add_backend(p)
    p.add_argument("--trace", type=cli.nonneg_int, default=None, metavar="TRIAL",
                   help="only draw the trained student on trial TRIAL (track --track-seed + "
                        "TRIAL) beside its teacher, and its GIF, into --results")
    p.add_argument("--track-seed", type=cli.nonneg_int, default=MULTI_TRACK_SEED,
                   help="--trace: the first track's seed (default Table II's)")
    p.add_argument("--results", default="experiments/results/student",
                   help="--trace: where the drawing and the GIF go")
    p.add_argument("--memory-probe", action="store_true",
                   help="only measure whether a memory would help: fit the labels of the run's "
                        "buffer from the last 1 and 4 inputs (distill.memory_probe), into --results")
    p.add_argument("--commit", action="store_true",
                   help="copy the run's latest checkpoint, config, logs and curves to "
                        "models/policies/<name>/ (then git-commit that folder) and exit")
    p.add_argument("--checkpoint", default=None,
                   help="--commit: this checkpoint folder (one chosen on tuning tracks) in place "
                        "of the run's latest")
    a = p.parse_args(argv)
    run_dir = pathlib.Path(a.out) / a.name
    if a.commit:
        print(f"committed copy: "
              f"{runs_lib.commit_run(run_dir, plot_fn=curves.distill_curves, ckpt=a.checkpoint)}")
        return 0
    cfg = default_distill_config()
    cfg.seed, cfg.env.backend = a.seed, a.backend
    for flag, (section, key) in _SETTINGS.items():
        if getattr(a, flag) is not None:
            (cfg[section] if section else cfg)[key] = getattr(a, flag)
    if a.teacher:
        cfg.distill.teacher = a.teacher
    if a.teacher_runs:
        cfg.distill.teacher_runs = a.teacher_runs
    if a.hidden:
        cfg.network.policy_hidden = tuple(a.hidden)
    saved = runs_lib.read_json(run_dir / "config.json") if (run_dir / "config.json").exists() else {}
    for key in ("teacher", "buffer_size", "num_envs", "unroll_length"):  # fixed for a run
        old = saved.get("distill", {}).get(key)
        if old is not None and old != cfg.distill[key]:
            raise SystemExit(f"error: {run_dir} was made with distill.{key} = {old!r}, not "
                             f"{cfg.distill[key]!r}; use another --name")
    from biped_switch.products import student  # JAX and the teacher's parts: after the checks
    if a.memory_probe:
        from biped_switch.products import student_memory as probe
        print(f"wrote {probe.write(probe.memory_probe(run_dir, cfg), pathlib.Path(a.results))}")
        return 0
    if a.trace is not None:
        paths = student.draw_trial(cfg, run_dir, a.trace, a.track_seed, pathlib.Path(a.results))
        print("\n".join(f"wrote {p}" for p in paths))
        return 0
    student.train(cfg, run_dir, a.max_chunks, print_fn=functools.partial(print, flush=True))
    return 0


if __name__ == "__main__":
    cli.run(main)

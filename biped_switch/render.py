"""Render a rollout to a GIF (or MP4) with MuJoCo's offscreen renderer.

The command line of `biped_switch.simulation.render`: `python -m biped_switch.render` or `biped-switch render`.
"""

from __future__ import annotations

import argparse
import pathlib
import jax
from biped_switch import cli
from biped_switch.names import ALL_POLICY_NAMES as POLICY_NAMES, TERRAIN_KINDS
from biped_switch.config import EVAL_TRACK_SEED
from biped_switch.simulation import render as render_lib


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.render", description=__doc__.split("\n")[0])
    p.add_argument("--policy", default=None, choices=POLICY_NAMES, help="a trained policy")
    cli.add_init(p)
    p.add_argument("--scripted", action="store_true", help="scripted standing controller, no policy")
    p.add_argument("--kind", default=None, choices=TERRAIN_KINDS, help="terrain kind (default: the policy's)")
    cli.add_runs(p)
    p.add_argument("--seconds", type=cli.positive_float, default=8.0)
    p.add_argument("--seed", type=cli.nonneg_int, default=0,
                   help=f"rng seed; the track's seed is {EVAL_TRACK_SEED:,} + this unless --track-seed")
    p.add_argument("--track-seed", type=cli.nonneg_int, default=None,
                   help="the track's seed (e.g. one of a Table I row's success_track_seeds)")
    p.add_argument("--table1", default=None, metavar="JSON",
                   help="replay a trial of this table1.json (with --trial): its track and initial state")
    p.add_argument("--trial", type=cli.nonneg_int, default=None,
                   help="the trial of --table1's row for --policy/--init (0-based; track seed = "
                        "the row's track_seed + this)")
    cli.add_backend(p)
    cli.add_out(p, "experiments/results/videos", "<policy>_<kind>.gif (a path ending in .gif or "
                ".mp4 names the file itself)")
    p.add_argument("--size", default="480x320", help="frame WIDTHxHEIGHT in pixels")
    p.add_argument("--every", type=cli.positive_int, default=2, help="draw every n-th control step (50 Hz)")
    p.add_argument("--colors", type=int, default=256, help="GIF palette size (2-256)")
    p.add_argument("--sheet", default=None, metavar="PNG",
                   help="also write 24 frames spread over the clip as one contact-sheet PNG")
    a = p.parse_args(argv)
    try:
        width, height = (int(v) for v in a.size.lower().split("x"))
    except ValueError:
        p.error(f"--size {a.size!r}: expected WIDTHxHEIGHT, e.g. 360x240")
    if a.every < 1 or not 2 <= a.colors <= 256:
        p.error(f"--every {a.every} must be >= 1 and --colors {a.colors} within 2-256")
    if not a.scripted and a.policy is None:
        p.error("give --policy NAME or --scripted")
    if (a.table1 is None) != (a.trial is None):
        p.error("--table1 JSON and --trial I go together")
    reset_key, row = None, None
    if a.table1 is not None:
        import json

        doc = json.loads(pathlib.Path(a.table1).read_text())
        row = next((r for r in doc["rows"] if r["policy"] == a.policy and r["init"] == a.init), None)
        if row is None:
            p.error(f"{a.table1} has no {a.policy}/{a.init} row")
        if not 0 <= a.trial < row["n"]:
            p.error(f"--trial {a.trial}: {a.table1}'s {a.policy}/{a.init} row has trials 0-{row['n'] - 1}")
        if a.track_seed is not None:
            p.error("--track-seed and --table1: the trial sets the track")
        a.track_seed = row["track_seed"] + a.trial
        if a.backend == "auto":
            a.backend = row.get("backend", "auto")
    from biped_switch.simulation import env as env_lib
    from biped_switch.learning import runs as runs_lib
    from biped_switch.learning.policies import load_policy

    kind = a.kind or a.policy or "mixed"
    ckpt, overrides = None, {}
    if not a.scripted:
        ckpt = runs_lib.find_policy(a.policy, a.init, pathlib.Path(a.runs))
        if ckpt is None:
            p.error(f"no trained {a.policy}/{a.init} policy under {a.runs}/ or models/policies/")
        overrides = runs_lib.policy_env_overrides(ckpt)
    track_seed = EVAL_TRACK_SEED + a.seed if a.track_seed is None else a.track_seed
    env = env_lib.make_env(kind, a.init, n_tracks=1, seed=track_seed,
                           backend=a.backend, **overrides)
    act = None if ckpt is None else load_policy(ckpt, env)[0]
    if row is not None:
        from biped_switch.evaluation.single import trial_reset_key

        s = doc["settings"]
        reset_key = trial_reset_key(int(s["seed"]), int(s["batch"]), a.trial)
        if str(ckpt) != row.get("checkpoint"):
            print(f"note: {a.table1} ran {row.get('checkpoint')}; this renders {ckpt}", flush=True)
    qpos, boxes, metrics = render_lib.record(env, act, a.seconds, a.seed, reset_key=reset_key,
                                  batch=1 if row is None else int(doc["settings"]["batch"]))
    fps = 1.0 / (a.every * env.dt)
    out = pathlib.Path(a.out)
    if out.suffix not in (".gif", ".mp4"):
        out = out / f"{a.policy or 'scripted'}_{kind}.gif"
    images = render_lib.frames(qpos, boxes, width, height, a.every)
    render_lib.write(images, out, fps, a.colors)
    if a.sheet:
        render_lib.contact_sheet(images, pathlib.Path(a.sheet))
    print(f"wrote {out} ({len(qpos)} steps, track seed {track_seed}, {env.backend} backend on "
          f"{jax.devices()[0].platform}); "
          f"final metrics {metrics}")
    return 0


if __name__ == "__main__":
    from biped_switch.cli import run

    run(main)

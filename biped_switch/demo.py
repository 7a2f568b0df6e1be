"""`make demo`: the switching pipeline end to end on a CPU, at a small size.

With the committed stand-init policy suite (models/policies/{walk,jumps,gaps,stairs}_stand, or newer
runs under runs/), switch estimators (models/estimators/) and lookup table
(experiments/results/lookup/), runs every switching method, the no-overlap ablation where the
random-init suite is trained, and the DQN and end-to-end baselines where they are trained
(models/baselines/dqn_stand, models/policies/mixed_stand), on the same two dozen short `mixed`
tracks (2 artifacts of different kinds, so that a good policy can finish within a time limit a
2-core CPU can afford in under 10 minutes), prints Table II, draws the paper's Fig. 5 for one trial
of the estimator method and renders that trial to a GIF (offscreen MuJoCo; skipped with a message
when no OpenGL backend is available). Where a learned terrain detector is trained
(models/detector/stand/), `lookup_context` runs once more with it in place of the oracle, and its
success is printed beside the oracle's. Everything goes to runs/demo/ (git-ignored);
`--refresh-example` rewrites the committed example output, experiments/results/demo/ (then
`make docs`: docs/results.md copies its table).

A missing stand-init policy is an error naming it and the command that trains it; nothing stands
in for it. It reports honestly what it ran on: the provenance of every policy is printed and saved,
and policies whose training runs are unfinished (curriculum or push stage not done) are flagged as
"policies in training, not results".
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import jax
import numpy as np

from biped_switch import cli, paths
from biped_switch.simulation import render

from biped_switch.evaluation import trace as fig5
from biped_switch.reports import fig5 as fig5_report
from biped_switch.learning import policies as pol
from biped_switch.learning import runs as runs_lib
from biped_switch.evaluation import multi as table2
from biped_switch.reports import table2 as table2_report
from biped_switch.config import MULTI_TRACK_SEED, default_env_config

OUT = "runs/demo"  # git-ignored: a demo run leaves the tree clean
EXAMPLE = "experiments/results/demo"  # the committed example output (--refresh-example)
DETECTOR = paths.MODELS_DIR / "detector" / "stand"  # the learned terrain detector, where trained

def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.demo", description=__doc__.split("\n")[0])
    # A step costs ~13 ms + 0.5 ms per env on 2 CPU cores (measured), so the time limit, not the
    # trials, sets the demo's length: 32 trials of 3 artifacts (32 s) took 9 min 13 s.
    p.add_argument("--trials", type=int, default=24)
    p.add_argument("--n-artifacts", type=int, default=2, help="artifacts per track (paper: 7)")
    p.add_argument("--horizon-s", type=float, default=None,
                   help="episode time limit [s] (default: the longest track at the 0.8 m/s target speed, x1.4)")
    p.add_argument("--seed", type=int, default=0)
    cli.add_runs(p)
    p.add_argument("--estimators", default="models/estimators")
    p.add_argument("--lookup", default="experiments/results/lookup")
    p.add_argument("--dqn", default=None, help="DQN run directory (default: RUNS/dqn_stand, then models/baselines/)")
    cli.add_backend(p)
    p.add_argument("--no-video", action="store_true")
    cli.add_out(p, None, f"the demo's tables, figure and GIF (default {OUT}, git-ignored)")
    p.add_argument("--refresh-example", action="store_true",
                   help=f"write the committed example output, {EXAMPLE}/, instead (then `make docs`)")
    a = p.parse_args(argv)
    if a.refresh_example and a.out:
        p.error("--refresh-example writes to " + EXAMPLE + "; give it or --out, not both")
    a.out = EXAMPLE if a.refresh_example else (a.out or OUT)
    if a.trials < 1 or a.n_artifacts < 1:
        p.error("--trials and --n-artifacts must be >= 1")
    if a.horizon_s is None:
        a.horizon_s = horizon_for(a.trials, a.n_artifacts)
    untrained = _untrained(a.runs)
    if untrained:
        for n in untrained:
            print(f"demo: no trained stand-init {n} policy under {a.runs}/ or {runs_lib.COMMITTED_DIR}/"
                  f"; train it with `python -m biped_switch.train --policy {n} --init stand`",
                  file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    methods, skipped = table2.available_methods(table2.MULTI_METHODS, a.runs, a.estimators,
                                                a.lookup, a.dqn)
    print(f"demo: {len(methods)} methods x {a.trials} mixed {a.n_artifacts}-artifact tracks "
          f"({a.horizon_s:.0f} s limit), then Fig. 5 and a GIF of one trial. Finishes in under 10 "
          f"minutes on 2 CPU cores (about 40% of it compiling the rollouts), about a minute on a GPU.",
          flush=True)
    for s in skipped:
        print(f"  skipped {s}")
    in_training = _in_training(a.runs)
    if in_training:
        print(f"  POLICIES IN TRAINING, NOT RESULTS: {' | '.join(in_training)}", flush=True)
    rows, setups = table2.evaluate_multi(
        methods, a.trials, a.trials, a.horizon_s, a.seed, a.runs, None, a.estimators,
        a.lookup, print_fn=lambda *s: print(*s, flush=True), guide_scale=0.0, dqn_dir=a.dqn,
        n_artifacts=a.n_artifacts, backend=a.backend)
    md = table2_report.table2_markdown(rows)
    if in_training:
        md = (f"POLICIES IN TRAINING, NOT RESULTS: {' | '.join(in_training)}; {a.trials} trials "
              f"of {a.n_artifacts}-artifact tracks, {a.horizon_s:.0f} s limit.\n\n" + md)
    print(md)
    (out / "table2_demo.md").write_text(md + "\n")
    detector = _with_detector(a, rows)
    summary = {"methods": methods, "skipped": skipped, "trials": a.trials, "horizon_s": a.horizon_s,
               "n_artifacts": a.n_artifacts,
               "guide_scale": 0.0, "in_training": in_training,
               "policies": list(setups["stand"].suite.sources) if "stand" in setups else None,
               "rows": rows, "device": str(jax.devices()[0]),
               "backend": sorted({r["backend"] for r in rows}), "detector": detector}
    setup = setups.get("stand")
    if setup is not None and setup.est_apply is not None:
        rec = fig5.trace_trial(setup, "estimator", 0, a.seed)
        track = table2.trial_track(setup, 0)
        title = "demo: estimator switching, trial 0" + (" (policies in training)"
                                                        if in_training else "")
        fig5_report.plot_trial(rec, track, out / "fig5_demo.png", title)
        summary["fig5"] = str(out / "fig5_demo.png")
        print(f"wrote {out / 'fig5_demo.png'}")
        if not a.no_video:
            summary["video"] = _video(rec, setup, out / "trial0.gif")
    summary["wall_s"] = round(time.perf_counter() - t0, 1)
    (out / "demo_summary.json").write_text(json.dumps(summary, indent=2, default=str))
    print(json.dumps({"demo_wall_s": summary["wall_s"], "device": summary["device"],
                      "backend": summary["backend"], "video": summary.get("video")}))
    return 0

def _with_detector(a, rows) -> dict | None:
    """`lookup_context` with the learned terrain detector in place of the oracle, on the same
    tracks, its success printed beside the oracle's; None (and why, printed) without one."""
    oracle = next((r for r in rows if r["method"] == "lookup_context"), None)
    if not (DETECTOR / "meta.json").is_file() or oracle is None:
        why = (f"no learned detector at {paths.rel(DETECTOR)} (`python -m biped_switch.detector` "
               f"trains it)" if oracle is not None else "no lookup_context row")
        print(f"learned terrain detector: skipped, {why}")
        return None
    (row,), _ = table2.evaluate_multi(
        ["lookup_context"], a.trials, a.trials, a.horizon_s, a.seed, a.runs, None, a.estimators,
        a.lookup, print_fn=lambda *s: print(*s, flush=True), guide_scale=0.0,
        n_artifacts=a.n_artifacts, backend=a.backend, track_seed=MULTI_TRACK_SEED,
        detector_dir=DETECTOR)

    def pct(r):
        return f"{r['success_pct']:.1f}% ({r['success_ci'][0]:.1f}-{r['success_ci'][1]:.1f})"

    print(f"learned terrain detector ({paths.rel(DETECTOR)}): lookup_context success {pct(row)} "
          f"against {pct(oracle)} with the oracle, the same {a.trials} tracks")
    return {"detector": paths.rel(DETECTOR), "method": "lookup_context",
            "success_pct": row["success_pct"], "success_ci": row["success_ci"],
            "oracle_success_pct": oracle["success_pct"], "oracle_success_ci": oracle["success_ci"]}


def horizon_for(trials: int, n_artifacts: int, margin: float = 1.4) -> float:
    """Time limit [s] that lets a robot walking at the target speed finish the longest of the
    demo's tracks with `margin` to spare (after the 0.5 s standing pause)."""
    finish_m = max(table2.mixed_track(MULTI_TRACK_SEED + i, n_artifacts).finish_x_m
                   for i in range(trials))
    ecfg = default_env_config()
    return float(np.ceil(ecfg.pause_s + margin * finish_m / ecfg.target_speed_mps))

def _in_training(runs) -> list[str]:
    """'<policy>: <why>' for each found stand-init policy whose run is not finished, the
    end-to-end `mixed` one included (`runs.run_notes`: short of its step goal is not counted, an
    unfinished curriculum is), and for the DQN selector short of its step goal."""
    out = []
    for n in pol.POLICY_NAMES + ("mixed",):
        ckpt = runs_lib.find_policy(n, "stand", pathlib.Path(runs))
        if ckpt is None:
            continue
        notes = runs_lib.run_notes(ckpt.parent.parent, step_goal=False)
        if notes:
            out.append(f"{n}: {'; '.join(notes)}")
    dqn_dir = runs_lib.find_dqn(runs, "stand")  # a selector has no curriculum: its step goal counts
    if dqn_dir is not None and (notes := runs_lib.run_notes(dqn_dir)):
        out.append(f"dqn selector: {'; '.join(notes)}")
    return out

def _untrained(runs) -> list:
    """Stand-init behaviour policies with no checkpoint under `runs`/ or models/policies/."""
    return [n for n in pol.POLICY_NAMES if runs_lib.find_policy(n, "stand", pathlib.Path(runs)) is None]

def _video(rec: dict, setup, path: pathlib.Path) -> str | None:
    """GIF of the traced trial, or None (with the reason printed) when rendering is unavailable."""
    live = int(np.sum(rec["ended"] < 0.5))
    boxes = np.asarray(setup.env.track_arrays(0, 1.0)[0])
    try:
        # every 6th control step, 8.3 fps in real time: the committed example stays under 1.5 MB
        images = render.frames(rec["qpos"][: max(live, 2)], boxes, width=320, height=240, every=6)
        render.write(images, path, fps=1.0 / (6 * setup.env.dt))
    except Exception as e:  # no OpenGL backend (e.g. no libOSMesa): say so, keep the rest
        print(f"video skipped: offscreen rendering failed ({type(e).__name__}: {e}); "
              f"`make render-deps` installs OSMesa on a CPU host")
        return None
    print(f"wrote {path} ({len(images)} frames)")
    return str(path)

if __name__ == "__main__":
    from biped_switch.cli import run

    run(main)

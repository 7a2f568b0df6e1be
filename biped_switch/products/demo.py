"""The body of `make demo` (biped_switch/demo.py parses its flags): every Table II row on a few
short tracks, Fig. 5 and a GIF of one trial, and `lookup_context` with the learned detector."""

from __future__ import annotations

import json
import pathlib
import sys
import time

import jax
import numpy as np

from biped_switch import paths
from biped_switch.config import MULTI_TRACK_SEED, default_env_config
from biped_switch.evaluation import multi as table2
from biped_switch.evaluation.parts import available_methods
from biped_switch.evaluation import trace as fig5
from biped_switch.learning import policies as pol
from biped_switch.learning import runs as runs_lib
from biped_switch.reports import fig5 as fig5_report
from biped_switch.reports import table2 as table2_report
from biped_switch.simulation import render

DETECTOR = paths.MODELS_DIR / "detector" / "stand"  # the learned terrain detector, where trained


def _print(*s):
    print(*s, flush=True)


def _config(a, **kw) -> table2.MultiConfig:
    """The demo's Table II settings: every trial in one batch, the committed parts."""
    return table2.MultiConfig(a.trials, a.trials, a.horizon_s, a.runs, est_dir=a.estimators,
                              lookup_dir=a.lookup, n_artifacts=a.n_artifacts, backend=a.backend,
                              **kw)


def run_demo(a) -> int:
    """The demo for the flags `a` of demo.py; its exit status."""
    untrained = untrained_policies(a.runs)
    if untrained:
        for n in untrained:
            print(f"demo: no trained stand-init {n} policy under {a.runs}/ or {runs_lib.COMMITTED_DIR}/"
                  f"; train it with `python -m biped_switch.train --policy {n} --init stand`",
                  file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    methods, skipped = available_methods(table2.MULTI_METHODS, a.runs, a.estimators, a.lookup,
                                         a.dqn)
    print(f"demo: {len(methods)} methods x {a.trials} mixed {a.n_artifacts}-artifact tracks "
          f"({a.horizon_s:.0f} s limit), then Fig. 5 and a GIF of one trial. Finishes in under 10 "
          f"minutes on 2 CPU cores (about 40% of it compiling the rollouts), about a minute on a GPU.",
          flush=True)
    for s in skipped:
        print(f"  skipped {s}")
    flagged = in_training(a.runs)
    if flagged:
        print(f"  POLICIES IN TRAINING, NOT RESULTS: {' | '.join(flagged)}", flush=True)
    rows, setups = table2.evaluate_multi(methods, _config(a, dqn_dir=a.dqn), a.seed, _print)
    md = table2_report.table2_markdown(rows)
    if flagged:
        md = (f"POLICIES IN TRAINING, NOT RESULTS: {' | '.join(flagged)}; {a.trials} trials "
              f"of {a.n_artifacts}-artifact tracks, {a.horizon_s:.0f} s limit.\n\n" + md)
    print(md)
    (out / "table2_demo.md").write_text(md + "\n")
    detector = _with_detector(a, rows)
    summary = {"methods": methods, "skipped": skipped, "trials": a.trials, "horizon_s": a.horizon_s,
               "n_artifacts": a.n_artifacts,
               "guide_scale": 0.0, "in_training": flagged,
               "policies": list(setups["stand"].suite.sources) if "stand" in setups else None,
               "rows": rows, "device": str(jax.devices()[0]),
               "backend": sorted({r["backend"] for r in rows}), "detector": detector}
    setup = setups.get("stand")
    if setup is not None and setup.est_apply is not None:
        rec = fig5.trace_trial(setup, "estimator", 0, a.seed)
        track = table2.trial_track(setup, 0)
        title = "demo: estimator switching, trial 0" + (" (policies in training)"
                                                        if flagged else "")
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
    (row,), _ = table2.evaluate_multi(["lookup_context"], _config(a, detector_dir=DETECTOR),
                                      a.seed, _print)

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

def in_training(runs) -> list[str]:
    """'<policy>: <why>' for each found stand-init policy whose run is not finished, the
    end-to-end `mixed` one included (`runs.run_notes`: short of its step goal is not counted, an
    unfinished curriculum is), and for the DQN selector and the distilled student short of
    their step goals (neither has a curriculum)."""
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
    student = runs_lib.find_policy("student", "stand", pathlib.Path(runs))
    if student is not None and (notes := runs_lib.run_notes(student.parent.parent)):
        out.append(f"student: {'; '.join(notes)}")
    return out

def untrained_policies(runs) -> list:
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

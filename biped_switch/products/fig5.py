"""Fig. 5 of each Table II row that has one (`evaluate multi --fig5-trial`): which trial, traced
(evaluation/trace.py) and drawn (reports/fig5.py)."""

from __future__ import annotations

import pathlib

import numpy as np

from biped_switch.evaluation.multi import trial_track
from biped_switch.evaluation.trace import trace_trial
from biped_switch.methods import method as method_record
from biped_switch.reports.fig5 import plot_trial


def setup_trial(setup, first: int, trials: int) -> int:
    """The first trial from `first` on whose track has an artifact pair (source, target) that one
    of `setup`'s setup policies serves (a Fig. 5 with a setup phase), else `first`."""
    for i in range(first, first + trials):
        codes = trial_track(setup, i % trials).artifact_codes
        for a, b in zip(codes[:-1], codes[1:]):
            if setup.setup.setup_of[int(a) + 1, int(b)] >= 0:
                return i % trials
    return first


def fig5_traces(setups: dict, methods, first: int, trials: int, seed: int, track_seed: int,
                n_artifacts: int, out: pathlib.Path) -> None:
    """Fig. 5 (png and its trace, npz) of each row of `methods` that has one (`Method.fig5_suffix`)
    and whose rollout `setups` ran (evaluate_multi's): trial `first`, or for a row with setup
    policies the first trial from `first` on whose track has a pair a setup policy serves."""
    for rec in map(method_record, methods):
        if rec.fig5_suffix is None or rec.rollout not in setups:
            continue
        s = setups[rec.rollout]
        trial = (setup_trial(s, first, trials) if rec.setup else first) % trials
        trace = trace_trial(s, rec.name, trial, seed)
        trace["policy_names"] = np.asarray(s.policy_names)
        threshold = None
        if rec.when:  # its trace holds the score, against the margin
            trace["output_kind"] = np.asarray("score")
            threshold = float(s.when_cfg.margin)
            trace["threshold"] = np.asarray(threshold)
        path = out / f"fig5_trial{trial}{rec.fig5_suffix}.png"
        plot_trial(trace, trial_track(s, trial), path, f"{rec.label} switching, trial {trial}",
                   threshold)
        np.savez_compressed(path.with_suffix(".npz"), **trace, track_seed=track_seed + trial,
                            n_artifacts=n_artifacts)
        print(f"wrote {path}")


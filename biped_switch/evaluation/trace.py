"""Fig. 5 of the paper: one trial of a switching method over time (`evaluate multi --fig5-trial`).

`trace_trial` records every control step of one trial of a Table II set-up (table2.MultiSetup):
the estimators' outputs, the detections, the switches, the active policy, the CoM and feet;
`fig5_figure` draws it (one drawing for the CLI, the demo and the notebook), `plot_trial` saves it.
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from biped_switch.switching import rules as sw


def trace_trial(setup, method: str, trial: int, seed: int) -> dict:
    """Per-step record of trial `trial` of a table2.MultiSetup (Fig. 5). A stand-init reset on a
    given track uses no randomness, so this is the trial of the table; a random-init trace draws
    its own start joints (key seed + trial), and the `random` rule its own distances."""
    rules, est_params = setup.rules_for(method)
    f = jax.jit(functools.partial(sw.trace_rollout, setup.env, setup.suite.apply,
                                  est_apply=setup.est_apply, horizon=setup.horizon,
                                  guide_scale=setup.guide_scale, det_apply=setup.det_apply))
    rec = jax.device_get(f(suite_params=setup.suite.params,
                           est_params=est_params, det_params=setup.det_params,
                           rules=rules, rng=jax.random.PRNGKey(seed + trial), track_id=trial))
    return {k: np.asarray(v) for k, v in rec.items()}

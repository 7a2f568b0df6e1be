"""Fig. 5 drawn from a recorded trial: each estimator's output over time, detections and switches. Plain Python and matplotlib."""

from __future__ import annotations

import pathlib
import numpy as np
from biped_switch.config import default_switching_config
from biped_switch.names import ARTIFACT_KINDS, FIG5_KEYS, POLICY_NAMES
from biped_switch.reports import style


def load_trial(path) -> dict:
    """A trace `evaluate multi --fig5-trial` saved (fig5_trial<i>.npz), checked for FIG5_KEYS."""
    with np.load(path) as z:
        rec = {k: np.asarray(z[k]) for k in z.files}
    missing = [k for k in FIG5_KEYS if k not in rec]
    if missing:
        raise KeyError(f"{path} lacks {missing}; rewrite it with the current evaluate multi")
    return rec


def policy_names(rec: dict) -> tuple:
    """The names of the suite's policies, by active index (a setup method's suite adds its setup
    policies after POLICY_NAMES, and its trace records their names)."""
    return tuple(str(n) for n in rec["policy_names"]) if "policy_names" in rec else POLICY_NAMES


def trial_length(rec: dict) -> int:
    live = np.flatnonzero(np.asarray(rec["ended"]) < 0.5)
    return int(live[-1]) + 1 if len(live) else 1


def trial_outcome(rec: dict) -> str:
    n = trial_length(rec)
    if rec["success"][:n].max() > 0.5:
        return "success"
    return "fell" if rec["fell"][:n].max() > 0.5 else "time limit"


def trial_events(rec: dict):
    """(headers, rows) of the trial's detections and switches, in order."""
    n = trial_length(rec)
    kind = rec["det_kind"][:n].astype(int)
    rows = []
    for i in np.flatnonzero((kind >= 0) & (np.r_[-1, kind[:-1]] != kind)):
        rows.append([int(i), f"{rec['time_s'][i]:.2f}", "detect", ARTIFACT_KINDS[kind[i]],
                     f"{rec['det_dist_m'][i]:.2f}", "-", "-"])
    for i in np.flatnonzero(rec["switched"][:n] > 0.5):
        k = int(kind[i])
        e = f"{rec['est_probs'][i, k]:.2f}" if k >= 0 else "-"
        rows.append([int(i), f"{rec['time_s'][i]:.2f}", "switch",
                     f"{policy_names(rec)[int(rec['active'][i])]}",
                     f"{rec['det_dist_m'][i]:.2f}" if k >= 0 else "-", e,
                     "yes" if rec["com_ok"][i] > 0.5 else "no"])
    rows.sort(key=lambda r: (r[0], r[2] == "switch"))
    return ["step", "t [s]", "event", "kind / new policy", "distance [m]", "E_target",
            "CoM over feet"], rows


def active_strip(ax, active: np.ndarray, names, ylabel: str) -> None:
    """A strip on `ax` coloured by the policy index `active` at each control step."""
    t = np.arange(len(active))
    for j, name in enumerate(names):
        on = active == j
        if on.any():
            ax.fill_between(t, 0, 1, where=on, step="mid", color=style.policy_colour(name),
                            alpha=0.7, label=name, lw=0)
    ax.set_yticks([])
    ax.set_ylabel(ylabel, fontsize=8)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))


def fig5_figure(rec: dict, track, title: str = "", threshold: float | None = None):
    """The paper's Fig. 5 (one drawing for the CLI, the demo and the notebook): estimator outputs
    while an artifact is detected (green lines: detections, red: switches), the active policy, and
    the terrain under the CoM with foot and CoM heights, the periods with the CoM over the feet
    shaded."""
    # lazy: matplotlib loads slowly and only the drawing needs it; pyplot must come after the
    # caller has chosen a backend (plot_trial: Agg; a notebook: inline)
    import matplotlib.pyplot as plt

    # the learned rule's trace holds its score (P(now) - best later P), not estimates E_i(s)
    score = str(rec.get("output_kind", "estimate")) == "score"
    if threshold is None:  # the trace's own (the learned rule's margin), or the estimator rule's
        threshold = float(rec.get("threshold", default_switching_config().estimator_threshold))

    n = trial_length(rec)
    t = np.arange(n)
    kind = rec["det_kind"][:n].astype(int)
    fig, (ax0, axp, ax1) = plt.subplots(3, 1, figsize=(13, 7.5), sharex=True,
                                        gridspec_kw={"height_ratios": [3, 0.6, 3]})
    for k, name in enumerate(ARTIFACT_KINDS):
        p = rec["est_probs"][:n, k]
        if not score:  # a score exists only for the detected target: no faint lines
            ax0.plot(t, p, color=style.KIND_COLOURS[name], lw=0.5, alpha=0.25)
        ax0.plot(t, np.where(kind == k, p, np.nan), color=style.KIND_COLOURS[name], lw=1.5,
                 label=f"into {name}" if score else f"E_{name}")
    new_det = np.flatnonzero((kind >= 0) & (np.r_[-1, kind[:-1]] != kind))
    switches = np.flatnonzero(rec["switched"][:n] > 0.5)
    for ax in (ax0, axp, ax1):
        for i in new_det:
            ax.axvline(i, color="g", lw=1)
        for i in switches:
            ax.axvline(i, color="r", lw=1)
    ax0.axhline(threshold, color="k", ls=":", lw=0.8,
                label=f"{'margin' if score else 'threshold'} {threshold:g}")
    ax0.legend(fontsize=8, loc="lower right", ncol=4)
    if score:
        ax0.set_ylabel("P(now) - best later P")
        ax0.set_ylim(-1.02, 1.02)
        ax0.set_title("the learned rule's score for the detected artifact; it switches once the "
                      "score reaches the margin (1: no later moment left)", fontsize=8)
    else:
        ax0.set_ylabel("switch estimate E_i(s)")
        ax0.set_ylim(-0.02, 1.02)
        ax0.set_title("thick: the detected artifact's estimator; faint: every estimator at every "
                      "step", fontsize=8)
    active = rec["active"][:n].astype(int)
    names = policy_names(rec)
    active_strip(axp, active, names, "active")
    # terrain under the CoM, feet and CoM heights
    boxes = track.boxes
    x = rec["com_x_m"][:n]
    lo, hi = boxes[:, 0] - boxes[:, 3], boxes[:, 0] + boxes[:, 3]
    top = boxes[:, 2] + boxes[:, 5]
    ground = np.array([np.max(np.where((lo <= xi) & (xi <= hi), top, -1.0)) for xi in x])
    com_z = rec["body_com"][:n, 2]
    ymin = min(-0.8, float(ground.min()) - 0.1)
    ok = rec["com_ok"][:n] > 0.5
    ax1.fill_between(t, ymin, com_z.max() + 0.2, where=ok, step="mid", color="gold", alpha=0.25,
                     lw=0, label="CoM over feet")
    ax1.fill_between(t, ymin, ground, color="pink", step="mid", label="terrain under the CoM")
    in_setup = np.array([names[j].startswith("setup_") for j in active])
    if in_setup.any():  # the setup phases (a setup policy acting), marked on the terrain panel
        ax1.fill_between(t, ymin, com_z.max() + 0.2, where=in_setup, step="mid", color="tab:red",
                         alpha=0.15, lw=0, label="setup policy acting")
    soles_z = rec["soles"][:n, :, 2]
    ax1.plot(t, soles_z[:, :4].mean(1), color="tab:blue", lw=1, label="left foot")
    ax1.plot(t, soles_z[:, 4:].mean(1), color="tab:green", lw=1, label="right foot")
    ax1.plot(t, np.where(ok, com_z, np.nan), "r.", ms=2, label="CoM (over feet)")
    ax1.plot(t, com_z, color="r", lw=0.3)
    ax1.set_ylim(ymin, com_z.max() + 0.2)
    ax1.set_ylabel("height [m]")
    ax1.set_xlabel("control step (20 ms)")
    ax1.legend(fontsize=8, loc="upper right", ncol=5)
    dt = float(np.median(np.diff(rec["time_s"][:n]))) if n > 1 else 0.02
    sec = ax0.secondary_xaxis("top", functions=(lambda s: s * dt, lambda s: s / max(dt, 1e-9)))
    sec.set_xlabel("time [s]", fontsize=8)
    fig.suptitle(f"{title} ({trial_outcome(rec)})", fontsize=9)
    fig.tight_layout()
    return fig


def plot_trial(rec: dict, track, path: pathlib.Path, title: str = "", threshold: float | None = None) -> None:
    """Fig. 5 (`fig5_figure`) saved as a PNG, off screen."""
    import matplotlib  # lazy, as in fig5_figure; the Agg backend before pyplot

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = fig5_figure(rec, track, title, threshold)
    fig.savefig(path, dpi=110)
    plt.close(fig)

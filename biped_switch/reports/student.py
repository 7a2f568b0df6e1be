"""The distilled student on one trial (products/student.trace_trial), drawn in the manner of
Fig. 5: the policy the teacher has active along the student's own path, the student's actions
beside the teacher's on a few joints, their gap, and the terrain under the CoM. Plain Python and
matplotlib."""

from __future__ import annotations

import pathlib

import numpy as np

from biped_switch.reports.fig5 import active_strip, trial_length, trial_outcome

# joints drawn (action indices: the actuators' order in the model) and their labels
JOINTS = {2: "left hip pitch", 3: "left knee"}


def trace_figure(rec: dict, track, title: str = ""):
    """Four panels against control steps: the teacher's active policy (a strip), the student's
    action (solid) and the teacher's (dotted) on JOINTS, the RMS gap over all 12 joints, and the
    terrain under the CoM with the CoM's distance travelled."""
    import matplotlib.pyplot as plt  # lazy, as reports/fig5.py

    n = trial_length(rec)
    t = np.arange(n)
    names = [str(s) for s in rec["policy_names"]]
    fig, (axp, ax0, ax1, ax2) = plt.subplots(4, 1, figsize=(13, 8.5), sharex=True,
                                             gridspec_kw={"height_ratios": [0.6, 3, 1.4, 2]})
    active = rec["active"][:n].astype(int)
    active_strip(axp, active, names, "teacher")
    axp.set_title("the policy the teacher's controller has active along the student's path",
                  fontsize=8)
    colours = ("tab:blue", "tab:orange")
    for (j, label), c in zip(JOINTS.items(), colours):
        ax0.plot(t, rec["student"][:n, j], color=c, lw=1, label=f"{label}: student")
        ax0.plot(t, rec["teacher"][:n, j], color=c, lw=1, ls=":", label="teacher")
    ax0.set_ylabel("action [-1, 1]")
    ax0.set_ylim(-1.05, 1.05)
    ax0.legend(fontsize=7, ncol=4, loc="lower right")
    gap = np.sqrt(np.mean((rec["student"][:n] - rec["teacher"][:n]) ** 2, axis=1))
    ax1.plot(t, gap, color="k", lw=0.8)
    ax1.set_ylabel("RMS gap")
    switches = np.flatnonzero(np.r_[False, active[1:] != active[:-1]])
    for ax in (axp, ax0, ax1, ax2):
        for i in switches:
            ax.axvline(i, color="r", lw=0.8, alpha=0.6)
    boxes = track.boxes
    x = rec["com_x_m"][:n]
    lo, hi, top = boxes[:, 0] - boxes[:, 3], boxes[:, 0] + boxes[:, 3], boxes[:, 2] + boxes[:, 5]
    ground = np.array([np.max(np.where((lo <= xi) & (xi <= hi), top, -1.0)) for xi in x])
    ymin = min(-0.8, float(ground.min()) - 0.1)
    ax2.fill_between(t, ymin, ground, color="pink", step="mid", label="terrain under the CoM")
    ax2.set_ylim(ymin, max(0.5, float(ground.max()) + 0.3))
    ax2.set_ylabel("height [m]")
    ax2.set_xlabel("control step (20 ms); red lines: the teacher switches")
    xa = ax2.twinx()
    xa.plot(t, x, color="tab:gray", lw=1)
    xa.set_ylabel("CoM x [m]", color="tab:gray")
    ax2.legend(fontsize=8, loc="upper left")
    fig.suptitle(f"{title} ({trial_outcome(rec)}, track {int(rec['track_seed'])})", fontsize=9)
    fig.tight_layout()
    return fig


def plot_trace(rec: dict, track, path: pathlib.Path, title: str = "") -> None:
    """`trace_figure` saved as a PNG, off screen."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = trace_figure(rec, track, title)
    fig.savefig(path, dpi=110)
    plt.close(fig)

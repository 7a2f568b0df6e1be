"""The figures of Tables I-III, the training runs and the switch estimators: ours beside the
paper's numbers (paper.py), kinds and methods coloured and labelled from their records
(reports/style.py). The result notebooks draw them through experiments/notebooks/_common.py.
Plain Python, NumPy and matplotlib (imported when a figure is drawn), no JAX.
"""

from __future__ import annotations

import csv
import math
import pathlib
from typing import Callable, Sequence

import numpy as np

from biped_switch import paper
from biped_switch.learning.runs import curve_series
from biped_switch.reports import curves, fig4b
from biped_switch.reports import style
from biped_switch.stats import wilson_ci

OURS_COLOUR = "tab:blue"  # our bars beside the paper's (grey, hatched)


def _plt():
    import matplotlib.pyplot as plt  # lazy: a notebook picks its backend first

    return plt


def _yerr(vals, cis):
    lo = [v - (c[0] if c and c[0] is not None else v) for v, c in zip(vals, cis)]
    hi = [(c[1] if c and c[1] is not None else v) - v for v, c in zip(vals, cis)]
    return np.nan_to_num(np.array([lo, hi], float), nan=0.0).clip(min=0)


def bars_ours_vs_paper(ax, labels, ours, ours_ci, paper_vals, ylabel, title):
    """Grouped bars: ours (with 95% CI error bars) beside the paper's value, per label."""
    x = np.arange(len(labels))
    w = 0.38
    o = np.array([np.nan if v is None else v for v in ours], float)
    has = np.isfinite(o)
    ax.bar(x[has] - w / 2, o[has], w, yerr=_yerr(o[has], [c for c, h in zip(ours_ci, has) if h]),
           capsize=3, color=OURS_COLOUR, label="ours (95% CI)")
    pp = np.array([np.nan if v is None else v for v in paper_vals], float)
    ax.bar(x + w / 2, np.nan_to_num(pp), w, color="0.75", hatch="//", edgecolor="0.4",
           label="paper")
    for i in np.flatnonzero(~has):
        ax.text(x[i] - w / 2, 1, "not run", rotation=90, ha="center", va="bottom", fontsize=7)
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.set_ylim(0, 105)
    ax.grid(axis="y", alpha=0.3)


def plot_table1(doc: dict, title: str = ""):
    """Table I's % distance and % success per (policy, init) row, ours beside the paper's."""
    plt = _plt()
    rows = doc["rows"]
    labels = [f"{r['policy']}/{r['init']}" for r in rows]
    ref = [paper.TABLE1.get(r["policy"], {}).get(r["init"]) for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.8))
    bars_ours_vs_paper(axes[0], labels, [r["distance_pct"] for r in rows],
                       [r.get("distance_ci") for r in rows],
                       [p.distance_pct if p else None for p in ref], "% of total distance",
                       "Table I: distance")
    bars_ours_vs_paper(axes[1], labels, [r["success_pct"] for r in rows],
                       [r.get("success_ci") for r in rows],
                       [p.success_pct if p else None for p in ref], "% success",
                       "Table I: success")
    axes[1].legend(fontsize=8, loc="upper right")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def _wilson_pct(pct, n):
    if n <= 0 or not np.isfinite(pct):
        return None
    lo, hi = wilson_ci(pct / 100.0 * n, n)
    return [100 * lo, 100 * hi]


def plot_table2(doc: dict, title: str = ""):
    """Distance, success and per-artifact failure rates of every method, ours beside the paper's."""
    plt = _plt()
    ours = {r["method"]: r for r in doc["rows"]}
    methods = list(ours) + [m for m in paper.TABLE2 if m not in ours]
    labels = [style.method_label(m) for m in methods]
    ref = [paper.TABLE2.get(m) for m in methods]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.2), gridspec_kw={"width_ratios": [1, 1, 1.4]})
    for ax, key, name in ((axes[0], "distance", "% of total distance"),
                          (axes[1], "success", "% success")):
        bars_ours_vs_paper(ax, labels, [ours[m][f"{key}_pct"] if m in ours else None for m in methods],
                           [ours[m].get(f"{key}_ci") if m in ours else None for m in methods],
                           [getattr(p, f"{key}_pct") if p else None for p in ref], name,
                           f"Table II: {key}")
    axes[1].legend(fontsize=8, loc="upper right")
    # failure location: grouped by artifact, ours (solid) and paper (hatched)
    ax = axes[2]
    x = np.arange(len(methods))
    w = 0.13
    for j, k in enumerate(paper.TABLE2_FAIL_ORDER):
        col = style.KIND_COLOURS[k]
        o = [ours[m]["fail_on"][k] if m in ours else np.nan for m in methods]
        n = [ours[m]["n"] if m in ours else 0 for m in methods]
        # Wilson interval of each failure proportion (as recorded, else from the rate and n)
        ci = [(ours[m].get("fail_ci") or {}).get(k) or _wilson_pct(v, nn) if m in ours else None
              for m, v, nn in zip(methods, o, n)]
        xo = x + (2 * j - 2.5) * w
        ax.bar(xo, np.nan_to_num(o), w, yerr=_yerr(np.nan_to_num(o), ci), capsize=2, color=col,
               label=f"ours: {k}")
        ax.bar(xo + w, [p.fail_pct[k] if p else 0 for p in ref], w, color=col, alpha=0.35,
               hatch="//", edgecolor="0.3", label=f"paper: {k}")
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("% of trials failing on")
    ax.set_title("Table II: where trials fail", fontsize=10)
    ax.legend(fontsize=7, ncol=3)
    ax.grid(axis="y", alpha=0.3)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def plot_table3(doc: dict, title: str = ""):
    """Table III's hours to retrain per method: the measured parts stacked, beside the paper's."""
    plt = _plt()
    rows = doc["rows"]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    x = np.arange(len(rows))
    w = 0.38
    cmap = plt.get_cmap("tab20")
    names, labelled = [], set()
    for r in rows:
        names += [k for k in (r.get("parts") or {}) if k not in names]
    for i, r in enumerate(rows):
        bottom = 0.0
        parts = r.get("parts") or {}
        for k, v in parts.items():  # the measured parts, stacked
            if v is None:
                continue
            ax.bar(x[i] - w / 2, v, w, bottom=bottom, color=cmap(names.index(k) % 20),
                   label=None if k in labelled else k)
            labelled.add(k)
            bottom += v
        if not parts and r.get("hours") is not None:
            ax.bar(x[i] - w / 2, r["hours"], w, color=OURS_COLOUR)
            bottom = r["hours"]
        missing = [k for k, v in parts.items() if v is None]
        if r.get("hours") is not None:
            note = f"{r['hours']:.1f}"
        elif missing:
            note = f"incomplete: {len(missing)} of {len(parts)} parts\nnot measured"
        else:
            note = "n/a"
        ax.text(x[i] - w / 2, bottom, note, ha="center", va="bottom", fontsize=7)
        ref = r.get("paper_hours", paper.TABLE3_H.get(r["method"]))
        if ref is not None:
            ax.bar(x[i] + w / 2, ref, w, color="0.75", hatch="//", edgecolor="0.4",
                   label="paper" if i == 0 else None)
            ax.text(x[i] + w / 2, ref, f"{ref:g}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(x)
    ax.set_xticklabels([style.method_label(r["method"]) for r in rows])
    ax.set_ylabel("wall-clock hours to retrain")
    ax.set_title("Table III: retraining cost when a new terrain is introduced", fontsize=10)
    ax.legend(fontsize=7)
    ax.grid(axis="y", alpha=0.3)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def plot_fig4b(doc: dict, smooth_bins: int = 5, title: str = ""):
    """Success of switching against distance to the artifact, per (source -> target) pair: the
    package's Fig. 4b (`fig4b.switch_success_figure`) of a lookup JSON."""
    return fig4b.switch_success_figure(
        fig4b.lookup_arrays(doc), title or f"{doc.get('init')} init: switch success against "
        "distance (dots: 1 cm bins, size ~ points; dotted: best distance)", smooth_bins)


# ------------------------------------------------------------------------------- training runs
def read_csv(path) -> dict:
    """{column: float array} of a CSV (blank cells NaN)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    cols = rows[0].keys() if rows else []

    def num(v):
        try:
            return float(v)
        except (TypeError, ValueError):
            return math.nan

    return {c: np.array([num(r.get(c)) for r in rows]) for c in cols}


def metrics_rows(run_dir) -> list[dict]:
    """The rows of a run's metrics.csv (the curves are drawn from them with `series`)."""
    with (pathlib.Path(run_dir) / "metrics.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def series(rows: list[dict], key: str):
    """(steps, values) of `key` (runs.curve_series), finite values only."""
    xy = curve_series(rows, key)
    ok = np.isfinite(xy).all(1)
    return xy[ok, 0], xy[ok, 1]


def plot_training_overview(runs: Sequence[pathlib.Path], name: Callable = str):
    """Every run on shared axes: episode reward, eval reward per step, guide scale; `name(run
    folder)` labels each."""
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(16, 3.8))
    for d in runs:
        m = metrics_rows(d)
        for ax, key in zip(axes, ("episode/sum_reward", "eval/reward_per_step", "guide_scale")):
            x, y = series(m, key)
            if len(x):
                (ax.step(x, y, where="post", label=name(d)) if key == "guide_scale"
                 else ax.plot(x, y, "-" if key.startswith("episode") else "o-", ms=3,
                              label=name(d)))
    for ax, t in zip(axes, ("training episodes: sum of rewards", "milestone rollouts: reward per step",
                            "curriculum: guide scale")):
        ax.set_title(t, fontsize=10)
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    return fig


def plot_training_run(run_dir: pathlib.Path, title: str = ""):
    """A run's curves.png, inline: the package's figure of a PPO or DQN run
    (`curves.run_figure`)."""
    return curves.run_figure(run_dir, title=title or str(run_dir))


def plot_estimators(ests):
    """Training curves of the switch estimators: `ests` [(name, metrics JSON, history CSV)]."""
    plt = _plt()
    fig, (a, b) = plt.subplots(1, 2, figsize=(14, 3.8))
    for name, _, h in ests:
        m = read_csv(h)
        (line,) = a.plot(m["epoch"], m["train_loss"], label=f"{name} train")
        a.plot(m["epoch"], m["val_loss"], "--", color=line.get_color(), label=f"{name} val")
        b.plot(m["epoch"], m["val_acc"], color=line.get_color(), label=name)
    a.set_ylabel("loss (E(s) - y)^2")
    b.set_ylabel("validation accuracy (threshold 0.5)")
    b.axhline(0.5, color="k", ls=":", lw=0.8)
    for ax in (a, b):
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    fig.suptitle("switch estimators: training curves", fontsize=9)
    fig.tight_layout()
    return fig

"""The switch estimators as tables and figures: their training curves, metrics rows and provenance. Plain Python, no JAX."""

from __future__ import annotations

import json
import math
import pathlib
import numpy as np
from biped_switch import paper
from biped_switch.reports import provenance as prov


def plot_history(history: dict, out_png, title: str = "") -> None:
    """Loss (train, val) and validation accuracy per epoch."""
    # lazy: matplotlib loads slowly and only this plot needs it; the backend is chosen before pyplot
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ep = np.arange(1, len(history["train_loss"]) + 1)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    a.plot(ep, history["train_loss"], label="train")
    a.plot(ep, history["val_loss"], label="validation")
    a.set_ylabel("loss (E(s) - y)^2")
    a.legend()
    b.plot(ep, history["val_acc"])
    b.set_ylabel("validation accuracy (threshold 0.5)")
    for ax in (a, b):
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)


def _read_metrics(path) -> dict:
    p = pathlib.Path(path)
    return json.loads(p.read_text()) if p.is_file() else {}


def estimator_rows(ests):
    """(headers, rows) of estimators' final metrics; `ests`: (name, metrics JSON, history CSV) as
    the CLI writes them (<results>/estimators/<init>_<target>.json, ..._history.csv)."""
    headers = ["estimator", "points (train / val)", "val acc", "best val acc (epoch)", "val AUC",
               "epochs", "train s", "device", "data"]
    rows = []
    for name, js, _ in ests:
        if not pathlib.Path(js).is_file():
            rows.append([name] + ["metrics JSON missing"] + ["-"] * 7)
            continue
        d = _read_metrics(js)
        m = d.get("metrics", {})
        rows.append([name, f"{m.get('train_points', 0):,} / {m.get('val_points', 0):,}",
                     f"{m.get('val_acc', math.nan):.3f}",
                     f"{m.get('best_val_acc', math.nan):.3f} ({m.get('best_val_acc_epoch', '?')})",
                     f"{m.get('val_auc', math.nan):.3f}", m.get("epochs", "?"),
                     f"{m.get('train_s', math.nan):.0f}", m.get("device", "not recorded"),
                     d.get("data_file", "?")])
    return headers, rows


def estimators_provenance(ests, print_fn=print) -> list[str]:
    """Prints each estimator's data and checkpoint and the verdict on the amount of sweep data
    (against the paper's points per target); returns the reasons ([] if none)."""
    reasons, few = [], []
    for name, js, _ in ests:
        d = _read_metrics(js)
        m = d.get("metrics", {})
        print_fn(f"  {name}: data {d.get('data_file', 'not recorded')}, checkpoint "
                 f"{d.get('checkpoint', 'not recorded')}")
        if m.get("points_total", 0) < paper.SWEEP_POINTS:
            few.append(f"{name} {m.get('points_total', 0):,}")
        lab = prov.pipeline_label(d)
        if lab:
            reasons.append(f"{name} labelled PIPELINE_CHECK ({lab})")
    if few:
        reasons.append(f"sweep points {', '.join(few)} (paper: {paper.SWEEP_POINTS:,} per target)")
    print_fn(prov.verdict(reasons))
    return reasons

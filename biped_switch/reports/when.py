"""The learned "when" rule's offline check as a table and a reliability diagram (from
`python -m biped_switch.when`'s offline.json). Plain Python, no JAX."""

from __future__ import annotations

import pathlib

import numpy as np

PREDICTORS = (("learned", "learned (ours)"), ("table", "(target, source, 5 cm) table"),
              ("paper_estimator", "paper's estimator"))


def markdown(doc: dict) -> str:
    lo, hi = doc["band_m"]
    tr = doc["train"]
    lines = [f"Held-out tracks' switches at {lo:g}-{hi:g} m (validation tracks: never trained on). "
             f"AUC: higher is better; Brier and ECE (10 bins): lower is better. Model "
             f"`{doc['model']}`: {tr['train_rows']:,} training rows, {tr['val_rows']:,} validation "
             f"rows on {tr['val_tracks']} tracks, temperature {tr['temperature']:.2f}, "
             f"training {tr['train_s']:.0f} s ({tr['device']}).", "",
             "| target | source | switches | success | "
             + " | ".join(f"{n}: AUC / Brier / ECE" for _, n in PREDICTORS) + " |",
             "|---|---|---|---|" + "---|" * len(PREDICTORS)]
    for r in doc["scores"]:
        cells = []
        for k, _ in PREDICTORS:
            m = r.get(k)
            cells.append("-" if m is None else f"{m['auc']:.3f} / {m['brier']:.4f} / {m['ece']:.4f}")
        lines.append(f"| {r['target']} | {r['source']} | {r['n']:,} | {r['success_pct']:.1f}% | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot_reliability(doc: dict, out_png) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.6, 4.2))
    ax.plot([0, 1], [0, 1], color="0.6", lw=1, ls="--")
    for k, name in PREDICTORS:
        r = doc["reliability"].get(k)
        if r is None:
            continue
        mp, fr, n = (np.asarray(r[f], float) for f in ("mean_p", "freq", "count"))
        ok = n > 0
        ax.plot(mp[ok], fr[ok], marker="o", label=name)
    ax.set_xlabel("predicted P(success)")
    ax.set_ylabel("observed success rate")
    ax.set_title("reliability, held-out tracks (0.3-0.9 m)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)


def tuning_markdown(doc: dict) -> str:
    first = doc["track_seed"]
    lines = [f"{doc['init']}-init suite, {doc['trials']:,} tuning tracks per setting (seeds "
             f"{first:,}-{first + doc['trials'] - 1:,}, never reported on), model `{doc['model']}`; "
             f"{doc['wall_s'] / 60:.0f} min ({doc['device']}). Chosen: later P from the "
             f"{doc['chosen']['later_from']}, band {doc['chosen']['band_tol']:g}, margin "
             f"{doc['chosen']['margin']:g}, {doc['chosen']['persist_steps']} step(s).", "",
             "| later P from | band | margin | run length [steps] | % success (95% CI) | "
             "% fail gap / jump / stair |", "|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        lo, hi = r["success_ci"]
        f = r["fail_on"]
        lines.append(f"| {r['later_from']} | {r['band_tol']:g} | {r['margin']:+.2f} | "
                     f"{r['persist_steps']} | "
                     f"{r['success_pct']:.1f} "
                     f"({lo:.1f}-{hi:.1f}) | {f['gaps']:.1f} / {f['jumps']:.1f} / "
                     f"{f['stairs']:.1f} |")
    return "\n".join(lines) + "\n"


def write(doc: dict, out_dir) -> None:
    out_dir = pathlib.Path(out_dir)
    (out_dir / "offline.md").write_text(markdown(doc))
    plot_reliability(doc, out_dir / "reliability.png")

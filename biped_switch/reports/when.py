"""The learned "when" rule's offline check as a table and a reliability diagram (from
`python -m biped_switch.when`'s offline.json). Plain Python, no JAX."""

from __future__ import annotations

import pathlib

import numpy as np

from biped_switch.kinds import KIND
from biped_switch.paper import TABLE2_FAIL_ORDER
from biped_switch.stats import bin_counts

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
             f"% fail {' / '.join(KIND[k].singular for k in TABLE2_FAIL_ORDER)} |",
             "|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        lo, hi = r["success_ci"]
        f = r["fail_on"]
        lines.append(f"| {r['later_from']} | {r['band_tol']:g} | {r['margin']:+.2f} | "
                     f"{r['persist_steps']} | "
                     f"{r['success_pct']:.1f} "
                     f"({lo:.1f}-{hi:.1f}) | "
                     + " / ".join(f"{f[k]:.1f}" for k in TABLE2_FAIL_ORDER) + " |")
    return "\n".join(lines) + "\n"


def write(doc: dict, out_dir) -> None:
    out_dir = pathlib.Path(out_dir)
    (out_dir / "offline.md").write_text(markdown(doc))
    plot_reliability(doc, out_dir / "reliability.png")


# ----------------------------------------------------------------------- the timing ceiling
def best_bin(dist_m, label, lost_m, bin_m: float = 0.05, band=(0.2, 0.9), min_n: int = 50):
    """The switch-distance bin [m] of width `bin_m` in `band` whose switches succeed most often
    (the nearest of equals): (bin start [m], successes, trials), or None when no bin has `min_n`
    trials. `lost_m`: the intended switch distances of episodes that fell before reaching them,
    each a failure in its bin. The max over bins is picked after the fact, so it flatters: a
    generous ceiling for any rule that chooses only the distance."""
    d = np.concatenate([np.asarray(dist_m), np.asarray(lost_m, np.asarray(dist_m).dtype)])
    y = np.concatenate([np.asarray(label, float), np.zeros(len(lost_m))])
    first = int(round(band[0] / bin_m))
    k, n = (a[0, first:] for a in bin_counts(d, y, np.zeros(len(d), int), 1, bin_m,
                                              int(round(band[1] / bin_m))))
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = np.where(n >= min_n, k / n, -1.0)
    if rate.max() < 0:
        return None
    i = int(np.argmax(rate))
    return round((first + i) * bin_m, 3), int(k[i]), int(n[i])


def phase_spread(phase, label, bins: int = 8) -> tuple[float, float, int, float] | None:
    """Success per phase-clock sector ((sin, cos) -> angle, `bins` equal sectors): (lowest %,
    highest %, fewest switches in a sector, chi-square p of "success does not depend on the
    sector"); None without switches in every sector. If the clock at the switch mattered, a rule
    could wait for a good sector."""
    from scipy.stats import chi2_contingency

    phase, label = np.asarray(phase), np.asarray(label)
    sector = ((np.arctan2(phase[:, 0], phase[:, 1]) + np.pi) / (2 * np.pi) * bins).astype(int)
    sector = np.minimum(sector, bins - 1)
    n = np.bincount(sector, minlength=bins)
    if len(label) == 0 or (n == 0).any():
        return None
    k = np.bincount(sector, weights=label, minlength=bins)
    pct = 100 * k / n
    table = np.stack([k, n - k])
    p = 1.0 if (table.sum(1) == 0).any() else float(chi2_contingency(table)[1])
    return float(pct.min()), float(pct.max()), int(n.min()), p


def ceiling_markdown(doc: dict) -> str:
    lines = [f"Success of switching into each target after each source: the best "
             f"{doc['bin_m'] * 100:.0f} cm bin of switch distance in {doc['band_m'][0]:g}-"
             f"{doc['band_m'][1]:g} m of each sweep (at least {doc['min_n']} switches; a fall "
             f"before the switch counts against its bin), against Table II's tracks (`evaluate "
             f"failures`: 1 - falls / artifacts reached). No rule that only chooses the distance "
             f"can beat its sweep's best bin by more than chance; the lead-in sweep starts each "
             f"episode with walk and hands over along the track as the controller does.", "",
             "| target | after | " + " | ".join(f"{s}: best bin [m], % (95% CI)"
                                                for s in doc["sweeps"])
             + " | " + " | ".join(f"Table II {m}: %" for m in doc["methods"])
             + f" | {doc['phase_sweep']}, best bin +-{doc['phase_halfwidth_m'] * 100:.0f} cm: % "
               f"over {doc['phase_bins']} phase sectors (chi-square p: the same in all) |",
             "|---|---|" + "---|" * (len(doc["sweeps"]) + len(doc["methods"]) + 1)]
    for r in doc["rows"]:
        cells = []
        for s in doc["sweeps"]:
            b = r["sweeps"].get(s)
            cells.append("-" if b is None else
                         f"{b['bin_m']:.2f}: {b['pct']:.1f} ({b['ci'][0]:.1f}-{b['ci'][1]:.1f}), "
                         f"n {b['n']:,}")
        for m in doc["methods"]:
            t = r["table2"].get(m)
            cells.append("-" if t is None else f"{t['pct']:.1f} ({t['ci'][0]:.1f}-{t['ci'][1]:.1f})")
        ph = r.get("phase")
        cells.append("-" if ph is None else f"{ph['min_pct']:.0f}-{ph['max_pct']:.0f} "
                     f"(n >= {ph['min_n']}; p {ph['p']:.2f})")
        lines.append(f"| {r['target']} | {r['source']} | " + " | ".join(cells) + " |")
    imp = doc.get("implied_pct", {})
    if imp:
        lines += ["", f"Implied success on Table II's {doc['tracks']:,} tracks (seeds "
                  f"{doc['track_seed']:,}+), each artifact crossed independently at its pair's "
                  f"rate: " + "; ".join(f"{k} {'-' if v is None else f'{v:.1f}%'}"
                                        for k, v in imp.items())
                  + ". The product of Table II's own pair rates, beside the row's measured success,"
                  " shows how far independence holds."]
    return "\n".join(lines) + "\n"


def implied_success(sequences, rate: dict) -> float | None:
    """Track success if every artifact is crossed independently at `rate[(target, after)]`: the
    mean over tracks (each a list of (kind, the kind before it or "start")) of the product of
    its rates; None if a pair has no rate."""
    out = []
    for seq in sequences:
        if any(pair not in rate for pair in seq):
            return None
        out.append(float(np.prod([rate[pair] for pair in seq])))
    return float(np.mean(out)) if out else None

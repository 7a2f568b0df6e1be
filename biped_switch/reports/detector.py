"""The learned terrain detector measured: confusion matrices against the oracle, the distance at
which it first names each artifact, its distance error, and a figure along one trial. Plain Python,
NumPy and matplotlib."""

from __future__ import annotations

import pathlib

import numpy as np

from biped_switch.names import ARTIFACT_KINDS, DETECTOR_CLASSES
from biped_switch.kinds import class_of_code

CLASSES = DETECTOR_CLASSES  # the class of each oracle kind: kinds.CLASS_OF_CODE


def confusion(true_kind: np.ndarray, kind: np.ndarray) -> np.ndarray:
    """(4, 4) counts, rows = the oracle's class (none, jumps, gaps, stairs), columns = predicted."""
    m = np.zeros((len(CLASSES), len(CLASSES)), np.int64)
    np.add.at(m, (class_of_code(true_kind, np), class_of_code(kind, np)), 1)
    return m


def episodes(data: dict):
    """Each episode's row indices of `data`, in step order (the data may interleave episodes)."""
    for e in np.unique(data["episode"]):
        idx = np.flatnonzero(data["episode"] == e)
        yield idx[np.argsort(data["step"][idx])]


def onsets(data: dict, kind: np.ndarray, detect_range_m: float = 0.9,
           window_m: float = 1.5) -> dict:
    """Per approach to an artifact (an oracle onset: none -> a kind within one episode): the
    oracle's distance [m] at the first step (from `window_m` before the start) at which the
    detector names the right kind, and whether it named a wrong kind first. Detection-distance
    error [cm] = that distance - the oracle's (its first step in range, <= `detect_range_m`)."""
    err, wrong, missed, linger = [], 0, 0, 0
    tk, dist = data["kind"], data["dist_m"]
    for idx in episodes(data):
        k, d, p = tk[idx], dist[idx], kind[idx]
        starts = np.flatnonzero((k[1:] >= 0) & (k[:-1] < 0)) + 1
        for s in starts:
            truth, d0 = k[s], d[s]
            # the approach: from window_m before the start until the oracle drops this artifact
            lo = s
            while lo > 0 and d[lo - 1] <= window_m and k[lo - 1] < 0:
                lo -= 1
            hi = s
            while hi + 1 < len(k) and k[hi + 1] == truth:
                hi += 1
            seg = slice(lo, hi + 1)
            before = k[:lo][k[:lo] >= 0]
            prev = int(before[-1]) if len(before) else -1  # the artifact just crossed
            named = np.flatnonzero(p[seg] == truth)
            other = np.flatnonzero((p[seg] >= 0) & (p[seg] != truth) & (p[seg] != prev))
            kept = np.flatnonzero((p[seg] == prev) & (prev >= 0) & (prev != truth))
            if len(named) == 0:
                missed += 1
                continue
            first = named[0]
            if len(other) and other[0] < first:
                wrong += 1
            if len(kept) and kept[0] < first:
                linger += 1
            err.append(100.0 * (d[seg][first] - d0))
    err = np.asarray(err)
    return {"approaches": int(len(err) + missed), "missed": int(missed), "wrong_first": int(wrong),
            "lingering": int(linger), "onset_error_cm": err}



def debounce(data: dict, kind: np.ndarray, steps: int, via_none: bool = False) -> np.ndarray:
    """`kind` (per step of `data`'s episodes) with every change held back until the new kind has
    been named `steps` control steps in a row (the reference of switching.rules.learned_detection);
    with `via_none`, a kind never directly follows another. Missing steps (the data keeps every
    n-th) count as one."""
    out = np.empty_like(kind)
    for idx in episodes(data):
        rep, cand, run = -1, -1, 0
        for i in idx:
            k = int(kind[i])
            if k == rep:
                run = 0
            elif k == cand:
                run += 1
            else:
                cand, run = k, 1
            if run >= steps and not (via_none and rep >= 0 and cand >= 0):
                rep, run = cand, 0
            out[i] = rep
    return out


def detector_metrics(data: dict, kind: np.ndarray, dist: np.ndarray, band_m=(0.0, 0.9)) -> dict:
    """Step accuracy, the confusion matrix, onset errors and the distance error [cm] (in `band_m`,
    where the artifact is named correctly) of one detector on `data` (switching.detector.collect)."""
    conf = confusion(data["kind"], kind)
    ons = onsets(data, kind)
    e = ons["onset_error_cm"]
    tk, td = data["kind"], data["dist_m"]
    # every change of the reported kind into a kind the oracle is not naming then (on or before
    # an artifact): each one switches into a wrong policy
    wrong_onsets = 0
    for idx in episodes(data):
        k = kind[idx]
        ch = np.flatnonzero(k[1:] != k[:-1]) + 1
        wrong_onsets += int(np.sum((k[ch] >= 0) & (k[ch] != tk[idx][ch])))
    inband = (tk >= 0) & (kind == tk) & (td >= band_m[0]) & (td <= band_m[1])
    seen = inband & np.isfinite(dist)  # a named kind with no height change ahead has no distance
    derr = 100.0 * np.abs(dist[seen] - td[seen])
    return {"steps": int(len(tk)), "accuracy": float(np.trace(conf) / max(conf.sum(), 1)),
            "confusion": conf.tolist(), "approaches": ons["approaches"], "missed": ons["missed"],
            "wrong_first": ons["wrong_first"], "lingering": ons["lingering"],
            "wrong_onsets": wrong_onsets,
            "onset_error_cm": {"mean": float(e.mean()) if len(e) else None,
                               "median": float(np.median(e)) if len(e) else None,
                               "p5": float(np.percentile(e, 5)) if len(e) else None,
                               "p95": float(np.percentile(e, 95)) if len(e) else None},
            "dist_abs_error_cm": {"mean": float(derr.mean()) if len(derr) else None,
                                  "p95": float(np.percentile(derr, 95)) if len(derr) else None,
                                  "band_m": list(band_m),
                                  "no_distance_pct": 100.0 * float(1 - seen.sum() / max(inband.sum(), 1))}}


def _fmt(v, f="{:.1f}"):
    return "-" if v is None else f.format(v)


def detector_markdown(meta: dict) -> str:
    """The report: one table per validation set and rule, and the cost."""
    lines = ["# Learned terrain detector against the oracle", ""]
    d = meta["data"]
    lines += [f"Training: {d['train_steps']:,} control steps of "
              f"{d['episodes_per_kind']} episodes per stand policy on its own terrain kind (walk on "
              f"flat tracks), track seeds from {d['track_seed']:,}; validation: held-out seeds "
              f"({d['val_steps']:,} steps) and 7-artifact mixed tracks crossed by the end-to-end "
              f"policy ({d['mixed_steps']:,} steps). Best validation epoch "
              f"{meta['history']['best_epoch']} of {len(meta['history']['val_loss'])}. Cost on "
              f"{meta['device']}: data {meta['cost_s']['data']:.0f} s, training "
              f"{meta['cost_s']['train']:.0f} s.", ""]
    lines += ["| data | rule | step accuracy | approaches | missed | a third kind first | "
              "still the last kind | a wrong kind named | onset error [cm] mean (median; 5-95%) | "
              "distance error [cm] mean (95%; % with none) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for key, m in meta["metrics"].items():
        data, rule = key.split("/")
        o, de = m["onset_error_cm"], m["dist_abs_error_cm"]
        lines.append(f"| {data} | {rule} | {100 * m['accuracy']:.2f}% | {m['approaches']} | "
                     f"{m['missed']} | {m['wrong_first']} | {m.get('lingering', '-')} | {m.get('wrong_onsets', '-')} | {_fmt(o['mean'])} ({_fmt(o['median'])}; "
                     f"{_fmt(o['p5'])} .. {_fmt(o['p95'])}) | {_fmt(de['mean'])} ({_fmt(de['p95'])}; {_fmt(de.get('no_distance_pct'))}) |")
    lines += ["", "Approaches: each time the oracle starts naming an artifact. A third kind first: "
              "before naming it right, the detector named a kind that is neither this artifact's "
              "nor the one just crossed (a switch into a wrong policy); still the last kind: it "
              "kept naming the artifact just crossed (whose policy is the one acting: no switch); "
              "a wrong kind named: each change of the reported kind into a kind the oracle is not "
              "naming then, on or before an artifact (a switch into a wrong policy). ",
              "Onset error: the oracle's distance to the artifact's start when the detector first "
              "names it, minus the oracle's own (its first step within 0.9 m); negative = later "
              "than the oracle. Distance error: |predicted - true| distance to the start while "
              "both name the artifact within 0-0.9 m.", ""]
    for key, m in meta["metrics"].items():
        lines += [f"Confusion, {key} (rows: oracle; columns: detector)", "",
                  "| | " + " | ".join(CLASSES) + " |", "|---" * (len(CLASSES) + 1) + "|"]
        for c, row in zip(CLASSES, m["confusion"]):
            lines.append(f"| {c} | " + " | ".join(f"{v:,}" for v in row) + " |")
        lines.append("")
    return "\n".join(lines)


def plot_trial(data: dict, kind: np.ndarray, dist: np.ndarray, episode: int,
               path: pathlib.Path) -> None:
    """One episode: the forward height profile over time (image), the oracle's and the
    detector's kind, and their distances to the next artifact's start."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    i = np.flatnonzero(data["episode"] == episode)
    i = i[np.argsort(data["step"][i])]
    t = data["step"][i] * 0.02
    fig, ax = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    prof = data["profile"][i]
    ax[0].imshow(-2.0 * prof.T, aspect="auto", origin="lower", cmap="terrain",
                 extent=(t[0], t[-1], -0.6, 0.9), vmin=-0.4, vmax=0.4)
    ax[0].set_ylabel("ahead of the CoM [m]")
    ax[0].set_title("heightmap forward profile (height relative to the feet [m])")
    ax[1].step(t, data["kind"][i], where="post", label="oracle", lw=2)
    ax[1].step(t, kind[i], where="post", label="learned", lw=1)
    ax[1].set_yticks(range(-1, len(ARTIFACT_KINDS)), CLASSES)
    ax[1].legend(loc="upper right")
    td = np.where(np.isfinite(data["dist_m"][i]) & (data["kind"][i] >= 0), data["dist_m"][i], np.nan)
    pd = np.where(np.isfinite(dist[i]), dist[i], np.nan)
    ax[2].plot(t, td, label="oracle", lw=2)
    ax[2].plot(t, pd, label="learned", lw=1)
    ax[2].set_ylabel("to the start [m]")
    ax[2].set_xlabel("time [s]")
    ax[2].legend(loc="upper right")
    fig.tight_layout()
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)

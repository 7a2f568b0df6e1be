"""Fig. 4b of the paper read back: the switch-point lookup tables `python -m biped_switch.sweep`
writes (<results>/lookup/lookup_<init>.json), as arrays, as per-pair rows and with their provenance
(how many sweep points, stand-in policies, guide forces), and drawn: `switch_success_figure` is
the one drawing of Fig. 4b, saved beside the lookup table by the sweep command (`draw_lookup`) and
shown by the notebook (experiments/notebooks/fig4b_switch_success.ipynb); the sweeps themselves
are sweep.py's.
"""

from __future__ import annotations

import numpy as np

from biped_switch import paper
from biped_switch.reports import provenance as prov
from biped_switch.names import POLICY_NAMES
from biped_switch.reports import style
import pathlib
import textwrap

from biped_switch.stats import smoothed_success_pct


def lookup_arrays(doc: dict) -> dict:
    """{target: {"rate": (P, nb) NaN where no data, "count": (P, nb), "bins_m": (nb,), "best_m":
    (P,) the best switch distance, NaN for the target itself or no data}}: the tables the sweep
    command draws from (switching.lookup), read back from a lookup JSON."""
    out = {}
    for target, t in doc["tables"].items():
        rate = np.array([[np.nan if v is None else v for v in r] for r in t["rate"]], float)
        count = np.asarray(t["count"], float)
        best = [doc["best_m"].get(f"{name}->{target}") for name in POLICY_NAMES]
        out[target] = {"rate": rate, "count": count, "bins_m": np.arange(rate.shape[1]) * 0.01,
                       "best_m": np.array([np.nan if b is None else b for b in best], float)}
    return out


def lookup_rows(doc: dict):
    """(headers, rows), per (source -> target) pair: points, overall success, best switch distance."""
    headers = ["pair", "switches", "% success (all distances)", "best switch distance [m]"]
    rows = []
    for target, t in lookup_arrays(doc).items():
        for j, name in enumerate(POLICY_NAMES):
            n = t["count"][j].sum()
            if name == target:
                continue
            succ = np.nansum(t["rate"][j] * t["count"][j])
            best = doc["best_m"].get(f"{name}->{target}")
            rows.append([f"{name} -> {target}", int(n), f"{100 * succ / n:.1f}" if n else "-",
                         "-" if best is None else f"{best:.2f}"])
    return headers, rows


def lookup_provenance(doc: dict, path, print_fn=print) -> list[str]:
    """Prints each sweep's size, settings, data and policies, and the verdict of a lookup table;
    returns the reasons it is a pipeline check ([] if none)."""
    fmt = prov.fmt
    meta = doc.get("meta") or {}
    print_fn(f"file: {prov.rel(path)} (init {doc.get('init')})")
    reasons, few, sub, guided, easy = [], [], [], [], []
    gs = meta.get("guide_scale")
    per = meta.get("settings") or {}  # per target: difficulty, guide_scale (when recorded)
    for target, st in (meta.get("sweeps") or {}).items():
        t_set = {**st, **(per.get(target) or {})}
        g = t_set.get("guide_scale", gs)
        print_fn(f"  sweep {target}: {st.get('points', 0):,} points, {fmt(st.get('success_pct'))}% "
                 f"successful switches, {fmt(st.get('wall_s'))} s on {fmt(st.get('device'))}; "
                 f"difficulty {fmt(t_set.get('difficulty'))}, guide_scale {fmt(g)}; data "
                 f"{fmt(st.get('data'))}")
        if st.get("points", 0) < paper.SWEEP_POINTS:
            few.append(f"{target} {st.get('points', 0):,}")
        if (g or 0) > 0:
            guided.append(f"{target} {g:g}")
        if t_set.get("difficulty") is not None and t_set["difficulty"] < 1:
            easy.append(f"{target} {t_set['difficulty']:g}")
    if not meta.get("sweeps"):
        print_fn(f"  guide_scale: {fmt(gs)}")
        if (gs or 0) > 0:
            guided.append(f"{gs:g}")
    for target, pols in (meta.get("policies") or {}).items():
        items = list(pols.items()) if isinstance(pols, dict) else list(enumerate(pols))
        print_fn(f"  policies of the {target} sweep:")
        for name, src in items:
            print_fn(f"    {name}: {src}")
        if prov.stand_ins(src for _, src in items):
            sub.append(target)
    if sub:
        reasons.append("stand-in policies in the " + ", ".join(sub) + " sweeps")
    if guided:
        reasons.append("scripted guide forces on (guide_scale " + ", ".join(guided) + ")")
    if easy:
        reasons.append("artifacts below full difficulty (" + ", ".join(easy) + ")")
    if few:
        reasons.append(f"sweep points {', '.join(few)} (paper: {paper.SWEEP_POINTS:,} per target)")
    return prov.conclude(doc, reasons, print_fn=print_fn)


def plot_switch_distances(by_method: dict, path=None, kind: str = "gaps"):
    """Where Table II's rules switched into `kind`'s policy (`table2.switch_summary` per method),
    one panel per artifact before it: the share of switches per 0.1 m of distance (lines) and the
    share of those that then fell on the artifact (dots, right axis), against Fig. 4b's axis.
    Saved to `path` and closed, or (no path: a notebook) returned."""
    import matplotlib.pyplot as plt  # lazy: only the figure needs it

    prevs = list(dict.fromkeys(p for d in by_method.values() for p in d.get(kind, {})))
    fig, axes = plt.subplots(1, max(len(prevs), 1), figsize=(4.6 * max(len(prevs), 1), 3.4),
                             squeeze=False)
    width = 0.1 / max(len(by_method), 1)
    for ax, prev in zip(axes[0], prevs):
        lost_ax = ax.twinx()
        for i, (m, d) in enumerate(by_method.items()):
            c = d.get(kind, {}).get(prev)
            if not c:
                continue
            b = np.array(c["lost_by_ahead"], float).reshape(-1, 4)
            x = b[:, 0] + (i + 0.5) * width  # side by side within each 0.1 m bin
            color = style.method_colour(m, f"C{i}")
            ax.bar(x, b[:, 2] / c["n"], width=width, color=color, alpha=0.45,
                   label=f"{m} (n {c['n']:,}, lost {c['lost_pct']:.0f}%)")
            lost_ax.plot(x, 100 * b[:, 3] / np.maximum(b[:, 2], 1), "D", color=color, ms=5,
                         mec="k", mew=0.5)
        ax.set_title(f"into {kind}, after {prev}")
        ax.set_xlabel("switch distance before the artifact [m] (0.1 m bins)")
        ax.set_ylabel("share of switches (bars)")
        ax.set_xlim(0.0, 1.0)
        ax.set_ylim(0.0, 1.05)
        lost_ax.set_ylabel("% of them lost (diamonds)")
        lost_ax.set_ylim(-2, 102)
        ax.legend(fontsize=7, loc="upper center")
    fig.tight_layout()
    if path is None:
        return fig
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return None


def switch_success_figure(tables: dict, title: str = "", smooth_bins: int = 5):
    """The paper's Fig. 4b: success of switching against distance to the artifact, per (source ->
    target) pair, one panel per target: each 1 cm bin's success rate (dots, sized by its points),
    their moving mean over `smooth_bins` bins (lines) and the best switch distance (dotted).
    `tables`: {target: {"rate", "count", "bins_m", "best_m"}} (switching.lookup's, or
    `lookup_arrays` of a lookup JSON). Returns the figure, open (a notebook shows it)."""
    import matplotlib.pyplot as plt  # lazy: only the figure needs it

    fig, axes = plt.subplots(1, len(tables), figsize=(5.2 * len(tables), 3.8), squeeze=False)
    for ax, (target, t) in zip(axes[0], tables.items()):
        for j, name in enumerate(POLICY_NAMES):
            cnt = t["count"][j]
            if name == target or cnt.sum() == 0:
                continue
            c = style.policy_colour(name)
            ax.scatter(t["bins_m"] + 0.005, 100 * t["rate"][j], s=4 + 20 * cnt / cnt.max(),
                       color=c, alpha=0.25, lw=0)
            ax.plot(t["bins_m"] + 0.005, smoothed_success_pct(t["rate"][j], cnt, smooth_bins),
                    color=c, label=f"{name} -> {target} (n={int(cnt.sum())})")
            if np.isfinite(t["best_m"][j]):
                ax.axvline(t["best_m"][j], ls=":", lw=1, color=c)
        ax.set_xlim(0.9, 0)  # the robot approaches from the left: far -> near
        ax.set_ylim(-2, 102)
        ax.set_xlabel("switch distance before the artifact [m]")
        ax.set_ylabel(f"% success (moving mean, {smooth_bins} cm)")
        ax.set_title(f"switch to {target}", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower left")
    fig.suptitle(textwrap.fill(title, 70 * len(tables)), fontsize=9)  # one panel: 2 lines
    fig.tight_layout()
    return fig


def plot_switch_success(tables: dict, path: pathlib.Path, title: str = "",
                        smooth_bins: int = 5) -> None:
    """`switch_success_figure`, saved to `path` and closed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = switch_success_figure(tables, title, smooth_bins)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def draw_lookup(tables: dict, init: str, out: pathlib.Path) -> pathlib.Path:
    """Fig. 4b of one sweep's lookup tables, beside its lookup_<init>.json."""
    what = (f"{init.removesuffix('_context')} init, after the source's own artifact"
            if init.endswith("_context") else f"{init} init")
    path = pathlib.Path(out) / f"fig4b_{init}.png"
    plot_switch_success(tables, path, f"{what}: switch success against distance (sweep data; "
                        "dots: 1 cm bins, size ~ points; dotted: best distance)")
    return path

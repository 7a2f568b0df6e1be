"""Statistics of evaluation episodes: 95% confidence intervals and the per-table episode summary.

`episode_table` turns per-episode rollout results (the final env metrics: progress_frac, success,
fell, fail_kind) into the % distance, % success and % failing per artifact kind, each with its 95%
interval (normal interval of the mean for distance, Wilson score interval for proportions), as
Tables I and II report them; `dist_success_cells` writes them as Markdown cells.
"""

from __future__ import annotations

import math

import numpy as np

from biped_switch.names import ARTIFACT_KINDS


def wilson_ci(successes: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """95% Wilson score interval of a proportion (fractions in [0, 1])."""
    if n <= 0:
        return (math.nan, math.nan)
    p = successes / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def mean_ci(x: np.ndarray, z: float = 1.96) -> tuple[float, float, float]:
    """Mean and its 95% normal interval."""
    x = np.asarray(x, float)
    m = float(x.mean())
    half = z * float(x.std(ddof=1)) / math.sqrt(len(x)) if len(x) > 1 else math.nan
    return m, m - half, m + half


def episode_table(result: dict, kinds=ARTIFACT_KINDS) -> dict:
    """% distance and % success (with CIs; the distance's normal interval is clipped to
    0-100) from per-episode rollout results, and the % of episodes failing on each artifact
    kind of `kinds` (index = artifact code: the paper's, or a line-up's `targets`; `fail_kind`:
    the kind's code, -1 for none)."""
    dist = 100.0 * np.asarray(result["progress_frac"])
    succ = np.asarray(result["success"]) > 0.5
    n = len(succ)
    d, d_lo, d_hi = mean_ci(dist)
    d_lo, d_hi = max(d_lo, 0.0), min(d_hi, 100.0)  # a few trials near 100%: no bound past it
    s_lo, s_hi = wilson_ci(float(succ.sum()), n)
    fail = np.asarray(result["fail_kind"])
    return {"n": n, "distance_pct": d, "distance_ci": [d_lo, d_hi],
            "success_pct": 100.0 * succ.mean(), "success_ci": [100 * s_lo, 100 * s_hi],
            "fell_pct": 100.0 * float((np.asarray(result["fell"]) > 0.5).mean()),
            "fail_on": {k: 100.0 * float((fail == i).mean()) for i, k in enumerate(kinds)},
            "fail_ci": {k: [100 * v for v in wilson_ci(float((fail == i).sum()), n)]
                        for i, k in enumerate(kinds)}}


def pct_ci(v: float, ci) -> str:
    """A percentage and its interval as a table cell: "v (lo-hi)"."""
    return f"{v:.1f} ({ci[0]:.1f}-{ci[1]:.1f})"


def pct_ci_cell(v, ci) -> str:
    """`pct_ci` of a recorded row: the value alone when its interval is missing or not finite,
    "-" without a value."""
    if v is None:
        return "-"
    lo, hi = (ci or [math.nan, math.nan])
    if lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
        return f"{v:.1f}"
    return pct_ci(v, (lo, hi))


def dist_success_cells(r: dict) -> str:
    """The "% distance (CI) | % success (CI)" cells of a Table I or II row."""
    return f"{pct_ci(r['distance_pct'], r['distance_ci'])} | {pct_ci(r['success_pct'], r['success_ci'])}"


def join_rows(old: dict | None, rows: list[dict], settings: dict, trial_keys, key,
              order=()) -> list[dict]:
    """`rows` joined with the rows of `old` (a saved table: `settings` and `rows`) whose `key(row)`
    is not among theirs, sorted by where `key(row)` stands in `order` (others last, in turn).
    A table's rows are ready at different times (a policy or estimator that trains longer), so an
    evaluation adds its rows to those already there. Raises ValueError naming the `trial_keys`
    whose values differ, so rows of other trials never stand together in one table."""
    if not old:
        return list(rows)
    before = old.get("settings", {})
    diff = {k: (before.get(k), settings.get(k)) for k in trial_keys if before.get(k) != settings.get(k)}
    if diff:
        raise ValueError("the table there was made with other settings ("
                         + ", ".join(f"{k}: {a!r} there, {b!r} now" for k, (a, b) in diff.items())
                         + "): use another --out, or --fresh to replace it")
    new = {key(r) for r in rows}
    kept = [r for r in old.get("rows", []) if key(r) not in new]
    rank = {k: i for i, k in enumerate(order)}
    return sorted(kept + list(rows), key=lambda r: rank.get(key(r), len(rank)))


def smoothed_success_pct(rate: np.ndarray, count: np.ndarray, bins: int) -> np.ndarray:
    """% success per 1 cm bin as a count-weighted moving mean over `bins` bins (the paper's Fig. 4b,
    drawn by sweep.plot_switch_success and the notebook); NaN where no point is near."""
    k = np.ones(bins)
    s = np.convolve(np.nan_to_num(rate * count), k, "same")
    n = np.convolve(count, k, "same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return 100 * s / n


def bin_counts(dist_m, label, group, n_groups: int, bin_m: float, n_bins: int):
    """(successes, trials), each (n_groups, n_bins): outcomes `label` (N,) of switches at
    `dist_m` (N,) [m] in groups `group` (N,) (a source policy, a (target, source) pair), binned
    by floor(dist / bin_m), clipped into [0, n_bins). The one success-against-distance table
    behind the lookup tables, the when rule's prior and the timing ceiling."""
    # in the distances' own precision: a float32 distance on a bin edge stays in its bin
    b = np.clip(np.floor(np.asarray(dist_m) / bin_m).astype(int), 0, n_bins - 1)
    key = np.asarray(group, int) * n_bins + b
    size = n_groups * n_bins
    k = np.bincount(key, np.asarray(label, np.float64), size).reshape(n_groups, n_bins)
    return k, np.bincount(key, minlength=size).reshape(n_groups, n_bins)


def brier(p, y) -> float:
    """Mean squared error of probabilities `p` against 0/1 outcomes `y`."""
    p, y = np.asarray(p, np.float64), np.asarray(y, np.float64)
    return float(np.mean((p - y) ** 2))


def reliability(p, y, bins: int = 10) -> dict:
    """Per equal-width probability bin: the mean prediction, the observed frequency and the count
    (a reliability diagram's points; empty bins are NaN)."""
    p, y = np.asarray(p, np.float64), np.asarray(y, np.float64)
    b = np.clip((p * bins).astype(int), 0, bins - 1)
    n = np.bincount(b, minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_p = np.bincount(b, p, bins) / n
        freq = np.bincount(b, y, bins) / n
    return {"mean_p": mean_p, "freq": freq, "count": n}


def ece(p, y, bins: int = 10) -> float:
    """Expected calibration error: the count-weighted mean |frequency - mean prediction| over
    `reliability`'s bins."""
    r = reliability(p, y, bins)
    ok = r["count"] > 0
    return float(np.sum(r["count"][ok] * np.abs(r["freq"][ok] - r["mean_p"][ok]))
                 / max(r["count"].sum(), 1))

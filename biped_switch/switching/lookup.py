"""Lookup tables from the sweeps: the success rate per distance bin for each (source, target) pair, its best bin, and the files they are saved in."""

from __future__ import annotations

import json
import pathlib
import numpy as np
from biped_switch.names import POLICY_INDEX, POLICY_NAMES
from biped_switch.names import ARTIFACT_KINDS
from biped_switch.stats import bin_counts
from biped_switch.switching.estimator import sweep_name


# ----------------------------------------------------------------------- lookup tables
def lookup_table(dist_m, label, source, target: str, bin_m: float = 0.01, max_m: float = 0.9):
    """Success rate per switch-distance bin for each source policy -> `target`, and the argmax.

    Returns {"bins_m": bin lower edges, "rate": (P, nbins) NaN where empty, "count": (P, nbins),
    "best_m": (P,) centre of the best bin (NaN for the target itself or no data)}. Ties go to the
    bin farthest from the artifact (the first maximum scanning from 0.9 m down)."""
    succ, count = bin_counts(dist_m, label, source, len(POLICY_NAMES), bin_m,
                             int(round(max_m / bin_m)))
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = succ / count
    return table_from_rates(rate, count, target, bin_m)


def table_from_rates(rate, count, target: str, bin_m: float = 0.01) -> dict:
    """`lookup_table`'s dict from its (P, nbins) rates and counts: the best bin per source. A
    lookup JSON stores rates and counts, so a target swept in an earlier session (whose data
    is gone) keeps its table when another target is swept."""
    rate, count = np.asarray(rate, float), np.asarray(count, float)
    nb = rate.shape[1]
    best = np.full(rate.shape[0], np.nan)
    for j in range(rate.shape[0]):
        if j == POLICY_INDEX[target] or not np.any(count[j] > 0):
            continue
        r = np.where(count[j] > 0, rate[j], -1.0)[::-1]
        best[j] = (nb - 1 - int(np.argmax(r)) + 0.5) * bin_m
    return {"bins_m": np.arange(nb) * bin_m, "rate": rate, "count": count, "best_m": best}


def lookup_matrix(tables: dict) -> np.ndarray:
    """(P, 3) best switch distance [m] for active -> target from per-target tables."""
    m = np.full((len(POLICY_NAMES), len(ARTIFACT_KINDS)), np.nan)
    for k, t in tables.items():
        m[:, ARTIFACT_KINDS.index(k)] = t["best_m"]
    return m


def tables_from_data(data_by_target: dict, cfg) -> dict:
    tables = {}
    for target, d in data_by_target.items():
        at = d["offset"] == 0  # one row per sample
        tables[target] = lookup_table(d["switch_dist_m"][at], d["label"][at], d["source"][at],
                                      target, cfg.lookup_bin_m, cfg.switch_max_m)
    return tables


def save_lookup(tables: dict, init: str, out: pathlib.Path, meta: dict) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    mat = lookup_matrix(tables)
    doc = {"init": init, "best_m": {f"{POLICY_NAMES[j]}->{k}": (None if np.isnan(mat[j, i])
                                                                   else round(float(mat[j, i]), 3))
                                    for i, k in enumerate(ARTIFACT_KINDS) for j in
                                    range(len(POLICY_NAMES))},
           "matrix_m": [[None if np.isnan(v) else float(v) for v in row] for row in mat],
           "tables": {k: {"rate": [[None if np.isnan(v) else round(float(v), 4) for v in r]
                                   for r in t["rate"]], "count": t["count"].astype(int).tolist()}
                      for k, t in tables.items()},
           "meta": meta}
    (out / f"lookup_{init}.json").write_text(json.dumps(doc, indent=1, default=str))
    return doc


def load_lookup(init: str, results: str | pathlib.Path = "experiments/results/lookup") -> np.ndarray:
    """(P, 3) switch distance matrix saved by the sweep (NaN where not applicable)."""
    path = pathlib.Path(results) / f"lookup_{init}.json"
    if not path.exists():
        raise FileNotFoundError(f"{path} missing: run `python -m biped_switch.sweep --init {init}`")
    m = json.loads(path.read_text())["matrix_m"]
    return np.array([[np.nan if v is None else v for v in row] for row in m])


def load_context_lookup(init: str, results: str | pathlib.Path = "experiments/results/lookup"
                        ) -> tuple[np.ndarray, list[str]]:
    """(P, 3) switch distances of the context sweep (`lookup_<init>_context.json`), each target
    it has no table for taken from the plain `lookup_<init>.json`; and per target, the file used."""
    results = pathlib.Path(results)
    name = sweep_name(init, True)
    if lookup_missing(name, results) is None:
        raise FileNotFoundError(f"{results / f'lookup_{name}.json'} missing: run "
                                f"`python -m biped_switch.sweep --init {init} --context`")
    m, missing = load_lookup(name, results), lookup_missing(name, results)
    plain = load_lookup(init, results) if missing else None
    used = []
    for i, k in enumerate(ARTIFACT_KINDS):
        if k in missing:
            m[:, i] = plain[:, i]
        used.append(f"{k}: {results / f'lookup_{init if k in missing else name}.json'}")
    return m, used


def context_lookup_missing(init: str, results: str | pathlib.Path = "experiments/results/lookup"
                           ) -> list[str] | None:
    """Targets neither the context lookup nor the plain one covers (None: no context lookup)."""
    ctx = lookup_missing(sweep_name(init, True), results)
    if ctx is None:
        return None
    plain = lookup_missing(init, results)
    return [k for k in ctx if plain is None or k in plain]


def lookup_missing(init: str, results: str | pathlib.Path = "experiments/results/lookup"
                   ) -> list[str] | None:
    """The artifact kinds the saved lookup table has no table for (None: no lookup file). Targets
    may be swept one at a time, across sessions, so a lookup may cover only some."""
    path = pathlib.Path(results) / f"lookup_{init}.json"
    if not path.exists():
        return None
    tables = json.loads(path.read_text()).get("tables", {})
    return [k for k in ARTIFACT_KINDS if k not in tables]

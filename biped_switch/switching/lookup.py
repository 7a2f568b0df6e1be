"""Lookup tables from the sweeps: the success rate per distance bin for each (source, target) pair,
its best bin, and the files they are saved in. Every table is sized by a line-up
(`lineups.Lineup`: rows its policies in slot order, columns its targets in code order); the default
is the paper's, whose files and shapes (4 x 3) stay as they were."""

from __future__ import annotations

import json
import pathlib
import numpy as np
from biped_switch.lineups import PAPER_LINEUP, Lineup
from biped_switch.paths import LOOKUP as RESULTS
from biped_switch.stats import bin_counts
from biped_switch.switching.estimator import sweep_name


def target_slot(target: str, lineup: Lineup = PAPER_LINEUP) -> int:
    """The policy slot of the policy that crosses `target`, one of `lineup`'s targets."""
    return lineup.policy_of_code[lineup.target_index(target)]


def _lineup_flag(lineup: Lineup) -> str:
    """The `sweep` flag that picks `lineup` ("" for the paper's, the default)."""
    return "" if lineup == PAPER_LINEUP else f" --lineup {lineup.name}"


# ----------------------------------------------------------------------- lookup tables
def lookup_table(dist_m, label, source, target: str, bin_m: float = 0.01, max_m: float = 0.9,
                 lineup: Lineup = PAPER_LINEUP):
    """Success rate per switch-distance bin for each source policy -> `target`, and the argmax.

    Returns {"bins_m": bin lower edges, "rate": (P, nbins) NaN where empty, "count": (P, nbins),
    "best_m": (P,) centre of the best bin (NaN for the target itself or no data)}, P =
    `lineup.n_policies`. Ties go to the bin farthest from the artifact (the first maximum scanning
    from 0.9 m down)."""
    succ, count = bin_counts(dist_m, label, source, lineup.n_policies, bin_m,
                             int(round(max_m / bin_m)))
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = succ / count
    return table_from_rates(rate, count, target, bin_m, lineup=lineup)


def table_from_rates(rate, count, target: str, bin_m: float = 0.01,
                     lineup: Lineup = PAPER_LINEUP) -> dict:
    """`lookup_table`'s dict from its (P, nbins) rates and counts: the best bin per source. A
    lookup JSON stores rates and counts, so a target swept in an earlier session (whose data
    is gone) keeps its table when another target is swept."""
    rate, count = np.asarray(rate, float), np.asarray(count, float)
    if rate.shape[0] != lineup.n_policies or count.shape != rate.shape:
        raise ValueError(f"a {target} table of {rate.shape[0]} rows (counts {count.shape}) for "
                         f"line-up {lineup.name}'s {lineup.n_policies} policies {lineup.policies}")
    tgt = target_slot(target, lineup)
    nb = rate.shape[1]
    best = np.full(rate.shape[0], np.nan)
    for j in range(rate.shape[0]):
        if j == tgt or not np.any(count[j] > 0):
            continue
        r = np.where(count[j] > 0, rate[j], -1.0)[::-1]
        best[j] = (nb - 1 - int(np.argmax(r)) + 0.5) * bin_m
    return {"bins_m": np.arange(nb) * bin_m, "rate": rate, "count": count, "best_m": best}


def lookup_matrix(tables: dict, lineup: Lineup = PAPER_LINEUP) -> np.ndarray:
    """(P, T) best switch distance [m] for active -> target from per-target tables (P, T: the
    line-up's policies and targets; NaN for a target without a table)."""
    m = np.full((lineup.n_policies, lineup.n_targets), np.nan)
    for k, t in tables.items():
        i = lineup.target_index(k)  # a target of another line-up is an error, not a lost column
        if len(t["best_m"]) != lineup.n_policies:
            raise ValueError(f"a {k} table of {len(t['best_m'])} rows for line-up "
                             f"{lineup.name}'s {lineup.n_policies} policies {lineup.policies}")
        m[:, i] = t["best_m"]
    return m


def tables_from_data(data_by_target: dict, cfg, lineup: Lineup = PAPER_LINEUP) -> dict:
    tables = {}
    for target, d in data_by_target.items():
        at = d["offset"] == 0  # one row per sample
        tables[target] = lookup_table(d["switch_dist_m"][at], d["label"][at], d["source"][at],
                                      target, cfg.lookup_bin_m, cfg.switch_max_m, lineup=lineup)
    return tables


def save_lookup(tables: dict, init: str, out: pathlib.Path, meta: dict,
                lineup: Lineup = PAPER_LINEUP) -> dict:
    """Writes `lookup_<init>.json` (`init`: the sweep's name) into `out`; returns its document."""
    out.mkdir(parents=True, exist_ok=True)
    mat = lookup_matrix(tables, lineup)
    pols = lineup.policies
    doc = {"init": init, "best_m": {f"{pols[j]}->{k}": (None if np.isnan(mat[j, i])
                                                        else round(float(mat[j, i]), 3))
                                    for i, k in enumerate(lineup.targets)
                                    for j in range(lineup.n_policies)},
           "matrix_m": [[None if np.isnan(v) else float(v) for v in row] for row in mat],
           "tables": {k: {"rate": [[None if np.isnan(v) else round(float(v), 4) for v in r]
                                   for r in t["rate"]], "count": t["count"].astype(int).tolist()}
                      for k, t in tables.items()},
           "meta": meta}
    (out / f"lookup_{init}.json").write_text(json.dumps(doc, indent=1, default=str))
    return doc


def load_lookup(name: str, results: str | pathlib.Path = RESULTS,
                lineup: Lineup = PAPER_LINEUP) -> np.ndarray:
    """(P, T) switch distance matrix saved by the sweep `name` (`lookup_<name>.json`; NaN where
    not applicable); a file of another shape than `lineup`'s is an error."""
    path = pathlib.Path(results) / f"lookup_{name}.json"
    if not path.exists():
        raise FileNotFoundError(f"{path} missing: run `python -m biped_switch.sweep --init "
                                f"{name}{_lineup_flag(lineup)}`")
    m = json.loads(path.read_text())["matrix_m"]
    m = np.array([[np.nan if v is None else v for v in row] for row in m], float)
    if m.shape != (lineup.n_policies, lineup.n_targets):
        raise ValueError(f"{path}: a {m.shape} lookup, not line-up {lineup.name}'s "
                         f"({lineup.n_policies} policies x {lineup.n_targets} targets)")
    return m


def load_context_lookup(init: str, results: str | pathlib.Path = RESULTS,
                        lineup: Lineup = PAPER_LINEUP) -> tuple[np.ndarray, list[str]]:
    """(P, T) switch distances of the context sweep (`lookup_<init>_context[_<line-up>].json`),
    each target it has no table for taken from the plain lookup of the same line-up (the paper's:
    `lookup_<init>.json`; other line-ups have no plain sweep, so the context sweep must cover
    every target); and per target, the file used."""
    results = pathlib.Path(results)
    name, plain_name = sweep_name(init, True, lineup=lineup), sweep_name(init, lineup=lineup)
    if lookup_missing(name, results, lineup) is None:
        raise FileNotFoundError(f"{results / f'lookup_{name}.json'} missing: run "
                                f"`python -m biped_switch.sweep --init {init} --context"
                                f"{_lineup_flag(lineup)}`")
    m, missing = load_lookup(name, results, lineup), lookup_missing(name, results, lineup)
    if missing and lookup_missing(plain_name, results, lineup) is None:
        raise FileNotFoundError(
            f"{results / f'lookup_{name}.json'} has no table for {missing} and there is no "
            f"{results / f'lookup_{plain_name}.json'} to take them from: run `python -m "
            f"biped_switch.sweep --init {init} --context{_lineup_flag(lineup)} --targets "
            f"{' '.join(missing)}`")
    plain = load_lookup(plain_name, results, lineup) if missing else None
    used = []
    for i, k in enumerate(lineup.targets):
        if k in missing:
            m[:, i] = plain[:, i]
        used.append(f"{k}: {results / f'lookup_{plain_name if k in missing else name}.json'}")
    return m, used


def context_lookup_missing(init: str, results: str | pathlib.Path = RESULTS,
                           lineup: Lineup = PAPER_LINEUP) -> list[str] | None:
    """Targets neither the context lookup nor the plain one covers (None: no context lookup)."""
    ctx = lookup_missing(sweep_name(init, True, lineup=lineup), results, lineup)
    if ctx is None:
        return None
    plain = lookup_missing(sweep_name(init, lineup=lineup), results, lineup)
    return [k for k in ctx if plain is None or k in plain]


def lookup_missing(name: str, results: str | pathlib.Path = RESULTS,
                   lineup: Lineup = PAPER_LINEUP) -> list[str] | None:
    """The line-up's targets the saved lookup table `lookup_<name>.json` (`name`: the sweep's)
    has no table for (None: no lookup file). Targets may be swept one at a time, across
    sessions, so a lookup may cover only some."""
    path = pathlib.Path(results) / f"lookup_{name}.json"
    if not path.exists():
        return None
    tables = json.loads(path.read_text()).get("tables", {})
    return [k for k in lineup.targets if k not in tables]

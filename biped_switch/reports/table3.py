"""Table III: hours to add a new terrain type to a suite, read from the recorded logs
(`evaluate retrain-cost`).

Nothing is trained here: the hours are the wall-clock times that the training runs' progress.json
(runs.run_record), the sweeps' lookup-table metadata and the estimators' training logs recorded.
"""

from __future__ import annotations

import json
import pathlib

import numpy as np

from biped_switch import paper
from biped_switch.reports import provenance as prov
from biped_switch.learning import runs as runs_lib
from biped_switch.config import SETUP_SUITE
from biped_switch.names import ARTIFACT_KINDS
from biped_switch.paths import WHEN_DIR


def retrain_cost(runs: pathlib.Path, results: pathlib.Path, init: str = "stand",
                 when_dir: pathlib.Path = WHEN_DIR) -> dict:
    """Table III from recorded logs: hours to add a new terrain to a two-behaviour suite.

    ours: one new policy (the mean training wall time of the artifact policies) plus, for each
    of the three policies' switch estimators, its sweep and its training; DQN: the new policy
    plus retraining the selector (the paper's 25 h = 17 h policy + 8 h selector); end-to-end:
    retraining the single policy. A missing log leaves the row's total empty and says what is
    missing; a row built from unfinished, stand-in or pipeline-check runs says so in `status`."""
    rows, missing = [], []
    pol_r = {}
    for p in ARTIFACT_KINDS:  # the artifact policies
        r = runs_lib.run_record(runs_lib.find_policy(p, init, runs))
        if r is None:
            missing.append(f"policy {p}_{init}")
        else:
            pol_r[p] = r
    policy_h = np.mean([v["wall_s"] for v in pol_r.values()]) / 3600 if pol_r else None
    pol_notes = [n for v in pol_r.values() for n in v["notes"]]
    sweep_h, est_h, data_notes = {}, {}, []
    lookup = results / "lookup" / f"lookup_{init}.json"
    lmeta = json.loads(lookup.read_text())["meta"] if lookup.exists() else {}
    sweeps = lmeta.get("sweeps", {})
    for k in ARTIFACT_KINDS:
        if k in sweeps:
            sweep_h[k] = sweeps[k]["wall_s"] / 3600
            if any("stand-in" in str(v) for v in lmeta.get("policies", {}).get(k, {}).values()):
                data_notes.append(f"sweep {k} ran stand-in policies")
        else:
            missing.append(f"sweep {init}/{k}")
        e = results / "estimators" / f"{init}_{k}.json"
        if e.exists():
            est_h[k] = json.loads(e.read_text())["metrics"]["train_s"] / 3600
        else:
            missing.append(f"estimator {init}_{k}")
    if "PIPELINE_CHECK" in lmeta:
        data_notes.append(f"lookup/sweeps: {lmeta['PIPELINE_CHECK']}")
    ours_parts = {"new policy": policy_h, **{f"sweep {k}": v for k, v in sweep_h.items()},
                  **{f"estimator {k}": v for k, v in est_h.items()}}
    ours_ok = (policy_h is not None and len(sweep_h) == len(ARTIFACT_KINDS)
               and len(est_h) == len(ARTIFACT_KINDS))
    devices = sorted({v["device"] for v in pol_r.values()})

    def status(notes, ok):
        return "not measured" if not ok else ("; ".join(notes) if notes else "complete")

    rows.append({"method": "ours", "hours": sum(ours_parts.values()) if ours_ok else None,
                 "parts": ours_parts, "device": ", ".join(devices) or "?",
                 "status": status(pol_notes + data_notes, ours_ok),
                 "paper_hours": paper.TABLE3_H["ours"]})
    # ours + setup: the same, plus every trained setup policy (one per target with thin overlap;
    # adding a behaviour adds at most its own setup policy and retrains those whose sources
    # it joins: still linear in behaviours, where the DQN and end-to-end retrain on everything)
    setup_r = {n: runs_lib.run_record(runs_lib.find_policy(n, init, runs))
               for n in SETUP_SUITE}
    setup_r = {n: r for n, r in setup_r.items() if r is not None}
    setup_parts = {**ours_parts, **{n: r["wall_s"] / 3600 for n, r in setup_r.items()}}
    setup_notes = pol_notes + data_notes + [x for r in setup_r.values() for x in r["notes"]]
    if setup_r:
        rows.append({"method": "ours_setup",
                     "hours": sum(setup_parts.values()) if ours_ok else None, "parts": setup_parts,
                     "setup_env_steps": {n: r["step"] for n, r in setup_r.items()},
                     "device": ", ".join(sorted({r["device"] for r in setup_r.values()})),
                     "status": status(setup_notes, ours_ok),
                     "paper_hours": paper.TABLE3_H["ours"]})
    # ours with the learned when rule: the new policy, its context sweeps with approach records
    # and the rule's training, in place of the paper's sweeps and estimators
    when_meta = pathlib.Path(when_dir) / init / "meta.json"
    if when_meta.exists():
        wm = json.loads(when_meta.read_text())
        parts = {"new policy": policy_h,
                 **{f"when sweep {k}": v["wall_s"] / 3600 for k, v in wm["sweeps"].items()},
                 "when rule": (wm["train_s"] + wm.get("data_s", 0.0)) / 3600}
        ok = policy_h is not None and all(v is not None for v in parts.values())
        rows.append({"method": "ours_learned", "hours": sum(parts.values()) if ok else None,
                     "parts": parts, "device": wm.get("device", "?"),
                     "status": status(pol_notes, ok), "paper_hours": paper.TABLE3_H["ours"]})
    dqn_dir = runs_lib.find_dqn(runs, init)
    dqn = runs_lib.run_record(runs_lib.latest_checkpoint(dqn_dir) if dqn_dir else None)
    if dqn is None:
        missing.append(f"DQN run dqn_{init}")
    dqn_ok = dqn is not None and policy_h is not None
    rows.append({"method": "dqn", "hours": policy_h + dqn["wall_s"] / 3600 if dqn_ok else None,
                 "parts": {"new policy": policy_h, "selector": dqn["wall_s"] / 3600 if dqn else None},
                 "device": dqn["device"] if dqn else "?",
                 "status": status(pol_notes + (dqn["notes"] if dqn else []), dqn_ok),
                 "paper_hours": paper.TABLE3_H["dqn"]})
    e2e = runs_lib.run_record(runs_lib.find_policy("mixed", init, runs))
    if e2e is None:
        missing.append(f"end-to-end run mixed_{init}")
    rows.append({"method": "end_to_end", "hours": e2e["wall_s"] / 3600 if e2e else None,
                 "parts": {"policy": e2e["wall_s"] / 3600 if e2e else None},
                 "device": e2e["device"] if e2e else "?",
                 "status": status(e2e["notes"] if e2e else [], e2e is not None),
                 "paper_hours": paper.TABLE3_H["end_to_end"]})
    # compose, then distil (learning/distillation.py): the suite with its setup policies, plus
    # distilling it again into one student
    stu = runs_lib.run_record(runs_lib.find_policy("student", init, runs))
    if stu is None:
        missing.append(f"distilled student run student_{init}")
    elif setup_r:
        parts = {**setup_parts, "distillation": stu["wall_s"] / 3600}
        rows.append({"method": "distilled", "hours": sum(parts.values()) if ours_ok else None,
                     "parts": parts, "distill_env_steps": stu["step"], "device": stu["device"],
                     "status": status(setup_notes + stu["notes"], ours_ok), "paper_hours": None})
    return {"rows": rows, "missing": missing, "init": init, "runs": str(runs), "results": str(results),
            "notes": "hours of wall-clock time read from progress.json / sweep and estimator logs"}


def table3_markdown(doc: dict) -> str:
    lines = ["| method | hours (ours) | parts [h] | device | status | paper [h, CPU] |",
             "|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        parts = ", ".join(f"{k} {v:.2f}" if v is not None else f"{k} -" for k, v in r["parts"].items())
        h = f"{r['hours']:.2f}" if r["hours"] is not None else "not measured"
        lines.append(f"| {r['method']} | {h} | {parts} | {r['device']} | {r.get('status', '?')} | "
                     f"{'-' if r['paper_hours'] is None else format(r['paper_hours'], '.0f')} |")
    if doc["missing"]:
        lines.append("")
        lines.append("missing logs: " + "; ".join(doc["missing"]))
    return "\n".join(lines)


def hours_cell(v) -> str:
    """Hours as a table cell: "n/a" for None, minutes or seconds beside small values."""
    if v is None:
        return "n/a"
    if v >= 0.1:
        return f"{v:.2f}"
    return f"{v:.2f} ({60 * v:.1f} min)" if v >= 1 / 60 else f"{v:.4f} ({3600 * v:.1f} s)"


def table3_rows(doc: dict, checks: dict | None = None):
    """(headers, rows) of a table3.json. Per method: total hours (n/a unless every part was
    measured), the measured parts' sum; with `checks` (table3_checks), a column saying whether the
    hours come from complete real runs."""
    headers = ["method", "our hours"] + (["hours from"] if checks is not None else []) + [
        "measured parts (sum)", "parts not measured", "paper hours", "device"]
    rows = []
    for r in doc["rows"]:
        ref = r.get("paper_hours", paper.TABLE3_H.get(r["method"]))
        parts = r.get("parts") or {}
        known = [v for v in parts.values() if v is not None]
        src = []
        if checks is not None:
            notes = checks.get(r["method"]) or []
            src = ["-" if not known and r.get("hours") is None else
                   "PIPELINE CHECK" if any("pipeline" in n for n in notes) else
                   "UNFINISHED RUNS" if notes else "complete runs"]
        rows.append([r["method"], hours_cell(r.get("hours"))] + src + [
                     (f"{len(known)}/{len(parts)}" + (f" ({hours_cell(sum(known))})" if known else ""))
                     if parts else "-",
                     ", ".join(k for k, v in parts.items() if v is None) or "-",
                     "-" if ref is None else f"{ref:g}", r.get("device") or "not recorded"])
    return headers, rows


def table3_parts_rows(doc: dict):
    """(headers, rows): one row per measured or missing part of each method."""
    headers = ["method", "part", "hours"]
    return headers, [[r["method"], k, hours_cell(v)] for r in doc["rows"]
                     for k, v in (r.get("parts") or {}).items()]


def _run_dir(ckpt) -> pathlib.Path | None:
    return None if ckpt is None else pathlib.Path(ckpt).parent.parent


def table3_checks(doc: dict, results, runs) -> tuple[pathlib.Path, dict]:
    """(the runs root, {method: notes}) of a Table III file: why each method's measured hours are
    not those of complete, real training runs ([] when they are, or when nothing was measured).

    A row's notes are its recorded `status` when the file has one for it (retrain_cost writes it;
    "not measured" does not count), else the `run_notes` of the runs behind its measured parts,
    found again as retrain_cost finds them (runs.find_policy / find_dqn) under the file's recorded
    runs root (relative paths from the repository root), else `runs`. Sweep and estimator hours of
    a pipeline-check results root, or of sweeps smaller than the paper's, are noted too."""
    results = pathlib.Path(results)
    init = doc.get("init") or "stand"
    runs = prov.repo_path(doc["runs"]) if doc.get("runs") else pathlib.Path(runs)
    pols = [_run_dir(runs_lib.find_policy(k, init, runs)) for k in ARTIFACT_KINDS]
    deps = {"new policy": pols, "selector": [runs_lib.find_dqn(runs, init)],
            "policy": [_run_dir(runs_lib.find_policy("mixed", init, runs))]}
    lookup = results / "lookup" / f"lookup_{init}.json"
    try:
        sweeps = (json.loads(lookup.read_text()).get("meta") or {}).get("sweeps") or {}
    except (OSError, ValueError):
        sweeps = {}
    checks = {}
    for r in doc["rows"]:
        parts, notes = r.get("parts") or {}, []
        measured = [k for k, v in parts.items() if v is not None]
        if not measured and r.get("hours") is None:
            checks[r["method"]] = notes
            continue
        status = r.get("status")  # "not measured" (a part missing) says nothing about the others
        own = status in (None, "not measured")
        if not own and status != "complete":
            notes += [n.strip() for n in str(status).split(";") if n.strip()]
        if own and not parts:
            notes.append("no parts recorded: its runs cannot be checked")
        for k in measured:
            if k in deps and own:
                found = [d for d in deps[k] if d is not None]
                if not found:
                    notes.append(f"{k}: no run under {prov.rel(runs)}/ or models/ (cannot tell "
                                 "whether it finished)")
                notes += [f"{d.name}: {n}" for d in found for n in runs_lib.run_notes(d)]
            if k.startswith(("sweep", "estimator")) and prov.is_pipeline_check(results):
                notes.append(f"{k}: from a pipeline-check results root")
            if k.startswith("sweep ") and k[6:] in sweeps:
                n_pts = sweeps[k[6:]].get("points", 0)
                if n_pts < paper.SWEEP_POINTS:
                    notes.append(f"{k}: {n_pts:,} points (paper: {paper.SWEEP_POINTS:,})")
        checks[r["method"]] = list(dict.fromkeys(notes))
    return runs, checks


def table3_provenance(doc: dict, path, results, runs, print_fn=print) -> list[str]:
    """Prints where each method's hours come from (runs, their steps and curriculum, devices, the
    parts not measured) and the verdict: complete real training runs, or a pipeline check /
    unfinished runs / missing parts. `runs`: as in `table3_checks`."""
    results = pathlib.Path(results)
    runs, checks = table3_checks(doc, results, runs)
    print_fn(f"file: {prov.rel(path)}   init: {doc.get('init', 'not recorded')}")
    print_fn(f"  runs: {prov.rel(runs)}" + ("" if doc.get("runs") else
                                            " (not recorded in the file: the runs root of the "
                                            "recompute command)"))
    print_fn(f"  results: {prov.fmt(doc.get('results'))}   notes: "
             f"{doc.get('notes') or 'none recorded'}")
    for r in doc["rows"]:
        print_fn(f"  {r['method']}: {hours_cell(r.get('hours'))} h on "
                 f"{r.get('device') or 'not recorded'}, status {r.get('status', 'not recorded')}")
        for n in checks.get(r["method"]) or []:
            print_fn(f"    - {n}")
    for m in doc.get("missing") or []:
        print_fn("  missing:", m)
    reasons = []
    if prov.is_pipeline_check(results):
        reasons.append(f"the results root {prov.rel(results)} is a pipeline check")
    flagged = [m for m, n in checks.items() if n]
    if flagged:
        reasons.append("hours of " + ", ".join(flagged) + " are from pipeline-check, unfinished or "
                       "unverified runs (listed above), not complete training runs")
    incomplete = [r["method"] for r in doc["rows"] if r.get("hours") is None]
    if incomplete:
        reasons.append("no total hours for " + ", ".join(incomplete) + " (parts not measured)")
    return prov.conclude(doc, reasons, print_fn=print_fn,
                         ok="every method's hours come from complete training runs "
                            "(step goal reached, curriculum finished), outside any pipeline check.")

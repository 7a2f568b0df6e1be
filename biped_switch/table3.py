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
from biped_switch import runs as runs_lib
from biped_switch.terrain import ARTIFACT_KINDS


def retrain_cost(runs: pathlib.Path, results: pathlib.Path, init: str = "stand") -> dict:
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
    return {"rows": rows, "missing": missing, "init": init, "runs": str(runs), "results": str(results),
            "notes": "hours of wall-clock time read from progress.json / sweep and estimator logs"}


def table3_markdown(doc: dict) -> str:
    lines = ["| method | hours (ours) | parts [h] | device | status | paper [h, CPU] |",
             "|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        parts = ", ".join(f"{k} {v:.2f}" if v is not None else f"{k} -" for k, v in r["parts"].items())
        h = f"{r['hours']:.2f}" if r["hours"] is not None else "not measured"
        lines.append(f"| {r['method']} | {h} | {parts} | {r['device']} | {r.get('status', '?')} | "
                     f"{r['paper_hours']:.0f} |")
    if doc["missing"]:
        lines.append("")
        lines.append("missing logs: " + "; ".join(doc["missing"]))
    return "\n".join(lines)

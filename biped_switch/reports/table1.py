"""Table I as tables: Markdown, notes, the paper's rows and provenance. Plain Python, no JAX."""

from __future__ import annotations

import math
from biped_switch import paper
from biped_switch.reports import provenance as prov
from biped_switch.stats import dist_success_cells, pct_ci_cell


def curriculum_cell(c: dict, r: dict | None = None) -> str:
    """A checkpoint's curriculum as 'stage d=.. g=.. p=..' (fine guide levels kept: 0.025), and
    how it ended when the row says (a push plateau holds the level below: curriculum.py)."""
    cell = (f"{c.get('stage_name', '?')} d={c.get('difficulty', math.nan):.1f} "
            f"g={round(c.get('guide_scale', math.nan), 3)} p={round(c.get('push_scale', 0.0), 3)}")
    r = r or {}
    if r.get("curriculum_end") == "push plateau":
        cell += f", done on a push plateau (holds p={round(float(r['push_held']), 3)})"
    elif r.get("curriculum_done"):
        cell += ", done"
    elif r.get("curriculum_done") is False:
        cell += ", in training"
    return cell


def hours_cell(r: dict) -> str:
    """Training hours on the run's own hardware (progress.json's wall_s), '-' when unknown."""
    return "-" if r.get("train_h") is None else f"{r['train_h']:.2f}"


def table1_markdown(rows: list[dict]) -> str:
    lines = ["| policy | init | trials | % total dist. (95% CI) | % success (95% CI) | paper dist. | "
             "paper success | trained steps | train h | curriculum | speed m/s (95% CI) | "
             "horizon s | track seed | backend |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        pd, ps = paper_row(r)
        c = r["curriculum"]
        speed = (f"{r['speed_mps']:.2f} ({r['speed_ci'][0]:.2f}-{r['speed_ci'][1]:.2f})"
                 if "speed_mps" in r else "-")
        horizon = f"{r['horizon_s']:g}" if r.get("horizon_s") is not None else "-"
        lines.append(
            f"| {r['policy']} | {r['init']} | {r['n']} | {dist_success_cells(r)} | {pd} | {ps} | "
            f"{r['train_step']:,} | {hours_cell(r)} | {curriculum_cell(c, r)} | "
            f"{speed} | {horizon} | {r.get('track_seed', '-')} | {r.get('backend', '-')} |")
    notes = table1_notes(rows)
    return "\n".join(lines + ([""] + [f"- {n}" for n in notes] if notes else []))


def table1_notes(rows: list[dict]) -> list[str]:
    """The table's notes: each policy's warm start (a deviation from training from scratch;
    `train --warm-start`, omitted = from scratch) and each curriculum that ended on a push
    plateau (a deviation from pushes grown to the full scale: curriculum.py)."""
    notes = []
    for r in rows:
        name = f"{r['policy']}/{r['init']}"
        if r.get("warm_start"):
            notes.append(f"{name} was warm-started from {r['warm_start']} (its parameters and "
                         "normaliser; `train` without `--warm-start` trains from scratch)")
        if r.get("curriculum_end") == "push plateau":
            notes.append(f"{name}'s push stage ended on a plateau: it holds push "
                         f"{float(r['push_held']):.2f} of the full scale "
                         f"({r.get('full_push', '?')}), not 1")
    return notes


def paper_row(r: dict):
    """The paper's (% distance, % success) of a Table I row's policy and init, ("-", "-") when the
    paper has none."""
    ref = paper.TABLE1.get(r["policy"], {}).get(r["init"])
    return (ref.distance_pct, ref.success_pct) if ref else ("-", "-")


def table1_rows(doc: dict):
    """(headers, rows) of a table1.json as the notebook prints it: ours beside the paper's."""
    headers = ["policy", "init", "trials", "% dist. (95% CI)", "paper % dist.",
               "% success (95% CI)", "paper % success", "% fell", "trained steps", "train h",
               "curriculum"]
    rows = []
    for r in doc["rows"]:
        pd, ps = paper_row(r)
        c = r.get("curriculum") or {}
        rows.append([r["policy"], r["init"], r["n"], pct_ci_cell(r["distance_pct"], r.get("distance_ci")),
                     pd, pct_ci_cell(r["success_pct"], r.get("success_ci")),
                     ps, f"{r.get('fell_pct', math.nan):.1f}", f"{r.get('train_step', 0):,}",
                     hours_cell(r), curriculum_cell(c, r)])
    return headers, rows


def table1_provenance(doc: dict, path, print_fn=print) -> list[str]:
    """Prints where a table1.json's rows come from (settings, each row's checkpoint and
    curriculum) and its verdict; returns the reasons it is a pipeline check ([] if none)."""
    s, rows = doc.get("settings", {}), doc["rows"]
    print_fn(f"file: {prov.rel(path)}")
    for k in ("trials", "seed", "horizon_s", "runs"):
        print_fn(f"  {k}: {prov.fmt(s.get(k))}")
    print_fn(f"  device: {prov.fmt(doc.get('device'))}")
    reasons, stand_in, unfinished = [], [], []
    for r in rows:
        c = r.get("curriculum") or {}
        print_fn(f"  {r['policy']}/{r['init']}: {r.get('checkpoint')} (step {r.get('train_step', 0):,}, "
                 f"curriculum {c.get('stage_name')} difficulty {prov.fmt(c.get('difficulty'))} "
                 f"guide_scale {prov.fmt(c.get('guide_scale'))} push_scale "
                 f"{prov.fmt(c.get('push_scale'))})")
        if "stand-in" in str(r.get("checkpoint", "")):
            stand_in.append(f"{r['policy']}/{r['init']}")
        if (c.get("guide_scale") or 0) > 0 or c.get("stage_name") not in (None, "pushes"):
            unfinished.append(f"{r['policy']}/{r['init']} ({c.get('stage_name')}, guide_scale "
                              f"{prov.fmt(c.get('guide_scale'))})")
    if stand_in:
        reasons.append("stand-in policies: " + ", ".join(stand_in))
    if unfinished:
        reasons.append("policies not through their curriculum: " + ", ".join(unfinished))
    return prov.conclude(doc, reasons, rows, paper.TRIALS["table1"], "row", print_fn=print_fn)

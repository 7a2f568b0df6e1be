"""What a results file says about where its numbers come from: pipeline-check labels, stand-in
policies, and the one verdict line every result notebook prints (table1, table2, table3, fig4b,
runs and estimator build their provenance from these). Plain Python.
"""

from __future__ import annotations

import pathlib
from typing import Callable, Iterable

from biped_switch.paths import REPO, rel, repo_path  # noqa: F401  (re-exported)


def is_pipeline_check(path) -> bool:
    """Whether `path` lies in a pipeline-check tree: any folder named pipeline_check (e.g. the
    results and runs of one's own check of the pipeline with untrained or stand-in policies)."""
    return "pipeline_check" in pathlib.Path(path).resolve().parts


def stand_ins(sources: Iterable[str]) -> list[str]:
    """The policy sources that are stand-ins ("stand-in for <policy>: ...")."""
    return [s for s in sources if str(s).startswith("stand-in")]


def pipeline_label(doc: dict) -> str | None:
    """The "PIPELINE_CHECK" note a results file carries (top level, settings or meta), if any."""
    for d in (doc, doc.get("settings") or {}, doc.get("meta") or {}):
        for k in ("PIPELINE_CHECK", "pipeline_check"):
            if isinstance(d, dict) and d.get(k):
                return str(d[k])
    return None


def fmt(v) -> str:
    """A recorded setting as printed ("not recorded" for None)."""
    if v is None:
        return "not recorded"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def verdict(reasons: list[str], ok: str | None = None) -> str:
    """One line saying whether the file can be read as a result, or why not (stand-ins, guide
    forces, too few trials, unfinished runs)."""
    if reasons:
        return "VERDICT: NOT A FINAL RESULT: " + "; ".join(reasons) + "."
    return "VERDICT: " + (ok or "no pipeline-check markers (no stand-ins, no guide forces, the "
                          "paper's trial count).")


def conclude(doc: dict, reasons: list[str], rows=None, paper_trials: int = 0, per: str = "",
             ok: str | None = None, print_fn: Callable = print) -> list[str]:
    """Adds the file's own pipeline-check label (and, for a table's `rows`, fewer trials per `per`
    than the paper's `paper_trials`) to `reasons`, prints the verdict line (`ok`: its text when
    there is no reason) and returns the reasons."""
    if rows is not None:
        n = min((r["n"] for r in rows), default=0)
        if n < paper_trials:
            reasons.append(f"{n} trials per {per} (paper: {paper_trials})")
    lab = pipeline_label(doc)
    if lab:
        print_fn(f"  labelled PIPELINE_CHECK: {lab}")
        reasons.insert(0, f"labelled so ({lab})")
    print_fn(verdict(reasons, ok))
    return reasons


"""Table II as tables: failures by context, switch outcomes, the paper's claims, Markdown and provenance. Plain Python and NumPy, no JAX."""

from __future__ import annotations

import math
import numpy as np
from biped_switch import paper
from biped_switch.reports import provenance as prov
from biped_switch.names import ARTIFACT_KINDS, HEURISTICS
from biped_switch.kinds import KIND, POLICY_NAMES, policy_for
from biped_switch.config import default_env_config
from biped_switch.stats import dist_success_cells, pct_ci, pct_ci_cell


def _reached(track, progress_frac: float, detect_range_m: float) -> tuple[float, list[int]]:
    """(x [m] of the trial's end, the indices of the artifacts whose detection zone it entered).
    Positions come from `progress_frac` along start -> finish line (the start taken at x = 0:
    a few cm off)."""
    x = float(progress_frac) * track.finish_x_m
    return x, [k for k, (_, a0, _) in enumerate(track.artifacts) if a0 - detect_range_m <= x]


def suite_ceiling(table1_rows: list[dict], tracks, init: str = "stand",
                  artifacts_per_trial: int = 7) -> dict:
    """The success a suite with perfect transitions would reach on `tracks`: each artifact
    crossed by its own policy with the per-artifact success that policy shows on its own terrain
    in Table I (success ** (1 / artifacts_per_trial) of its Table I trials, artifacts taken as
    independent), a track's success the product over its artifacts, averaged over the tracks.
    The interval takes every policy at its Table I success CI's lower, then upper, bound. What
    is left between a row and this ceiling is lost in the transitions."""
    per = {}
    for r in table1_rows:
        if r.get("init") == init and r.get("policy") in ARTIFACT_KINDS:
            per[r["policy"]] = [(v / 100.0) ** (1.0 / artifacts_per_trial)
                                for v in (r["success_pct"], *r["success_ci"])]
    missing = [k for k in ARTIFACT_KINDS if k not in per]
    if missing:
        raise ValueError(f"Table I has no {init}-init row for {missing}: no ceiling")
    counts = np.array([[sum(1 for a in t.artifacts if a[0] == k) for k in ARTIFACT_KINDS]
                       for t in tracks], float)
    out = []
    for j in range(3):  # estimate, low, high
        p = np.array([per[k][j] for k in ARTIFACT_KINDS])
        out.append(100.0 * float(np.mean(np.prod(p[None, :] ** counts, axis=1))))
    return {"ceiling_pct": out[0], "ceiling_ci": out[1:],
            "per_artifact_success_pct": {k: 100.0 * per[k][0] for k in ARTIFACT_KINDS},
            "artifacts_per_track": {k: float(counts[:, i].mean())
                                    for i, k in enumerate(ARTIFACT_KINDS)},
            "tracks": len(tracks), "init": init}


def ceiling_markdown(ceil: dict, rows: list[dict]) -> str:
    """The ceiling and each row's distance from it [points]."""
    lo, hi = ceil["ceiling_ci"]
    per = ", ".join(f"{k} {v:.2f}%" for k, v in ceil["per_artifact_success_pct"].items())
    lines = [f"Ceiling of a perfect-transition suite on these {ceil['tracks']:,} tracks: "
             f"**{ceil['ceiling_pct']:.1f}%** ({lo:.1f}-{hi:.1f}), from Table I's {ceil['init']}-"
             f"init policies on their own terrain (per artifact: {per}).", "",
             "| method | % success | below the ceiling [points] |", "|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['success_pct']:.1f} | "
                     f"{ceil['ceiling_pct'] - r['success_pct']:.1f} |")
    return "\n".join(lines)


def failures_by_context(tracks, progress_frac, fell, fail_kind,
                        detect_range_m: float | None = None) -> dict:
    """{kind: {previous kind or "start": [reached, fell on it]}} over trials on `tracks`.

    Why a row fails, by where: an artifact is reached when the body came within `detect_range_m`
    of its start; a trial that fell is charged to the last artifact it reached if the env blamed
    that artifact's kind (`fail_kind`, env.blame_kind). `detect_range_m` defaults to the env's
    detection range."""
    if detect_range_m is None:
        detect_range_m = float(default_env_config().detect_range_m)
    out = {k: {} for k in ARTIFACT_KINDS}
    for i, t in enumerate(tracks):
        arts = t.artifacts
        _, reached = _reached(t, progress_frac[i], detect_range_m)
        charged = _charged_fall(t, progress_frac[i], fell[i], fail_kind[i], detect_range_m)
        for k in reached:
            kind, prev = arts[k][0], ("start" if k == 0 else arts[k - 1][0])
            cell = out[kind].setdefault(prev, [0, 0])
            cell[0] += 1
            cell[1] += int(charged is not None and charged[0] == k)
    return out


def _charged_fall(track, progress_frac: float, fell: float, fail_kind: int,
                  detect_range_m: float) -> tuple[int, float] | None:
    """(index of the artifact a fall is charged to, x [m] of the trial's end), or None: a trial
    that fell is charged to the last artifact it reached if the env blamed that artifact's kind."""
    x, reached = _reached(track, progress_frac, detect_range_m)
    if not reached or fell < 0.5:
        return None
    k = reached[-1]
    return (k, x) if int(fail_kind) == ARTIFACT_KINDS.index(track.artifacts[k][0]) else None


def fall_positions(tracks, progress_frac, fell, fail_kind, detect_range_m: float | None = None
                   ) -> dict:
    """{kind: {"before", "on", "after": falls, "x_m": [each fall's x - the artifact's start]}}:
    where on the artifact each fall charged to it (as `failures_by_context` charges them) ended:
    on its approach, on it (start to end), or past its end."""
    if detect_range_m is None:
        detect_range_m = float(default_env_config().detect_range_m)
    out = {k: {"before": 0, "on": 0, "after": 0, "x_m": []} for k in ARTIFACT_KINDS}
    for i, t in enumerate(tracks):
        charged = _charged_fall(t, progress_frac[i], fell[i], fail_kind[i], detect_range_m)
        if charged is None:
            continue
        kind, a0, a1 = t.artifacts[charged[0]]
        x = charged[1]
        cell = out[kind]
        cell["before" if x < a0 else "on" if x <= a1 else "after"] += 1
        cell["x_m"].append(round(x - a0, 3))
    return out


def fall_positions_markdown(by_method: dict) -> str:
    lines = ["Where the falls charged to an artifact ended: on its approach, on it, or past its "
             "end (the body's x at the end, from the trial's progress), and the median x [m] "
             "from the artifact's start.", "",
             "| method | " + " | ".join(f"{k}: before / on / after (median m)" for k in ARTIFACT_KINDS)
             + " |", "|---" * (len(ARTIFACT_KINDS) + 1) + "|"]
    for m, d in by_method.items():
        lines.append(f"| {m} | " + " | ".join(
            f"{d[k]['before']} / {d[k]['on']} / {d[k]['after']} "
            f"({np.median(d[k]['x_m']):.2f})" if d[k]["x_m"] else "0 / 0 / 0 (-)"
            for k in ARTIFACT_KINDS) + " |")
    return "\n".join(lines)


def policy_on_falls(tracks, progress_frac, fell, fail_kind, active_at_start,
                    detect_range_m: float | None = None) -> dict:
    """{kind: {"falls", "wrong_policy", "before_start"}}: the falls charged to an artifact (as
    `failures_by_context` charges them), those where another policy than the artifact's was
    acting as the CoM came over its start (a missed or wrong detection: with the oracle the 1 cm
    force rules that out), and those before its start was reached."""
    if detect_range_m is None:
        detect_range_m = float(default_env_config().detect_range_m)
    out = {k: {"falls": 0, "wrong_policy": 0, "before_start": 0} for k in ARTIFACT_KINDS}
    for i, t in enumerate(tracks):
        charged = _charged_fall(t, progress_frac[i], fell[i], fail_kind[i], detect_range_m)
        if charged is None:
            continue
        k = charged[0]
        kind = t.artifacts[k][0]
        cell = out[kind]
        cell["falls"] += 1
        on = int(active_at_start[i][k])
        if on < 0:
            cell["before_start"] += 1
        elif on != policy_for(kind):
            cell["wrong_policy"] += 1
    return out


def policy_on_falls_markdown(by_method: dict) -> str:
    lines = ["Falls on an artifact, and how many came with another policy than the artifact's "
             "acting as the body came over its start (a missed or wrong detection), or before "
             "the start was reached.", "",
             "| method | " + " | ".join(f"{k}: falls / wrong policy / before start"
                                       for k in ARTIFACT_KINDS) + " |",
             "|---" * (len(ARTIFACT_KINDS) + 1) + "|"]
    for m, d in by_method.items():
        lines.append(f"| {m} | " + " | ".join(
            f"{d[k]['falls']} / {d[k]['wrong_policy']} / {d[k]['before_start']}"
            for k in ARTIFACT_KINDS) + " |")
    return "\n".join(lines)


def switch_outcomes(tracks, switch_ahead_m, progress_frac, fell, fail_kind,
                    detect_range_m: float | None = None, switch_output=None,
                    switch_forced=None) -> list[dict]:
    """One record per switch into an artifact's policy: {"kind", "prev" (the artifact before it, or
    "start"), "ahead_m" (CoM to its start when switched), "outcome": "fell" (the trial fell on
    this artifact, as `failures_by_context` charges it), "crossed" (the CoM passed its end) or
    "open" (time ran out first)}. Trials are `tracks` (terrain.Track, trial order). With the
    rollout's logs (`switch_output`, `switch_forced`, per trial and slot), also "output" (the
    rule's model output there) and "forced"."""
    if detect_range_m is None:
        detect_range_m = float(default_env_config().detect_range_m)
    out = []
    for i, t in enumerate(tracks):
        arts = t.artifacts
        x, reached = _reached(t, progress_frac[i], detect_range_m)
        last = reached[-1] if reached else -1
        for k, (kind, _, a1) in enumerate(arts):
            ahead = float(switch_ahead_m[i][k])
            if np.isnan(ahead):
                continue
            fell_here = (k == last and fell[i] > 0.5
                         and int(fail_kind[i]) == ARTIFACT_KINDS.index(kind))
            rec = {"kind": kind, "prev": "start" if k == 0 else arts[k - 1][0], "ahead_m": ahead,
                   "outcome": "fell" if fell_here else ("crossed" if x > a1 else "open")}
            if switch_output is not None:
                rec["output"] = float(switch_output[i][k])
            if switch_forced is not None:
                rec["forced"] = bool(switch_forced[i][k])
            out.append(rec)
    return out


def switch_summary(records: list[dict], forced_m: float = 0.01) -> dict:
    """{kind: {prev: {"n", "ahead_m_q" (quartiles [m]), "forced_pct" (switched within
    `forced_m`: the rule never fired), "lost_pct" (fell on it), "lost_by_ahead": [[bin lo, bin hi,
    n, fell], ...] (0.1 m bins)}}."""
    out = {}
    for kind in ARTIFACT_KINDS:
        for prev in sorted({r["prev"] for r in records if r["kind"] == kind},
                           key=lambda q: (q != "start", q)):
            rs = [r for r in records if r["kind"] == kind and r["prev"] == prev]
            ahead = np.array([r["ahead_m"] for r in rs])
            lost = np.array([r["outcome"] == "fell" for r in rs])
            edges = np.round(np.arange(0.0, 1.0, 0.1), 2)
            # the first bin takes the forced switches a step past the start too (ahead < 0)
            bins = [[float(lo), round(float(lo) + 0.1, 2), int(m.sum()), int(lost[m].sum())]
                    for lo in edges for m in [((ahead >= lo) | (lo == 0)) & (ahead < lo + 0.1)]
                    if m.any()]
            forced = np.array([r.get("forced", a <= forced_m) for r, a in zip(rs, ahead)])
            out.setdefault(kind, {})[prev] = {
                "n": len(rs), "ahead_m_q": [float(q) for q in np.quantile(ahead, (0.25, 0.5, 0.75))],
                "forced_pct": float(100 * np.mean(forced)),
                "lost_pct": float(100 * lost.mean()), "lost_by_ahead": bins}
            if all("output" in r for r in rs):  # the rule's model output at its switches
                o = np.array([r["output"] for r in rs])
                out[kind][prev]["output_q"] = [float(q) for q in np.quantile(o, (0.25, 0.5, 0.75))]
    return out


def switches_markdown(by_method: dict) -> str:
    """One table per artifact kind: where each method switched into its policy, by the artifact
    before it, and how often that artifact was then lost."""
    lines = []
    for kind in ARTIFACT_KINDS:
        lines += [f"**into {kind}**: switch distance before it, median (quartiles) [m]; % forced "
                  f"(within 1 cm); % lost (fell on it); the rule's model output at the switch, "
                  f"median (quartiles): an estimator's E(s), the learned rule's score", "",
                  "| method | after | switches | distance [m] | % forced | % lost | model output |",
                  "|---|---|---|---|---|---|---|"]
        for m, d in by_method.items():
            for prev, c in d.get(kind, {}).items():
                q1, q2, q3 = c["ahead_m_q"]
                o = c.get("output_q")
                out_cell = "-" if o is None else f"{o[1]:.2f} ({o[0]:.2f}-{o[2]:.2f})"
                lines.append(f"| {m} | {prev} | {c['n']:,} | {q2:.2f} ({q1:.2f}-{q3:.2f}) | "
                             f"{c['forced_pct']:.1f} | {c['lost_pct']:.1f} | {out_cell} |")
        lines.append("")
    return "\n".join(lines)


def failures_markdown(by_method: dict) -> str:
    """One table per artifact kind: % fell on it (fell / reached) by the artifact before it."""
    lines = []
    for kind in ARTIFACT_KINDS:
        prevs = sorted({p for d in by_method.values() for p in d[kind]},
                       key=lambda p: (p != "start", p))
        lines += [f"**{kind}**, fell on it / reached, by the artifact before it", "",
                  "| method | " + " | ".join(f"after {p}" for p in prevs) + " |",
                  "|---|" + "---|" * len(prevs)]
        for m, d in by_method.items():
            cells = [(f"{f:,} / {n:,} ({100 * f / n:.1f}%)" if n else "-")
                     for n, f in (d[kind].get(p, [0, 0]) for p in prevs)]
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def compare(a: dict, b: dict, key: str = "success") -> int:
    """+1 when row a's 95% CI on `key` ("success" or "distance") lies wholly above b's, -1 wholly
    below, 0 when they overlap (no difference claimed)."""
    (alo, ahi), (blo, bhi) = a[f"{key}_ci"], b[f"{key}_ci"]
    return 1 if alo > bhi else (-1 if ahi < blo else 0)


def _cell(r: dict) -> str:
    return f"{r['method']} {pct_ci(r['success_pct'], r['success_ci'])}"


def paper_claims(rows: list[dict]) -> list[dict]:
    """The paper's four Table II claims, tested on our rows by their 95% CIs on % success
    (`compare`): {claim, verdict, evidence}. verdict: "holds", "fails" (with the rows that break
    it) or "not tested" (a row it needs was not run). "Comparable" means overlapping CIs."""
    by = {r["method"]: r for r in rows}

    def beats_all(m, others, show_all: bool):
        """(verdict, evidence) of "row m beats each of `others`": every row's cell and the names
        not beaten (`show_all`, a few rows), else the cells of those not beaten only."""
        if not others:
            return "not tested", f"{_cell(by[m])}; no other rows"
        lost = [o for o in others if compare(by[m], by[o]) < 1]
        if show_all:
            ev = "; ".join(_cell(by[r]) for r in (m, *others))
            return ("fails", f"{ev}; not beaten: {', '.join(lost)}") if lost else ("holds", ev)
        if lost:
            return "fails", f"{_cell(by[m])}; not beaten: " + "; ".join(_cell(by[o]) for o in lost)
        return "holds", f"{_cell(by[m])}; above all {len(others)} other rows"

    def dqn_vs_estimator():
        c = compare(by["dqn"], by["estimator"])
        return ("holds" if c == 0 else "fails", f"{_cell(by['dqn'])}; {_cell(by['estimator'])}"
                + ("" if c == 0 else f"; the DQN is {'better' if c > 0 else 'worse'}"))

    claims = (  # (claim, rows it needs, test)
        ("the estimator beats every heuristic (success)", ("estimator", *HEURISTICS),
         lambda: beats_all("estimator", HEURISTICS, show_all=True)),
        ("without overlap the estimator collapses (success)", ("estimator", "estimator_no_overlap"),
         lambda: ("holds" if compare(by["estimator_no_overlap"], by["estimator"]) < 0 else "fails",
                  f"{_cell(by['estimator_no_overlap'])}; {_cell(by['estimator'])}")),
        ("the DQN is comparable to the estimator (overlapping success CIs)", ("dqn", "estimator"),
         dqn_vs_estimator),
        ("end-to-end is best (success)", ("end_to_end",),
         lambda: beats_all("end_to_end", [m for m in by if m != "end_to_end"], show_all=False)),
        # the paper's central claim, tested with our learned rule (switching/when.py)
        ("ours: a learned rule beats every hand-made rule (success)",
         ("learned", *HEURISTICS, "lookup_context"),
         lambda: beats_all("learned", (*HEURISTICS, "lookup_context"), show_all=True)),
        ("ours: with setup policies too, the learned rule beats the lookup table (success)",
         ("learned_setup", "lookup_context_setup"),
         lambda: beats_all("learned_setup", ("lookup_context_setup",), show_all=True)),
        # "compose, then distil" against training one policy on everything (learning/distillation.py)
        ("ours: a student distilled from the composed suite beats the end-to-end policy trained "
         "by RL (success)", ("student", "end_to_end"),
         lambda: beats_all("student", ("end_to_end",), show_all=True)),
        ("ours: without overlap the learned rule collapses (success)",
         ("learned", "learned_no_overlap"),
         lambda: ("holds" if compare(by["learned_no_overlap"], by["learned"]) < 0 else "fails",
                  f"{_cell(by['learned_no_overlap'])}; {_cell(by['learned'])}")),
    )
    out = []
    for claim, need, test in claims:
        missing = [m for m in need if m not in by]
        verdict, evidence = (("not tested", "missing rows: " + ", ".join(missing)) if missing
                             else test())
        out.append({"claim": claim, "verdict": verdict, "evidence": evidence})
    return out


def claims_markdown(claims: list[dict]) -> str:
    lines = ["| the paper's claim | on our system | evidence: % success (95% CI) |", "|---|---|---|"]
    lines += [f"| {c['claim']} | {c['verdict']} | {c['evidence']} |" for c in claims]
    return "\n".join(lines)


def table2_markdown(rows: list[dict]) -> str:
    fails = [KIND[k].singular for k in paper.TABLE2_FAIL_ORDER]
    lines = ["| method | trials | % total dist. (95% CI) | % success (95% CI) | "
             + "".join(f"% {s} fail (CI) | " for s in fails)
             + f"paper (dist. / success / {' / '.join(fails)}) |",
             "|---" * (5 + len(fails)) + "|"]
    for r in rows:
        ref = paper.TABLE2.get(r["method"])
        f = r["fail_on"]
        lines.append(
            f"| {r['method']} | {r['n']} | {dist_success_cells(r)} | "
            + " | ".join(pct_ci(f[k], r["fail_ci"][k]) for k in paper.TABLE2_FAIL_ORDER) + " | "
            + (" / ".join(f"{v}" for v in ref.cells()) if ref else "-") + " |")
    return "\n".join(lines)


def table2_rows(doc: dict, with_paper_only: bool = True):
    """(headers, rows) of a table2.json as the notebook prints it, each method beside the paper's
    row; with `with_paper_only`, the paper's methods not run here as "not run" rows."""
    order = paper.TABLE2_FAIL_ORDER
    fails = [KIND[k].singular for k in order]
    headers = ["method", "init", "trials", "% dist. (95% CI)", "% success (95% CI)",
               *(f"% {s} fail" for s in fails), "switches/trial",
               f"paper dist. / success / {' / '.join(fails)}"]
    rows, seen = [], set()
    for r in doc["rows"]:
        f, p = r["fail_on"], paper.TABLE2.get(r["method"])
        seen.add(r["method"])
        rows.append([r["method"], r["init"], r["n"], pct_ci_cell(r["distance_pct"], r.get("distance_ci")),
                     pct_ci_cell(r["success_pct"], r.get("success_ci")),
                     *(f"{f[k]:.1f}" for k in order),
                     f"{r.get('switches_per_trial', math.nan):.2f}",
                     " / ".join(f"{v}" for v in p.cells()) if p else "-"])
    if with_paper_only:
        for m, p in paper.TABLE2.items():
            if m not in seen:
                rows.append([m, "-", "not run", "-", "-", *["-"] * len(order), "-",
                             " / ".join(f"{v}" for v in p.cells())])
    return headers, rows


def table2_provenance(doc: dict, path, print_fn=print) -> list[str]:
    """Prints where a table2.json's rows come from (settings, methods not run, each init's
    policies) and its verdict; returns the reasons it is a pipeline check ([] if none)."""
    s, rows = doc.get("settings", {}), doc["rows"]
    fmt = prov.fmt
    print_fn(f"file: {prov.rel(path)}")
    for k in ("trials", "seed", "horizon_s", "n_artifacts", "stand_in", "guide_scale", "runs",
              "estimators", "dqn", "lookup"):
        print_fn(f"  {k}: {fmt(s.get(k))}")
    for sk in doc.get("skipped") or []:
        print_fn(f"  not run: {sk}")
    print_fn(f"  device: {fmt(doc.get('device'))}   track_seed: {fmt(doc.get('track_seed'))}   "
             f"wall: {fmt(round(doc['wall_s'])) if doc.get('wall_s') is not None else 'not recorded'} s")
    reasons, seen, subs = [], set(), {}
    for r in rows:
        srcs = tuple(r.get("policies") or ())
        if srcs and (r["init"], srcs) not in seen:
            seen.add((r["init"], srcs))
            print_fn(f"  policies ({r['init']} init), {'/'.join(POLICY_NAMES)}:")
            for src in srcs:
                print_fn(f"    {src}")
            subs[r["init"]] = [x.split(":")[0].removeprefix("stand-in for ")
                               for x in prov.stand_ins(srcs)]
    for r in rows:
        if r.get("switch_parts"):
            print_fn(f"  {r['method']} switches with: " + "; ".join(r["switch_parts"]))
    subs = {k: v for k, v in subs.items() if v}
    if subs:
        reasons.append("stand-in policies: " + "; ".join(f"{k} init {', '.join(v)}"
                                                         for k, v in subs.items()))
    if s.get("stand_in"):
        reasons.append(f"--stand-in {s['stand_in']}")
    if (s.get("guide_scale") or 0) > 0:
        reasons.append(f"scripted guide forces on (guide_scale {s['guide_scale']:g})")
    if s.get("n_artifacts") not in (None, paper.ARTIFACTS):
        reasons.append(f"{s['n_artifacts']} artifacts per track (paper: {paper.ARTIFACTS})")
    mismatch = sorted({x for r in rows for x in (r.get("policies") or ()) if "MISMATCH" in str(x)})
    if mismatch:
        reasons.append("DQN selector trained with other policies than those evaluated")
    return prov.conclude(doc, reasons, rows, paper.TRIALS["table2"], "method", print_fn=print_fn)

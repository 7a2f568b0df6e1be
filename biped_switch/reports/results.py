"""docs/results.md, generated from the committed result files, so its numbers never drift from them.

    python -m biped_switch.reports.results           # writes docs/results.md (`make docs`)
    python -m biped_switch.reports.results --check   # exit 1 when docs/results.md is stale

Plain Python (no JAX). `TEMPLATE` is the page: its prose, its order, and two kinds of
placeholder. `{{include <file> [+N]}}` copies a Markdown table a command wrote under
experiments/results/ (its headings N levels deeper); `{{name}}` is a number read from a JSON file
there (or from a committed run's progress.json and recipe.json) by `values()`. Table III is built
from table3.json (`table3_md`).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
import sys

from biped_switch.paths import REPO, RESULTS

DOC = REPO / "docs" / "results.md"
WORDS = {1: "one", 2: "two", 3: "three", 4: "four", 5: "five", 6: "six", 7: "seven"}

TEMPLATE = """\
<!-- generated from experiments/results/** by `make docs` (python -m biped_switch.reports.results); do not edit by hand -->

# Results

Every table the pipeline writes, collected in one place. Each section names the file it copies;
the numbers are those files' content, unedited. All runs: MuJoCo C engine (`mujoco` backend) on a
2-core CPU VM, no GPU. 95% confidence intervals in brackets (Wilson for rates, normal for
distance and speed).

## Table I: each policy alone on its own terrain

From `experiments/results/table1/table1.md`: {{t1_trials}} unseen 7-artifact tracks per row (seeds {{t1_seeds}}),
difficulty 1, no guides, no pushes; `python -m biped_switch.evaluate single --trials {{t1_trials_arg}}`.

{{include table1/table1.md}}

### The walk policies on flat tracks

From `experiments/results/walk_stand/table1.md` and `experiments/results/walk_random/table1.md`: {{walk_trials}} unseen flat tracks
(seeds {{walk_seeds}}); `python -m biped_switch.evaluate single --policies walk --inits stand --trials {{walk_trials_arg}} --out experiments/results/walk_stand` (and `--inits random`).

{{include walk_stand/table1.md}}

{{include walk_random/table1.md}}

### Two seeds: the stand suite replayed by its recipes (seed 1, in progress)

From `experiments/results/table1_seed1/table1.md`: the seed-1 replays (`models/replay_seed1/`,
`train --recipe ... --seed 1`, unattended), each on Table I's tracks once it finishes; so far
`walk_stand`, on 500 flat tracks beside seed 0's on the same 500
(`experiments/results/table1_walk_seed0/table1.md`). The artifact policies' rows come when their
replays end.

{{include table1_seed1/table1.md}}

{{include table1_walk_seed0/table1.md}}

## Table II: switching methods and baselines on mixed tracks

From `experiments/results/table2/table2.md`: {{t2_trials}} random {{t2_artifacts}}-artifact `mixed` tracks (seeds {{t2_seeds}}),
{{t2_horizon}} s, no guides, no pushes, the stand-init suite (the random-init suite for
`estimator_no_overlap` and `learned_no_overlap`); `python -m biped_switch.evaluate multi --trials {{t2_trials_arg}}`. The failure columns
are % of trials that end in a fall on that artifact kind. `lookup_context`, `estimator_context` and
`estimator_context_persist` are ours (context sweeps, docs/switching.md), `learned` and
`learned_no_overlap` our learned when rule on the stand and random-init suites ("Learning when to
switch" below), `lookup_context_setup` is `lookup_context` with the setup policies
(docs/switching.md, "Setup policies") and `learned_setup` the learned rule with them (a pair
without a setup policy: the rule decides); `end_to_end` here is the
curriculum-final policy ({{e2e_steps}} env steps) and `dqn` the {{dqn_steps}}-env-step selector.

{{include table2/table2.md}}

The paper's claims tested on these rows (`experiments/results/table2/claims.md`; a row beats another when its
95% CI on success lies wholly above; overlapping CIs count as comparable):

{{include table2/claims.md}}

### End-to-end trained on to {{more_round}} env steps

From `experiments/results/end_to_end_more/table2.md`: the same {{more_trials}} trials; only the `end_to_end` row differs
(`{{more_run}}`, {{more_step}} env steps, {{more_hours}} h).

{{include end_to_end_more/table2.md}}

{{include end_to_end_more/claims.md}}

### DQN trained on to {{dqn_more_round}} env steps

From `experiments/results/dqn_more/table2.md`: the same {{dqn_more_trials}} trials; only the `dqn` row differs
(`{{dqn_more_run}}`, {{dqn_more_step}} env steps, {{dqn_more_hours}} h).

{{include dqn_more/table2.md}}

{{include dqn_more/claims.md}}

## Table III: hours to add a terrain

From `experiments/results/table3/table3.json` (`python -m biped_switch.evaluate retrain-cost`), wall-clock hours read
from progress.json and the sweep and estimator logs, on the shared 2-core CPU:

{{table3}}

No row counts the `walk_stand` prior the runs were warm-started from ({{prior_h}} h to its {{prior_steps}}-step
checkpoint for the artifact policies, {{prior_e2e_h}} h to its {{prior_e2e_steps}}-step one for the end-to-end policy).
The end-to-end policy trained on to {{more_short}} env steps took {{more_hours}} h (paper {{e2e_paper_h}}).

## Failures by context

From `experiments/results/table2/failures_by_context.md` (`python -m biped_switch.evaluate failures`): falls on each
artifact kind over the trials that reached it, split by the artifact before it (Table II trials;
`random` and `detection` ran before per-trial outcomes were kept).

{{include table2/failures_by_context.md}}


With the {{more_round}} end-to-end policy (`experiments/results/end_to_end_more/failures_by_context.md`):

{{include end_to_end_more/failures_by_context.md}}


## Switch distances

From `experiments/results/table2/switch_distances.md` (`python -m biped_switch.evaluate switches`): Table II's
first {{sw_trials}} trials; where each rule switched into each policy, by the artifact before it.

{{include table2/switch_distances.md}}


![switch distances into gaps](../experiments/results/table2/switch_distances_gaps.png)

## End-to-end success against training

From `experiments/results/end_to_end_curve/curve.md` (`scripts/checkpoint_curve.py`):

{{include end_to_end_curve/curve.md +2}}

![end-to-end curve](../experiments/results/end_to_end_curve/curve.png)

## DQN success against training

From `experiments/results/dqn_curve/curve.md` (`scripts/dqn_checkpoint_curve.sh`):

{{include dqn_curve/curve.md +2}}

![DQN curve](../experiments/results/dqn_curve/curve.png)

## The learned terrain detector (ours)

From `experiments/results/detector/detector.md` (`python -m biped_switch.detector`; docs/switching.md):

{{include detector/detector.md +1}}

![the detector along one mixed validation trial](../experiments/results/detector/detector_trial.png)

## Table II with the learned detector (ours)

From `experiments/results/table2_learned_detector/table2.md` (`python -m biped_switch.evaluate multi
--methods lookup_context dqn lookup_context_setup --detector learned --out experiments/results/table2_learned_detector`):
Table II's tracks, seeds, horizon and batch, with the learned detector in place of the oracle.

{{include table2_learned_detector/table2.md +1}}

{{include table2_learned_detector/failures_by_context.md +1}}

## Learning when to switch (ours)

The learned `when` rule (`switching/when.py`; docs/switching.md): one calibrated model of the
success of switching at a later distance, given the state now; it switches when now is the best
remaining moment. Offline, from `experiments/results/when/offline.md` (`python -m biped_switch.when
--init stand`), on the held-out tracks' switches:

{{include when/offline.md}}

![reliability on the held-out tracks](../experiments/results/when/reliability.png)

Label noise, from `experiments/results/when/label_noise.json` (`python -m biped_switch.sweep --init
stand --context --switch-min 0.2 --out runs/sweeps_when --replay 512 --results
experiments/results/when`): recorded switches replayed from their own starts at their own
distances in a program of another batch size.

{{label_noise}}

Margin and run length, chosen on tuning tracks (seeds {{when_tune_seeds}}), from
`experiments/results/when/tuning.md`:

{{include when/tuning.md}}

How far timing alone can go, from `experiments/results/when/ceiling.md` (`python -m
biped_switch.when --init stand --ceiling`): each sweep's best switch-distance bin per pair, beside
what Table II's rows reached there. The lead-in sweep (`sweep --lead-in`) hands over along the
track as the controller does:

{{include when/ceiling.md}}

![the lead-in sweep: success against switch distance](../experiments/results/lookup/fig4b_stand_leadin.png)

The rule trained on the lead-in sweeps as well (`when --lead-in use`), against the committed
one, on the same tracks:

{{lead_in_check}}

## Setup policies (ours)

From `experiments/results/setup/setup.md` (`python -m biped_switch.switching.setup eval --full-tracks
[--target stairs] --setup <policy or source> --out experiments/results/setup/<name>.json`, then
`python -m biped_switch.reports.setup`): each pair on held-out two-artifact tracks.

{{include setup/setup.md +1}}

## Action space: torque against PD targets

From `experiments/results/action_space/compare.md` (`python scripts/compare_runs.py`; docs/training.md):

{{include action_space/compare.md}}

## Demo table

From `experiments/results/demo/table2_demo.md` (`make demo`: {{demo_trials}} {{demo_artifacts}}-artifact tracks, {{demo_horizon}} s; far less telling than
Table II, since only one switch per track can follow another artifact; the committed example,
refreshed by `python -m biped_switch.demo --refresh-example`):

{{include demo/table2_demo.md}}

## Figures

- Fig. 4b, switch success against switch distance: [stand](../experiments/results/lookup/fig4b_stand.png),
  [random](../experiments/results/lookup/fig4b_random.png), [stand, context sweep](../experiments/results/lookup/fig4b_stand_context.png).
- Fig. 5, one trial over time: [estimator](../experiments/results/table2/fig5_trial0.png),
  [context estimator](../experiments/results/table2/fig5_trial0_context.png),
  [context estimator, 5-step run](../experiments/results/table2/fig5_trial0_context_persist.png),
  [setup policies, setup phases marked](../experiments/results/table2/fig5_trial0_lookup_context_setup.png),
  [the learned when rule, its score](../experiments/results/table2/fig5_trial0_learned.png).
- Estimator training curves: `experiments/results/estimators/<init>_<target>.png`; metrics in the
  `.json` beside each (docs/switching.md tabulates them).
"""


def _json(path: pathlib.Path) -> dict:
    return json.loads(pathlib.Path(path).read_text())


def _int(n) -> str:
    return f"{int(n):,}"


def _millions(step: int, digits: int = 2) -> str:
    """303218688 -> "303.22M"; digits 0: "500M"."""
    return f"{step / 1e6:.{digits}f}M"


def _hours(x: float) -> str:
    """Two decimals, three below 0.01 h (an estimator that trained in seconds)."""
    return f"{x:.3f}" if 0 < x < 0.01 else f"{x:.2f}"


def _seeds(first: int, n: int) -> str:
    return f"{first:,}-{first + n - 1:,}"


def _row(doc: dict, method: str) -> dict:
    return next(r for r in doc["rows"] if r["method"] == method)


def _checkpoint(spec: str) -> tuple[str, int]:
    """(run name, step) of a checkpoint named in a results row ("<...>/<run>/checkpoints/<step> ...")."""
    m = re.search(r"([A-Za-z0-9_]+)/(?:checkpoints|warm_start)/(\d{12})", spec)
    if m is None:
        raise ValueError(f"no checkpoint in {spec!r}")
    return m.group(1), int(m.group(2))


def _committed(kind: str, run: str, step: int) -> dict:
    """The progress.json of a committed run's checkpoint at `step`."""
    return _json(REPO / "models" / kind / run / "checkpoints" / f"{step:012d}" / "progress.json")


def table3_md(doc: dict, e2e_steps: str) -> str:
    """Table III as the page shows it: the parts grouped (sweeps and estimators per target)."""
    lines = ["| method | hours | parts | status | paper hours |", "|---|---|---|---|---|"]
    for r in doc["rows"]:
        parts = r["parts"]
        if r["method"] == "ours":
            kinds = [k.split(" ", 1)[1] for k in parts if k.startswith("sweep ")]
            text = (f"new policy {_hours(parts['new policy'])} (mean of the three stand artifact "
                    f"runs), sweeps {' + '.join(_hours(parts[f'sweep {k}']) for k in kinds)} "
                    f"({', '.join(kinds)}), estimators "
                    f"{' + '.join(_hours(parts[f'estimator {k}']) for k in kinds)}")
        elif r["method"] == "ours_setup":
            steps = r.get("setup_env_steps", {})
            text = "ours, plus " + ", ".join(
                f"{k} {_hours(v)} ({steps[k] / 1e6:.2f}M env steps)" if k in steps else
                f"{k} {_hours(v)}" for k, v in parts.items() if k.startswith("setup_"))
        elif r["method"] == "end_to_end":
            text = f"policy {_hours(parts['policy'])} ({e2e_steps} env steps)"
        else:
            text = ", ".join(f"{k} {_hours(v)}" for k, v in parts.items())
        hours = "-" if r["hours"] is None else _hours(r["hours"])
        paper_h = "-" if r["paper_hours"] is None else f"{r['paper_hours']:g}"  # rows of ours
        lines.append(f"| {r['method']} | {hours} | {text} | {r['status']} | {paper_h} |")
    return "\n".join(lines)


def values(results: pathlib.Path) -> dict:
    """Every `{{name}}` of the template, read from the result files and committed runs."""
    t1, ws = _json(results / "table1/table1.json"), _json(results / "walk_stand/table1.json")
    t2, more = _json(results / "table2/table2.json"), _json(results / "end_to_end_more/table2.json")
    dqn_more, t3 = _json(results / "dqn_more/table2.json"), _json(results / "table3/table3.json")
    sw, demo = _json(results / "table2/switch_distances.json"), _json(results / "demo/demo_summary.json")
    tune = _json(results / "when/tuning.json")
    e2e = _checkpoint(_row(t2, "end_to_end")["policies"][0])[1]
    dqn = _checkpoint(_row(t2, "dqn")["policies"][-1])[1]
    more_run, more_step = _checkpoint(_row(more, "end_to_end")["policies"][0])
    dqn_run, dqn_step = _checkpoint(_row(dqn_more, "dqn")["policies"][-1])
    more_h = _committed("policies", more_run, more_step)["wall_s"] / 3600
    dqn_h = _committed("baselines", dqn_run, dqn_step)["wall_s"] / 3600
    # the walk_stand checkpoints the stand suite and the end-to-end policy started from (recipes)
    prior = _json(REPO / "models/policies/jumps_stand/recipe.json")["warm_start"]
    prior_e2e = _json(REPO / "models/policies/mixed_stand/recipe.json")["warm_start"]
    prior_p = _json(REPO / prior["path"] / "progress.json")
    prior_e2e_p = _json(REPO / prior_e2e["path"] / "progress.json")
    n1, nw, n2 = t1["rows"][0]["n"], ws["rows"][0]["n"], t2["settings"]["trials"]
    return {
        "t1_trials": _int(n1), "t1_trials_arg": str(n1), "t1_seeds": _seeds(t1["track_seed"], n1),
        "walk_trials": _int(nw), "walk_trials_arg": str(nw), "walk_seeds": _seeds(ws["track_seed"], nw),
        "t2_trials": _int(n2), "t2_trials_arg": str(n2), "t2_seeds": _seeds(t2["track_seed"], n2),
        "t2_artifacts": str(t2["settings"]["n_artifacts"]), "t2_horizon": f"{t2['settings']['horizon_s']:g}",
        "e2e_steps": _millions(e2e), "dqn_steps": _millions(dqn),
        "more_round": _millions(more_step, 0), "more_short": _millions(more_step),
        "more_trials": _int(more["settings"]["trials"]), "more_run": f"models/policies/{more_run}",
        "more_step": _int(more_step), "more_hours": _hours(more_h),
        "dqn_more_round": _millions(dqn_step, 0), "dqn_more_trials": _int(dqn_more["settings"]["trials"]),
        "dqn_more_run": f"models/baselines/{dqn_run}", "dqn_more_step": _int(dqn_step),
        "dqn_more_hours": _hours(dqn_h),
        "table3": table3_md(t3, _millions(e2e)),
        "prior_h": _hours(prior_p["wall_s"] / 3600), "prior_steps": _millions(prior_p["step"]),
        "prior_e2e_h": _hours(prior_e2e_p["wall_s"] / 3600),
        "prior_e2e_steps": _millions(prior_e2e_p["step"]),
        "e2e_paper_h": f"{_row(t3, 'end_to_end')['paper_hours']:g}",
        "sw_trials": _int(sw["settings"]["trials"]),
        "demo_trials": _int(demo["trials"]),
        "demo_artifacts": WORDS.get(demo["n_artifacts"], str(demo["n_artifacts"])),
        "demo_horizon": f"{demo['horizon_s']:g}",
        "label_noise": label_noise_md(results / "when/label_noise.json"),
        "lead_in_check": paired_md(results / "when", "tune1000_committed", {
            "tune1000_use": "context + lead-in sweeps", "tune1000_use_gaps":
            "context sweeps + the gaps lead-in sweep"}),
        "when_tune_seeds": _seeds(tune["track_seed"], tune["trials"]),
    }


def label_noise_md(path: pathlib.Path) -> str:
    """The label-noise replay (`sweep --replay`) as a table, one row per target."""
    rows = json.loads(path.read_text())
    lines = ["| target | switches replayed (0.3-0.9 m) | same switch step | labels agreeing | "
             "1 -> 0 / 0 -> 1 | success recorded / replayed | batch: sweep / replay |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['target']} | {r['n']:,} | {r['same_switch_step_pct']:.1f}% | "
                     f"**{r['agree_pct']:.1f}%** | {r['flips_1_to_0']} / {r['flips_0_to_1']} | "
                     f"{r['success_pct_recorded']:.1f}% / {r['success_pct_replayed']:.1f}% | "
                     f"{r['sweep_batch']} / {r['batch']} |")
    return "\n".join(lines)


def paired_md(results: pathlib.Path, base: str, others: dict) -> str:
    """Rows of `evaluate multi` runs of the learned rule on the same tracks, each against `base`
    (folder names under `results`): success, and the trials only one of the two won."""
    import numpy as np

    def load(name):
        doc = _json(results / name / "table2.json")
        won = np.load(results / name / "table2_trials.npz")["learned/success"] > 0.5
        return _row(doc, "learned"), won, doc

    b_row, b_won, b_doc = load(base)
    s = b_doc["settings"]
    lines = [f"{s['trials']:,} tuning tracks (seeds {_seeds(s['track_seed'], s['trials'])}), "
             f"`evaluate multi --methods learned --track-seed {s['track_seed']} --trials "
             f"{s['trials']} [--when-dir DIR]` ({b_doc['device']}):", "",
             "| run (experiments/results/when/) | rule trained on | % success (95% CI) | trials "
             "won only by it / only by the committed model |", "|---|---|---|---|",
             f"| {base} | context sweeps (the committed {s['when_dir']}) | "
             f"{b_row['success_pct']:.1f} ({b_row['success_ci'][0]:.1f}-"
             f"{b_row['success_ci'][1]:.1f}) | - |"]
    for name, what in others.items():
        row, won, doc = load(name)
        lines.append(f"| {name} | {what} | {row['success_pct']:.1f} "
                     f"({row['success_ci'][0]:.1f}-{row['success_ci'][1]:.1f}) | "
                     f"{int((won & ~b_won).sum())} / {int((b_won & ~won).sum())} |")
    return "\n".join(lines)


def _include(results: pathlib.Path, spec: str) -> str:
    name, *opt = spec.split()
    text = (results / name).read_text().strip()
    deeper = int(opt[0].lstrip("+")) if opt else 0
    return re.sub(r"(?m)^#", "#" * (deeper + 1), text) if deeper else text


def render(results: pathlib.Path | None = None) -> str:
    """The page: the template with every include and value filled in."""
    results = pathlib.Path(results or REPO / RESULTS)
    vals = values(results)
    text = re.sub(r"\{\{include ([^}]+)\}\}", lambda m: _include(results, m.group(1)), TEMPLATE)

    def fill(m):
        if m.group(1) not in vals:
            raise KeyError(f"docs/results.md template: no value for {{{{{m.group(1)}}}}}")
        return vals[m.group(1)]

    return re.sub(r"\{\{(\w+)\}\}", fill, text)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.reports.results",
                                description="write docs/results.md from experiments/results/**")
    p.add_argument("--check", action="store_true",
                   help="only compare: exit 1 (and say so) when docs/results.md is stale")
    p.add_argument("--out", default=str(DOC), help="the page to write or check")
    a = p.parse_args(argv)
    text, out = render(), pathlib.Path(a.out)
    if a.check:
        if not out.is_file() or out.read_text() != text:
            print(f"{out} is stale: run `make docs` (python -m biped_switch.reports.results)",
                  file=sys.stderr)
            return 1
        print(f"{out} is up to date")
        return 0
    out.write_text(text)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""What a Table II row needs besides its rollout: its trained parts (policies, setup policies,
estimators, lookup tables, the learned rule, the DQN), whether they exist, and on a line-up other
than the paper's (`lineups.Lineup`; Table II-4: stones) whether they can exist at all.

The estimators, the learned when rule, the plain sweep's lookup table and the learned terrain
detector were made for the paper's line-up: they have no output for a policy or kind it lacks,
so a row reading one is refused on another line-up, naming the row, the line-up and the part
(`lineup_gap`, `check_rows`). The heuristics need only the line-up's suite, the context lookup is
swept per line-up (`sweep --context --lineup`), and the baselines (DQN, end-to-end, student) run
as they are: never trained on the new kind, which is what Table II-4 measures.
"""

from __future__ import annotations

import pathlib

from biped_switch import kinds, lineups
from biped_switch.config import SETUP_SUITE
from biped_switch.learning import policies as pol
from biped_switch.learning import runs as runs_lib
from biped_switch.methods import Method, method as method_record
from biped_switch.paths import WHEN_DIR
from biped_switch.switching import estimator as est_lib
from biped_switch.switching import lookup


def new_names(lineup: lineups.Lineup) -> tuple[str, ...]:
    """The policies and targets of `lineup` that the paper's line-up lacks (the paper's: none)."""
    paper = lineups.PAPER_LINEUP
    return tuple(dict.fromkeys([p for p in lineup.policies if p not in paper.policies]
                               + [t for t in lineup.targets if t not in paper.targets]))


def lineup_gap(rec: Method, lineup: lineups.Lineup) -> str | None:
    """The part row `rec` reads that cannot exist for `lineup` (None: the row can run on it)."""
    new = ", ".join(new_names(lineup))
    if not new:
        return None
    if rec.when:
        return f"learned when rule for {new} (switching/when.py is sized for the paper's line-up)"
    if rec.estimators is not None:
        return (f"switch estimator for {new} (the {rec.estimators} sweep's estimators are the "
                f"paper line-up's, one per paper target)")
    if rec.lookup == "sweep":
        return (f"plain-sweep lookup table for {new} (a line-up other than the paper's is swept "
                f"with --context only: its row is lookup_context)")
    return None


def check_rows(recs, lineup: lineups.Lineup) -> None:
    """Raises ValueError naming each row of `recs` that `lineup` cannot run, and its missing part."""
    bad = [f"row {r.name}: line-up {lineup.name} has no {gap}"
           for r in recs if (gap := lineup_gap(r, lineup))]
    if bad:
        raise ValueError("; ".join(bad))


def check_detector(detector_dir, lineup: lineups.Lineup) -> None:
    """A learned terrain detector names the paper's classes only (kinds.DETECTOR_CLASSES): on a
    line-up with a target it cannot name, it would never switch into that target's policy."""
    blind = [t for t in lineup.targets if t not in kinds.DETECTOR_CLASSES]
    if detector_dir is not None and blind:
        raise ValueError(f"line-up {lineup.name}: the learned detector {detector_dir} names only "
                         f"{kinds.DETECTOR_CLASSES[1:]}, not {', '.join(blind)} (use the oracle: "
                         f"--detector oracle)")


def find_setup_policies(init: str, runs, names=SETUP_SUITE) -> dict:
    """{setup policy name: (target kind, source policy names, hand-over distance [m])} of the
    trained setup policies `names` of an init mode (`train --policy setup_<target>`; default: the
    controller's, config.SETUP_SUITE), each as its run's config says it was trained: the sources
    it takes over from and the distance it hands over at."""
    found = {}
    for name in names:
        ckpt = runs_lib.find_policy(name, init, runs)
        if ckpt is None:
            continue
        s = runs_lib.read_config(ckpt.parent.parent).get("setup")
        if not s:
            raise ValueError(f"{ckpt}: a setup policy's run config.json without a setup section")
        found[name] = (s["target"], tuple(s["sources"]), float(s["handover_m"]))
    return found


def available_methods(methods, runs, est_dir, lookup_dir, dqn_dir=None,
                      stand_in: str | None = None, when_dir=WHEN_DIR,
                      lineup: lineups.Lineup = lineups.PAPER_LINEUP) -> tuple[list, list]:
    """(methods whose trained parts exist for `lineup`, ["method: what is missing", ...])."""
    ok, skipped = [], []
    for m in methods:
        why = _missing(method_record(m), pathlib.Path(runs), est_dir, lookup_dir, dqn_dir,
                       stand_in, when_dir, lineup)
        if why:
            skipped.append(f"{m}: {why}")
        else:
            ok.append(m)
    return ok, skipped


def _missing(rec: Method, runs: pathlib.Path, est_dir, lookup_dir, dqn_dir, stand_in,
             when_dir, lineup: lineups.Lineup = lineups.PAPER_LINEUP) -> str | None:
    """The first part of `rec`'s row that is not trained, with the command that makes it (None:
    all there), in the order a user would make them; first, a part `lineup` cannot have."""
    init = rec.suite
    if gap := lineup_gap(rec, lineup):
        return f"line-up {lineup.name} has no {gap}"
    if rec.policy is not None:
        if runs_lib.find_policy(rec.policy, "stand", runs) is None:
            return (f"no {rec.policy}_stand policy (python -m biped_switch."
                    f"{'distill' if rec.policy == 'student' else 'train --policy ' + rec.policy})")
    else:  # the suite: the line-up's policies (the DQN's: the paper's), or with a stand-in, walk or it
        names = pol.POLICY_NAMES if rec.baseline else lineup.policies
        missing = [n for n in names if runs_lib.find_policy(n, init, runs) is None]
        if stand_in is not None and (runs_lib.find_policy("walk", init, runs) is not None
                                     or runs_lib.find_policy(stand_in, init, runs) is not None):
            missing = []
        if missing:
            return (f"no {init}-init {', '.join(missing)} policy under {runs}/ or models/policies/ "
                    f"(python -m biped_switch.train --policy P --init {init})")
    if rec.setup and not find_setup_policies(init, runs):
        return (f"no {init}-init setup policy under {runs}/ or models/policies/ "
                f"(python -m biped_switch.train --policy setup_gaps --init {init})")
    if rec.when and not (pathlib.Path(when_dir) / init / "meta.json").exists():
        return f"no learned when rule in {when_dir}/{init} (python -m biped_switch.when --init {init})"
    if rec.estimators == "context" and est_lib.context_estimator_paths(init, est_dir) is None:
        return (f"no {init}_context estimator in {est_dir} (python -m biped_switch.estimator "
                f"--init {init} --context), or a target has no estimator at all")
    if rec.estimators == "sweep" and not all(
            (pathlib.Path(est_dir) / f"{init}_{k}").exists() for k in lineup.targets):
        return f"no {init}-init estimators in {est_dir} (make train-estimators)"
    if rec.lookup == "context":
        missing = lookup.context_lookup_missing("stand", lookup_dir, lineup=lineup)
        if missing is None or missing:
            of, flag = (("", "") if lineup == lineups.PAPER_LINEUP
                        else (f" of line-up {lineup.name}", f" --lineup {lineup.name}"))
            return (f"no context lookup table covering every target{of} in {lookup_dir} "
                    f"(python -m biped_switch.sweep --init stand --context{flag})")
    if rec.lookup == "sweep":
        missing = lookup.lookup_missing("stand", lookup_dir)
        if missing is None:
            return f"no lookup table in {lookup_dir} (python -m biped_switch.sweep)"
        if missing:  # swept one target at a time, across sessions
            return (f"the lookup table in {lookup_dir} has no {', '.join(missing)} (python -m "
                    f"biped_switch.sweep --targets {' '.join(missing)})")
    if rec.name == "dqn" and runs_lib.find_dqn(runs, "stand", dqn_dir) is None:
        return (f"no DQN checkpoint in {dqn_dir or f'{runs}/dqn_stand'} or "
                f"{runs_lib.BASELINE_DIR}/ (make train-dqn)")
    return None

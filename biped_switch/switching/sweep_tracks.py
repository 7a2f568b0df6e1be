"""The tracks of the switch-point sweeps, and which policy acts before the switch on each.

Three plans, one per kind of sweep:
  the paper's    single-artifact tracks of the target kind; sources cycle over the other policies
                 and start on flat ground before it
  context        two-artifact tracks: an artifact policy j crosses its own artifact, then hands
                 over before the target's ([j, target], switch before the 2nd); walk switches
                 before an [target, other] track's first
  lead-in        as on Table II's tracks: walk starts every episode and the controller hands over
                 along the track by the context lookup table (jittered), so the source j took over
                 from walk or from another artifact's policy before crossing its own artifact:
                 [j, target], [x, j, target] for each kind x != j; walk as in the context plan

The context and lead-in plans are a line-up's (`lineups.Lineup`, default the paper's): its policies
are the sources, its targets the kinds on the tracks, its track kind the env's.
"""

from __future__ import annotations

import numpy as np

from biped_switch.config import SWEEP_TRACK_SEED, default_terrain_config
from biped_switch.kinds import BEHAVIOUR
from biped_switch.lineups import LINEUP, PAPER_LINEUP, Lineup
from biped_switch.simulation import env as env_lib
from biped_switch.simulation import terrain
from biped_switch.switching.lookup import target_slot


def make_env(target: str, init: str, n_tracks: int, difficulty: float = 1.0, **overrides):
    """Single-artifact `target` tracks SWEEP_TRACK_SEED + i; `overrides` (env config: the physics
    `backend`, the suite's action mode and phase clock) go to `env.make_env`."""
    return env_lib.make_env(target, init, n_artifacts=1, n_tracks=n_tracks,
                            seed=SWEEP_TRACK_SEED, difficulty=difficulty, **overrides)


def sweep_lineup(meta: dict) -> Lineup:
    """The line-up a sweep's meta names (sweeps of the paper's, and those made before line-ups
    existed, name none)."""
    name = meta.get("lineup", PAPER_LINEUP.name)
    if name not in LINEUP:
        raise ValueError(f"sweep meta names line-up {name!r}, not one of {sorted(LINEUP)}")
    return LINEUP[name]


def check_sweep_kind(lineup: Lineup, context: bool, lead_in: bool) -> None:
    """Only context sweeps are made for a line-up other than the paper's: the plain sweep's
    single-artifact tracks and the lead-in's hand-overs (the paper's policy per artifact code,
    its lookup) are the paper's."""
    if lineup != PAPER_LINEUP and (lead_in or not context):
        what = "a lead-in sweep" if lead_in else "a plain sweep (no --context)"
        raise ValueError(f"line-up {lineup.name!r}: {what} is made for the paper's line-up "
                         f"only; sweep it with --context")


def others(target: str, lineup: Lineup = PAPER_LINEUP) -> list[int]:
    """The slots of `lineup`'s policies that switch into `target` (all but the one crossing it)."""
    tgt = target_slot(target, lineup)
    return [j for j in range(lineup.n_policies) if j != tgt]


def _plan(target: str, n_tracks: int, artifact_track, lineup: Lineup
          ) -> tuple[list[list[str]], np.ndarray, np.ndarray]:
    """Track i's source cycles over the target's other policies. Walk only ever acts before a
    track's first artifact: [target, another kind] (the 2nd cycling over the line-up's other
    targets), switch before the 1st. An artifact source j gets `artifact_track(j's kind, round)`,
    ending in the target's artifact, switched before."""
    srcs = others(target, lineup)
    after = [k for k in lineup.targets if k != target]
    kinds, src, tidx = [], [], []
    for i in range(n_tracks):
        j, rnd = srcs[i % len(srcs)], i // len(srcs)
        crosses = BEHAVIOUR[lineup.policies[j]].crosses
        kinds.append([target, after[rnd % len(after)]] if crosses is None
                     else artifact_track(crosses, rnd))
        tidx.append(0 if crosses is None else len(kinds[-1]) - 1)
        src.append(j)
    return kinds, np.asarray(src, np.int32), np.asarray(tidx, np.int32)


def context_plan(target: str, n_tracks: int, lineup: Lineup = PAPER_LINEUP
                 ) -> tuple[list[list[str]], np.ndarray, np.ndarray]:
    """(artifact kinds, source policy, target artifact index) per track of a context sweep.

    On a multi-artifact track (the line-up's `tracks`) an artifact policy hands over after
    crossing its own artifact, and walk only before the first: so an artifact source gets [its
    kind, target] and switches before the 2nd artifact; walk gets [target, another kind] and
    switches before the 1st (the plain sweep's situation)."""
    return _plan(target, n_tracks, lambda name, rnd: [name, target], lineup)


def leadin_plan(target: str, n_tracks: int, lineup: Lineup = PAPER_LINEUP
                ) -> tuple[list[list[str]], np.ndarray, np.ndarray]:
    """(artifact kinds, source policy, target artifact index) per track of a lead-in sweep.

    Sources and walk's tracks as in `context_plan`. An artifact source j's tracks cycle over what
    comes before its artifact: nothing ([j, target]: walk hands over to j) or each other kind x
    ([x, j, target]: walk -> x -> j), as a mixed track's neighbours never repeat a kind."""
    def track(name, rnd):
        before = [[]] + [[k] for k in lineup.targets if k != name]
        return before[rnd % len(before)] + [name, target]

    return _plan(target, n_tracks, track, lineup)


def make_context_env(kinds, init: str, difficulty: float = 1.0, lineup: Lineup = PAPER_LINEUP,
                     **overrides):
    """Tracks SWEEP_TRACK_SEED + i of the kinds `kinds[i]` (a plan's; up to 3 artifacts each,
    the bank padded to the longest), in an env of the line-up's track kind; a kind the line-up
    does not switch into is an error (its policies could not cross it)."""
    stray = sorted({k for row in kinds for k in row} - set(lineup.targets))
    if stray:
        raise ValueError(f"tracks lay {stray}, not targets of line-up {lineup.name} "
                         f"{lineup.targets}")
    tcfg = default_terrain_config(max(len(k) for k in kinds))
    tracks = [terrain.sequence_track(SWEEP_TRACK_SEED + i, k, 1.0, tcfg)
              for i, k in enumerate(kinds)]
    return env_lib.make_env(lineup.tracks, init, terrain_cfg=tcfg, tracks=tracks,
                            n_tracks=len(tracks), seed=SWEEP_TRACK_SEED, difficulty=difficulty,
                            **overrides)

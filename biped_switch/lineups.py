"""Switching line-ups, one record each: which behaviours act and which artifact kinds they switch
into, on which tracks. The paper's line-up is the paper=True records of `kinds.py`; a kind added
with `paper=False` switches only in a line-up that names it. Plain Python, importing only
`kinds`, so every layer can read it."""

from __future__ import annotations

import dataclasses

from biped_switch import kinds


@dataclasses.dataclass(frozen=True)
class Lineup:
    """A switching line-up: the behaviours that act (in slot order, slot = `Behaviour.index`) and the
    artifact kinds they switch into (target index = artifact code), on multi-artifact tracks of
    the terrain kind `tracks`. Sweeps, lookup tables, rules and Table II-style evaluations are
    sized by it; the paper's is `paper`, and a kind added with `paper=False` switches only in a
    line-up that names it. (Not a policy suite, `policies.PolicySuite`: a line-up names the
    behaviours; a suite is their checkpoints of one init.)"""

    name: str
    policies: tuple[str, ...]
    targets: tuple[str, ...]
    tracks: str  # the terrain kind of its multi-artifact tracks (it lays exactly `targets`)

    @property
    def n_policies(self) -> int:
        return len(self.policies)

    @property
    def n_targets(self) -> int:
        return len(self.targets)

    @property
    def policy_of_code(self) -> tuple[int, ...]:
        """Per target (artifact code) the slot of the policy that crosses it."""
        return tuple(next(b.index for b in kinds.BEHAVIOURS if b.crosses == t) for t in self.targets)

    def target_index(self, target: str) -> int:
        """`target`'s index among the line-up's targets (its artifact code); ValueError naming the
        line-up when it is not one."""
        if target not in self.targets:
            raise ValueError(f"target {target!r} is not one of line-up {self.name}'s targets "
                             f"{self.targets}")
        return self.targets.index(target)

    def source_slot(self, policy: str) -> int:
        """`policy`'s slot in the line-up; ValueError naming the line-up when it is not one."""
        if policy not in self.policies:
            raise ValueError(f"source {policy!r} is not one of line-up {self.name}'s policies "
                             f"{self.policies}")
        return self.policies.index(policy)

    @property
    def walk_policy(self) -> int:
        """The slot of the flat-ground policy (acts while nothing is detected)."""
        return next(kinds.BEHAVIOUR[p].index for p in self.policies if kinds.BEHAVIOUR[p].crosses is None)


LINEUPS: tuple[Lineup, ...] = (
    Lineup("paper", policies=("walk", "jumps", "gaps", "stairs"), targets=("jumps", "gaps", "stairs"),
          tracks="mixed"),
    # issue 57: the paper's line-up and the stones policy, on tracks of all four artifact kinds
    Lineup("stones", policies=("walk", "jumps", "gaps", "stairs", "stones"),
          targets=("jumps", "gaps", "stairs", "stones"), tracks="mixed4"),
)


def problems(terrain=kinds.TERRAIN, behaviours=kinds.BEHAVIOURS, lineups=LINEUPS) -> list[str]:
    """Each line-up: its policies the behaviours of slots 0..n-1 in order, its targets the artifact
    kinds of codes 0..m-1 in order, each crossed by one of its policies, one flat-ground policy,
    and its track kind laying exactly its targets; the first line-up is the paper's."""
    kinds, pols = {k.name: k for k in terrain}, {b.name: b for b in behaviours}
    out = []
    if [s.name for s in lineups][:1] != ["paper"] or len({s.name for s in lineups}) != len(lineups):
        out.append(f"lineups must start with 'paper' and have unique names: {[s.name for s in lineups]}")
    elif (set(lineups[0].policies) != {b.name for b in behaviours if b.paper}
          or set(lineups[0].targets) != {k.name for k in terrain if k.paper and k.is_artifact}):
        out.append(f"line-up paper must be the paper=True records: {lineups[0]}")
    for s in lineups:
        if [pols[p].index if p in pols else None for p in s.policies] != list(range(len(s.policies))):
            out.append(f"line-up {s.name}: policies {s.policies} must be behaviours of slots 0..n-1")
        if [getattr(kinds.get(t), "code", None) for t in s.targets] != list(range(len(s.targets))):
            out.append(f"line-up {s.name}: targets {s.targets} must be artifact kinds of codes 0..m-1")
        crossed = [pols[p].crosses for p in s.policies if p in pols]
        if crossed.count(None) != 1 or sorted(c for c in crossed if c) != sorted(s.targets):
            out.append(f"line-up {s.name}: one flat-ground policy and one per target, got {crossed}")
        if s.tracks not in kinds or sorted(kinds[s.tracks].artifacts) != sorted(s.targets):
            out.append(f"line-up {s.name}: track kind {s.tracks!r} must lay its targets {s.targets}")
    return out



def check(terrain=kinds.TERRAIN, behaviours=kinds.BEHAVIOURS, lineups=LINEUPS) -> None:
    """Raises ValueError unless every line-up is consistent with the kind and behaviour records."""
    found = problems(terrain, behaviours, lineups)
    if found:
        raise ValueError("line-up records: " + "; ".join(found))


check()

LINEUP = {s.name: s for s in LINEUPS}
PAPER_LINEUP = LINEUP["paper"]


def policy_of_code(code, xp, lineup: Lineup | None = None):
    """The policy slot per artifact code in `lineup` (default the paper's; NO_ARTIFACT, or a code
    the line-up does not switch into: its flat-ground policy)."""
    lineup = lineup or PAPER_LINEUP
    known, i = kinds._known(xp.asarray(code), lineup.policy_of_code, xp)
    return xp.where(known, xp.asarray(lineup.policy_of_code)[i], lineup.walk_policy)

"""Terrain kinds and behaviour policies, one record each; every table of codes, stream ids, colours
and policy slots is derived here. Plain Python, importing nothing, so every layer can read it.
Stream ids are fixed per record (a new kind re-lays no track). The tables without a prefix
(ARTIFACT_KINDS, POLICY_NAMES, ...) are the paper's suite (`paper=True`), which every committed
suite, detector and one-hot was made for; a kind added with `paper=False` changes none of them,
and the ALL_ tables (the generator, training, `evaluate single --kind`) hold every record."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class TerrainKind:
    """A kind of track the terrain generator lays.

    `artifacts`: the artifact kinds its tracks lay, in the order the generator draws from (one:
    every artifact that kind; several: a random one each time, never the previous one twice; none:
    flat ground). An artifact kind lays itself and has `code` (its value in artifact arrays) and
    `detector_class` (the terrain detector's class for it; class 0 is "nothing in range")."""

    name: str
    stream: int  # seeds each track's random stream with (seed, stream); fixed forever
    colour: str  # matplotlib colour of the kind in every plot
    singular: str  # one artifact of it, in table headers ("% gap fail")
    artifacts: tuple[str, ...] = ()
    code: int | None = None  # artifact code (None: lays no artifact of its own)
    detector_class: int | None = None
    paper: bool = True  # in the paper's suite (the tables without ALL_); False: opted in only

    @property
    def is_artifact(self) -> bool:
        return self.code is not None


@dataclasses.dataclass(frozen=True)
class Behaviour:
    """A behaviour policy of the suite: its slot `index` (its action in a policy suite, a DQN's
    Q-value, a switch's target) and the artifact kind it is trained to cross (None: tied to no
    terrain; the first such, walk, is the one that acts while nothing is detected)."""

    name: str
    index: int
    crosses: str | None
    colour: str  # matplotlib colour of the policy in every plot
    trains_on: str = ""  # the terrain kind it is trained on ("": the kind of its name)
    paper: bool = True  # in the paper's suite (POLICY_NAMES, load_suite); False: opted in only

    @property
    def terrain(self) -> str:
        return self.trains_on or self.name


NO_ARTIFACT = -1  # the artifact code of "none" (padding, nothing detected, no fall)
NONE_CLASS = 0  # the terrain detector's class for "nothing in range"

TERRAIN: tuple[TerrainKind, ...] = (
    TerrainKind("walk", stream=0, colour="tab:blue", singular="flat"),
    TerrainKind("jumps", stream=1, colour="tab:orange", singular="jump", artifacts=("jumps",),
                code=0, detector_class=1),
    TerrainKind("gaps", stream=2, colour="tab:purple", singular="gap", artifacts=("gaps",),
                code=1, detector_class=2),
    TerrainKind("stairs", stream=3, colour="tab:brown", singular="stair", artifacts=("stairs",),
                code=2, detector_class=3),
    TerrainKind("mixed", stream=4, colour="tab:gray", singular="mixed",
                artifacts=("jumps", "gaps", "stairs")),
    # issue 57: a fifth kind none of the paper's four policies crosses (docs/environment.md)
    TerrainKind("stones", stream=5, colour="tab:green", singular="stone", artifacts=("stones",),
                code=3, detector_class=4, paper=False),
    TerrainKind("mixed4", stream=6, colour="tab:olive", singular="mixed4",
                artifacts=("jumps", "gaps", "stairs", "stones"), paper=False),
)

BEHAVIOURS: tuple[Behaviour, ...] = (
    Behaviour("walk", index=0, crosses=None, colour="tab:blue"),
    Behaviour("jumps", index=1, crosses="jumps", colour="tab:orange"),
    Behaviour("gaps", index=2, crosses="gaps", colour="tab:purple"),
    Behaviour("stairs", index=3, crosses="stairs", colour="tab:brown"),
    Behaviour("stones", index=4, crosses="stones", colour="tab:green", paper=False),
)


def check(terrain=TERRAIN, behaviours=BEHAVIOURS) -> None:
    """Raises ValueError unless the records are consistent: unique names and streams, artifact
    codes and detector classes 0.. / 1.. without holes, pools and behaviours naming artifact
    kinds, policy slots 0.. without holes, a behaviour tied to no terrain (walk) and exactly one
    behaviour per artifact kind."""
    names = [k.name for k in terrain]
    arts = sorted((k for k in terrain if k.is_artifact), key=lambda k: k.code)
    problems = []
    if len(set(names)) != len(names):
        problems.append(f"duplicate kind names {names}")
    if len({k.stream for k in terrain}) != len(terrain):
        problems.append(f"duplicate stream ids {[k.stream for k in terrain]}")
    if [k.code for k in arts] != list(range(len(arts))):
        problems.append(f"artifact codes must be 0..{len(arts) - 1}: {[k.code for k in arts]}")
    if [k.detector_class for k in arts] != list(range(NONE_CLASS + 1, len(arts) + 1)):
        problems.append(f"detector classes must be 1..{len(arts)}: "
                        f"{[k.detector_class for k in arts]}")
    art_names = {k.name for k in arts}
    for k in terrain:
        if not set(k.artifacts) <= art_names:
            problems.append(f"{k.name}: lays {k.artifacts}, not all artifact kinds")
        if k.is_artifact and k.artifacts != (k.name,):
            problems.append(f"artifact kind {k.name} must lay itself only, not {k.artifacts}")
    for b in behaviours:
        if b.terrain not in names:
            problems.append(f"behaviour {b.name} trains on {b.terrain!r}, not a terrain kind")
    if sorted(b.index for b in behaviours) != list(range(len(behaviours))):
        problems.append(f"policy indices must be 0..{len(behaviours) - 1}")
    crosses = [b.crosses for b in behaviours]
    if None not in crosses:
        problems.append("a behaviour must cross nothing (walk on flat ground)")
    if sorted(c for c in crosses if c is not None) != sorted(art_names):
        problems.append(f"one behaviour per artifact kind: {crosses} vs {sorted(art_names)}")
    paper_arts = [k for k in arts if k.paper]
    if arts[:len(paper_arts)] != paper_arts:
        problems.append("the paper's artifact kinds must take the first codes (index = code)")
    paper_pols = sorted((b for b in behaviours if b.paper), key=lambda b: b.index)
    if [b.index for b in paper_pols] != list(range(len(paper_pols))):
        problems.append("the paper's behaviours must take the first policy slots")
    paper_names = {k.name for k in terrain if k.paper}
    for k in terrain:
        if k.paper and not set(k.artifacts) <= paper_names:
            problems.append(f"paper kind {k.name} lays {k.artifacts}, not all paper kinds")
    for b in behaviours:
        if b.paper and b.crosses is not None and b.crosses not in paper_names:
            problems.append(f"paper behaviour {b.name} crosses non-paper kind {b.crosses}")
    if problems:
        raise ValueError("kind records: " + "; ".join(problems))


check()

KIND = {k.name: k for k in TERRAIN}
BEHAVIOUR = {b.name: b for b in BEHAVIOURS}
_ALL_ARTS = sorted((k for k in TERRAIN if k.is_artifact), key=lambda k: k.code)
_ALL_POLS = sorted(BEHAVIOURS, key=lambda b: b.index)
_ARTS = [k for k in _ALL_ARTS if k.paper]  # the paper's suite: the tables below without ALL_
_POLS = [b for b in _ALL_POLS if b.paper]

# Every record: what the track generator lays and `train` / `evaluate single --kind` accept.
ALL_ARTIFACT_KINDS = tuple(k.name for k in _ALL_ARTS)  # index = artifact code
ALL_ARTIFACT_CODE = {k.name: k.code for k in _ALL_ARTS}
ALL_POLICY_NAMES = tuple(b.name for b in _ALL_POLS)  # index = policy slot
TERRAIN_KINDS = tuple(k.name for k in TERRAIN)  # every kind of track (no index meaning)

# The paper's suite (what every committed policy suite, detector and Q-network was made for).
ARTIFACT_KINDS = tuple(k.name for k in _ARTS)  # index = artifact code
PAPER_TERRAIN_KINDS = tuple(k.name for k in TERRAIN if k.paper)
POLICY_NAMES = tuple(b.name for b in _POLS)  # index = policy slot
POLICY_INDEX = {b.name: b.index for b in _POLS}
DETECTOR_CLASSES = ("none",) + tuple(k.name for k in _ARTS)  # index = detector class
ARTIFACT_CODE = {k.name: k.code for k in _ARTS}
KIND_COLOURS = {k.name: k.colour for k in TERRAIN}
POLICY_COLOURS = {b.name: b.colour for b in BEHAVIOURS}

# The policy for flat ground (acts while nothing is detected), and per artifact code the policy
# that crosses it / per policy slot the code it crosses (NO_ARTIFACT: flat ground). Tuples, so hot
# code builds one (n,) array of them once and indexes it.
WALK_POLICY = next(b.index for b in _POLS if b.crosses is None)
POLICY_OF_CODE = tuple(next(b.index for b in BEHAVIOURS if b.crosses == k.name) for k in _ARTS)
CODE_OF_POLICY = tuple(NO_ARTIFACT if b.crosses is None else KIND[b.crosses].code for b in _POLS)
# the terrain detector's class per artifact code, and the artifact code per class
CLASS_OF_CODE = tuple(k.detector_class for k in _ARTS)
CODE_OF_CLASS = tuple(NO_ARTIFACT if c == NONE_CLASS else
                      next(k.code for k in _ARTS if k.detector_class == c)
                      for c in range(len(DETECTOR_CLASSES)))


def policy_for(kind: str) -> int:
    """The slot of the behaviour that crosses artifact kind `kind` ("walk": the flat policy; any
    record's kind, the paper's or not)."""
    return WALK_POLICY if kind == "walk" else next(b.index for b in BEHAVIOURS if b.crosses == kind)


# Vectorised forms for arrays of codes or classes; `xp` is numpy or jax.numpy (jittable), so this
# module itself imports neither.
# A code outside the paper's suite (a kind with paper=False) maps like NO_ARTIFACT: the paper's
# suite has no policy and no detector class for it (jnp would otherwise clamp it onto stairs).
def _known(code, table, xp):
    return (code >= 0) & (code < len(table)), xp.clip(code, 0, len(table) - 1)


def policy_of_code(code, xp):
    """The paper suite's policy slot per artifact code (NO_ARTIFACT: the flat-ground policy)."""
    known, i = _known(xp.asarray(code), POLICY_OF_CODE, xp)
    return xp.where(known, xp.asarray(POLICY_OF_CODE)[i], WALK_POLICY)


def class_of_code(code, xp):
    """The paper detector's class per artifact code (NO_ARTIFACT: NONE_CLASS)."""
    known, i = _known(xp.asarray(code), CLASS_OF_CODE, xp)
    return xp.where(known, xp.asarray(CLASS_OF_CODE)[i], NONE_CLASS)


def code_of_class(cls, xp):
    """The artifact code per terrain detector class (NONE_CLASS: NO_ARTIFACT)."""
    return xp.asarray(CODE_OF_CLASS)[xp.asarray(cls)]

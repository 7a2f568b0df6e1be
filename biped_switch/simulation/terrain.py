"""Box-terrain tracks of the paper: flat run-ups and artifacts (stairs, gaps, jumps) along +x.

A track is a row of *segments* along x, each a box (flat, stair step, step block) or a hole (gap).
Each segment's length and top height are affine in `difficulty`, so one `layout()` gives the boxes
on the host (numpy) and inside jitted code (jnp) when a curriculum raises the difficulty: a new
difficulty never recompiles and never needs a new track.

Artifacts (n = 4..9 segments each, sizes at difficulty 1; kinds.py holds the kind records, BUILDERS
below one segment builder per artifact kind):
  stairs  n steps up then down, rise 0.17 m, run U(0.36, 0.44) m; step k has height 0.17 * min(k, n+1-k)
  jumps   n segments alternating a block 0.3 m high and 0.16 m long with a flat U(0.36, 0.44) m,
          starting with a block (the robot steps or jumps onto and off each block)
  gaps    n segments alternating a 0.7 m hole with a flat platform U(0.36, 0.44) m, starting with a hole
  stones  n segments alternating a 0.45 m hole with a stone 0.3 m long, its top 0.15 m up, starting
          with a hole (kind record paper=False: outside the paper's suite, issue 57)
Difficulty d in [0, 1] scales stair rise, block height, gap length, stone height and the holes
between stones by d (d = 0 is flat ground).
Every artifact has 3 flats U(0.36, 0.44) m (>= 1.08 m >= 0.9 m) before it; the track starts 1 m
behind the robot (x = 0) and ends with >= 2 m of flat.

Boxes are slabs of one thickness under their tops (thin, equal slabs rank well in MJX's bounding-
sphere broad phase); the slab thickness covers the tallest riser, so no foot passes under a step.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from biped_switch import kinds as kinds_lib
from biped_switch.config import default_terrain_config
from biped_switch.kinds import ARTIFACT_KINDS, NO_ARTIFACT, TERRAIN_KINDS as KINDS  # noqa: F401

# Segment table columns: length = LEN0 + LEN_D * d, top z = TOP_D * d, SOLID = 1 box / 0 hole.
LEN0, LEN_D, TOP_D, SOLID = range(4)
N_SEG_COLS = 4
PARK_Z_M = -50.0  # unused box slots and holes are parked far below the track
PARK_HALF_M = 0.01
FAR_X_M = 1e6  # x of padding artifacts (never reached)


def layout(segments, difficulty, x_origin_m, xp=np):
    """Segment x-extents and tops at a difficulty; `xp` is numpy or jax.numpy (jittable)."""
    length = segments[..., LEN0] + segments[..., LEN_D] * difficulty
    x1 = x_origin_m + xp.cumsum(length, axis=-1)
    x0 = x1 - length
    top = segments[..., TOP_D] * difficulty
    return x0, x1, top


def segment_boxes(segments, difficulty, x_origin_m, width_m, thickness_m, xp=np):
    """One box per segment, (S, 6) = centre xyz, half sizes xyz; holes parked far below."""
    x0, x1, top = layout(segments, difficulty, x_origin_m, xp)
    solid = segments[..., SOLID] > 0.5
    # Holes and padding are parked far away in x too, so no nearest-box search ever picks them.
    xc = xp.where(solid, 0.5 * (x0 + x1), FAR_X_M)
    half_x = xp.where(solid, 0.5 * (x1 - x0), PARK_HALF_M)
    half_y = xp.where(solid, 0.5 * width_m, PARK_HALF_M)
    half_z = xp.where(solid, 0.5 * thickness_m, PARK_HALF_M)
    zc = xp.where(solid, top - 0.5 * thickness_m, PARK_Z_M)
    return xp.stack([xc, xp.zeros_like(xc), zc, half_x, half_y, half_z], axis=-1)


def artifact_extents(segments, codes, spans, difficulty, x_origin_m, finish_after_m, xp=np):
    """Start x, end x [m] of each artifact (FAR_X_M for padding) and the finish line x [m].

    The finish line is `finish_after_m` past the last artifact; on a track without artifacts
    (walk) it is 2 * finish_after_m before the track's end.
    """
    x0, x1, _ = layout(segments, difficulty, x_origin_m, xp)
    valid = codes >= 0
    a0 = xp.where(valid, x0[spans[..., 0]], FAR_X_M)
    a1 = xp.where(valid, x1[spans[..., 1]], FAR_X_M)
    last = xp.max(xp.where(valid, a1, -FAR_X_M), initial=-FAR_X_M)
    finish = xp.where(xp.any(valid), last + finish_after_m, x1[-1] - 2.0 * finish_after_m)
    return a0, a1, finish


@dataclasses.dataclass(frozen=True)
class Track:
    """A generated track: its segment table plus the boxes and artifacts at its difficulty."""

    kind: str
    seed: int
    difficulty: float
    width_m: float
    x_origin_m: float
    thickness_m: float
    segments: np.ndarray  # (S, 4) segment table
    artifact_codes: np.ndarray  # (A,) artifact code (index into kinds.ALL_ARTIFACT_KINDS)
    artifact_segments: np.ndarray  # (A, 2) first and last segment of each artifact (inclusive)
    finish_after_m: float

    @property
    def n_segments(self) -> int:
        return int(self.segments.shape[0])

    @property
    def boxes(self) -> np.ndarray:
        """(N, 6) solid boxes: centre xyz [m] and half sizes xyz [m]."""
        b = segment_boxes(self.segments, self.difficulty, self.x_origin_m, self.width_m,
                          self.thickness_m)
        return b[self.segments[:, SOLID] > 0.5]

    def _extents(self):
        return artifact_extents(self.segments, self.artifact_codes, self.artifact_segments,
                                self.difficulty, self.x_origin_m, self.finish_after_m)

    @property
    def artifacts(self) -> list[tuple[str, float, float]]:
        """(kind, start x [m], end x [m]) of each artifact, in order along the track."""
        a0, a1, _ = self._extents()
        names = kinds_lib.ALL_ARTIFACT_KINDS
        return [(names[c], float(x0), float(x1))
                for c, x0, x1 in zip(self.artifact_codes, a0, a1)]

    @property
    def end_x_m(self) -> float:
        return float(layout(self.segments, self.difficulty, self.x_origin_m)[1][-1])

    @property
    def finish_x_m(self) -> float:
        """Success line (see `artifact_extents`)."""
        return float(self._extents()[2])

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "seed": self.seed,
            "difficulty": self.difficulty,
            "width": self.width_m,
            "boxes": self.boxes.round(6).tolist(),
            "artifacts": [{"kind": k, "x0": round(a, 6), "x1": round(b, 6)}
                          for k, a, b in self.artifacts],
            "finish_x": round(self.finish_x_m, 6),
        }


def _check_kind(kind: str) -> None:
    if kind not in kinds_lib.KIND:
        raise ValueError(f"unknown terrain kind {kind!r}; expected one of {tuple(kinds_lib.KIND)}")


def check_difficulty(difficulty: float) -> None:
    if not (0.0 <= float(difficulty) <= 1.0) or not np.isfinite(difficulty):
        raise ValueError(f"difficulty must be in [0, 1], got {difficulty!r}")


def _flats(rng: np.random.Generator, cfg, min_total_m: float) -> list[list[float]]:
    segs, total = [], 0.0
    while total < min_total_m:
        length = rng.uniform(cfg.flat_min_m, cfg.flat_max_m)
        segs.append([length, 0.0, 0.0, 1.0])
        total += length
    return segs


def _flat(rng: np.random.Generator, cfg) -> list[float]:
    return [rng.uniform(cfg.flat_min_m, cfg.flat_max_m), 0.0, 0.0, 1.0]


def _stairs(rng: np.random.Generator, cfg, n: int) -> list[list[float]]:
    return [[rng.uniform(cfg.flat_min_m, cfg.flat_max_m), 0.0,
             cfg.stair_rise_m * min(k, n + 1 - k), 1.0] for k in range(1, n + 1)]


def _jumps(rng: np.random.Generator, cfg, n: int) -> list[list[float]]:
    return [[cfg.step_length_m, 0.0, cfg.step_height_m, 1.0] if i % 2 == 0 else _flat(rng, cfg)
            for i in range(n)]


def _gaps(rng: np.random.Generator, cfg, n: int) -> list[list[float]]:
    return [[0.0, cfg.gap_length_m, 0.0, 0.0] if i % 2 == 0 else _flat(rng, cfg)
            for i in range(n)]


def _stones(rng: np.random.Generator, cfg, n: int) -> list[list[float]]:
    """Stepping stones: a hole, then a raised stone, alternating (the robot must place each foot
    on a short, raised top; neither the gaps' level platforms nor the jumps' blocks on flats)."""
    return [[0.0, cfg.stone_hole_m, 0.0, 0.0] if i % 2 == 0
            else [cfg.stone_length_m, 0.0, cfg.stone_height_m, 1.0] for i in range(n)]


# Each artifact kind's segment builder: (rng, terrain config, n segments) -> n segment rows, its
# sizes read from config.py's default_terrain_config.
BUILDERS = {"jumps": _jumps, "gaps": _gaps, "stairs": _stairs, "stones": _stones}


def check_builders(builders=None, artifact_kinds=None) -> None:
    """Raises unless every artifact kind of the records has a builder and every builder a kind."""
    builders = BUILDERS if builders is None else builders
    names = set(kinds_lib.ALL_ARTIFACT_KINDS if artifact_kinds is None else artifact_kinds)
    if set(builders) != names:
        raise ValueError(f"segment builders {sorted(builders)} != artifact kinds {sorted(names)}")


check_builders()


def _artifact(rng: np.random.Generator, cfg, kind: str) -> list[list[float]]:
    n = int(rng.integers(cfg.segments_min, cfg.segments_max + 1))
    return BUILDERS[kind](rng, cfg, n)


def generate_track(seed: int, kind: str, difficulty: float = 1.0, cfg=None) -> Track:
    """A seeded track of `kind` at `difficulty`; the same seed and kind give the same layout."""
    _check_kind(kind)
    check_difficulty(difficulty)
    cfg = cfg or default_terrain_config()
    rec = kinds_lib.KIND[kind]
    rng = np.random.default_rng([int(seed), rec.stream])

    def next_kind(prev):  # one kind in the pool: always it; several: never the previous twice
        if len(rec.artifacts) > 1:
            choices = [k for k in rec.artifacts if k != prev]
            return choices[int(rng.integers(len(choices)))]
        return rec.artifacts[0]

    return _build_track(rng, cfg, kind, int(seed), difficulty,
                        next_kind if rec.artifacts else None, cfg.n_artifacts)


def sequence_track(seed: int, kinds: Sequence[str], difficulty: float = 1.0, cfg=None) -> Track:
    """A `mixed` track whose artifacts are `kinds`, in order (the context sweeps: a source policy
    crosses its own artifact, then switches before the next). Sizes and flats are drawn as in
    `generate_track`; `kinds` may not exceed the config's n_artifacts (the bank's padding)."""
    check_difficulty(difficulty)
    cfg = cfg or default_terrain_config()
    code = kinds_lib.ALL_ARTIFACT_CODE
    bad = [k for k in kinds if k not in code]
    if bad or not kinds:
        raise ValueError(f"sequence kinds must be a non-empty list of {tuple(code)}, got {list(kinds)}")
    if len(kinds) > cfg.n_artifacts:
        raise ValueError(f"{len(kinds)} kinds but the terrain config allows {cfg.n_artifacts} artifacts")
    codes = [code[k] for k in kinds]
    rng = np.random.default_rng([int(seed), kinds_lib.KIND["mixed"].stream, 1 + len(kinds), *codes])
    it = iter(kinds)
    return _build_track(rng, cfg, "mixed", int(seed), difficulty, lambda prev: next(it), len(kinds))


def _build_track(rng, cfg, kind: str, seed: int, difficulty: float, next_kind, n_artifacts: int
                 ) -> Track:
    """The layout both track makers share; `next_kind(previous kind)` names each artifact (None:
    flat ground where the artifacts would be, as long as an average artifact)."""
    width = float(rng.uniform(cfg.width_min_m, cfg.width_max_m))
    segs = _flats(rng, cfg, cfg.start_back_m + cfg.runup_m)
    codes, spans = [], []
    prev = None
    for _ in range(n_artifacts):
        segs += _flats(rng, cfg, cfg.flat_before_m)
        if next_kind is None:
            segs += _flats(rng, cfg, 0.5 * (cfg.segments_min + cfg.segments_max) * cfg.flat_min_m)
            continue
        art = next_kind(prev)
        first = len(segs)
        segs += _artifact(rng, cfg, art)
        codes.append(kinds_lib.ALL_ARTIFACT_CODE[art])
        spans.append((first, len(segs) - 1))
        prev = art
    segs += _flats(rng, cfg, cfg.goal_flat_m)
    return Track(
        kind=kind, seed=seed, difficulty=float(difficulty), width_m=width,
        x_origin_m=-float(cfg.start_back_m), thickness_m=float(cfg.slab_thickness_m),
        segments=np.asarray(segs, dtype=np.float64),
        artifact_codes=np.asarray(codes, dtype=np.int32),
        artifact_segments=np.asarray(spans, dtype=np.int32).reshape(-1, 2),
        finish_after_m=float(cfg.finish_after_m),
    )


@dataclasses.dataclass(frozen=True)
class TrackBank:
    """Tracks padded to a fixed box capacity and artifact count, stacked for jitted code."""

    segments: np.ndarray  # (B, C, 4); padding rows are zero-length holes
    width_m: np.ndarray  # (B,)
    x_origin_m: np.ndarray  # (B,)
    artifact_codes: np.ndarray  # (B, A) artifact code, NO_ARTIFACT for padding
    artifact_segments: np.ndarray  # (B, A, 2)
    finish_after_m: np.ndarray  # (B,)
    thickness_m: float

    @property
    def size(self) -> int:
        return int(self.segments.shape[0])


def stack_tracks(tracks: Sequence[Track], capacity: int, n_artifacts: int) -> TrackBank:
    """Pads and stacks tracks; raises if one needs more box slots than the compiled capacity."""
    if not tracks:
        raise ValueError("stack_tracks needs at least one track")
    seg = np.zeros((len(tracks), capacity, N_SEG_COLS))
    codes = np.full((len(tracks), n_artifacts), NO_ARTIFACT, np.int32)
    spans = np.zeros((len(tracks), n_artifacts, 2), np.int32)
    for i, t in enumerate(tracks):
        if t.n_segments > capacity:
            raise ValueError(
                f"track (kind={t.kind!r}, seed={t.seed}) needs {t.n_segments} boxes but the "
                f"compiled box capacity is {capacity}; raise model box_capacity")
        if len(t.artifact_codes) > n_artifacts:
            raise ValueError(f"track (kind={t.kind!r}, seed={t.seed}) has "
                             f"{len(t.artifact_codes)} artifacts, more than {n_artifacts}")
        seg[i, : t.n_segments] = t.segments
        codes[i, : len(t.artifact_codes)] = t.artifact_codes
        spans[i, : len(t.artifact_codes)] = t.artifact_segments
    thick = {t.thickness_m for t in tracks}
    if len(thick) != 1:
        raise ValueError(f"tracks mix slab thicknesses {sorted(thick)}")
    return TrackBank(
        segments=seg,
        width_m=np.array([t.width_m for t in tracks]),
        x_origin_m=np.array([t.x_origin_m for t in tracks]),
        artifact_codes=codes,
        artifact_segments=spans,
        finish_after_m=np.array([t.finish_after_m for t in tracks]),
        thickness_m=thick.pop(),
    )


def plot_track(track: Track, ax=None, path_xz: np.ndarray | None = None):
    """Side view (x, z) of the boxes, artifacts shaded by kind; optionally a path of (x, z) points."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    ax = ax or plt.subplots(figsize=(14, 3))[1]
    for k, a, b in track.artifacts:
        ax.axvspan(a, b, color=kinds_lib.KIND_COLOURS[k], alpha=0.15, lw=0)
        ax.text(0.5 * (a + b), 1.0, k, ha="center", va="bottom", fontsize=8)
    for xc, _, zc, hx, _, hz in track.boxes:
        ax.add_patch(Rectangle((xc - hx, zc - hz), 2 * hx, 2 * hz, fc="0.55", ec="0.25", lw=0.5))
    ax.axvline(track.finish_x_m, color="k", ls="--", lw=0.8)
    if path_xz is not None:
        ax.plot(path_xz[:, 0], path_xz[:, 1], color="tab:blue", lw=1.2, label="pelvis CoM")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlim(track.x_origin_m, track.end_x_m)
    ax.set_ylim(-0.4, 1.3)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_title(f"{track.kind} track, seed {track.seed}, difficulty {track.difficulty:g}, "
                 f"width {track.width_m:.2f} m")
    return ax

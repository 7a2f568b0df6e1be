"""The oracle terrain detector (which artifacts the robot has come within detection range of, and
which one a fall is blamed on) and the filter a learned detector's output passes. Pure, jittable
functions on arrays."""

from __future__ import annotations

import jax.numpy as jnp
from biped_switch.simulation import terrain


def kinds_met(x, art_x0, art_kind, detect_range_m: float):
    """(3,) float32: 1 for each artifact kind (terrain.ARTIFACT_KINDS order) whose detection zone the CoM
    at `x` [m] has entered (start - `detect_range_m` <= x). At an episode's end: the kinds it met,
    which shows whether `mixed` training episodes are long enough to see every kind."""
    reached = detection_zone_entered(x, art_x0, art_kind, detect_range_m)
    codes = jnp.arange(len(terrain.ARTIFACT_KINDS))
    return jnp.any(reached[None, :] & (art_kind[None, :] == codes[:, None]), axis=1).astype(
        jnp.float32)


def detection_zone_entered(x, art_x0, art_kind, detect_range_m: float):
    """(A,) bool: artifacts (not padding) whose detection zone the CoM at `x` [m] has entered."""
    return (art_x0 - detect_range_m <= x) & (art_kind >= 0)


def blame_kind(x, art_x0, art_x1, art_kind, detect_range_m: float, after_m: float):
    """Kind of the artifact a fall at `x` [m] is blamed on, or -1 (flat ground).

    The latest artifact whose detection zone has begun (start - `detect_range_m` <= x) is blamed
    while x is within `after_m` past its end. The flats between artifacts are shorter than
    `detect_range_m + after_m`, so in the overlap the next artifact wins: a fall there comes after
    the detector names it and the switch to its policy, as Table II's failure columns need.
    Artifacts are sorted by x; padding (kind -1) sits at `terrain.FAR_X_M`."""
    reached = detection_zone_entered(x, art_x0, art_kind, detect_range_m)
    i = jnp.maximum(jnp.sum(reached) - 1, 0)
    return jnp.where(jnp.any(reached) & (x <= art_x1[i] + after_m), art_kind[i], -1)


def debounce_step(reported, cand, run, kind, steps: int, via_none: bool = False):
    """One control step of the learned detector's filter: a change of `kind` (per env, -1 none)
    is reported once the new kind has been named `steps` steps in a row; a one-step misreading
    never switches policies. With `via_none` (static), one kind never follows another directly:
    on a track every artifact has a flat before it, so a kind named while another is reported
    is a misreading (over a gap's hole, its far edge looks like a block). (reported, candidate,
    run) in and out, int32 arrays."""
    same = kind == reported
    run = jnp.where(same, 0, jnp.where(kind == cand, run + 1, 1))
    cand = jnp.where(same | (kind == cand), cand, kind)
    flip = run >= steps
    if via_none:
        flip &= (reported < 0) | (cand < 0)
    return (jnp.where(flip, cand, reported).astype(jnp.int32), cand.astype(jnp.int32),
            jnp.where(flip, 0, run).astype(jnp.int32))

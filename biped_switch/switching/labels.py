"""What one switch sample of a sweep is: its label (steps past the artifact, no fall) and the
window of observations recorded around the switch step. Pure functions of per-env arrays; the
sweep's rollout (`switching/sweep.py`) applies them every control step."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from biped_switch.config import default_sweep_config

# the sweep config's window as a length (evaluation/multi.py's persistence rule reads it)
N_WINDOW = len(default_sweep_config().window)


def window_span(window) -> int:
    """The points before the switch step of a window of consecutive step offsets around it (the
    sweep config's `window`, (-2, -1, 0, 1, 2): 2)."""
    w = tuple(int(o) for o in window)
    before = -w[0]
    if before < 0 or w != tuple(range(-before, len(w) - before)) or len(w) - before < 1:
        raise ValueError(f"a sweep window is consecutive step offsets from <= 0 to >= 0, got {w}")
    return before


# ----------------------------------------------------------------------- labelling (pure)
def touchdowns(contact, contact_prev) -> jax.Array:
    """(2,) 1 where the left / right foot lands now: some sole touches and none did a step ago."""
    now = contact.reshape(2, 4).max(axis=1) > 0.5
    before = contact_prev.reshape(2, 4).max(axis=1) > 0.5
    return now & ~before


LEFT, RIGHT, NO_FOOT = 0, 1, -1  # `Labelling.last_foot` values


def count_steps_past(steps, last_foot, contact, contact_prev, soles_x, art_end_x):
    """(steps, last_foot) updated with this step's landings of feet whose centre is past the end.

    A step is a landing of the other foot than the one that made the last step there, so one foot
    landing twice (a bounce, a shuffle) is one step and `steps >= 2` means both feet have landed
    past the end. Both feet landing together (after a hop) is one step; either foot's next
    landing is then the second."""
    feet_x = soles_x.reshape(2, 4).mean(axis=1)
    land = touchdowns(contact, contact_prev) & (feet_x > art_end_x)
    both = land[0] & land[1]
    new = both | (land[0] & (last_foot != LEFT)) | (land[1] & (last_foot != RIGHT))
    last = jnp.where(both, NO_FOOT, jnp.where(land[0], LEFT, jnp.where(land[1], RIGHT, last_foot)))
    return steps + new.astype(jnp.int32), last


class Labelling(NamedTuple):
    """Per-env label state of a switch episode (leading batch axes allowed)."""

    steps: jax.Array  # int32: steps past the artifact's end after the switch (count_steps_past)
    last_foot: jax.Array  # int32: LEFT / RIGHT / NO_FOOT, the foot of the last step there
    ended: jax.Array  # bool: fell, labelled, or the env's episode is over: the record is final
    label: jax.Array  # bool
    fell: jax.Array  # bool
    fell_before: jax.Array  # bool: fell before the switch (no sample)


def labelling_init(shape=()) -> Labelling:
    z = jnp.zeros(shape, jnp.int32)
    f = jnp.zeros(shape, bool)
    return Labelling(z, z + NO_FOOT, f, f, f, f)


def is_live(lab: Labelling, t, horizon) -> jax.Array:
    """The episode still runs at control step t: not ended and within the horizon (a timeout
    leaves the label 0)."""
    return ~lab.ended & (t < horizon)


def label_step(lab: Labelling, live, switched_before, switched, contact, contact_prev, soles_x,
               art_end_x, fell, success, done, steps_past: int) -> Labelling:
    """One control step of the label rule for one env.

    `contact`, `contact_prev`, `soles_x` are this step's (the observation's) sole flags and sole x
    [m]; `fell`, `success`, `done` (bool) come from the env step taken from it. Landings count
    from the step after the switch (`switched_before`). Label 1 once `steps_past` steps are made
    past the end (or the finish is reached) and that step's env step does not fall; a fall first,
    the env's episode ending or the horizon leave 0. Once labelled the record is final."""
    steps, last = count_steps_past(lab.steps, lab.last_foot, contact, contact_prev, soles_x,
                                   art_end_x)
    counting = live & switched_before
    steps = jnp.where(counting, steps, lab.steps)
    last = jnp.where(counting, last, lab.last_foot)
    fell = live & fell
    label = live & switched & ((steps >= steps_past) | success) & ~fell
    ended = lab.ended | fell | label | (live & done)
    return Labelling(steps, last, ended, lab.label | label, lab.fell | fell,
                     lab.fell_before | (fell & ~switched))


class Window(NamedTuple):
    """Rolling record of observations around a switch, per env: a window of `before` points
    before the switch step, the switch step and the points after it (the sweep config's
    `window`; the array shapes carry the sizes)."""

    ring: jax.Array  # (before + 1, O): the last observations up to now, oldest first
    window: jax.Array  # (len(window), O)
    n_after: jax.Array  # int32: observations after the switch written so far


def window_init(obs, window=None) -> Window:
    """An empty record for step offsets `window` (default: the sweep config's)."""
    window = default_sweep_config().window if window is None else window
    before = window_span(window)
    ring = jnp.broadcast_to(obs, (before + 1,) + obs.shape)
    return Window(ring, jnp.zeros((len(window),) + obs.shape, obs.dtype), jnp.zeros((), jnp.int32))


def window_update(w: Window, obs, switched_now, switched_before) -> Window:
    """`obs` is the observation the (possibly new) policy acts on at this step.

    At the switch step t the ring (t-2, t-1, t with the default window) fills the first slots;
    each of the next steps writes one slot. An episode that ends first repeats its last
    observation."""
    before, n = w.ring.shape[0] - 1, w.window.shape[0]
    ring = jnp.concatenate([w.ring[1:], obs[None]])
    window = jnp.where(switched_now, w.window.at[: before + 1].set(ring), w.window)
    write = switched_before & (w.n_after < n - before - 1)
    slot = before + 1 + w.n_after
    window = jnp.where(write, window.at[jnp.minimum(slot, n - 1)].set(obs), window)
    return Window(ring, window, w.n_after + write.astype(jnp.int32))


def window_fill(w: Window) -> jax.Array:
    """The window with missing after-switch slots (episode ended) filled by the last written."""
    before, n = w.ring.shape[0] - 1, w.window.shape[0]
    idx = jnp.minimum(jnp.arange(n), before + w.n_after)
    return w.window[idx]

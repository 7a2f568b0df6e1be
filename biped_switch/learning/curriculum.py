"""The guided curriculum as a pure function: (curriculum state, episode stats) -> new state.

Three stages, each advanced one notch whenever a milestone of average episode reward is reached
(Tidd et al., "Guided Curriculum Learning for Walking Over Complex Terrain"):
  0 terrain   difficulty rises 0 -> 1 while the guide forces help (guide_scale = 1);
  1 guides    at full difficulty, guide_scale anneals 1 -> 0;
  2 pushes    random pushes grow, push_scale 0 -> 1.
A stage ends when its value reaches its end and one more milestone is met there; the trainer
records the end of the last one as `curriculum_done` in progress.json (the state stays at stage 2).

It also steps back one notch when most evaluation episodes fall (`regress_fell`), across stage
boundaries if need be (pushes 0 -> guides 0.025, guides 1 -> terrain), as legged_gym's terrain
curriculum moves a robot that fails down a level. It is needed because with a 5 s evaluation
that met about one artifact, jumps and stairs had annealed their guides to 0 while every 20 s
training episode still fell at the first or second artifact. A step back waits for
`regress_patience` such evaluations in a row (`strikes` counts them): the first check after an
advance often fell badly and the next one recovered at the same level (gaps stepped
0.2 -> 0.3 four times after one check each, jumps 0.025 -> 0.05 twice, stairs pushes 0.6 -> 0.5).
With a patience of 2, gaps at guides 0.1 fell 92-100% of four checks over two visits while its
training episodes went further each chunk (mean distance 1.7 -> 4.0 m, then 3.1 -> 5.3 m): it was
adapting when the step back came, so the patience is 4.

The guides' last notches are finer: once `guide_notch` of the scale is less than guide_step, each
notch takes that fraction of it, down to `guide_min_step` (0.5 halves: 0.2 -> 0.1 -> 0.05 ->
0.025 -> 0). Jumps at guides 0.1 fell in 12-27% of its evaluations and at 0 in 100%, twice, so
the step to 0 was a cliff. The end-to-end `mixed` policy met a cliff one notch
earlier: over 13 cuts 0.2 -> 0.1 every check at 0.1 fell 66-100% and each visit
ended in a step back, while its checkpoint at 0.2 fell 31% / 12% / 41% / 61% / 86% at guides
0.2 / 0.175 / 0.15 / 0.125 / 0.1, so it trains with `guide_notch` 0.25
(0.2 -> 0.15 -> 0.1125 -> 0.084 -> 0.059 -> 0.034 -> 0).
The push stage can also end on a plateau (`push_plateau_steps`; 0 disables): when its
highest level has not risen for that many env steps. The paper gives no push magnitude and says
the gradual pushes "allowed for greater final disturbances", so the level a policy holds is a
result, not a given. Under uniform pushes the longest wait before a rise was 8.5M steps (gaps
0.5 -> 0.6), while stairs (at 1.0), jumps (0.8) and gaps (0.6) then held their
levels for 4-12M steps with the milestone checks falling 36-64% and no trend (README, tuning
log). `push_held` is the level a policy last met a milestone at: the highest level below its
plateau. This host-side bookkeeping lives in progress.json, not in the traced state.
The state is a small pytree of scalars: it is logged, saved with every checkpoint, restored on
resume, and enters the environment as traced values, so a stage change never recompiles.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from biped_switch.config import default_curriculum_config

STAGES = ("terrain", "guides", "pushes")


class CurriculumState(NamedTuple):
    stage: int | jnp.ndarray = 0
    difficulty: float | jnp.ndarray = 0.0
    guide_scale: float | jnp.ndarray = 1.0
    push_scale: float | jnp.ndarray = 0.0
    strikes: int | jnp.ndarray = 0  # evaluations in a row that fell more than regress_fell

    def as_dict(self) -> dict:
        return {"stage": int(self.stage), "stage_name": STAGES[int(self.stage)],
                "difficulty": float(self.difficulty), "guide_scale": float(self.guide_scale),
                "push_scale": float(self.push_scale), "strikes": int(self.strikes)}

    @classmethod
    def from_dict(cls, d: dict) -> "CurriculumState":
        # checkpoints saved before the step-back patience existed have no strikes
        return cls(int(d["stage"]), float(d["difficulty"]), float(d["guide_scale"]),
                   float(d["push_scale"]), int(d.get("strikes", 0)))

    def levels(self) -> tuple:
        """What the environment sees (its traced difficulty, guide_scale, push_scale); neither
        the stage nor the strikes reach it, so only a change here restarts episodes under way."""
        return (self.difficulty, self.guide_scale, self.push_scale)


def milestone(reward_per_step, progress_frac, cfg=None, fell_frac=0.0):
    """True when the mean reward per step, the progress (if asked) and the fall rate meet the
    milestone. The fall cap matters on artifact tracks: a policy that walks well and then falls
    into the gap still scores a high reward per step (gaps reached difficulty 1 with 70% of its
    5 s evaluation episodes falling)."""
    cfg = cfg or default_curriculum_config()
    ok = reward_per_step >= cfg.reward_milestone * cfg.reward_per_step_max
    return ok & (progress_frac >= cfg.min_progress) & (fell_frac <= cfg.max_fell)


def regressed(fell_frac, cfg=None):
    """True when so many evaluation episodes fell that the curriculum steps back a notch."""
    cfg = cfg or default_curriculum_config()
    return jnp.asarray(fell_frac) > cfg.regress_fell


def update(cs: CurriculumState, reward_per_step, progress_frac, cfg=None,
           fell_frac=0.0) -> CurriculumState:
    """One notch forward on a milestone, one back when more than `regress_fell` of the
    evaluation episodes fell in `regress_patience` evaluations in a row, else no change; pure and
    jittable."""
    cfg = cfg or default_curriculum_config()
    hit = milestone(reward_per_step, progress_frac, cfg, fell_frac)
    bad = regressed(fell_frac, cfg) & ~hit
    strikes = jnp.where(bad, jnp.asarray(cs.strikes) + 1, 0)
    back = bad & (strikes >= cfg.regress_patience)
    strikes = jnp.where(back, 0, strikes)
    stage = jnp.asarray(cs.stage)
    in_terrain, in_guides, in_pushes = stage == 0, stage == 1, stage == 2
    at_full = cs.difficulty >= 1.0 - 1e-6
    guides_off = cs.guide_scale <= 1e-6
    guides_full = cs.guide_scale >= 1.0 - 1e-6
    pushes_off = cs.push_scale <= 1e-6
    # forward
    difficulty = jnp.where(hit & in_terrain, jnp.minimum(cs.difficulty + cfg.difficulty_step, 1.0),
                           cs.difficulty)
    g = cs.guide_scale
    # the last guide notches take `guide_notch` of the scale (0.5: 0.1 -> 0.05 -> 0.025 -> 0);
    # a step back undoes one (0.5: doubles), so forward and back walk the same ladder
    f = cfg.guide_notch
    fwd = jnp.minimum(cfg.guide_step, jnp.maximum(f * g, cfg.guide_min_step))
    bwd = jnp.minimum(cfg.guide_step, jnp.maximum(g * f / (1.0 - f), cfg.guide_min_step))
    guide = jnp.where(hit & in_guides, jnp.maximum(g - fwd, 0.0), g)
    # a notch that would leave less than guide_min_step goes to 0
    guide = jnp.where(guide < cfg.guide_min_step - 1e-6, 0.0, guide)
    push = jnp.where(hit & in_pushes, jnp.minimum(cs.push_scale + cfg.push_step, 1.0), cs.push_scale)
    new_stage = jnp.where(hit & in_terrain & at_full, 1,
                          jnp.where(hit & in_guides & guides_off, 2, stage))
    # back: pushes down, then guides up, then terrain down
    push = jnp.where(back & in_pushes, jnp.maximum(cs.push_scale - cfg.push_step, 0.0), push)
    to_guides = back & in_pushes & pushes_off
    guide = jnp.where(back & in_guides, jnp.minimum(g + bwd, 1.0), guide)
    guide = jnp.where(to_guides, cfg.guide_min_step, guide)
    to_terrain = back & in_guides & guides_full
    difficulty = jnp.where((back & in_terrain) | to_terrain,
                           jnp.maximum(cs.difficulty - cfg.difficulty_step, 0.0), difficulty)
    new_stage = jnp.where(to_guides, 1, jnp.where(to_terrain, 0, new_stage))
    return CurriculumState(new_stage, difficulty, guide, push, strikes)


def push_high_update(high: float, high_step: int, stage: int, push_scale: float,
                     step: int) -> tuple[float, int]:
    """The push stage's highest level so far and the env step it was first reached at."""
    if int(stage) == 2 and float(push_scale) > high + 1e-6:
        return float(push_scale), int(step)
    return high, high_step


def push_high_from_rows(rows) -> tuple[float, int]:
    """`push_high_update` replayed over metrics.csv rows (checkpoints saved before the plateau rule
    existed did not record it); rows without a curriculum column are skipped."""
    high, high_step = 0.0, 0
    for r in rows:
        if r.get("curriculum/push_scale") not in (None, "") and r.get("curriculum/stage") not in (None, ""):
            high, high_step = push_high_update(high, high_step, int(float(r["curriculum/stage"])),
                                               float(r["curriculum/push_scale"]), int(float(r["step"])))
    return high, high_step


def push_plateaued(high: float, high_step: int, step: int, cfg=None) -> bool:
    """True when the push stage's highest level has not risen for
    `push_plateau_steps` env steps: the curriculum ends there (`push_held` is one notch below)."""
    cfg = cfg or default_curriculum_config()
    n = int(cfg.get("push_plateau_steps", 0))
    return n > 0 and high > 1e-6 and step - high_step >= n


def push_held(high: float, cfg=None) -> float:
    """The highest push level a policy met a milestone at, given its plateau's highest level."""
    cfg = cfg or default_curriculum_config()
    return round(max(high - cfg.push_step, 0.0), 6)


class CurriculumEnd(NamedTuple):
    """The host-side record of how far a run's curriculum has come beyond its traced state: the
    push stage's highest level and when it was reached (for the plateau rule), and whether, how
    and at which push level the curriculum ended. Saved in progress.json with every checkpoint."""

    done: bool = False
    end: str | None = None  # "full pushes" | "push plateau"
    held: float | None = None  # the push level the policy holds at the end
    high: float = 0.0
    high_step: int = 0

    @classmethod
    def from_progress(cls, prog: dict, rows_fn) -> "CurriculumEnd":
        """From a checkpoint's progress record; `rows_fn()` gives metrics.csv's rows up to it,
        read only for checkpoints saved before the plateau was recorded."""
        high, high_step = ((float(prog["push_high"]), int(prog["push_high_step"]))
                           if "push_high" in prog else push_high_from_rows(rows_fn()))
        return cls(bool(prog.get("curriculum_done", False)), prog.get("curriculum_end"),
                   prog.get("push_held"), high, high_step)

    def as_progress(self) -> dict:
        return {"curriculum_done": self.done, "curriculum_end": self.end,
                "push_held": self.held, "push_high": self.high, "push_high_step": self.high_step}

    def after_check(self, cs: CurriculumState, new_cs: CurriculumState, ev: dict, step: int,
                    cfg=None) -> tuple["CurriculumEnd", str | None]:
        """The record after a chunk's check `ev` moved `cs` to `new_cs` at env step `step`, and a
        message when the push stage just ended on a plateau. The last stage ends like the others:
        at its end value, with one more milestone there."""
        cfg = cfg or default_curriculum_config()
        done, end, held = self.done, self.end, self.held
        done = done or bool(int(cs.stage) == 2 and float(cs.push_scale) >= 1.0 - 1e-6
                            and milestone(ev["reward_per_step"], ev["progress_frac"], cfg,
                                          fell_frac=ev["fell"]))
        if done and end is None:
            end, held = "full pushes", 1.0
        high, high_step = push_high_update(self.high, self.high_step, int(new_cs.stage),
                                           float(new_cs.push_scale), step)
        msg = None
        if not done and push_plateaued(high, high_step, step, cfg):
            done, end, held = True, "push plateau", push_held(high, cfg)
            msg = (f"the push stage has not risen above {high:.2f} for {step - high_step:,} env "
                   f"steps (push_plateau_steps {int(cfg.push_plateau_steps):,}): the curriculum "
                   f"ends on a plateau, holding push {held:.2f}")
        return CurriculumEnd(done, end, held, high, high_step), msg

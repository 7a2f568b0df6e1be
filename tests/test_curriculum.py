"""The guided curriculum's stage logic on synthetic rewards (pure function, no environment)."""

import jax
import numpy as np
import pytest

from biped_switch.learning import curriculum as cl
from biped_switch.config import default_curriculum_config

CFG = default_curriculum_config()
CFG1 = default_curriculum_config()  # steps back after one bad evaluation
CFG1.regress_patience = 1
HIT = CFG.reward_milestone * CFG.reward_per_step_max  # 0.65 * 5.4 = 3.51 reward per step
MISS = HIT - 0.01


def test_milestone_threshold_is_hand_computed():
    assert HIT == pytest.approx(3.51)
    assert bool(cl.milestone(3.5101, 1.0, CFG))
    assert not bool(cl.milestone(3.50, 1.0, CFG))


def test_fall_cap_blocks_a_milestone():
    """A high reward per step with too many falls (late falls at an artifact) is no milestone."""
    assert CFG.max_fell == pytest.approx(0.25)
    assert bool(cl.milestone(4.5, 1.0, CFG, fell_frac=0.25))
    assert not bool(cl.milestone(4.5, 1.0, CFG, fell_frac=0.26))
    cs = cl.update(cl.CurriculumState(0, 0.9, 1.0, 0.0), 4.5, 1.0, CFG, fell_frac=0.5)
    assert float(cs.difficulty) == pytest.approx(0.9)
    cs = cl.update(cs, 4.5, 1.0, CFG, fell_frac=0.1)
    assert float(cs.difficulty) == pytest.approx(1.0)


def test_many_falls_step_back_across_stages():
    """Above `regress_fell` the state walks back, one notch per evaluation: pushes 0.2 -> 0.1 -> 0,
    then guides 0.025 -> 0.05 -> 0.1 -> 0.2 ... -> 1, then difficulty 1 -> 0.9 -> ... -> 0, and
    stays there."""
    assert CFG.regress_fell == pytest.approx(0.6)
    cs = cl.CurriculumState(2, 1.0, 0.0, 0.2)
    trace = []
    for _ in range(25):
        cs = cl.update(cs, 4.5, 1.0, CFG1, fell_frac=0.61)
        trace.append((int(cs.stage), round(float(cs.difficulty), 6), round(float(cs.guide_scale), 6),
                      round(float(cs.push_scale), 6)))
    assert trace[:6] == [(2, 1.0, 0.0, 0.1), (2, 1.0, 0.0, 0.0), (1, 1.0, 0.025, 0.0),
                         (1, 1.0, 0.05, 0.0), (1, 1.0, 0.1, 0.0), (1, 1.0, 0.2, 0.0)]
    assert trace[12] == (1, 1.0, 0.9, 0.0) and trace[13] == (1, 1.0, 1.0, 0.0)
    assert trace[14] == (0, 0.9, 1.0, 0.0)  # guides full and still falling: terrain steps down
    assert trace[15] == (0, 0.8, 1.0, 0.0)
    assert trace[23] == (0, 0.0, 1.0, 0.0) and trace[24] == (0, 0.0, 1.0, 0.0)


def test_between_the_thresholds_holds():
    """Falls between max_fell and regress_fell neither advance nor regress; exactly at
    regress_fell holds too."""
    cs0 = cl.CurriculumState(1, 1.0, 0.5, 0.0)
    for fell in (0.26, 0.45, 0.6):
        cs = cl.update(cs0, 4.5, 1.0, CFG, fell_frac=fell)
        assert (int(cs.stage), float(cs.guide_scale)) == (1, pytest.approx(0.5))
    cs = cl.update(cs0, 4.5, 1.0, CFG, fell_frac=0.2)
    assert float(cs.guide_scale) == pytest.approx(0.4)
    cs = cl.update(cs0, 1.0, 1.0, CFG1, fell_frac=0.9)
    assert float(cs.guide_scale) == pytest.approx(0.6)


def test_a_step_back_waits_for_patience():
    """With regress_patience 4, bad evaluations count strikes; the fourth in a row steps back and
    clears them; a good evaluation (a hold or a milestone) clears them too."""
    assert CFG.regress_patience == 4
    cs = cl.CurriculumState(1, 1.0, 0.2, 0.0)
    for n in (1, 2, 3):
        cs = cl.update(cs, 1.0, 1.0, CFG, fell_frac=0.9)
        assert (float(cs.guide_scale), int(cs.strikes)) == (pytest.approx(0.2), n)
    held = cl.update(cs, 3.0, 1.0, CFG, fell_frac=0.4)  # between the thresholds
    assert (float(held.guide_scale), int(held.strikes)) == (pytest.approx(0.2), 0)
    hit = cl.update(cs, 4.5, 1.0, CFG, fell_frac=0.1)
    assert (float(hit.guide_scale), int(hit.strikes)) == (pytest.approx(0.1), 0)
    cs = cl.update(cs, 1.0, 1.0, CFG, fell_frac=0.9)
    assert (float(cs.guide_scale), int(cs.strikes)) == (pytest.approx(0.3), 0)
    # the next bad one is a first strike again at the new level
    cs = cl.update(cs, 1.0, 1.0, CFG, fell_frac=0.9)
    assert (float(cs.guide_scale), int(cs.strikes)) == (pytest.approx(0.3), 1)


def test_coarse_guide_notches_when_min_step_is_the_step():
    cfg = default_curriculum_config()
    cfg.guide_min_step = cfg.guide_step
    cs = cl.update(cl.CurriculumState(1, 1.0, 0.1, 0.0), HIT + 0.1, 1.0, cfg)
    assert float(cs.guide_scale) == 0.0
    cfg.regress_patience = 1
    cs = cl.update(cl.CurriculumState(1, 1.0, 0.0, 0.0), 1.0, 1.0, cfg, fell_frac=1.0)
    assert float(cs.guide_scale) == pytest.approx(0.1)


def test_a_finer_guide_notch_walks_a_ladder_both_ways():
    """guide_notch 0.25 (the mixed policy's): from 0.4 the notch is 0.1, below it a quarter of the
    scale, at least guide_min_step, and a notch that would leave less than that ends at 0 (0.034375
    - 0.025 < 0.025); a step back undoes a notch (g / 0.75, at least guide_min_step). Hand-computed:
    0.2 * 0.75 = 0.15, 0.15 * 0.75 = 0.1125, 0.1125 * 0.75 = 0.084375, then 0.25 * 0.084375 <
    0.025, so - 0.025 twice."""
    cfg = default_curriculum_config()
    cfg.guide_notch = 0.25
    cs, fwd = cl.CurriculumState(1, 1.0, 0.4, 0.0), []
    for _ in range(8):
        cs = cl.update(cs, HIT + 0.1, 1.0, cfg)
        fwd.append(round(float(cs.guide_scale), 6))
    # 0.4 - 0.1; then * 0.75 while a quarter is >= 0.025 (0.126563 / 4 = 0.0316, 0.094922 / 4 =
    # 0.0237 < 0.025); then - 0.025 until less than 0.025 would be left
    assert fwd == [0.3, 0.225, 0.16875, 0.126563, 0.094922, 0.069922, 0.044922, 0.0]
    cs = cl.update(cl.CurriculumState(1, 1.0, 0.2, 0.0), HIT + 0.1, 1.0, cfg)
    ladder = [round(float(cs.guide_scale), 6)]
    for _ in range(5):
        cs = cl.update(cs, HIT + 0.1, 1.0, cfg)
        ladder.append(round(float(cs.guide_scale), 6))
    assert ladder == [0.15, 0.1125, 0.084375, 0.059375, 0.034375, 0.0]
    assert int(cl.update(cs, HIT + 0.1, 1.0, cfg).stage) == 2  # one more milestone at 0 ends it
    cfg.regress_patience = 1
    back = []
    for g in (0.0, 0.034375, 0.084375, 0.1125, 0.15, 0.2):
        cs = cl.update(cl.CurriculumState(1, 1.0, g, 0.0), 1.0, 1.0, cfg, fell_frac=1.0)
        back.append(round(float(cs.guide_scale), 6))
    assert back == [0.025, 0.059375, 0.1125, 0.15, 0.2, 0.266667]  # 0.2667 * 0.75 = 0.2


def test_guide_notch_half_is_the_halving_ladder():
    """The default 0.5 keeps every run before session 20 on its own ladder."""
    assert CFG.guide_notch == 0.5
    cs, ladder = cl.CurriculumState(1, 1.0, 0.3, 0.0), []
    for _ in range(5):
        cs = cl.update(cs, HIT + 0.1, 1.0, CFG)
        ladder.append(round(float(cs.guide_scale), 6))
    assert ladder == [0.2, 0.1, 0.05, 0.025, 0.0]


def test_regress_can_be_disabled():
    cfg = default_curriculum_config()
    cfg.regress_fell = 1.0
    cs = cl.CurriculumState(2, 1.0, 0.0, 0.3)
    for _ in range(3):
        cs = cl.update(cs, 1.0, 1.0, cfg, fell_frac=1.0)
    assert float(cs.push_scale) == pytest.approx(0.3)


def test_no_milestone_no_change():
    cs = cl.CurriculumState(0, 0.3, 1.0, 0.0)
    for _ in range(5):
        cs = cl.update(cs, MISS, 1.0, CFG)
    assert (int(cs.stage), float(cs.difficulty), float(cs.guide_scale)) == (0, pytest.approx(0.3), 1.0)


def _run(rewards, cs=cl.CurriculumState()):
    trace = []
    for r in rewards:
        cs = cl.update(cs, r, 1.0, CFG)
        trace.append(tuple(float(v) for v in cs))
    return cs, trace


def test_full_sequence_terrain_then_guides_then_pushes():
    # 10 milestones raise difficulty 0 -> 1, the 11th ends stage 0; 9 anneal guides to 0.1, then
    # the finer notches 0.05, 0.025, 0; the 24th ends stage 1; then pushes rise and cap at 1.
    cs, trace = _run([HIT] * 40)
    stages = [int(t[0]) for t in trace]
    assert stages[:10] == [0] * 10 and stages[10] == 1
    assert trace[9][1] == pytest.approx(1.0) and trace[8][1] == pytest.approx(0.9)
    assert all(t[2] == 1.0 for t in trace[:11])  # guides untouched during the terrain stage
    assert [round(t[2], 6) for t in trace[18:23]] == [0.2, 0.1, 0.05, 0.025, 0.0]
    assert stages[22] == 1 and stages[23] == 2
    assert all(t[3] == 0.0 for t in trace[:24])  # no pushes before stage 2
    assert trace[24][3] == pytest.approx(0.1)
    assert float(cs.push_scale) == pytest.approx(1.0) and int(cs.stage) == 2


def test_misses_interleaved_only_count_hits():
    rewards = [HIT, MISS, MISS, HIT, MISS, HIT]
    cs, _ = _run(rewards)
    assert float(cs.difficulty) == pytest.approx(0.3)


def test_progress_gate():
    cfg = default_curriculum_config()
    cfg.min_progress = 0.5
    cs = cl.update(cl.CurriculumState(), HIT, 0.4, cfg)
    assert float(cs.difficulty) == 0.0
    cs = cl.update(cl.CurriculumState(), HIT, 0.5, cfg)
    assert float(cs.difficulty) == pytest.approx(0.1)


def test_jit_matches_python():
    f = jax.jit(lambda cs, r, fell: cl.update(cs, r, 1.0, CFG, fell_frac=fell))
    cs_py, cs_jit = cl.CurriculumState(), cl.CurriculumState()
    seq = ([(HIT, 0.0), (MISS, 0.0)] * 3 + [(HIT, 0.0)] * 15 + [(MISS, 0.9)] * 5
           + [(MISS, 0.4), (MISS, 0.9)] * 2 + [(MISS, 0.9)] * 4 + [(HIT, 0.1)] * 3)
    for r, fell in seq:
        cs_py = cl.update(cs_py, r, 1.0, CFG, fell_frac=fell)
        cs_jit = f(cs_jit, r, fell)
    np.testing.assert_allclose([float(v) for v in cs_py], [float(v) for v in cs_jit], atol=1e-6)


def test_dict_round_trip():
    cs = cl.CurriculumState(2, 1.0, 0.0, 0.4, 1)
    d = cs.as_dict()
    assert d["stage_name"] == "pushes" and d["strikes"] == 1
    assert cl.CurriculumState.from_dict(d) == cs
    del d["strikes"]  # a checkpoint from before session 8
    assert cl.CurriculumState.from_dict(d) == cs._replace(strikes=0)


def test_curve_series_after_a_restart():
    from biped_switch.learning.runs import curve_series

    rows = [{"step": "1", "r": "1"}, {"step": "2", "r": "2"}, {"step": "3", "r": ""},
            {"step": "4", "r": "4"},  # chunk abandoned by a restart at step 2
            {"step": "2", "r": "20"}, {"step": "3", "r": "30"}]
    np.testing.assert_array_equal(curve_series(rows, "r"), [[1, 1], [2, 20], [3, 30]])
    assert curve_series(rows, "missing").shape == (0, 2)


def test_push_plateau_by_hand():
    """The plateau clock starts when the push stage first reaches a new highest level; a step
    back and a return to that level do not restart it, and only the push stage counts."""
    cfg = default_curriculum_config()
    cfg.push_plateau_steps = 1000
    rows = [  # (step, stage, push after the check)
        (100, 1, 0.0), (200, 2, 0.0), (300, 2, 0.1), (400, 2, 0.2), (500, 2, 0.1), (600, 2, 0.2),
        (700, 2, 0.2)]
    high, at = 0.0, 0
    for step, stage, push in rows:
        high, at = cl.push_high_update(high, at, stage, push, step)
    assert (high, at) == (0.2, 400)
    assert not cl.push_plateaued(high, at, 1399, cfg) and cl.push_plateaued(high, at, 1400, cfg)
    assert cl.push_held(high, cfg) == pytest.approx(0.1)
    csv_rows = [{"step": str(s), "curriculum/stage": str(st), "curriculum/push_scale": str(p)}
                for s, st, p in rows] + [{"step": "750", "curriculum/stage": "", "reward": "1"}]
    assert cl.push_high_from_rows(csv_rows) == (0.2, 400)
    assert not cl.push_plateaued(0.0, 0, 10**9, cfg)  # never in the push stage
    cfg.push_plateau_steps = 0  # disabled: only a milestone at push 1 ends the curriculum
    assert not cl.push_plateaued(high, at, 10**9, cfg)

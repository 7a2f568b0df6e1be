"""The guided curriculum's stage logic on synthetic rewards (pure function, no environment)."""

import jax
import numpy as np
import pytest

from biped_switch import curriculum as cl
from biped_switch.config import default_curriculum_config

CFG = default_curriculum_config()
HIT = CFG.reward_milestone * CFG.reward_per_step_max  # 0.7 * 5.4 = 3.78 reward per step
MISS = HIT - 0.01


def test_milestone_threshold_is_hand_computed():
    assert HIT == pytest.approx(3.78)
    assert bool(cl.milestone(3.78, 1.0, CFG))
    assert not bool(cl.milestone(3.77, 1.0, CFG))


def test_fall_cap_blocks_a_milestone():
    """A high reward per step with too many falls (late falls at an artifact) is no milestone."""
    assert CFG.max_fell == pytest.approx(0.25)
    assert bool(cl.milestone(4.5, 1.0, CFG, fell_frac=0.25))
    assert not bool(cl.milestone(4.5, 1.0, CFG, fell_frac=0.26))
    cs = cl.update(cl.CurriculumState(0, 0.9, 1.0, 0.0), 4.5, 1.0, CFG, fell_frac=0.7)
    assert float(cs.difficulty) == pytest.approx(0.9)
    cs = cl.update(cs, 4.5, 1.0, CFG, fell_frac=0.1)
    assert float(cs.difficulty) == pytest.approx(1.0)


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
    # 10 milestones raise difficulty 0 -> 1, the 11th ends stage 0; 10 more anneal guides to 0,
    # the 21st ... ends stage 1; then pushes rise and cap at 1.
    cs, trace = _run([HIT] * 40)
    stages = [int(t[0]) for t in trace]
    assert stages[:10] == [0] * 10 and stages[10] == 1
    assert trace[9][1] == pytest.approx(1.0) and trace[8][1] == pytest.approx(0.9)
    assert all(t[2] == 1.0 for t in trace[:11])  # guides untouched during the terrain stage
    assert trace[20][2] == pytest.approx(0.0) and stages[20] == 1 and stages[21] == 2
    assert all(t[3] == 0.0 for t in trace[:22])  # no pushes before stage 2
    assert trace[22][3] == pytest.approx(0.1)
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
    f = jax.jit(lambda cs, r: cl.update(cs, r, 1.0, CFG))
    cs_py, cs_jit = cl.CurriculumState(), cl.CurriculumState()
    for r in [HIT, MISS] * 3 + [HIT] * 15:
        cs_py = cl.update(cs_py, r, 1.0, CFG)
        cs_jit = f(cs_jit, r)
    np.testing.assert_allclose([float(v) for v in cs_py], [float(v) for v in cs_jit], atol=1e-6)


def test_dict_round_trip():
    cs = cl.CurriculumState(2, 1.0, 0.0, 0.4)
    d = cs.as_dict()
    assert d["stage_name"] == "pushes"
    assert cl.CurriculumState.from_dict(d) == cs


def test_curve_series_after_a_restart():
    from biped_switch.runs import curve_series

    rows = [{"step": "1", "r": "1"}, {"step": "2", "r": "2"}, {"step": "3", "r": ""},
            {"step": "4", "r": "4"},  # chunk abandoned by a restart at step 2
            {"step": "2", "r": "20"}, {"step": "3", "r": "30"}]
    np.testing.assert_array_equal(curve_series(rows, "r"), [[1, 1], [2, 20], [3, 30]])
    assert curve_series(rows, "missing").shape == (0, 2)

"""Table I metrics on hand-made rollouts, against hand-computed values."""

import numpy as np
import pytest

from biped_switch import evaluate as ev


def test_wilson_interval_hand_values():
    lo, hi = ev.wilson_ci(5, 10)  # p = 0.5, n = 10: 0.2366 .. 0.7634
    assert (lo, hi) == (pytest.approx(0.23659, abs=1e-5), pytest.approx(0.76341, abs=1e-5))
    lo, hi = ev.wilson_ci(0, 20)  # all failures: [0, 0.1611]
    assert lo == 0.0 and hi == pytest.approx(0.16113, abs=1e-5)
    lo, hi = ev.wilson_ci(20, 20)
    assert hi == 1.0 and lo == pytest.approx(1 - 0.16113, abs=1e-5)


def test_episode_table_from_hand_made_rollouts():
    # 4 episodes: two reach the finish, one falls on a gap at 50%, one on stairs at 25%.
    res = {
        "progress_frac": np.array([1.0, 1.0, 0.5, 0.25]),
        "success": np.array([1.0, 1.0, 0.0, 0.0]),
        "fell": np.array([0.0, 0.0, 1.0, 1.0]),
        "fail_kind": np.array([-1.0, -1.0, 1.0, 2.0]),
    }
    t = ev.episode_table(res)
    assert t["n"] == 4
    assert t["distance_pct"] == pytest.approx(68.75)
    sd = np.std([100, 100, 50, 25], ddof=1)
    assert t["distance_ci"][1] - t["distance_pct"] == pytest.approx(1.96 * sd / 2)
    assert t["success_pct"] == pytest.approx(50.0)
    assert t["success_ci"] == [pytest.approx(100 * x) for x in ev.wilson_ci(2, 4)]
    assert t["fell_pct"] == pytest.approx(50.0)
    assert t["fail_on"] == {"jumps": 0.0, "gaps": pytest.approx(25.0), "stairs": pytest.approx(25.0)}


def test_markdown_row_has_paper_figures():
    row = {"policy": "gaps", "init": "random", "n": 4, "distance_pct": 68.75, "distance_ci": [40, 90],
           "success_pct": 50.0, "success_ci": [15, 85], "train_step": 1000,
           "curriculum": {"stage_name": "terrain", "difficulty": 0.3, "guide_scale": 1.0}}
    md = ev.table1_markdown([row])
    assert "| gaps | random | 4 | 68.8 (40.0-90.0) | 50.0 (15.0-85.0) | 87.4 | 75.5 |" in md

"""Which policy was acting when the robot fell on an artifact (`evaluate failures`), on
hand-made trials."""

from types import SimpleNamespace

import numpy as np
import pytest

from biped_switch.reports.table2 import policy_on_falls, policy_on_falls_markdown


def test_policy_on_falls_counts_wrong_policies_by_hand():
    # one track: jumps at 3-4 m, gaps at 6-7 m; finish line at 10 m
    track = SimpleNamespace(artifacts=[("jumps", 3.0, 4.0), ("gaps", 6.0, 7.0)], finish_x_m=10.0)
    tracks = [track] * 4
    progress = np.array([0.65, 0.65, 0.35, 1.0])  # x = 6.5, 6.5, 3.5, 10 m
    fell = np.array([1.0, 1.0, 1.0, 0.0])
    fail_kind = np.array([1, 1, 0, -1])  # gaps, gaps, jumps, none
    # policy index acting as the CoM came over each start: walk 0, jumps 1, gaps 2, stairs 3
    on = np.array([[1, 2],    # right policy on the gap
                   [1, 1],    # the jumps policy still acting on the gap: a missed detection
                   [-1, -1],  # fell before the jumps' start
                   [1, 2]])
    out = policy_on_falls(tracks, progress, fell, fail_kind, on, detect_range_m=0.9)
    assert out["gaps"] == {"falls": 2, "wrong_policy": 1, "before_start": 0}
    assert out["jumps"] == {"falls": 1, "wrong_policy": 0, "before_start": 1}
    assert out["stairs"] == {"falls": 0, "wrong_policy": 0, "before_start": 0}
    md = policy_on_falls_markdown({"lookup_context": out})
    assert "| lookup_context | 1 / 0 / 1 | 2 / 1 / 0 | 0 / 0 / 0 |" in md


def test_suite_ceiling_by_hand():
    """Per-artifact success = Table I success ** (1/7); a track's = the product over its
    artifacts; the ceiling = the mean over tracks (hand-computed)."""
    from biped_switch.reports.table2 import suite_ceiling

    rows = [{"policy": k, "init": "stand", "success_pct": 100 * s, "success_ci": [100 * lo, 100]}
            for k, s, lo in (("jumps", 0.5 ** 7, 0.25 ** 7), ("gaps", 1.0, 1.0),
                             ("stairs", 0.9 ** 7, 0.8 ** 7))]
    rows.append({"policy": "walk", "init": "stand", "success_pct": 0.0, "success_ci": [0, 0]})
    tracks = [SimpleNamespace(artifacts=[("jumps", 0, 1), ("gaps", 2, 3), ("stairs", 4, 5)]),
              SimpleNamespace(artifacts=[("gaps", 0, 1), ("gaps", 2, 3)])]
    c = suite_ceiling(rows, tracks)
    assert abs(c["ceiling_pct"] - 100 * (0.5 * 0.9 + 1.0) / 2) < 1e-9
    assert abs(c["ceiling_ci"][0] - 100 * (0.25 * 0.8 + 1.0) / 2) < 1e-9
    assert abs(c["ceiling_ci"][1] - 100.0) < 1e-9
    assert c["artifacts_per_track"] == {"jumps": 0.5, "gaps": 1.5, "stairs": 0.5}
    with pytest.raises(ValueError, match="stairs"):
        suite_ceiling(rows[:2], tracks)

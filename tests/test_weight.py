"""The repository's weight: every tracked GIF at most 1.5 MB (scripts/shrink_gifs.py re-encodes
one that is not), and each committed run tracks only its final checkpoint."""

from __future__ import annotations

import re
import subprocess

from biped_switch.learning import runs as runs_lib
from biped_switch.paths import REPO

GIF_LIMIT = 1_500_000


def _tracked(*patterns) -> list[str]:
    return subprocess.run(["git", "ls-files", *patterns], cwd=REPO, capture_output=True, text=True,
                          check=True).stdout.split()


def test_gifs_at_most_1_5_mb():
    gifs = _tracked("*.gif")
    big = {g: (REPO / g).stat().st_size for g in gifs if (REPO / g).stat().st_size > GIF_LIMIT}
    assert gifs and not big, f"over 1.5 MB (python scripts/shrink_gifs.py shrinks them): {big}"


def test_only_the_final_checkpoint_is_committed():
    """One checkpoint per committed run under checkpoints/, its newest (a warm-start source that
    only git history held lies in warm_start/, outside the resume path)."""
    per_run = {}
    for f in _tracked("models"):
        m = re.match(r"(models/[^/]+/[^/]+)/checkpoints/(\d{12})/", f)
        if m:
            per_run.setdefault(m.group(1), set()).add(m.group(2))
    assert per_run and all(len(v) == 1 for v in per_run.values()), per_run
    for run, (step,) in per_run.items():
        assert runs_lib.latest_checkpoint(REPO / run).name == step, run

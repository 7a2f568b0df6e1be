"""docs/results.md is generated from the committed result files (reports/results.py): this fails
when it is stale, i.e. when a result file changed and `make docs` was not run."""

from __future__ import annotations

import json
import shutil

from biped_switch.paths import REPO
from biped_switch.reports import results


def test_results_doc_is_current():
    assert results.DOC.read_text() == results.render(), (
        "docs/results.md is stale: run `make docs` (python -m biped_switch.reports.results)")


def test_numbers_follow_the_files(tmp_path):
    """A changed result file changes the page: its tables are copied and its prose numbers read."""
    res = tmp_path / "results"
    skip = shutil.ignore_patterns("*.npz", "*.png", "*.gif", "s0*")

    def ignore(folder, names):  # the page reads the when comparison's per-trial outcomes
        return set() if "tune1000_" in folder else skip(folder, names)

    shutil.copytree(REPO / "experiments" / "results", res, ignore=ignore)
    t3 = json.loads((res / "table3/table3.json").read_text())
    t3["rows"][0]["hours"] = 99.125
    (res / "table3/table3.json").write_text(json.dumps(t3))
    (res / "table1/table1.md").write_text("| a table that changed |\n")
    page = results.render(res)
    assert "| ours | 99.12 |" in page and "| a table that changed |" in page
    assert "{{" not in page and "}}" not in page


def test_check_mode(tmp_path, capsys):
    stale = tmp_path / "results.md"
    stale.write_text("old\n")
    assert results.main(["--check", "--out", str(stale)]) == 1
    assert results.main(["--check"]) == 0


def test_paired_rows_count_the_trials_only_one_model_won(tmp_path):
    import numpy as np

    def run(name, won, when_dir):
        d = tmp_path / name
        d.mkdir()
        n = len(won)
        (d / "table2.json").write_text(json.dumps({
            "settings": {"trials": n, "track_seed": 50000, "when_dir": when_dir},
            "device": "cpu:0", "rows": [{"method": "learned", "success_pct": 100 * np.mean(won),
                                         "success_ci": [1.0, 99.0]}]}))
        np.savez(d / "table2_trials.npz", **{"learned/success": np.asarray(won, float)})

    run("a", [1, 1, 0, 0, 1], "models/switch_when")
    run("b", [1, 0, 1, 1, 0], "runs/x")
    md = results.paired_md(tmp_path, "a", {"b": "more data"})
    # b alone wins trials 2 and 3, a alone trials 1 and 4
    assert "| a | context sweeps (the committed models/switch_when) | 60.0 (1.0-99.0) | - |" in md
    assert "| b | more data | 60.0 (1.0-99.0) | 2 / 2 |" in md
    run("c", [1, 1, 1, 1, 1], "runs/y")
    assert "| c | all | 100.0 (1.0-99.0) | 2 / 0 |" in results.paired_md(tmp_path, "a", {"c": "all"})

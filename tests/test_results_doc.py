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
    shutil.copytree(REPO / "experiments" / "results", res,
                    ignore=shutil.ignore_patterns("*.npz", "*.png", "*.gif", "s0*"))
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

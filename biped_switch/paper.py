"""The paper's reference numbers (Tidd et al., Learning When to Switch), typed in once.

Our tables and figures print these beside our own numbers (reports/: table1, table2, table3,
fig4b, plots). Every number is a named field, never a position in a tuple. Plain values only:
importing this module imports nothing else.
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class Outcome:
    """% of total distance and % success of a row."""

    distance_pct: float
    success_pct: float


@dataclasses.dataclass(frozen=True)
class Table2Row(Outcome):
    """A Table II row: `fail_pct` {artifact kind: % of trials failing on it}."""

    fail_pct: dict

    def cells(self) -> tuple:
        """(distance, success, then each failure in the paper's column order), as printed."""
        return (self.distance_pct, self.success_pct, *(self.fail_pct[k] for k in TABLE2_FAIL_ORDER))


# Table I: each artifact policy on its own terrain: {policy: {init: Outcome}}
TABLE1 = {
    "jumps": {"stand": Outcome(93.1, 87.8), "random": Outcome(86.2, 77.5)},
    "gaps": {"stand": Outcome(76.0, 56.3), "random": Outcome(87.4, 75.5)},
    "stairs": {"stand": Outcome(71.4, 52.1), "random": Outcome(78.7, 59.0)},
}

TABLE2_FAIL_ORDER = ("gaps", "jumps", "stairs")  # the order of Table II's failure columns


def _t2(distance_pct, success_pct, gaps, jumps, stairs) -> Table2Row:
    return Table2Row(distance_pct, success_pct, {"gaps": gaps, "jumps": jumps, "stairs": stairs})


# Table II: {method: Table2Row}
TABLE2 = {
    "random": _t2(42.7, 10.1, gaps=70.6, jumps=11.6, stairs=7.6),
    "detection": _t2(75.6, 60.1, gaps=21.4, jumps=3.3, stairs=15.2),
    "lookup": _t2(76.3, 59.0, gaps=21.2, jumps=4.7, stairs=14.9),
    "com_over_feet": _t2(79.1, 66.8, gaps=17.6, jumps=2.7, stairs=12.9),
    "estimator": _t2(82.4, 71.4, gaps=16.7, jumps=2.4, stairs=9.4),
    "estimator_no_overlap": _t2(17.5, 0.7, gaps=58.6, jumps=12.9, stairs=27.7),
    "dqn": _t2(83.2, 72.4, gaps=15.1, jumps=3.7, stairs=8.8),
    "end_to_end": _t2(92.7, 90.2, gaps=4.2, jumps=1.8, stairs=3.7),
}

# Table III: hours (CPU) to add a new terrain type to a two-behaviour suite
TABLE3_H = {"ours": 20.0, "dqn": 25.0, "end_to_end": 34.0}

# the paper's experiment sizes
TRIALS = {"table1": 500, "table2": 2500}  # trials per row
SWEEP_POINTS = 100_000  # switch-sweep data points per target terrain kind
ARTIFACTS = 7  # artifacts per test track

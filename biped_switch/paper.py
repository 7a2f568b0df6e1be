"""The paper's reference numbers (Tidd et al., Learning When to Switch), typed in once.

Our tables print these beside our own numbers (table1.py, table2.py, table3.py, fig4b.py) and
the result notebooks draw them (experiments/notebooks/_common.py). Plain values only: importing this module
imports nothing else.
"""

# Table I: % total distance and % success of each artifact policy on its own terrain, stand init
# then random init: (dist. stand, success stand, dist. random, success random)
TABLE1 = {
    "jumps": (93.1, 87.8, 86.2, 77.5),
    "gaps": (76.0, 56.3, 87.4, 75.5),
    "stairs": (71.4, 52.1, 78.7, 59.0),
}

# Table II: % total distance, % success, then % of trials failing on gaps / jumps / stairs
TABLE2 = {
    "random": (42.7, 10.1, 70.6, 11.6, 7.6),
    "detection": (75.6, 60.1, 21.4, 3.3, 15.2),
    "lookup": (76.3, 59.0, 21.2, 4.7, 14.9),
    "com_over_feet": (79.1, 66.8, 17.6, 2.7, 12.9),
    "estimator": (82.4, 71.4, 16.7, 2.4, 9.4),
    "estimator_no_overlap": (17.5, 0.7, 58.6, 12.9, 27.7),
    "dqn": (83.2, 72.4, 15.1, 3.7, 8.8),
    "end_to_end": (92.7, 90.2, 4.2, 1.8, 3.7),
}
TABLE2_FAIL_ORDER = ("gaps", "jumps", "stairs")  # the order of Table II's failure columns

# Table III: hours (CPU) to add a new terrain type to a two-behaviour suite
TABLE3_H = {"ours": 20.0, "dqn": 25.0, "end_to_end": 34.0}

# the paper's experiment sizes
TRIALS = {"table1": 500, "table2": 2500}  # trials per row
SWEEP_POINTS = 100_000  # switch-sweep data points per target terrain kind
ARTIFACTS = 7  # artifacts per test track

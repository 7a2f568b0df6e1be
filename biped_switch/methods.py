"""Table II's rows as records: one `Method` per row, saying what it runs and what it needs.

Every place that asks "which rule, which suite, which parts" of a row reads its record here
(evaluation/multi.py builds the rollout from it, the CLIs pick what to draw, the reports label
it), so no code decodes a method's name. Plain Python: importing this imports nothing of the
package (names.py derives its method tuples from it), so the reports layer may read it.
"""

from __future__ import annotations

from dataclasses import dataclass

RULES = ("random", "detection", "lookup", "com_over_feet", "estimator")  # switching/rules.py
PARTS_FROM = ("sweep", "context")  # a lookup table or estimators from the plain or context sweeps
# estimator_context_persist's run: as many control steps as a sweep sample's window
# (labels.N_WINDOW; a test ties the two)
WINDOW_STEPS = 5


@dataclass(frozen=True)
class Method:
    """One Table II row. `rule` is None for a baseline (its own rollout: DQN, end-to-end)."""

    name: str
    label: str  # for tables and figures
    whose: str  # "paper" (the paper's method on our policies) or "ours"
    colour: str  # its colour in figures (matplotlib name)
    rule: str | None = None  # one of RULES (switching/rules.py METHODS)
    suite: str = "stand"  # the policy suite and start: stand, or random (the no-overlap rows)
    lookup: str | None = None  # its lookup table: from the plain "sweep" or the "context" sweep
    estimators: str | None = None  # its switch estimators: "sweep" or "context"
    when: bool = False  # the learned when rule's model (switching/when.py) as its estimate
    setup_of: str | None = None  # the row whose rule it runs, with the setup policies added
    persist_steps: int | None = None  # estimate held this many steps in a row (None: config's)
    heuristic: bool = False  # one of the paper's hand-made rules
    reads_detector: bool = True  # False: the end-to-end policy reads only its heightmap
    fig5_suffix: str | None = None  # `evaluate multi` draws Fig. 5 as fig5_trial<i><suffix>.png
    policy: str | None = None  # a one-policy row (a baseline): the run <policy>_stand it runs

    def __post_init__(self):
        if self.rule is not None and self.rule not in RULES:
            raise ValueError(f"{self.name}: rule {self.rule!r} is not one of {RULES}")
        if self.suite not in ("stand", "random") or self.whose not in ("paper", "ours"):
            raise ValueError(f"{self.name}: suite {self.suite!r} / whose {self.whose!r}")
        if {self.lookup, self.estimators} - {None, *PARTS_FROM}:
            raise ValueError(f"{self.name}: parts from {self.lookup!r} / {self.estimators!r}")
        if self.policy is not None and self.rule is not None:
            raise ValueError(f"{self.name}: a one-policy row ({self.policy!r}) has no switching rule")

    @property
    def baseline(self) -> bool:
        return self.rule is None

    @property
    def setup(self) -> bool:
        """Runs a suite with the setup policies (switching/setup.py)."""
        return self.setup_of is not None

    @property
    def reads_model(self) -> bool:
        """Switches on a model's output (an estimator or the learned rule), logged at a switch."""
        return self.estimators is not None or self.when

    @property
    def rollout(self) -> str:
        """The compiled rollout it shares with the rows of equal key: suite, setup policies or
        not, the learned rule's model or not (a baseline: its own)."""
        if self.baseline:
            return self.name
        return self.suite + ("+setup" if self.setup else "") + ("+learned" if self.when else "")


_M = Method
TABLE2 = (
    _M("random", "Random", "paper", "tab:gray", "random", heuristic=True),
    _M("detection", "On detection", "paper", "tab:olive", "detection", heuristic=True),
    _M("lookup", "Lookup table", "paper", "tab:cyan", "lookup", lookup="sweep", heuristic=True),
    _M("com_over_feet", "CoM over feet", "paper", "tab:pink", "com_over_feet", heuristic=True),
    _M("estimator", "Estimator", "paper", "tab:blue", "estimator", estimators="sweep",
       fig5_suffix=""),
    _M("estimator_no_overlap", "Estimator, no overlap", "paper", "tab:purple", "estimator",
       suite="random", estimators="sweep"),
    _M("dqn", "DQN", "paper", "tab:brown"),
    _M("end_to_end", "End-to-end", "paper", "black", reads_detector=False, policy="mixed"),
    _M("lookup_context", "Lookup table (context sweep)", "ours", "tab:orange", "lookup",
       lookup="context"),
    _M("estimator_context", "Estimator (context sweep)", "ours", "tab:green", "estimator",
       estimators="context", persist_steps=1,
       fig5_suffix="_context"),
    _M("estimator_context_persist", f"Estimator (context sweep, {WINDOW_STEPS}-step run)", "ours",
       "darkgreen", "estimator", estimators="context", persist_steps=WINDOW_STEPS,
       fig5_suffix="_context_persist"),
    _M("lookup_context_setup", "Lookup table (context) + setup policies", "ours", "tab:red",
       "lookup", lookup="context", setup_of="lookup_context",
       fig5_suffix="_lookup_context_setup"),
    _M("learned_setup", "Learned when rule + setup policies", "ours", "darkred", "estimator",
       when=True, setup_of="learned",
       fig5_suffix="_learned_setup"),
    _M("learned", "Learned when rule", "ours", "navy", "estimator", when=True,
       fig5_suffix="_learned"),
    _M("learned_no_overlap", "Learned when rule, no overlap", "ours", "slateblue", "estimator",
       suite="random", when=True),
    # one policy distilled from lookup_context_setup by DAgger (learning/distillation.py)
    _M("student", "Student (distilled)", "ours", "goldenrod", reads_detector=False,
       policy="student"),
)
BY_NAME = {m.name: m for m in TABLE2}


def method(name: str) -> Method:
    """The record of Table II row `name`."""
    try:
        return BY_NAME[name]
    except KeyError:
        raise ValueError(f"unknown Table II method {name!r}; expected one of {tuple(BY_NAME)}") from None


def names(pred=lambda m: True) -> tuple[str, ...]:
    """The names of the rows whose record satisfies `pred`, in Table II's order."""
    return tuple(m.name for m in TABLE2 if pred(m))

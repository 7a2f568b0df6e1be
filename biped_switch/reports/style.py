"""The colours and labels every figure and table uses, read from the records: terrain kinds and
behaviours from kinds.py, Table II's methods from methods.py. Plain Python."""

from __future__ import annotations

from biped_switch import methods as methods_lib
from biped_switch.kinds import KIND_COLOURS, POLICY_COLOURS  # noqa: F401  (re-exported)

# setup policies (switching/setup.py) are named setup_<target>; their colours in the active strip
SETUP_COLOURS = {"setup_gaps": "tab:red", "setup_stairs": "tab:pink", "setup_jumps": "tab:olive"}
# Table III's rows that are no Table II method: the whole switching pipeline of ours
OTHER_LABELS = {"ours": "Ours (switching pipeline)"}


def policy_colour(name: str, default: str = "0.5") -> str:
    """A suite policy's colour: a behaviour's (its kind's), a setup policy's, else `default`."""
    return POLICY_COLOURS.get(name) or SETUP_COLOURS.get(name, default)


def method_label(name: str) -> str:
    """A Table II (or Table III) row's label for figures; the name itself if it has none."""
    rec = methods_lib.BY_NAME.get(name)
    return rec.label if rec else OTHER_LABELS.get(name, name)


def method_colour(name: str, default: str) -> str:
    """A Table II method's colour in figures (`default` for a name with no record)."""
    rec = methods_lib.BY_NAME.get(name)
    return rec.colour if rec else default

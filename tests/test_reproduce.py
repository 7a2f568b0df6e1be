"""`make reproduce`: each command of its chain (scripts/reproduce.sh, as the Makefile calls it) parses
with its command line's own parser, reads its policies from RUNS, writes under OUT only, and never
into the committed experiments/results/ or models/. Nothing is run: the script's dry run prints the
commands, and each parser stops right after parsing."""

from __future__ import annotations

import argparse
import importlib
import os
import pathlib
import shlex
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
RUNS, OUT = "runs/some_replay", "/tmp/reproduce_check_out"
ROWS = ("lookup_context", "learned", "lookup_context_setup", "learned_setup")
# flags that name where a command writes, or reads what an earlier step made: under OUT
UNDER_OUT = ("out", "results", "data", "lookup", "when_dir")
# committed folders a command may read, never write: the paper's estimators the when rule is
# scored beside offline (when), and defaults of flags the rows run here leave unused (the
# estimator rows' --estimators, the learned detector's folder, the ceiling's Table II)
READ_ONLY = {("when", "estimators"), ("evaluate multi", "estimators"),
             ("evaluate multi", "detector_dir"), ("when", "table2")}
COMMITTED = (REPO / "experiments", REPO / "models")


class _Parsed(Exception):
    def __init__(self, ns):
        self.ns = ns


def _make_line(**variables) -> str:
    """The script's invocation, as `make reproduce` expands it (make -n: nothing runs)."""
    args = [f"{k}={v}" for k, v in variables.items()]
    out = subprocess.run(["make", "-n", "-s", "reproduce", *args], cwd=REPO, capture_output=True,
                         text=True, check=True).stdout
    lines = out.replace("\\\n", " ").splitlines()
    [line] = [ln for ln in lines if "scripts/reproduce.sh" in ln]
    return line


def chain(**variables) -> list[tuple[str, list[str]]]:
    """(step, argv) of every step of `make reproduce` with these Make variables."""
    line = _make_line(RUNS=RUNS, OUT=OUT, **variables)
    out = subprocess.run(["bash", "-c", line], cwd=REPO, capture_output=True, text=True,
                         env={**os.environ, "REPRODUCE_DRY_RUN": "1"})
    assert out.returncode == 0, out.stderr
    return [(s, shlex.split(c)) for s, c in (ln.split("\t", 1) for ln in out.stdout.splitlines())]


def parse(argv: list[str]) -> tuple[str, argparse.Namespace]:
    """(command, namespace) of `python -m biped_switch.<module> ...`, from the module's own
    parser: its `main` runs up to `parse_args` and stops there."""
    assert argv[1:3] == ["-m", argv[2]] and argv[2].startswith("biped_switch."), argv
    module = importlib.import_module(argv[2])
    original = argparse.ArgumentParser.parse_args

    def stop(self, args=None, namespace=None):
        raise _Parsed(original(self, args, namespace))

    argparse.ArgumentParser.parse_args = stop
    try:
        module.main(argv[3:])
    except _Parsed as p:
        ns = p.ns
    except SystemExit as e:  # argparse refused the flags
        raise AssertionError(f"{shlex.join(argv)}: the flags do not parse (exit {e.code})") from None
    else:
        raise AssertionError(f"{argv[2]}.main returned without parsing flags")
    finally:
        argparse.ArgumentParser.parse_args = original
    name = argv[2].removeprefix("biped_switch.")
    return (f"{name} {ns.cmd}" if name == "evaluate" else name), ns


def _under(path, root) -> bool:
    p, r = (pathlib.Path(os.path.abspath(REPO / x)) for x in (path, root))
    return p == r or r in p.parents


def violations(command: str, ns: argparse.Namespace) -> list[str]:
    """What in one parsed command breaks the chain's rules."""
    bad = []
    for key, value in vars(ns).items():
        if not isinstance(value, str):
            continue
        if key == "runs" and value != RUNS:
            bad.append(f"{command}: --runs {value}, not RUNS={RUNS}")
        elif key == "setup" and value != "source" and not _under(value, RUNS):
            bad.append(f"{command}: --setup {value} is not under RUNS={RUNS}")
        elif key in UNDER_OUT and not _under(value, OUT):
            bad.append(f"{command}: --{key.replace('_', '-')} {value} is not under OUT={OUT}")
        elif any(_under(value, c) for c in COMMITTED) and (command, key) not in READ_ONLY:
            bad.append(f"{command}: --{key.replace('_', '-')} {value} is a committed folder")
    if "runs" not in vars(ns) and command not in ("reports.setup",):
        bad.append(f"{command}: takes no --runs")
    return bad


@pytest.fixture(scope="module")
def steps():
    return [(step, argv, *parse(argv)) for step, argv in chain()]


def test_every_command_parses_and_stays_in_runs_and_out(steps):
    bad = [v for _, _, command, ns in steps for v in violations(command, ns)]
    assert not bad, "\n".join(bad)


def test_the_chain_makes_every_published_row(steps):
    commands = [c for _, _, c, _ in steps]
    assert commands.count("sweep") == 4 and "when" in commands
    assert {"switching.setup", "reports.setup", "evaluate single", "evaluate retrain-cost"} <= set(commands)
    # the order: sweeps, then the rule trained on them, then the tables that read both
    assert max(i for i, c in enumerate(commands) if c == "sweep") < commands.index("when") \
        < commands.index("evaluate multi")
    assert commands[-1] == "evaluate retrain-cost"
    by = {c: ns for _, _, c, ns in steps if c != "evaluate multi"}
    multi = [ns for _, _, c, ns in steps if c == "evaluate multi"]
    assert sorted(m for ns in multi for m in ns.methods) == sorted(ROWS)
    assert {ns.trials for ns in multi} == {2500} and by["evaluate single"].trials == 500
    assert by["evaluate single"].track_seed == 10_000
    sweeps = [ns for _, _, c, ns in steps if c == "sweep"]
    # lookup_context's: gaps context-swept (50,000 points), jumps and stairs flat-start (100,000)
    lookups = [ns for ns in sweeps if ns.switch_min is None]
    assert {(tuple(ns.targets), ns.context, ns.points) for ns in lookups} == {
        (("jumps", "stairs"), False, 100_000), (("gaps",), True, 50_000)}
    # the when rule's: context sweeps with approach records, in a folder of their own
    when_sweeps = [ns for ns in sweeps if ns.switch_min is not None]
    assert {ns.switch_min for ns in when_sweeps} == {0.2} and all(ns.context for ns in when_sweeps)
    assert sorted(t for ns in when_sweeps for t in ns.targets) == ["gaps", "jumps", "stairs"]
    assert {ns.out for ns in when_sweeps} == {by["when"].data}
    assert not {ns.results for ns in when_sweeps} & {ns.results for ns in lookups}
    # the rows read what the chain made
    assert {ns.lookup for ns in multi} == {lookups[0].results}
    assert {ns.when_dir for ns in multi} == {by["when"].out} == {by["evaluate retrain-cost"].when_dir}


def test_size_knobs_reach_the_commands():
    steps = [parse(argv) for _, argv in chain(SWEEP_POINTS=300, SWEEP_BATCH=16, TRIALS1=8,
                                              TRIALS2=4, SETUP_EPISODES=8)]
    sweeps = [ns for c, ns in steps if c == "sweep"]
    assert {ns.points for ns in sweeps} == {300} and {ns.batch for ns in sweeps} == {16}
    assert {ns.trials for c, ns in steps if c == "evaluate multi"} == {4}
    assert {ns.n for c, ns in steps if c == "switching.setup"} == {8}


def test_the_check_fails_on_a_stray_path(steps):
    """The rules catch a command reading committed policies or writing a committed folder."""
    (_, argv, command, _) = next(s for s in steps if s[2] == "sweep")
    i = argv.index("--runs")
    no_runs = argv[:i] + argv[i + 2:]
    assert any("--runs runs," in v for v in violations(*parse(no_runs)))
    (_, argv, command, _) = next(s for s in steps if s[2] == "evaluate multi")
    i = argv.index("--out")
    committed = argv[:i + 1] + ["experiments/results/table2"] + argv[i + 2:]
    assert any("--out experiments/results/table2 is not under OUT" in v
               for v in violations(*parse(committed)))
    i = argv.index("--lookup")
    default_lookup = argv[:i] + argv[i + 2:]
    assert violations(*parse(default_lookup))


@pytest.mark.parametrize("out", ["experiments/results/again", "models/x"])
def test_out_in_a_committed_folder_is_refused(out):
    line = _make_line(RUNS=RUNS, OUT=out)
    res = subprocess.run(["bash", "-c", line], cwd=REPO, capture_output=True, text=True,
                         env={**os.environ, "REPRODUCE_DRY_RUN": "1"})
    assert res.returncode == 2 and "give it a folder of its own" in res.stderr


def test_runs_missing_a_policy_is_refused(tmp_path):
    """RUNS must hold every run the chain reads: a missing one would come from models/ unsaid."""
    (tmp_path / "walk_stand" / "checkpoints" / "000000000001").mkdir(parents=True)
    line = _make_line(RUNS=tmp_path, OUT=tmp_path / "out")
    res = subprocess.run(["bash", "-c", line], cwd=REPO, capture_output=True, text=True)
    assert res.returncode == 2 and "jumps_stand" in res.stderr, res.stderr
    assert not (tmp_path / "out").exists()


def test_bad_sizes_are_refused():
    line = _make_line(RUNS=RUNS, OUT=OUT, TRIALS2="2,500")
    res = subprocess.run(["bash", "-c", line], cwd=REPO, capture_output=True, text=True,
                         env={**os.environ, "REPRODUCE_DRY_RUN": "1"})
    assert res.returncode == 2 and "TRIALS2 must be a positive integer, got '2,500'" in res.stderr

"""The package's layering: each stage imports only the stages below it, the reports layer loads
no JAX, command lines stay thin and no module grows past 500 lines."""

import ast
import pathlib
import subprocess
import sys

PKG = pathlib.Path(__file__).resolve().parents[1] / "biped_switch"
BOTTOM = ("config", "kinds", "lineups", "methods", "names", "paths", "paper", "stats")  # import nothing of the package's stages
ORDER = {**{m: 0 for m in BOTTOM}, "simulation": 1, "learning": 2, "switching": 3, "evaluation": 4,
         "reports": 5, "products": 6}
PURE = {"biped_switch.learning.runs"}  # plain-Python modules the reports layer may read
# the top-level modules that are not command lines; every other one is (discovered, not listed)
NOT_COMMANDS = BOTTOM + ("cli", "__init__")
COMMANDS = tuple(sorted(p.stem for p in PKG.glob("*.py") if p.stem not in NOT_COMMANDS))
MAX_CLI_LINES = 150


def _imports(path: pathlib.Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("biped_switch"):
            if node.module == "biped_switch":
                yield from (f"biped_switch.{a.name}" for a in node.names)
            else:
                yield from (f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            yield from (a.name for a in node.names if a.name.startswith("biped_switch"))


def _layer(parts) -> str:
    return parts[0] if len(parts) > 1 else parts[0].removesuffix(".py")


def test_imports_flow_one_way():
    bad = []
    for path in sorted(PKG.rglob("*.py")):
        parts = path.relative_to(PKG).parts
        me = _layer(parts)
        if me not in ORDER:
            continue  # the command lines on top may import anything
        for mod in _imports(path):
            target = mod.split(".")[1]
            if target not in ORDER:
                bad.append(f"{path.relative_to(PKG)} imports the command line {mod}")
            elif me == "reports" and ORDER[target] not in (0, 5) and not any(
                    mod.startswith(p) for p in PURE):
                bad.append(f"{path.relative_to(PKG)} (reports: no JAX) imports {mod}")
            elif me != "reports" and ORDER[target] > ORDER[me]:
                bad.append(f"{path.relative_to(PKG)} ({me}) imports {mod}, a stage above it")
    assert not bad, "\n".join(bad)


def test_reports_load_no_jax():
    mods = [f"biped_switch.reports.{p.stem}" for p in sorted((PKG / "reports").glob("*.py"))
            if p.stem != "__init__"]
    code = ("import sys\n" + "".join(f"import {m}\n" for m in mods)
            + "print(sorted(m for m in ('jax', 'mujoco', 'orbax', 'flax') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_no_module_over_500_lines():
    long = {str(p.relative_to(PKG)): n for p in PKG.rglob("*.py")
            if (n := len(p.read_text().splitlines())) > 500}
    assert not long, long


def _private_reaches(tree: ast.AST) -> list[str]:
    """`module._name` uses in a module: a name the library keeps to itself."""
    mods = {a.asname or a.name.split(".")[0] for n in ast.walk(tree)
            if isinstance(n, (ast.Import, ast.ImportFrom)) for a in n.names}
    return [f"{n.value.id}.{n.attr}" for n in ast.walk(tree)
            if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)
            and n.value.id in mods and n.attr.startswith("_") and not n.attr.startswith("__")]


def test_command_lines_are_thin_and_all_reachable():
    """Every top-level module but the bottom layer and cli.py is a command line: reachable as
    `biped-switch <command>`, with a `main`, at most MAX_CLI_LINES lines, no classes and no
    private name of the library (its work lives in the stages)."""
    from biped_switch import cli
    assert set(cli.COMMANDS) == set(COMMANDS)
    bad = []
    for cmd in COMMANDS:
        text = (PKG / f"{cmd}.py").read_text()
        tree = ast.parse(text)
        defs = [n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))]
        if "main" not in defs:
            bad.append(f"{cmd}.py has no main")
        if [n for n in tree.body if isinstance(n, ast.ClassDef)]:
            bad.append(f"{cmd}.py defines a class")
        if len(text.splitlines()) > MAX_CLI_LINES:
            bad.append(f"{cmd}.py has {len(text.splitlines())} lines (> {MAX_CLI_LINES})")
        bad += [f"{cmd}.py reaches into {r}" for r in _private_reaches(tree)]
    assert not bad, "\n".join(bad)


def test_console_script_dispatches(capsys):
    from biped_switch import cli
    assert cli.main([]) == 2 and "usage: biped-switch" in capsys.readouterr().out
    assert cli.main(["nope"]) == 2 and "unknown command 'nope'" in capsys.readouterr().err
    try:
        cli.main(["terrain", "--help"])
    except SystemExit as e:  # argparse's --help exits 0 after printing the command's usage
        assert e.code == 0
    assert "--kind" in capsys.readouterr().out


def test_damaged_checkpoint_ends_in_one_line(tmp_path):
    """A truncated checkpoint in a run folder: the command ends in one line naming the folder,
    with no traceback after it (Orbax's event loop at exit), and status 2."""
    import shutil

    src = PKG.parent / "models" / "policies" / "walk_stand"
    run = tmp_path / "runs" / "walk_stand"
    shutil.copytree(src, run)
    for f in run.glob("checkpoints/*/d/*"):
        f.write_bytes(f.read_bytes()[:10])
    out = subprocess.run([sys.executable, "-m", "biped_switch.evaluate", "single", "--policies",
                          "walk", "--inits", "stand", "--trials", "1", "--batch", "1", "--runs",
                          str(tmp_path / "runs"), "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, cwd=PKG.parent, timeout=600)
    err = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr and "Event loop is closed" not in out.stderr, out.stderr
    assert len(err) == 1 and err[0].startswith("error: ") and "walk_stand" in err[0], out.stderr

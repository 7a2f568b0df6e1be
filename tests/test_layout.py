"""The package's layering: each stage imports only the stages below it, the reports layer loads
no JAX, command lines stay thin and no module grows past 500 lines."""

import ast
import pathlib
import subprocess
import sys

PKG = pathlib.Path(__file__).resolve().parents[1] / "biped_switch"
BOTTOM = ("config", "names", "paths", "paper", "stats")  # import nothing of the package's stages
ORDER = {**{m: 0 for m in BOTTOM}, "simulation": 1, "learning": 2, "switching": 3, "evaluation": 4,
         "reports": 5}
PURE = {"biped_switch.learning.runs"}  # plain-Python modules the reports layer may read
COMMANDS = ("train", "sweep", "estimator", "dqn", "evaluate", "demo", "render", "bench", "terrain",
            "detector")


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


def test_command_lines_are_thin_and_all_reachable():
    from biped_switch import cli
    assert set(cli.COMMANDS) == set(COMMANDS)
    for cmd in COMMANDS:
        tree = ast.parse((PKG / f"{cmd}.py").read_text())
        defs = [n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))]
        assert "main" in defs, cmd
        # library code lives in the stages: a command line defines no classes
        assert not [n for n in tree.body if isinstance(n, ast.ClassDef)], cmd


def test_console_script_dispatches(capsys):
    from biped_switch import cli
    assert cli.main([]) == 2 and "usage: biped-switch" in capsys.readouterr().out
    assert cli.main(["nope"]) == 2 and "unknown command 'nope'" in capsys.readouterr().err
    try:
        cli.main(["terrain", "--help"])
    except SystemExit as e:  # argparse's --help exits 0 after printing the command's usage
        assert e.code == 0
    assert "--kind" in capsys.readouterr().out

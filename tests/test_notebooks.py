"""The result notebooks (experiments/notebooks/*.ipynb) run top to bottom on the committed results.

Each notebook is executed in a fresh kernel of this interpreter with BIPED_SWITCH_RESULTS pointing at the
committed results of the trained stand-init policy suite (experiments/results/, `COMMITTED`), and
for the training curves BIPED_SWITCH_RUNS at the committed policy runs (models/policies/). The tests check that it drew its
figures, that its printed tables hold the numbers in the files and that it prints its verdict. A
committed input that is missing fails the test; there is no synthetic fallback. A notebook pointed
at an empty results root must fail with a message naming the command that makes its input.

A synthetic tree, written here with the package's own table and lookup functions, tests the
notebooks' helpers (_common) and the package functions they print (table2, table3, fig4b,
fig5, runs) on cases the committed results do not have (finished runs, a runs
folder without estimators).
"""

from __future__ import annotations

import csv
import json
import pathlib
import re
import sys

import numpy as np
import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
from nbclient.exceptions import CellExecutionError  # noqa: E402

REPO = pathlib.Path(__file__).resolve().parents[1]
NB_DIR = REPO / "experiments" / "notebooks"
KERNEL = "biped-switch-test"
NOTEBOOKS = ("table1_single_policies", "table2_switching", "table3_retrain_cost",
             "fig4b_switch_success", "fig5_trial", "training_curves")
INPUTS = {  # the file each notebook cannot do without, and the command its error must name
    "table1_single_policies": ("table1/table1.json", "python -m biped_switch.evaluate single"),
    "table2_switching": ("table2/table2.json", "python -m biped_switch.evaluate multi"),
    "table3_retrain_cost": ("table3/table3.json", "python -m biped_switch.evaluate retrain-cost"),
    "fig4b_switch_success": ("lookup/lookup_stand.json", "python -m biped_switch.sweep --init stand"),
    "fig5_trial": ("table2/fig5_trial0.npz", "python -m biped_switch.evaluate multi"),
    "training_curves": ("training", "python -m biped_switch.train"),
}
POLICY_RUNS = REPO / "models" / "policies"  # the committed training runs (train --commit)
REAL = REPO / "experiments" / "results"  # the results of the trained policies
# The committed results each notebook runs on: (results root, runs root for BIPED_SWITCH_RUNS or None).
COMMITTED = {"table1_single_policies": (REAL, None),
             "table2_switching": (REAL, None),
             "table3_retrain_cost": (REAL, None),
             "fig4b_switch_success": (REAL, None),
             "fig5_trial": (REAL, None),
             "training_curves": (REAL, POLICY_RUNS)}

sys.path.insert(0, str(NB_DIR))
import _common as C  # noqa: E402

from biped_switch.reports import fig4b  # noqa: E402
from biped_switch.reports import fig5
from biped_switch import paper
from biped_switch.evaluation import multi as table2
from biped_switch.reports import table2 as table2_report
from biped_switch.reports import table3
from biped_switch.learning import runs as runs_lib  # noqa: E402


# ----------------------------------------------------------------------------- synthetic tree
def _episodes(rng, n, p_success, fail_p=(0.2, 0.5, 0.3)):
    succ = rng.random(n) < p_success
    return {"progress_frac": np.where(succ, 1.0, rng.uniform(0.05, 0.95, n)),
            "success": succ.astype(float), "fell": (~succ).astype(float),
            "fail_kind": np.where(succ, -1, rng.choice(3, n, p=fail_p))}


def make_synthetic_results(root: pathlib.Path) -> pathlib.Path:
    """A small results tree in the formats the CLIs write (tables via stats.episode_table, the
    lookup table via sweep.lookup_table/save_lookup), labelled as a stand-in pipeline check."""
    from biped_switch.switching import sweep
    from biped_switch.switching import lookup
    from biped_switch.simulation import terrain
    from biped_switch.learning.policies import POLICY_NAMES
    from biped_switch.stats import episode_table
    from biped_switch.names import SWITCH_METHODS

    rng = np.random.default_rng(0)
    curr = {"stage": 0, "stage_name": "terrain", "difficulty": 0.3, "guide_scale": 1.0,
            "push_scale": 0.0}
    # Table I
    rows = []
    for init in ("stand", "random"):
        for k, policy in enumerate(("jumps", "gaps", "stairs")):
            r = episode_table(_episodes(rng, 20, 0.2 + 0.2 * k))
            r.update(policy=policy, init=init, checkpoint=f"runs/{policy}_{init}/checkpoints/000000100000",
                     train_step=100_000, curriculum=curr, wall_s=1.0)
            rows.append(r)
    (root / "table1").mkdir(parents=True)
    (root / "table1" / "table1.json").write_text(json.dumps(
        {"settings": {"policies": ["jumps", "gaps", "stairs"], "inits": ["stand", "random"],
                      "trials": 20, "batch": 20, "horizon_s": 20.0, "seed": 0, "runs": "runs",
                      "out": "x"}, "rows": rows}, default=str))
    # Table II
    src = ["runs/walk_stand/checkpoints/000000100000 (step 100,000, curriculum terrain)"]
    srcs = src + [f"stand-in for {p}: {src[0]}" for p in ("jumps", "gaps", "stairs")]
    rows, run = [], SWITCH_METHODS + ("dqn",)  # end_to_end left out: drawn as "not run"
    for i, m in enumerate(run):
        r = episode_table(_episodes(rng, 30, 0.1 * (i + 1)))
        r.update(method=m, init="random" if m == "estimator_no_overlap" else "stand", wall_s=2.0,
                 switches_per_trial=3.5, policies=srcs)
        rows.append(r)
    (root / "table2").mkdir()
    (root / "table2" / "table2.json").write_text(json.dumps(
        {"settings": {"methods": list(run), "trials": 30, "batch": 30,
                      "horizon_s": 30.0, "seed": 0, "runs": "runs", "estimators": "models/estimators",
                      "lookup": "x", "stand_in": "walk", "guide_scale": 0.5, "fig5_trial": 0,
                      "out": "x"},
         "rows": rows, "wall_s": 12.0, "device": "TFRT_CPU_0", "track_seed": 30_000}, default=str))
    np.savez_compressed(root / "table2" / "fig5_trial0.npz", **_trace(30_000))
    # lookup tables
    tables = {}
    for target in terrain.ARTIFACT_KINDS:
        n = 600
        others = [j for j in range(4) if POLICY_NAMES[j] != target]
        source = rng.choice(others, n)
        dist = rng.uniform(0, 0.9, n)
        label = rng.random(n) < 0.2 + 0.6 * dist  # switching early works better
        tables[target] = lookup.lookup_table(dist, label, source, target)
    meta = {"sweeps": {t: {"points": 600, "wall_s": 5.0, "points_per_s": 120.0, "success_pct": 47.0,
                           "data": f"runs/sweeps/stand/{t}.npz", "device": "TFRT_CPU_0"}
                       for t in terrain.ARTIFACT_KINDS},
            "policies": {t: dict(zip(POLICY_NAMES, srcs)) for t in terrain.ARTIFACT_KINDS}}
    lookup.save_lookup(tables, "stand", root / "lookup", meta)
    # estimators
    (root / "estimators").mkdir()
    for target in ("jumps", "gaps"):
        stem = root / "estimators" / f"stand_{target}"
        stem.with_suffix(".json").write_text(json.dumps(
            {"target": target, "init": "stand", "data_file": f"runs/sweeps/stand/{target}.npz",
             "metrics": {"train_points": 900, "val_points": 100, "val_acc": 0.71, "val_auc": 0.78,
                         "best_val_acc": 0.73, "best_val_acc_epoch": 7, "epochs": 10,
                         "train_s": 3.0, "device": "TFRT_CPU_0"}}))
        with stem.with_name(stem.name + "_history.csv").open("w") as f:
            f.write("epoch,train_loss,val_loss,val_acc\n")
            for e in range(1, 11):
                f.write(f"{e},{0.25 / e:.4f},{0.25 / e + 0.02:.4f},{0.5 + 0.02 * e:.3f}\n")
    # training runs
    for r_i, run in enumerate(("walk_stand", "gaps_stand")):
        d = root / "training" / run
        d.mkdir(parents=True)
        with (d / "metrics.csv").open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["step", "stage", "difficulty", "guide_scale", "push_scale",
                        "episode/sum_reward", "episode/length", "eval/reward_per_step", "wall_s"])
            for i in range(1, 13):
                ev = i % 4 == 0
                w.writerow([i * 10_000, 0, min(1.0, 0.1 * (i // 4)), 1.0 - 0.05 * (i // 4), 0.0,
                            (100.0 - 30 * r_i) * i, 500 + 10 * i,
                            f"{(0.5 - 0.1 * r_i) * i:.2f}" if ev else "",
                            f"{60.0 * i}" if ev else ""])
    # Table III
    (root / "table3").mkdir()
    (root / "table3" / "table3.json").write_text(json.dumps(
        {"rows": [{"method": "ours", "hours": 3.5, "parts": {"policy": 3.0, "sweeps": 0.3,
                                                               "estimators": 0.2},
                   "device": "TFRT_CPU_0", "paper_hours": 20.0},
                  {"method": "dqn", "hours": None, "parts": {}, "device": None, "paper_hours": 25.0},
                  {"method": "end_to_end", "hours": 6.0, "parts": {"policy": 6.0},
                   "device": "TFRT_CPU_0", "paper_hours": 34.0}],
         "notes": "synthetic test data"}))
    return root


def make_synthetic_runs(root: pathlib.Path) -> pathlib.Path:
    """A runs folder as `python -m biped_switch.train --out <root>` leaves it: gaps_random reached
    its step goal with its curriculum finished, jumps_stand stopped early with guide forces on."""
    for name, step, total, curr in (
            ("gaps_random", 200_000, 200_000, {"stage": 2, "stage_name": "pushes", "difficulty": 1.0,
                                               "guide_scale": 0.0, "push_scale": 1.0}),
            ("jumps_stand", 100_000, 1_000_000, {"stage": 0, "stage_name": "terrain",
                                                 "difficulty": 0.3, "guide_scale": 1.0,
                                                 "push_scale": 0.0})):
        d = root / name
        (d / "checkpoints" / f"{step:012d}").mkdir(parents=True)
        (d / "config.json").write_text(json.dumps({"policy": name.split("_")[0],
                                                   "total_timesteps": total}))
        (d / "checkpoints" / f"{step:012d}" / "progress.json").write_text(json.dumps(
            {"step": step, "wall_s": 7200.0, "curriculum": curr, "device": "cpu:0",
             "total_steps": total}))
        with (d / "metrics.csv").open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["step", "difficulty", "guide_scale", "push_scale", "episode/sum_reward",
                        "episode/length", "eval/reward_per_step", "wall_s"])
            for i in range(1, 5):
                w.writerow([i * step // 4, curr["difficulty"], curr["guide_scale"],
                            curr["push_scale"], 50.0 * i, 100 * i, "", 1800.0 * i])
    return root


def _trace(track_seed: int, T: int = 400) -> dict:
    """A plausible per-step record of one estimator-switching trial on the seed's mixed track."""
    from biped_switch.simulation import terrain

    track = terrain.generate_track(track_seed, "mixed", 1.0)
    rng = np.random.default_rng(1)
    x = np.linspace(0.0, 0.9 * track.finish_x_m, T)
    det_kind = np.full(T, -1, np.int32)
    det_dist = np.full(T, np.inf, np.float32)
    for k, a, _ in track.artifacts:
        d = a - x
        near = (d > 0) & (d <= 0.9)
        det_kind[near] = terrain.ARTIFACT_KINDS.index(k)
        det_dist[near] = d[near]
    probs = np.clip(np.cumsum(rng.normal(0, 0.08, (T, 3)), 0) % 1.0, 0, 1).astype(np.float32)
    active = np.zeros(T, np.int32)
    switched = np.zeros(T, bool)
    cur = 0
    for i in range(T):
        k = det_kind[i]
        if k >= 0 and cur != k + 1 and (probs[i, k] >= 0.85 or det_dist[i] <= 0.01 or
                                        (i + 1 < T and det_kind[i + 1] != k)):
            cur, switched[i] = k + 1, True
        active[i] = cur
    phase = np.arange(T) * 2 * np.pi / 40
    soles = np.zeros((T, 8, 3), np.float32)
    soles[..., 0] = x[:, None]
    soles[:, :4, 2] = 0.05 * np.clip(np.sin(phase), 0, None)[:, None]
    soles[:, 4:, 2] = 0.05 * np.clip(-np.sin(phase), 0, None)[:, None]
    body = np.stack([x, np.zeros(T), 0.9 + 0.02 * np.sin(2 * phase)], -1).astype(np.float32)
    ended = np.zeros(T, np.float32)
    ended[-20:] = 1.0
    success = np.zeros(T, np.float32)
    success[-21:] = 1.0
    return {"time_s": (np.arange(T) * 0.02).astype(np.float32), "com_x_m": x.astype(np.float32),
            "body_com": body, "soles": soles, "contact": (soles[..., 2] < 0.01).astype(np.float32),
            "det_kind": det_kind, "det_dist_m": np.where(np.isfinite(det_dist), det_dist, 9.0),
            "est_probs": probs, "com_ok": (np.sin(phase) ** 2 < 0.3),
            "active": active, "switched": switched, "ended": ended,
            "fell": np.zeros(T, np.float32), "success": success, "track_seed": np.int64(track_seed)}


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    return make_synthetic_results(tmp_path_factory.mktemp("results"))


@pytest.fixture(scope="module")
def synthetic_runs(tmp_path_factory):
    return make_synthetic_runs(tmp_path_factory.mktemp("runs"))


def committed_root(name: str, tmp: pathlib.Path) -> tuple[pathlib.Path, pathlib.Path | None]:
    """(results root, runs root) of the committed results notebook `name` runs on; fails when its
    input is not there (these files are committed: nothing to skip, nothing to stand in for)."""
    root, runs = COMMITTED[name]
    if runs is None:
        path = root / INPUTS[name][0]
        assert path.exists(), f"committed input {path} of {name} is missing"
    else:  # the training curves: the committed runs (and the estimators under the results root)
        assert list(runs.glob("*/metrics.csv")), f"no committed training run under {runs}"
        assert list(root.glob("estimators/*_history.csv")), f"no committed estimator under {root}"
    return root, runs


@pytest.fixture(scope="module")
def kernel_env(tmp_path_factory):
    """A kernel spec running ipykernel on this interpreter, found through JUPYTER_PATH."""
    base = tmp_path_factory.mktemp("jupyter")
    spec = base / "kernels" / KERNEL
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "biped_switch tests", "language": "python"}))
    (base / "ipython").mkdir()
    return {"JUPYTER_PATH": str(base), "IPYTHONDIR": str(base / "ipython"),
            "MPLBACKEND": "module://matplotlib_inline.backend_inline"}


def run_notebook(name: str, results: pathlib.Path, env: dict, monkeypatch, runs=None):
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    monkeypatch.setenv("BIPED_SWITCH_RESULTS", str(results))
    if runs is not None:
        monkeypatch.setenv("BIPED_SWITCH_RUNS", str(runs))
    else:
        monkeypatch.delenv("BIPED_SWITCH_RUNS", raising=False)
    nb = nbformat.read(NB_DIR / f"{name}.ipynb", as_version=4)
    client = nbclient.NotebookClient(nb, kernel_name=KERNEL, timeout=120, startup_timeout=90,
                                     resources={"metadata": {"path": str(NB_DIR)}})
    client.execute()
    text, images = [], 0
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            if out.get("output_type") == "stream" and out.get("name") == "stdout":
                text.append(out["text"])
            images += "image/png" in out.get("data", {})
    return "".join(text), images


# ----------------------------------------------------------------------------- tests
def test_helpers_on_synthetic_tree(synthetic, synthetic_runs, monkeypatch, tmp_path):
    """_common reads the synthetic tree back: tables hold the numbers, stand-ins are flagged."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    monkeypatch.setenv("BIPED_SWITCH_RESULTS", str(synthetic))
    assert C.results_root() == synthetic
    doc = json.loads((synthetic / "table2" / "table2.json").read_text())
    reasons = table2_report.table2_provenance(doc, synthetic / "table2" / "table2.json")
    assert any("stand-in" in r for r in reasons) and any("guide" in r for r in reasons)
    txt = C.text_table(*table2_report.table2_rows(doc))
    for r in doc["rows"]:
        line = next(ln for ln in txt.splitlines() if ln.startswith(r["method"] + " "))
        assert f"{r['success_pct']:.1f}" in line and f"{r['fail_on']['gaps']:.1f}" in line
    assert "not run" in next(ln for ln in txt.splitlines() if ln.startswith("end_to_end"))
    look = json.loads((synthetic / "lookup" / "lookup_stand.json").read_text())
    rows = fig4b.lookup_rows(look)[1]
    assert len(rows) == 9
    for pair, _, _, best in rows:
        v = look["best_m"][pair.replace(" ", "")]
        assert best == ("-" if v is None else f"{v:.2f}")
    rec = fig5.load_trial(synthetic / "table2" / "fig5_trial0.npz")
    ev = fig5.trial_events(rec)[1]
    assert sum(r[2] == "switch" for r in ev) == int(rec["switched"][:fig5.trial_length(rec)].sum()) > 0
    assert fig5.trial_outcome(rec) == "success"
    monkeypatch.setenv("BIPED_SWITCH_RUNS", str(synthetic_runs))
    assert C.run_roots() == [synthetic_runs] == [C.runs_root()]
    runs = C.find_training_runs(synthetic)  # <results>/training/* and the runs folder
    by_name = {d.name: d for d in runs}
    assert sorted(by_name) == ["gaps_random", "gaps_stand", "jumps_stand", "walk_stand"]
    assert runs_lib.training_rows([by_name["walk_stand"]], C.run_name)[1][0][1] == "120,000"
    reasons = runs_lib.training_checks(runs, C.run_name)
    assert not any(C.run_name(by_name["gaps_random"]) in r for r in reasons)  # finished: no note
    assert any("jumps_stand" in r and "100,000 of 1,000,000" in r and "curriculum unfinished" in r
               for r in reasons)
    assert C.train_command(synthetic_runs, "gaps")[-2:] == ["--out", str(synthetic_runs)]
    monkeypatch.delenv("BIPED_SWITCH_RUNS")
    assert C.runs_root() == REPO / "runs" and C.train_command()[-1] == "runs"
    assert C.run_roots() == [REPO / "runs", POLICY_RUNS]  # runs/, then the committed runs
    # Table III: hours whose runs cannot be found are not taken for complete runs
    # (the synthetic runs hold no mixed run, and the committed models/policies/ must not stand in)
    monkeypatch.setattr(runs_lib, "COMMITTED_DIR", tmp_path / "no_committed_policies")
    t3 = json.loads((synthetic / "table3" / "table3.json").read_text())
    runs3, checks = table3.table3_checks(t3, synthetic, synthetic_runs)
    assert runs3 == synthetic_runs and checks["dqn"] == []
    for m in ("end_to_end", "ours"):  # both synthetic rows have a "policy" part: the mixed run
        assert any("policy: no run under" in n and "cannot tell whether it finished" in n
                   for n in checks[m]), checks[m]
    t3_reasons = table3.table3_provenance(t3, synthetic / "table3" / "table3.json", synthetic,
                                     synthetic_runs)
    assert any("no total hours for dqn" in r for r in t3_reasons)
    hdr, rows3 = table3.table3_rows(t3, checks)
    assert [r[hdr.index("hours from")] for r in rows3] == ["UNFINISHED RUNS", "-", "UNFINISHED RUNS"]
    from biped_switch.simulation import terrain

    for fig in (C.plot_table1(json.loads((synthetic / "table1" / "table1.json").read_text())),
                C.plot_table2(doc), C.plot_fig4b(look),
                fig5.fig5_figure(rec, terrain.generate_track(int(rec["track_seed"]), "mixed", 1.0)),
                C.plot_table3(json.loads((synthetic / "table3" / "table3.json").read_text())),
                C.plot_training_run(runs[0]), C.plot_estimators(C.find_estimators(synthetic))):
        assert fig.axes
        plt.close(fig)


def test_require_names_the_command(tmp_path, monkeypatch):
    monkeypatch.setenv("BIPED_SWITCH_RESULTS", str(tmp_path))
    with pytest.raises(C.MissingResult, match="python -m biped_switch.evaluate multi --out"):
        C.load_json(tmp_path / "table2" / "table2.json", C.table2_command(tmp_path), "Table II")
    cmd = C.table2_command(tmp_path, {"trials": 40, "stand_in": "walk", "guide_scale": 0.5,
                                      "methods": ["random", "estimator"], "fig5_trial": 0})
    assert cmd[:3] == ["-m", "biped_switch.evaluate", "multi"]
    s = " ".join(cmd)
    assert "--trials 40" in s and "--stand-in walk" in s and "--guide-scale 0.5" in s
    assert "--methods random estimator" in s and "--fig5-trial 0" in s


class _Parsed(Exception):
    """Raised by a patched worker function: the CLI accepted its arguments."""


def _stop(*_a, **_k):
    raise _Parsed


PARSED = "parsed"  # the outcome of a command whose work function was reached (and patched out)


def _patch_everywhere(monkeypatch, name: str, value) -> None:
    """Sets `name` to `value` in every loaded biped_switch module that has it (a function imported
    into several modules, e.g. runs.find_policy, is looked up in the importer's namespace)."""
    import sys as _sys

    mods = [m for k, m in list(_sys.modules.items())
            if (k == "biped_switch" or k.startswith("biped_switch.")) and hasattr(m, name)]
    assert mods, f"no biped_switch module has {name}"
    for m in mods:
        monkeypatch.setattr(m, name, value)


def test_recompute_commands_parse(tmp_path, monkeypatch, capsys):
    """The commands the notebooks name (and run when RECOMPUTE = True) are accepted by the CLIs and
    get to their work, each with its one expected outcome; the work itself is patched out, except
    retrain-cost, which only reads logs and runs for real (into a temporary folder) on the
    committed results root the Table III notebook reads."""
    from biped_switch.switching import estimator
    from biped_switch import estimator as estimator_cli
    from biped_switch import evaluate
    from biped_switch.switching import sweep
    from biped_switch.switching import lookup
    from biped_switch import sweep as sweep_cli
    from biped_switch.learning import trainer as train
    from biped_switch import train as train_cli

    monkeypatch.chdir(REPO)  # the commands are typed from the repository root
    monkeypatch.delenv("BIPED_SWITCH_RUNS", raising=False)
    settings = {"methods": ["random", "estimator"], "trials": 8, "batch": 4, "horizon_s": 20.0,
                "seed": 1, "runs": "runs", "estimators": "models/estimators", "stand_in": "walk",
                "guide_scale": 0.5, "fig5_trial": 0, "policies": ["jumps"], "inits": ["stand"]}
    monkeypatch.setattr(evaluate.tables, "multi", _stop)
    monkeypatch.setattr(sweep, "run_sweep", _stop)
    monkeypatch.setattr(estimator, "load_data", _stop)
    monkeypatch.setattr(train, "train", _stop)
    with monkeypatch.context() as mp:  # retrain-cost below needs the real find_policy
        _patch_everywhere(mp, "find_policy", lambda *a: None)  # single: no policy found, rc 1
        cases = [(evaluate.main, C.table2_command(tmp_path), PARSED),
                 (evaluate.main, C.table2_command(tmp_path, settings), PARSED),
                 (evaluate.main, C.fig5_command(tmp_path, 3, settings), PARSED),
                 (evaluate.main, C.table1_command(tmp_path), 1),  # 1: no trained policy found
                 (evaluate.main, C.table1_command(tmp_path, settings), 1),
                 (sweep_cli.main, C.lookup_command(tmp_path, "random"), PARSED),
                 # 2: no sweep data in the (empty) --data folder, named on stderr
                 (estimator_cli.main, C.estimator_command(tmp_path) + ["--data", str(tmp_path / "none")], 2),
                 (train_cli.main, C.train_command(tmp_path, "gaps", "random"), PARSED),
                 (train_cli.main, C.train_command(None, "gaps", "random"), PARSED)]
        for main, argv, want in cases:
            assert argv[0] == "-m" and main.__module__ == argv[1]
            try:
                got = main(argv[2:])
            except _Parsed:
                got = PARSED
            assert got == want, (argv, got)
        err = capsys.readouterr().err
        assert err.count("no trained policy found for: jumps_stand") == 2
        assert "python -m biped_switch.sweep --init stand --targets jumps" in err
    # retrain-cost: reads <runs> and <results> of the notebook's root, writes <results>/table3
    root = REAL
    assert (root / "lookup").is_dir() and (root / "estimators").is_dir()
    argv = C.table3_command(root, None, "stand")
    assert argv[:3] == ["-m", "biped_switch.evaluate", "retrain-cost"]
    flags = dict(zip(argv[3::2], argv[4::2]))
    assert flags == {"--runs": C.rel(C.runs_root()), "--results": C.rel(root), "--init": "stand",
                     "--out": C.rel(root / "table3")}
    flags["--out"] = str(tmp_path / "table3")  # not over the committed table
    assert evaluate.main(["retrain-cost", *[x for kv in flags.items() for x in kv]]) == 0
    doc = json.loads((tmp_path / "table3" / "table3.json").read_text())
    ours = next(r for r in doc["rows"] if r["method"] == "ours")["parts"]
    assert ours["sweep jumps"] is not None and ours["estimator gaps"] is not None  # read <results>
    checks = table3.table3_checks(doc, root, C.runs_root())[1]
    # the trained suite's runs (runs/, else models/policies/): nothing from a pipeline check; a
    # run short of its step goal or curriculum flags the hours measured from it
    assert not any("pipeline" in n for notes in checks.values() for n in notes), checks
    e2e = next(r for r in doc["rows"] if r["method"] == "end_to_end")
    assert e2e["hours"] is not None  # the committed end-to-end run (models/policies/mixed_stand) ...
    mixed = runs_lib.find_policy("mixed", "stand", C.runs_root()).parent.parent
    assert bool(checks["end_to_end"]) == bool(runs_lib.run_notes(mixed))  # ... flagged iff unfinished
    for k in ("jumps", "gaps", "stairs"):  # ours: each unfinished new-policy run is named
        d = runs_lib.find_policy(k, "stand", C.runs_root()).parent.parent
        assert not runs_lib.run_notes(d) or any(d.name in n for n in checks["ours"]), (d, checks)


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_notebook_runs(name, tmp_path, kernel_env, monkeypatch):
    data_root, runs_dir = committed_root(name, tmp_path)
    text, images = run_notebook(name, data_root, kernel_env, monkeypatch, runs_dir)
    verdicts = [ln for ln in text.splitlines() if ln.startswith("VERDICT: ")]
    assert verdicts, text[-2000:]
    # the results of the trained policies carry no pipeline-check marker (stand-ins, a label, a
    # pipeline_check tree) and read as results; only the hours and curves of the training runs
    # themselves (Table III, training curves) may say "not a result", for runs still short of
    # their step goal or curriculum (checked below)
    assert not any(m in v for v in verdicts if v.startswith("VERDICT: NOT A FINAL RESULT")
                   for m in ("stand-in", "labelled so", "is a pipeline check",
                             "pipeline-check results root")), verdicts
    if name not in ("table3_retrain_cost", "training_curves"):
        assert all(not v.startswith("VERDICT: NOT A FINAL RESULT") for v in verdicts), verdicts
    if name == "table1_single_policies":
        doc = json.loads((data_root / "table1" / "table1.json").read_text())
        assert images == 1
        assert {r["init"] for r in doc["rows"]} <= {"stand", "random"} and doc["rows"]
        assert min(r["n"] for r in doc["rows"]) >= paper.TRIALS["table1"]
        for r in doc["rows"]:
            line = next(ln for ln in text.splitlines()
                        if ln.split()[:3] == [r["policy"], r["init"], str(r["n"])])
            assert f"{r['distance_pct']:.1f} (" in line and f"{r['success_pct']:.1f} (" in line
            assert f"{r['train_step']:,}" in line
    elif name == "table2_switching":
        doc = json.loads((data_root / "table2" / "table2.json").read_text())
        assert images >= 1
        for r in doc["rows"]:
            line = next(ln for ln in text.splitlines() if ln.startswith(r["method"] + " "))
            assert f"{r['distance_pct']:.1f} (" in line and f"{r['success_pct']:.1f} (" in line
        assert "82.4 / 71.4 / 16.7 / 2.4 / 9.4" in text  # the paper's estimator row beside ours
    elif name == "table3_retrain_cost":
        path = data_root / "table3" / "table3.json"
        doc = json.loads(path.read_text())
        assert images >= 1
        assert "hours from" in text
        # the verdict, and each method's "hours from" cell, follow from the runs as they are
        expect = []
        table3.table3_provenance(doc, path, data_root, C.runs_root(),
                                 print_fn=lambda *a: expect.append(" ".join(map(str, a))))
        assert verdicts == [expect[-1]], (verdicts, expect[-1])
        checks = table3.table3_checks(doc, data_root, C.runs_root())[1]
        hdr, rows3 = table3.table3_rows(doc, checks)
        for row in rows3:
            line = next(ln for ln in text.splitlines() if ln.split()[:1] == [row[0]])
            assert f" {row[hdr.index('hours from')]} " in line, line
        for r in doc["rows"]:
            assert r["method"] in text
            if r.get("hours") is not None:
                assert f"{r['hours']:.2f}" in text
            for part, v in (r.get("parts") or {}).items():  # the parts table, one line each
                assert any(ln.split()[:1] == [r["method"]] and f" {part} " in ln
                           and ln.rstrip().endswith(table3.hours_cell(v)) for ln in text.splitlines()), part
    elif name == "fig4b_switch_success":
        doc = json.loads((data_root / "lookup" / "lookup_stand.json").read_text())
        assert images >= 1
        best = [(pair, v) for pair, v in doc["best_m"].items() if v is not None]
        assert best  # the committed table has switch points to show
        for pair, v in best:
            src, dst = pair.split("->")
            assert f"{src} -> {dst}" in text and f"{v:.2f}" in text
    elif name == "fig5_trial":
        rec = fig5.load_trial(data_root / "table2" / "fig5_trial0.npz")
        n = fig5.trial_length(rec)
        assert images >= 2
        events = [ln.split() for ln in text.splitlines()
                  if re.match(r"\d+ +[\d.]+ +(detect|switch) ", ln)]
        assert sum(e[2] == "switch" for e in events) == int(rec["switched"][:n].sum()) > 0
        assert f"track seed {int(rec['track_seed'])}" in text
    elif name == "training_curves":
        monkeypatch.setenv("BIPED_SWITCH_RUNS", str(runs_dir))
        runs = C.find_training_runs(data_root)
        ests = C.find_estimators(data_root)
        assert runs and ests
        # <results>/training/* and every committed run of the runs folder
        committed = [p.parent for p in runs_dir.glob("*/metrics.csv")]
        results_runs = [p.parent for p in data_root.glob("training/*/metrics.csv")]
        assert sorted(d.resolve() for d in runs) == sorted(
            d.resolve() for d in committed + results_runs)
        assert images == 2 + len(runs)  # the overview, one per run, the estimators
        for d in runs:  # one table line per run, with the last step its metrics.csv logged
            steps = C.read_csv(d / "metrics.csv")["step"]
            line = next(ln for ln in text.splitlines() if ln.startswith(C.run_name(d) + " "))
            assert f"{int(np.nanmax(steps)):,}" in line, line
        train_verdict, est_verdict = verdicts  # the training runs', then the estimators'
        reasons = runs_lib.training_checks(runs, C.run_name)
        assert train_verdict.startswith("VERDICT: NOT A FINAL RESULT: ") == bool(reasons)
        for reason in reasons:  # e.g. a run short of its step goal
            assert reason in train_verdict
        for d in runs:  # named in the verdict exactly when its run is not finished
            assert (f"{C.run_name(d)}: " in train_verdict) == bool(runs_lib.run_notes(d)), d
        # the estimators of the paper's sweeps (100k points each) read as results; one made from
        # fewer points (our 50k-point context sweep of gaps) is named, and only it
        pts = {e: json.loads(pathlib.Path(js).read_text())["metrics"]["points_total"]
               for e, js, _ in ests}
        few = [e for e, n in pts.items() if n < paper.SWEEP_POINTS]
        assert est_verdict.startswith("VERDICT: NOT A FINAL RESULT") == bool(few), est_verdict
        for e, n in pts.items():
            assert (f"{e} {n:,}" in est_verdict) == (e in few), (e, est_verdict)
        for e, _, _ in ests:
            assert e in text


def test_training_curves_without_estimators(tmp_path, synthetic_runs, kernel_env, monkeypatch):
    """Training runs but no estimators: the notebook says what is missing instead of failing."""
    text, images = run_notebook("training_curves", tmp_path, kernel_env, monkeypatch, synthetic_runs)
    assert "VERDICT" in text and images >= 3
    assert "MISSING: no switch estimator curves" in text
    assert "python -m biped_switch.estimator" in text


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_notebook_without_data_fails_naming_the_command(name, tmp_path, kernel_env, monkeypatch):
    with pytest.raises(CellExecutionError) as e:
        run_notebook(name, tmp_path, kernel_env, monkeypatch, runs=tmp_path / "runs")
    msg = str(e.value)
    assert "MissingResult" in msg and INPUTS[name][1] in msg, msg[-2000:]


def test_cli_and_notebook_draw_the_same_fig5(tmp_path):
    """One Fig. 5 for `evaluate multi`, the demo and the notebook: the PNG the CLI saves comes from
    the figure the notebook shows (estimates, active-policy strip, heights)."""
    import matplotlib

    matplotlib.use("Agg")
    from biped_switch.reports import fig5
    from biped_switch.reports import fig5 as fig5_report
    from biped_switch.simulation import terrain

    rec = _trace(30_000)
    track = terrain.generate_track(30_000, "mixed", 1.0)
    fig = fig5.fig5_figure(rec, track, "t")
    assert len(fig.axes) == 3  # estimates, active policy, heights
    labels = [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]
    assert {"E_jumps", "E_gaps", "E_stairs", "walk", "left foot", "CoM over feet"} <= set(labels)
    fig5.plot_trial(rec, track, tmp_path / "f.png", "t")
    assert (tmp_path / "f.png").stat().st_size > 20_000

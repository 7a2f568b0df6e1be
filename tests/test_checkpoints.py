"""Damaged run folders: a config.json that is not JSON and a truncated checkpoint each end in one
error that names the file; a resume falls back to the newest intact checkpoint and says so."""

import json
import pathlib

import numpy as np
import pytest

from biped_switch.learning import checkpoints as ckpt_lib
from biped_switch.learning import runs as runs_lib


def _save(run_dir: pathlib.Path, step: int, value: float) -> pathlib.Path:
    tree = {"w": np.full((3, 4), value, np.float32), "b": np.arange(4, dtype=np.float32)}
    return ckpt_lib.save_tree(run_dir, step, tree, {"step": step, "wall_s": 1.0})


def _truncate(ckpt: pathlib.Path) -> None:
    """Cut every data file of a checkpoint to half its size (a copy or disk write cut short)."""
    files = [f for f in ckpt.rglob("*") if f.is_file() and f.name != "progress.json"]
    assert files
    for f in files:
        data = f.read_bytes()
        f.write_bytes(data[: len(data) // 2])


def test_config_that_is_not_json_names_the_file(tmp_path):
    (tmp_path / "config.json").write_text('{"policy": "walk", "ppo": {')
    with pytest.raises(runs_lib.RunFileError) as e:
        runs_lib.read_config(tmp_path)
    msg = str(e.value)
    assert str(tmp_path / "config.json") in msg and "not valid JSON" in msg and "line 1" in msg
    with pytest.raises(runs_lib.RunFileError, match="config.json is not valid JSON"):
        runs_lib.run_config(tmp_path)


def test_progress_that_is_not_json_names_the_file(tmp_path):
    ckpt = _save(tmp_path, 10, 1.0)
    (ckpt / "progress.json").write_text("{")
    with pytest.raises(runs_lib.RunFileError, match="progress.json is not valid JSON"):
        runs_lib.read_progress(ckpt)


def test_round_trip_restores_the_tree(tmp_path):
    ckpt = _save(tmp_path, 10, 2.5)
    tree, prog = ckpt_lib.load_checkpoint(ckpt)
    np.testing.assert_array_equal(tree["w"], np.full((3, 4), 2.5, np.float32))
    assert prog == {"step": 10, "wall_s": 1.0}


def test_truncated_checkpoint_is_one_short_error_naming_the_folder(tmp_path):
    ckpt = _save(tmp_path, 10, 1.0)
    _truncate(ckpt)
    with pytest.raises(ckpt_lib.CheckpointError) as e:
        ckpt_lib.load_checkpoint(ckpt)
    msg = str(e.value)
    assert str(ckpt.resolve()) in msg and "damaged or truncated" in msg
    assert len(msg) < 600  # not TensorStore's 1,500-character traceback text


def test_resume_falls_back_to_the_newest_intact_checkpoint(tmp_path):
    _save(tmp_path, 10, 1.0)
    newest = _save(tmp_path, 20, 2.0)
    _truncate(newest)
    said = []
    (tree, prog), ckpt = ckpt_lib.load_newest_intact(tmp_path, ckpt_lib.load_checkpoint, said.append,
                                                     set_aside=True)
    assert ckpt.name == f"{10:012d}" and prog["step"] == 10 and float(tree["w"][0, 0]) == 1.0
    assert len(said) == 1 and "skipping a damaged checkpoint" in said[0] and newest.name in said[0]
    # set aside: the run's next checkpoint (step 15 < 20) is its latest, not the damaged one
    assert not newest.exists() and newest.with_name(newest.name + ".damaged").is_dir()
    _save(tmp_path, 15, 1.5)
    assert runs_lib.latest_checkpoint(tmp_path).name == f"{15:012d}"


def test_resume_with_no_intact_checkpoint_says_so(tmp_path):
    _truncate(_save(tmp_path, 10, 1.0))
    with pytest.raises(ckpt_lib.CheckpointError, match="no checkpoint restores"):
        ckpt_lib.load_newest_intact(tmp_path, ckpt_lib.load_checkpoint, lambda s: None)
    assert ckpt_lib.load_newest_intact(tmp_path / "empty", ckpt_lib.load_checkpoint) == (None, None)


def test_committed_models_load_through_the_codec():
    """Every committed PPO and DQN checkpoint restores through the one codec."""
    from biped_switch.paths import BASELINE_DIR, COMMITTED_DIR
    runs = [d for d in sorted(COMMITTED_DIR.iterdir()) + sorted(BASELINE_DIR.iterdir()) if d.is_dir()]
    assert runs
    for d in runs:
        ckpt = runs_lib.latest_checkpoint(d)
        assert ckpt is not None, d
        tree, prog = ckpt_lib.load_checkpoint(ckpt)
        assert prog["step"] > 0 and json.dumps(runs_lib.read_config(d))


_SAVER = """
import sys, numpy as np
from biped_switch.learning import checkpoints as ckpt_lib
run = sys.argv[1]
print("ready", flush=True)
for step in range(1, 100000):
    tree = {"w": np.full((64, 256), step, np.float32), "b": np.arange(256, dtype=np.float32) + step}
    ckpt_lib.save_tree(run, step, tree, {"step": step, "pad": "x" * 20000}, keep=2)
"""


def test_kill_9_in_the_middle_of_checkpoint_writes_resumes_from_an_intact_one(tmp_path):
    """A process saving checkpoints back to back is killed with SIGKILL at random moments, mostly
    in the middle of a write (Orbax's files or progress.json): every time, the newest intact
    checkpoint restores, with the tree its progress.json says, and saving goes on after it."""
    import signal
    import subprocess
    import sys
    import time

    rng = np.random.default_rng(0)
    script = tmp_path / "saver.py"
    script.write_text(_SAVER)
    for trial in range(3):
        run = tmp_path / f"run{trial}"
        proc = subprocess.Popen([sys.executable, str(script), str(run)], stdout=subprocess.PIPE,
                                text=True)
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(1.0 + rng.uniform(0.0, 1.5))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        (tree, prog), ckpt = ckpt_lib.load_newest_intact(run, ckpt_lib.load_checkpoint,
                                                         lambda s: None, set_aside=True)
        assert ckpt is not None and int(ckpt.name) == prog["step"]
        np.testing.assert_array_equal(tree["w"], np.full((64, 256), prog["step"], np.float32))
        # the next save after a resume lands beside it and is the newest
        _save(run, prog["step"] + 1, 7.0)
        assert runs_lib.latest_checkpoint(run).name == f"{prog['step'] + 1:012d}"


def test_a_half_written_progress_file_is_passed_over(tmp_path):
    """A checkpoint whose progress.json was cut short counts as damaged: the resume takes the
    one before it."""
    _save(tmp_path, 10, 1.0)
    cut = _save(tmp_path, 20, 2.0)
    (cut / "progress.json").write_text('{"step": 2')
    said = []
    (tree, prog), ckpt = ckpt_lib.load_newest_intact(tmp_path, ckpt_lib.load_checkpoint, said.append)
    assert prog["step"] == 10 and ckpt.name == f"{10:012d}" and "progress.json" in said[0]

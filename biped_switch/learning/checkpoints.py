"""The one checkpoint codec: Orbax PyTree checkpoints with a progress.json beside them, for PPO,
the DQN and the switch estimators. A damaged file becomes an error that names it."""

from __future__ import annotations

import json
import logging
import os
import pathlib
import shutil
import sys
import warnings

import orbax.checkpoint as ocp

from biped_switch.learning.runs import PROGRESS, RunFileError, checkpoints, read_progress


class CheckpointError(ValueError):
    """A checkpoint that cannot be restored: the message names its folder and what is wrong."""


def write_tree(path: pathlib.Path, tree, save_args=None) -> pathlib.Path:
    """An Orbax PyTree checkpoint of `tree` at `path` (replaced if there)."""
    path = pathlib.Path(path).resolve()
    ocp.PyTreeCheckpointer().save(path, tree, force=True, save_args=save_args)
    return path


def _quiet_closed_loop(hook):
    """`sys.excepthook` that drops "Event loop is closed": TensorStore's callbacks print it (via
    PyErr_Print) when they reach Orbax's loop after a failed restore has closed it."""
    def quiet(kind, value, tb):
        if not (isinstance(value, RuntimeError) and "Event loop is closed" in str(value)):
            hook(kind, value, tb)
    quiet.quiet_closed_loop = True
    return quiet


def read_tree(path: pathlib.Path, item=None):
    """The tree of the Orbax checkpoint at `path` (in `item`'s structure when given). A missing,
    truncated or otherwise damaged checkpoint raises CheckpointError naming the folder, instead of
    Orbax's and TensorStore's long tracebacks."""
    path = pathlib.Path(path).resolve()
    if not path.is_dir():
        raise CheckpointError(f"{path}: no checkpoint folder there")
    # On a damaged checkpoint Orbax's other read tasks fail too, and asyncio logs each as "Task
    # exception was never retrieved" as it is collected, during the restore or after it: the
    # CheckpointError says it once, so that logger is quiet while restoring and after a failure.
    if not getattr(sys.excepthook, "quiet_closed_loop", False):
        sys.excepthook = _quiet_closed_loop(sys.excepthook)
    aio = logging.getLogger("asyncio")
    level = aio.level
    aio.setLevel(logging.CRITICAL)
    try:
        with warnings.catch_warnings():  # restoring on the host it was saved for: no sharding to give
            warnings.filterwarnings("ignore", message="Sharding info not provided")
            tree = ocp.PyTreeCheckpointer().restore(path, item=item)
        aio.setLevel(level)
        return tree
    except Exception as e:  # Orbax wraps TensorStore's errors in several exception types
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise CheckpointError(f"{path}: damaged or truncated checkpoint, cannot restore it "
                              f"({type(e).__name__}: {first[:200]})") from None


def save_tree(run_dir: pathlib.Path, step: int, tree, progress: dict,
              keep: int | None = None) -> pathlib.Path:
    """Orbax checkpoint <run>/checkpoints/<step>/ of `tree` with progress.json beside it (the
    layout `latest_checkpoint` finds; PPO and DQN runs alike); with `keep`, older checkpoints
    beyond the last `keep` are removed."""
    path = pathlib.Path(run_dir) / "checkpoints" / f"{step:012d}"
    write_tree(path, tree)
    # progress.json marks a checkpoint finished, so it appears whole or not at all: a process
    # killed while writing it leaves a checkpoint without one, which a resume passes over
    tmp = path / (PROGRESS + ".tmp")
    tmp.write_text(json.dumps(progress, indent=2))
    os.replace(tmp, path / PROGRESS)
    if keep is not None:
        for old in sorted(path.parent.glob("[0-9]" * 12))[:-keep]:
            shutil.rmtree(old, ignore_errors=True)
    return path


def save_ppo(run_dir: pathlib.Path, step: int, state, progress: dict, keep: int = 2) -> pathlib.Path:
    """A PPO checkpoint of a ppo.TrainState: parameters, optimiser state, normaliser; the last
    `keep` are kept."""
    tree = {"params": state.params, "opt_state": state.opt_state, "norm": state.norm._asdict()}
    return save_tree(run_dir, step, tree, progress, keep)


def load_checkpoint(path: pathlib.Path, template=None):
    """(state tree, progress dict) of a checkpoint (PPO: {params, opt_state, norm}). With
    `template` (a ppo.TrainState), the PPO tree is restored into its structure."""
    path = pathlib.Path(path)
    item = None
    if template is not None:
        item = {"params": template.params, "opt_state": template.opt_state,
                "norm": template.norm._asdict()}
    return read_tree(path, item), read_progress(path)


def load_newest_intact(run_dir: pathlib.Path, load, print_fn=print, set_aside: bool = False):
    """(load(ckpt), ckpt) of the run's newest checkpoint that restores; a damaged one is skipped
    with a line saying so and, with `set_aside`, renamed to <step>.damaged so that the run's next
    checkpoints are not ranked below it. (None, None) when the run has no checkpoint; raises
    CheckpointError when none restores."""
    last = None
    for ckpt in reversed(checkpoints(run_dir)):
        try:
            return load(ckpt), ckpt
        except (CheckpointError, RunFileError) as e:
            last = e
            if set_aside:
                ckpt.rename(ckpt.with_name(ckpt.name + ".damaged"))
            print_fn(f"skipping a damaged checkpoint{' (set aside as *.damaged)' if set_aside else ''}: {e}")
    if last is not None:
        raise CheckpointError(f"{run_dir}: no checkpoint restores (the last tried: {last})")
    return None, None

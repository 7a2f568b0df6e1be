"""The one checkpoint codec: Orbax PyTree checkpoints with a progress.json beside them, for PPO,
the DQN and the switch estimators. A damaged file becomes an error that names it."""

from __future__ import annotations

import json
import pathlib
import shutil

import orbax.checkpoint as ocp

from biped_switch.learning.runs import PROGRESS, read_progress


def save_tree(run_dir: pathlib.Path, step: int, tree, progress: dict,
              keep: int | None = None) -> pathlib.Path:
    """Orbax checkpoint <run>/checkpoints/<step>/ of `tree` with progress.json beside it (the
    layout `latest_checkpoint` finds; PPO and DQN runs alike); with `keep`, older checkpoints
    beyond the last `keep` are removed."""
    path = pathlib.Path(run_dir) / "checkpoints" / f"{step:012d}"
    ocp.PyTreeCheckpointer().save(path.resolve(), tree, force=True)
    (path / PROGRESS).write_text(json.dumps(progress, indent=2))
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
    ckptr = ocp.PyTreeCheckpointer()
    if template is not None:
        item = {"params": template.params, "opt_state": template.opt_state,
                "norm": template.norm._asdict()}
        tree = ckptr.restore(path.resolve(), item=item)
    else:
        tree = ckptr.restore(path.resolve())
    return tree, read_progress(path)



"""Training curves of a run folder's metrics.csv: PPO's and the DQN's, one figure module for both.
`ppo_figure`, `dqn_figure` and `run_figure` (either, by the run's metrics) return the figure, which
the notebooks show; `ppo_curves` and `dqn_curves` save it as the run's curves.png. Plain Python and
matplotlib."""

from __future__ import annotations

import csv
import pathlib

from biped_switch.learning.runs import curve_series


def _rows(run_dir) -> list[dict]:
    with (pathlib.Path(run_dir) / "metrics.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def is_dqn_run(rows: list[dict]) -> bool:
    """Whether metrics.csv rows are the DQN's (its episode keys) rather than PPO's."""
    return bool(rows) and "episode_env_return" in rows[0]


def ppo_figure(run_dir, title: str | None = None):
    """Training curves of a PPO run (metrics.csv): episode reward and length, eval reward per
    step and falls, curriculum values, against environment steps; `title` default: the run dir."""
    import matplotlib.pyplot as plt  # lazy: matplotlib loads slowly and only the plots need it

    rows = _rows(run_dir)
    # rows of a window in which no episode ended carry no episode statistics (runs of before
    # 2026-12-01 logged zeros there; an ended episode lasts at least one step)
    ep_rows = [r for r in rows if float(r.get("episode/length") or 0.0) > 0.0]

    def series(key):
        return curve_series(ep_rows if key.startswith("episode/") else rows, key)

    fig, axes = plt.subplots(1, 3, figsize=(15, 3.6))
    for key, ax in (("episode/sum_reward", axes[0]), ("episode/length", axes[0].twinx())):
        xy = series(key)
        ax.plot(xy[:, 0], xy[:, 1], "-" if "reward" in key else ":", label=key)
        ax.set_ylabel(key)
    axes[0].set_title("training episodes")
    xy = series("eval/reward_per_step")
    axes[1].plot(xy[:, 0], xy[:, 1], "o-", label="reward per step")
    axes[1].set_ylabel("reward per step")
    fell_ax = axes[1].twinx()
    xy = series("eval/fell")
    fell_ax.plot(xy[:, 0], xy[:, 1], "r.:", label="fell")
    fell_ax.set_ylabel("fraction fell", color="r")
    fell_ax.set_ylim(-0.02, 1.02)
    # the run's eval.horizon_steps sets the episode length (older runs: 5 s episodes, then 20 s)
    axes[1].set_title("milestone rollout at the current curriculum level")
    for key in ("difficulty", "guide_scale", "push_scale"):  # logged with every epoch
        xy = series(key)
        axes[2].step(xy[:, 0], xy[:, 1], where="post", label=key)
    axes[2].set_title("curriculum")
    axes[2].legend(fontsize=8)
    return _finish(fig, axes, run_dir, title)


def dqn_figure(run_dir, title: str | None = None):
    """The DQN's learning curves (metrics.csv, one row per jitted call): episode return and
    success, the share of steps on the oracle's policy, the TD loss, Q and epsilon, and the
    greedy evaluations; `title` default: the run dir."""
    import matplotlib.pyplot as plt  # lazy, as ppo_figure

    rows = _rows(run_dir)
    ep_rows = [r for r in rows if float(r.get("episodes") or 0) > 0]

    def series(key, src=rows):
        return curve_series(src, key)

    eval_rows = [r for r in rows if r.get("eval_success") not in (None, "")]
    fig, axes = plt.subplots(1, 4 if eval_rows else 3, figsize=(20 if eval_rows else 15, 3.6))
    for key, ax, style in (("episode_env_return", axes[0], "-"),
                           ("episode_success", axes[0].twinx(), "g:")):
        xy = series(key, ep_rows)
        ax.plot(xy[:, 0], xy[:, 1], style, label=key)
        ax.set_ylabel(key)
    axes[0].set_title("training episodes (epsilon-greedy)")
    for key in ("correct_choice_frac", "epsilon"):
        xy = series(key)
        axes[1].plot(xy[:, 0], xy[:, 1], label=key)
    axes[1].set_ylim(-0.02, 1.02)
    axes[1].legend(fontsize=8)
    axes[1].set_title("choice = the oracle's policy; exploration")
    xy = series("loss")
    axes[2].plot(xy[:, 0], xy[:, 1], label="TD loss (Huber)")
    axes[2].set_ylabel("loss")
    q_ax = axes[2].twinx()
    xy = series("q_mean")
    q_ax.plot(xy[:, 0], xy[:, 1], "r:", label="mean Q")
    q_ax.set_ylabel("mean Q", color="r")
    axes[2].set_title("learning")
    if eval_rows:
        n_ep = int(float(eval_rows[-1].get("eval_episodes") or 0))
        for key in ("eval_success", "eval_progress", "eval_fell"):
            xy = series(key, eval_rows)
            axes[3].plot(xy[:, 0], xy[:, 1], "o-", ms=3, label=key.removeprefix("eval_"))
        axes[3].set_ylim(-0.02, 1.02)
        axes[3].set_xlim(axes[0].get_xlim())  # the same steps as the others (it may start late)
        axes[3].legend(fontsize=8)
        axes[3].set_title(f"greedy selector, {n_ep} fixed training tracks (each chunk)")
    return _finish(fig, axes, run_dir, title)


def distill_figure(run_dir, title: str | None = None):
    """The distilled student's curves (metrics.csv): episode success and falls on its training
    tracks beside the teacher's share of the actions, the action MSE on the buffer and on the
    states just visited, and which teacher policy labelled the steps; `title` default: the run dir."""
    import matplotlib.pyplot as plt  # lazy, as ppo_figure

    rows = [r for r in _rows(run_dir) if r.get("dagger/mix") not in (None, "")]
    ep_rows = [r for r in rows if float(r.get("episode/count") or 0) > 0]
    fig, axes = plt.subplots(1, 3, figsize=(15, 3.6))
    for key, src in (("episode/success", ep_rows), ("episode/fell", ep_rows),
                     ("episode/progress_frac", ep_rows), ("dagger/mix", rows)):
        xy = curve_series(src, key)
        axes[0].plot(xy[:, 0], xy[:, 1], "k:" if key == "dagger/mix" else "-", label=key)
    axes[0].set_ylim(-0.02, 1.02)
    axes[0].legend(fontsize=8)
    axes[0].set_title("training episodes; P(teacher acts)")
    for key in ("loss/action_mse", "dagger/onpolicy_mse"):
        xy = curve_series(rows, key)
        axes[1].semilogy(xy[:, 0], xy[:, 1], label=key)
    axes[1].legend(fontsize=8)
    axes[1].set_title("action MSE: buffer minibatch, states just visited")
    keys = sorted(k for k in rows[0] if k.startswith("teacher/active_")) if rows else []
    for key in keys:
        xy = curve_series(rows, key)
        axes[2].plot(xy[:, 0], xy[:, 1], label=f"policy {key.rsplit('_', 1)[1]}")
    axes[2].set_ylim(-0.02, 1.02)
    axes[2].legend(fontsize=8)
    axes[2].set_title("teacher's active policy (share of steps)")
    return _finish(fig, axes, run_dir, title)


def is_distill_run(rows: list[dict]) -> bool:
    """Whether metrics.csv rows are a distillation's (its mixing column)."""
    return bool(rows) and "dagger/mix" in rows[0]


def run_figure(run_dir, title: str | None = None):
    """`dqn_figure` of a DQN run, `distill_figure` of a distillation, else `ppo_figure`."""
    rows = _rows(run_dir)
    fig = dqn_figure if is_dqn_run(rows) else distill_figure if is_distill_run(rows) else ppo_figure
    return fig(run_dir, title)


def _finish(fig, axes, run_dir, title):
    """The common end of a run's curve figure: step axes, a grid, the run as the title."""
    for ax in axes:
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
    fig.suptitle(str(run_dir) if title is None else title, fontsize=9)
    fig.tight_layout()
    return fig


def _save(make_figure, run_dir, out_png) -> None:
    import matplotlib

    matplotlib.use("Agg")  # before pyplot is first imported: no display needed
    import matplotlib.pyplot as plt

    fig = make_figure(run_dir)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)


def ppo_curves(run_dir: pathlib.Path, out_png: pathlib.Path) -> None:
    """`ppo_figure` of a run, saved to `out_png` (its curves.png)."""
    _save(ppo_figure, run_dir, out_png)


def distill_curves(run_dir, out_png) -> None:
    """`distill_figure` of a run, saved to `out_png` (its curves.png)."""
    _save(distill_figure, run_dir, out_png)


def dqn_curves(run_dir, out_png) -> None:
    """`dqn_figure` of a run, saved to `out_png` (its curves.png)."""
    _save(dqn_figure, run_dir, out_png)

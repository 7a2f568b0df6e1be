"""Train one behaviour policy with PPO (ppo.py) and the guided curriculum, resumable.

    python -m biped_switch.train --policy gaps --init stand [--preset cpu] [--total-steps N]

One env and one compiled PPO iteration serve the whole run (the compile is printed once): the
curriculum's difficulty, guide and push levels enter as traced values. Every `chunk_timesteps`
env steps a fixed-horizon rollout of the deterministic policy measures the mean reward per step,
`curriculum.update` advances a notch on a milestone, and an Orbax checkpoint is written of the
parameters, the optimiser's moments and the observation normaliser, with a `progress.json` (step,
curriculum, evaluation, wall time, speed) beside it. A rerun of the same command resumes from
runs/<policy>_<init>/, or, when that is absent (a fresh clone), from the committed copy under
models/policies/ (`commit_run` writes it: the latest checkpoint, config, metrics, curves).
Metrics go to stdout, `metrics.csv` and TensorBoard (`tb/`); the config is saved as `config.json`.

Devices: the envs are split over every local device (pmap; gradients and normaliser statistics
averaged). Multi-host: `--distributed` calls `jax.distributed.initialize()` first, the collectives
then span every process's devices, and only process 0 writes checkpoints and logs (not tested
here: one host).
"""

from __future__ import annotations

import argparse
import csv
import functools
import json
import pathlib
import sys
import time

import jax
import numpy as np
from ml_collections import config_dict

import jax.numpy as jnp

from biped_switch import curriculum as curr_lib
from biped_switch import env as env_lib
from biped_switch import model as model_lib
from biped_switch import ppo
from biped_switch.config import default_curriculum_config
from biped_switch.rollout import rollout, summarize

POLICIES = ("walk", "jumps", "gaps", "stairs")
# "mixed": the end-to-end baseline (issue 5), one policy trained on multi-artifact tracks with the
# same reward and guided curriculum
TRAIN_KINDS = POLICIES + ("mixed",)
COMMITTED_DIR = model_lib.MODELS_DIR / "policies"  # latest checkpoint of every run, committed


def default_train_config(preset: str = "gpu") -> config_dict.ConfigDict:
    """PPO (ppo.py), network and schedule; `preset` "cpu" sizes the batch for a 2-core machine.

    `env` holds env-config overrides the policy is trained (and so must be evaluated) with: the
    action mode, the phase clock and the physics backend ("auto": mujoco on a CPU)."""
    cfg = config_dict.create(
        policy="walk",
        init="stand",
        seed=0,
        total_timesteps=100_000_000,
        chunk_timesteps=5_000_000,  # env steps between curriculum checks and checkpoints
        n_tracks=256,
        episode_length=1000,  # control steps (20 s)
        log_every=10,  # iterations between progress lines
        warm_start="",  # a checkpoint directory whose parameters start this run (e.g. walk's)
        # torque actions: the side-by-side on walk (README, Training) favoured them over pd
        env=config_dict.create(backend="auto", action="torque", pd_offset="gait", phase_obs=True),
        ppo=config_dict.create(
            num_envs=4096, unroll_length=20, num_minibatches=32, num_updates_per_batch=4,
            learning_rate=3e-4, entropy_cost=1e-3, value_cost=0.5, discounting=0.99,
            gae_lambda=0.95, clipping_epsilon=0.2, reward_scaling=0.1, max_grad_norm=1.0,
            init_action_std=0.5,
        ),
        network=config_dict.create(policy_hidden=(256, 256), value_hidden=(256, 256),
                                   encoding="pool", pool=(2, 8), hm_hidden=(128, 64)),
        eval=config_dict.create(n_envs=256, horizon_steps=500),
        curriculum=default_curriculum_config(),
        start=config_dict.create(stage=0, difficulty=0.0, guide_scale=1.0, push_scale=0.0),
    )
    if preset == "cpu":
        cfg.chunk_timesteps = 1_000_000
        cfg.total_timesteps = 100_000_000
        cfg.n_tracks = 32
        cfg.ppo.update(num_envs=256, unroll_length=32, num_minibatches=4)
        cfg.eval.update(n_envs=64, horizon_steps=250)
    elif preset != "gpu":
        raise ValueError(f"unknown preset {preset!r}; expected 'gpu' or 'cpu'")
    return cfg


def make_env(cfg) -> env_lib.BipedEnv:
    """The training env of a run config; the curriculum's values enter as traced arguments."""
    if cfg.policy not in TRAIN_KINDS:
        raise ValueError(f"unknown policy {cfg.policy!r}; expected one of {TRAIN_KINDS}")
    return env_lib.make_env(cfg.policy, cfg.init, curriculum_cfg=cfg.curriculum,
                            n_tracks=cfg.n_tracks, seed=cfg.seed, **dict(cfg.env))


def run_config(run_dir: pathlib.Path) -> config_dict.ConfigDict:
    """The train config a run was made with (its config.json over today's defaults)."""
    saved = json.loads((run_dir / "config.json").read_text())
    cfg = default_train_config()
    for section in ("env", "network", "ppo"):
        for k, v in saved.get(section, {}).items():
            if k in cfg[section]:
                cfg[section][k] = tuple(v) if isinstance(v, list) else v
    for k in ("policy", "init", "episode_length"):
        if k in saved:
            cfg[k] = saved[k]
    return cfg


def policy_env_overrides(ckpt: pathlib.Path) -> dict:
    """Env-config overrides a checkpoint's policy needs (action mode, phase clock)."""
    env = dict(run_config(ckpt.parent.parent).env)
    env.pop("backend", None)  # physics backend: the evaluator's choice
    return env


def save_tree(run_dir: pathlib.Path, step: int, tree, progress: dict,
              keep: int | None = None) -> pathlib.Path:
    """Orbax checkpoint <run>/checkpoints/<step>/ of `tree` with progress.json beside it (the
    layout `latest_checkpoint` finds; PPO and DQN runs alike); with `keep`, older checkpoints
    beyond the last `keep` are removed."""
    import shutil

    import orbax.checkpoint as ocp

    path = pathlib.Path(run_dir) / "checkpoints" / f"{step:012d}"
    ocp.PyTreeCheckpointer().save(path.resolve(), tree, force=True)
    (path / "progress.json").write_text(json.dumps(progress, indent=2))
    if keep is not None:
        for old in sorted(path.parent.glob("[0-9]" * 12))[:-keep]:
            shutil.rmtree(old, ignore_errors=True)
    return path


def _save(run_dir: pathlib.Path, step: int, state, progress: dict, keep: int = 2) -> pathlib.Path:
    """A PPO checkpoint: parameters, optimiser state, normaliser; the last `keep` are kept."""
    tree = {"params": state.params, "opt_state": state.opt_state, "norm": state.norm._asdict()}
    return save_tree(run_dir, step, tree, progress, keep)


def latest_checkpoint(run_dir: pathlib.Path) -> pathlib.Path | None:
    ckpts = sorted(p for p in (run_dir / "checkpoints").glob("[0-9]" * 12) if (p / "progress.json").exists())
    return ckpts[-1] if ckpts else None


def load_checkpoint(path: pathlib.Path, template=None):
    """(state tree {params, opt_state, norm}, progress dict) of a checkpoint written by `train`.
    With `template` (a ppo.TrainState), the tree is restored into its structure."""
    import orbax.checkpoint as ocp

    ckptr = ocp.PyTreeCheckpointer()
    if template is not None:
        item = {"params": template.params, "opt_state": template.opt_state,
                "norm": template.norm._asdict()}
        tree = ckptr.restore(path.resolve(), item=item)
    else:
        tree = ckptr.restore(path.resolve())
    return tree, json.loads((path / "progress.json").read_text())


def restore(ckpt: pathlib.Path, template: "ppo.TrainState"):
    """(TrainState, progress) of a checkpoint: parameters, optimiser moments and normaliser, in
    the structure of `template` (a fresh `Trainer.init` of the same config)."""
    tree, prog = load_checkpoint(ckpt, template)
    return ppo.TrainState(tree["params"], tree["opt_state"], ppo.Normalizer.from_tree(tree["norm"])), prog


def policy_apply(cfg, env, deterministic: bool = True):
    """The policy of a run config as a pure function (params, obs (B, >= policy obs), rng) ->
    actions (B, 12) in [-1, 1], params = {"params": ..., "norm": ...} as `load_checkpoint` gives
    them; `deterministic`: the Gaussian's mean (rng unused), else a sample."""
    pol = ppo.make_policy(cfg.network, env)

    def apply(params, obs, rng=None):
        norm = ppo.Normalizer.from_tree(params["norm"])
        return jnp.clip(pol(params["params"], norm, obs, rng, deterministic), -1.0, 1.0)

    return apply


def load_policy(ckpt: pathlib.Path, env, deterministic: bool = True):
    """(batched policy (obs, rng) -> action, progress dict) of a checkpoint, with its run's network.
    `env` must have been made with `policy_env_overrides(ckpt)`."""
    tree, progress = load_checkpoint(ckpt)
    cfg = run_config(ckpt.parent.parent)
    need = policy_env_overrides(ckpt)
    wrong = {k: (env.cfg[k], v) for k, v in need.items() if env.cfg[k] != v}
    if wrong:
        raise ValueError(f"{ckpt}: the env's {wrong} (env, policy) differ from what the policy "
                         f"was trained with; make the env with train.policy_env_overrides")
    apply = policy_apply(cfg, env, deterministic)
    params = {"params": tree["params"], "norm": tree["norm"]}
    return (lambda obs, key: apply(params, obs, key)), progress


class Logger:
    """stdout + CSV + TensorBoard; one row per logged point."""

    def __init__(self, run_dir: pathlib.Path):
        self.csv_path = run_dir / "metrics.csv"
        self.tb = None
        try:
            from tensorboardX import SummaryWriter

            self.tb = SummaryWriter(str(run_dir / "tb"))
        except ImportError:  # pragma: no cover - tensorboardX ships with brax
            pass

    def drop_after(self, step: int) -> None:
        """On resume: forget CSV rows of an abandoned chunk (steps past the checkpoint)."""
        if not self.csv_path.exists():
            return
        with self.csv_path.open() as f:
            reader = csv.DictReader(f)
            fields, rows = reader.fieldnames, [r for r in reader if float(r["step"]) <= step]
        with self.csv_path.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=fields)
            w.writeheader()
            w.writerows(rows)

    def log(self, step: int, row: dict) -> None:
        row = {"step": step, **{k: (round(v, 5) if isinstance(v, float) else v) for k, v in row.items()}}
        new = not self.csv_path.exists()
        fields = list(row)
        if not new:
            with self.csv_path.open() as f:
                fields = next(csv.reader(f))
            fields += [k for k in row if k not in fields]
        rows = [] if new else list(csv.DictReader(self.csv_path.open()))
        with self.csv_path.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=fields)
            w.writeheader()
            w.writerows(rows + [row])
        if self.tb is not None:
            for k, v in row.items():
                if isinstance(v, (int, float)) and k != "step":
                    self.tb.add_scalar(k, v, step)
            self.tb.flush()


def _restore_committed(run_dir: pathlib.Path, print_fn) -> None:
    """A run absent from runs/ resumes from its committed copy under models/policies/."""
    import shutil

    committed = COMMITTED_DIR / run_dir.name
    if latest_checkpoint(run_dir) is None and latest_checkpoint(committed) is not None:
        run_dir.mkdir(parents=True, exist_ok=True)
        for item in committed.iterdir():
            dst = run_dir / item.name
            if item.is_dir():
                shutil.copytree(item, dst, dirs_exist_ok=True)
            else:
                shutil.copy2(item, dst)
        print_fn(f"no checkpoint under {run_dir}: resuming from the committed {committed}")


def commit_run(run_dir: pathlib.Path, out_dir: pathlib.Path | None = None) -> pathlib.Path:
    """Copies a run's latest checkpoint, config, metrics and curves to models/policies/<run>/
    (only the latest checkpoint), for a later session or a fresh clone to resume from."""
    import shutil

    out = out_dir or COMMITTED_DIR / run_dir.name
    ckpt = latest_checkpoint(run_dir)
    if ckpt is None:
        raise FileNotFoundError(f"no checkpoint under {run_dir}")
    if out.exists():
        shutil.rmtree(out / "checkpoints", ignore_errors=True)
    (out / "checkpoints").mkdir(parents=True, exist_ok=True)
    shutil.copytree(ckpt, out / "checkpoints" / ckpt.name)
    for name in ("config.json", "metrics.csv", "train.log"):
        if (run_dir / name).exists():
            shutil.copy2(run_dir / name, out / name)
    if (run_dir / "metrics.csv").exists():
        plot_curves(run_dir, out / "curves.png")
    return out


def train(cfg, run_dir: pathlib.Path, max_chunks: int | None = None, print_fn=print,
          env_fn=make_env, on_restore=None) -> dict:
    """Trains (or resumes) until `total_timesteps`; returns the last progress record.

    One env (`env_fn(cfg)`) and one compiled PPO iteration serve the whole run: the curriculum's
    difficulty, guide and push levels enter as traced arguments. Every `chunk_timesteps` steps a
    fixed-horizon rollout of the deterministic policy measures the mean reward per step,
    `curriculum.update` advances a notch on a milestone, and a checkpoint is written.
    `on_restore(train_state)` is called with the state a resume restored (a hook for tests)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    _restore_committed(run_dir, print_fn)
    logger = Logger(run_dir)
    ckpt = latest_checkpoint(run_dir)
    env = env_fn(cfg)
    trainer = ppo.make_train(cfg, env)
    ts = trainer.init(jax.random.PRNGKey(cfg.seed))
    step, wall_s, compile_s, done = 0, 0.0, None, False
    cs = curr_lib.CurriculumState(**cfg.start)
    if ckpt is not None:
        ts, prog = restore(ckpt, ts)
        if on_restore is not None:
            on_restore(ts)
        step, wall_s = prog["step"], prog["wall_s"]
        cs = curr_lib.CurriculumState.from_dict(prog["curriculum"])
        done = bool(prog.get("curriculum_done", False))
        logger.drop_after(step)
        print_fn(f"resuming {run_dir} at step {step:,} ({ckpt.name}), curriculum {cs.as_dict()}")
    elif cfg.warm_start:
        warm, prog = restore(pathlib.Path(cfg.warm_start), ts)
        ts = ts._replace(params=warm.params, norm=warm.norm)  # fresh optimiser moments
        print_fn(f"warm start from {cfg.warm_start} (step {prog['step']:,})")
    writer = jax.process_index() == 0  # multi-host: one process writes
    if writer:
        (run_dir / "config.json").write_text(cfg.to_json_best_effort(indent=2))
    if cfg.policy == "walk" and int(cs.stage) == 0:
        # flat tracks: difficulty scales nothing, so the terrain stage is moot
        cs = cs._replace(difficulty=1.0)

    def curr_array(c):
        return jnp.asarray([c.difficulty, c.guide_scale, c.push_scale], jnp.float32)

    @jax.jit
    def evaluate(params, norm, rng, curr):
        def act(obs, key):
            return trainer.policy(params, norm, obs, key, True)

        return rollout(env, act, rng, n_envs=cfg.eval.n_envs, horizon=cfg.eval.horizon_steps,
                       reset_args={"difficulty": curr[0], "guide_scale": curr[1],
                                   "push_scale": curr[2]})

    rng = jax.random.PRNGKey(cfg.seed + 7919 * (step // trainer.steps_per_iteration + 1))
    rng, k = jax.random.split(rng)
    envs = trainer.reset_envs(k, curr_array(cs))
    progress, chunks = {}, 0
    while step < cfg.total_timesteps and (max_chunks is None or chunks < max_chunks):
        t_chunk, chunk_start = time.perf_counter(), step
        chunk_end = min(step + cfg.chunk_timesteps, cfg.total_timesteps)
        curr = curr_array(cs)
        it, t_log, steps_log, ep_acc = 0, time.perf_counter(), step, {}
        while step < chunk_end:
            rng, k = jax.random.split(rng)
            t0 = time.perf_counter()
            ts, envs, m = trainer.iteration(ts, envs, k, curr)
            if compile_s is None:
                jax.block_until_ready(m)
                compile_s = time.perf_counter() - t0
                print_fn(f"[{cfg.policy}/{cfg.init}] compiled the PPO iteration in {compile_s:.1f} s "
                         f"(once per run; backend {env.backend}, {trainer.steps_per_iteration:,} "
                         f"env steps per iteration)")
                t_log = time.perf_counter()
            step += trainer.steps_per_iteration
            it += 1
            m = {k: float(v) for k, v in jax.device_get(m).items()}
            n_ep = m["episode/count"]
            for k, v in m.items():  # episode means over the log window, weighted by episodes
                if k.startswith("episode/") and k != "episode/count":
                    ep_acc[k] = ep_acc.get(k, 0.0) + v * n_ep
            ep_acc["episode/count"] = ep_acc.get("episode/count", 0.0) + n_ep
            if it % cfg.log_every == 0 or step >= chunk_end:
                ep_n = ep_acc.pop("episode/count")
                m.update({k: v / max(ep_n, 1.0) for k, v in ep_acc.items()})
                m["episode/count"] = ep_n
                if not ep_n:  # no episode ended in the window: no episode statistics to log
                    m = {k: v for k, v in m.items() if not k.startswith("episode/")}
                ep_acc = {}
                now = time.perf_counter()
                sps = (step - steps_log) / max(now - t_log, 1e-9)
                t_log, steps_log = now, step
                left = max(cfg.total_timesteps - step, 0) / max(sps, 1e-9)
                eps = (f"{int(ep_n)} episodes: reward {m['episode/sum_reward']:.1f} length "
                       f"{m['episode/length']:.0f} success {m['episode/success']:.2f}" if ep_n
                       else "no episode ended")
                print_fn(f"[{cfg.policy}/{cfg.init}] step {step:,}  {eps}  stage {curr_lib.STAGES[int(cs.stage)]} "
                         f"d={float(cs.difficulty):.2f} guide={float(cs.guide_scale):.2f} "
                         f"push={float(cs.push_scale):.2f}  {sps:,.0f} steps/s  elapsed "
                         f"{(wall_s + now - t_chunk) / 3600:.2f} h  left ~{left / 3600:.1f} h")
                if writer:
                    logger.log(step, {"train/steps_per_s": sps, **cs._asdict(), **m})
        jax.block_until_ready(ts)
        train_s = time.perf_counter() - t_chunk
        t_eval = time.perf_counter()
        rng, k = jax.random.split(rng)
        ev = summarize(evaluate(ts.params, ts.norm, k, curr), cfg.eval.horizon_steps)
        eval_s = time.perf_counter() - t_eval
        new_cs = curr_lib.update(cs, ev["reward_per_step"], ev["progress_frac"], cfg.curriculum)
        # the last stage ends like the others: its value at its end and one more milestone there
        done = done or bool(int(cs.stage) == 2 and float(cs.push_scale) >= 1.0 - 1e-6
                            and curr_lib.milestone(ev["reward_per_step"], ev["progress_frac"],
                                                   cfg.curriculum))
        new_cs = curr_lib.CurriculumState(*(np.asarray(v).item() for v in new_cs))
        wall_s += train_s + eval_s
        progress = {"step": step, "wall_s": wall_s, "chunk_train_s": train_s, "chunk_eval_s": eval_s,
                    "env_steps_per_s": (step - chunk_start) / train_s, "compile_s": compile_s, "eval": ev,
                    "curriculum_before": cs.as_dict(), "curriculum": new_cs.as_dict(),
                    "backend": env.backend, "device": str(jax.devices()[0]),
                    "n_devices": jax.device_count(), "total_steps": int(cfg.total_timesteps),
                    "curriculum_done": done}
        path = run_dir / "checkpoints" / f"{step:012d}"
        if writer:
            _save(run_dir, step, ts, progress)
            logger.log(step, {f"eval/{k}": v for k, v in ev.items()} | {"wall_s": wall_s} | {
                f"curriculum/{k}": v for k, v in new_cs._asdict().items()})
        print_fn(f"[{cfg.policy}/{cfg.init}] chunk done at step {step:,}: eval reward/step "
                 f"{ev['reward_per_step']:.2f}, fell {ev['fell']:.2f}, success {ev['success']:.2f}, "
                 f"distance {ev['distance_m']:.2f} m; curriculum {cs.as_dict()['stage_name']} "
                 f"d={float(cs.difficulty):.2f} -> {new_cs.as_dict()['stage_name']} "
                 f"d={float(new_cs.difficulty):.2f} guide={float(new_cs.guide_scale):.2f} "
                 f"push={float(new_cs.push_scale):.2f}; saved {path}")
        if new_cs != cs:  # episodes under way were drawn at the old levels: start afresh
            rng, k = jax.random.split(rng)
            envs = trainer.reset_envs(k, curr_array(new_cs))
        cs = new_cs
        chunks += 1
    return progress


def curve_series(rows: list[dict], key: str) -> np.ndarray:
    """(N, 2) (step, value) of `key` over metrics.csv rows. A row logged again after a restart
    supersedes the older rows from its step on, so the curve never runs backwards."""
    pts = []
    for r in rows:
        if r.get(key) not in (None, ""):
            step = float(r["step"])
            pts = [pt for pt in pts if pt[0] < step] + [(step, float(r[key]))]
    return np.array(pts).reshape(-1, 2)


def plot_curves(run_dir: pathlib.Path, out_png: pathlib.Path) -> None:
    """Training curves of a run (metrics.csv): episode reward and length, eval reward per step,
    curriculum values, against environment steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(csv.DictReader((run_dir / "metrics.csv").open()))
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
    axes[1].set_title("milestone rollout (5 s, current curriculum)")
    for key in ("difficulty", "guide_scale", "push_scale"):  # logged with every epoch
        xy = series(key)
        axes[2].step(xy[:, 0], xy[:, 1], where="post", label=key)
    axes[2].set_title("curriculum")
    axes[2].legend(fontsize=8)
    for ax in axes:
        ax.set_xlabel("environment steps")
    fig.suptitle(str(run_dir))
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.train", description=__doc__.split("\n")[0])
    p.add_argument("--policy", default="walk", choices=TRAIN_KINDS,
                   help="a behaviour policy, or mixed: the end-to-end baseline")
    p.add_argument("--init", default="stand", choices=env_lib.INITS)
    p.add_argument("--preset", default=None, choices=("gpu", "cpu"),
                   help="batch sizes; default: cpu on a CPU, gpu on an accelerator")
    p.add_argument("--backend", default=None, choices=("auto",) + env_lib.BACKENDS,
                   help="physics backend (default: the config's, auto = mujoco on a CPU)")
    p.add_argument("--action", default=None, choices=env_lib.ACTIONS,
                   help="action mode (default torque: the paper's; pd: joint targets)")
    p.add_argument("--pd-offset", default=None, choices=("gait", "stand"),
                   help="pd actions: offsets from the scripted gait (default) or the standing pose")
    p.add_argument("--no-phase", action="store_true", help="no gait phase clock in the observation")
    p.add_argument("--learning-rate", type=float, default=None,
                   help="PPO's Adam step size (a resume keeps the optimiser's moments)")
    p.add_argument("--warm-start", default=None, metavar="CKPT",
                   help="start a new run from this checkpoint's parameters")
    p.add_argument("--total-steps", type=int, default=None)
    p.add_argument("--chunk-steps", type=int, default=None)
    p.add_argument("--max-chunks", type=int, default=None, help="stop after this many chunks")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="runs", help="runs go to OUT/<policy>_<init>")
    p.add_argument("--name", default=None, help="run folder name (default <policy>_<init>)")
    p.add_argument("--distributed", action="store_true", help="jax.distributed.initialize() first")
    p.add_argument("--plot", metavar="PNG", help="only plot the run's training curves to PNG")
    p.add_argument("--commit", action="store_true",
                   help="only copy the run's latest checkpoint, config, metrics and curves to "
                        "models/policies/<run>/ (then git-commit that folder)")
    a = p.parse_args(argv)
    if a.plot:
        plot_curves(pathlib.Path(a.out) / (a.name or f"{a.policy}_{a.init}"), pathlib.Path(a.plot))
        return 0
    if a.commit:
        print(f"committed copy: {commit_run(pathlib.Path(a.out) / (a.name or f'{a.policy}_{a.init}'))}")
        return 0
    if a.distributed:
        jax.distributed.initialize()
    preset = a.preset or ("cpu" if jax.default_backend() == "cpu" else "gpu")
    cfg = default_train_config(preset)
    cfg.policy, cfg.init, cfg.seed = a.policy, a.init, a.seed
    if a.backend:
        cfg.env.backend = a.backend
    if a.action:
        cfg.env.action = a.action
    if a.no_phase:
        cfg.env.phase_obs = False
    if a.pd_offset:
        cfg.env.pd_offset = a.pd_offset
    if a.warm_start:
        cfg.warm_start = a.warm_start
    if a.learning_rate is not None:
        if not a.learning_rate > 0:
            p.error(f"--learning-rate must be > 0, got {a.learning_rate}")
        cfg.ppo.learning_rate = a.learning_rate
    if a.total_steps is not None:
        cfg.total_timesteps = a.total_steps
    if a.chunk_steps is not None:
        cfg.chunk_timesteps = a.chunk_steps
    run_dir = pathlib.Path(a.out) / (a.name or f"{a.policy}_{a.init}")
    print(f"training {a.policy}/{a.init} on {jax.device_count()} {jax.devices()[0].platform} device(s), "
          f"{cfg.total_timesteps:,} steps in chunks of {cfg.chunk_timesteps:,} -> {run_dir}", flush=True)
    train(cfg, run_dir, a.max_chunks, print_fn=functools.partial(print, flush=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Train one behaviour policy with Brax PPO and the guided curriculum, in resumable chunks.

    python -m biped_switch.train --policy gaps --init stand [--preset cpu] [--total-steps N]

Training runs in chunks of `chunk_timesteps` environment steps. Each chunk is one call of
`brax.training.agents.ppo.train` (all local devices, via its pmap) on an environment whose traced
curriculum values (difficulty, guide_scale, push_scale) are the current curriculum state, starting
from the previous chunk's parameters. After a chunk, a fixed-horizon rollout of the deterministic
policy measures the mean reward per step; `curriculum.update` advances a notch on a milestone.
Every chunk ends with an Orbax checkpoint of the parameters and a `progress.json` beside it holding
the step count, the curriculum state and the metrics; a rerun of the same command resumes from
there. Metrics go to stdout, `metrics.csv` and TensorBoard (`tb/`). The config is saved as
`config.json`. Not restored on resume: the optimiser's moments (Brax PPO restores parameters only),
so the first updates after a resume take slightly smaller steps.

Multi-host: call `jax.distributed.initialize()` before training (`--distributed`); Brax PPO then
splits environments over every process's devices.
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

from biped_switch import curriculum as curr_lib
from biped_switch import env as env_lib
from biped_switch import networks
from biped_switch.config import default_curriculum_config
from biped_switch.rollout import rollout, summarize

POLICIES = ("walk", "jumps", "gaps", "stairs")
# "mixed": the end-to-end baseline (issue 5), one policy trained on multi-artifact tracks with the
# same reward and guided curriculum
TRAIN_KINDS = POLICIES + ("mixed",)


def default_train_config(preset: str = "gpu") -> config_dict.ConfigDict:
    """PPO, network and schedule; `preset` "cpu" shrinks batch sizes for a 2-core machine."""
    cfg = config_dict.create(
        policy="walk",
        init="stand",
        seed=0,
        total_timesteps=100_000_000,
        chunk_timesteps=5_000_000,
        n_tracks=256,
        episode_length=1000,  # control steps (20 s)
        log_per_chunk=4,
        ppo=config_dict.create(
            num_envs=4096, batch_size=512, num_minibatches=32, unroll_length=20,
            num_updates_per_batch=4, learning_rate=3e-4, entropy_cost=1e-3, discounting=0.99,
            gae_lambda=0.95, clipping_epsilon=0.2, reward_scaling=0.1, max_grad_norm=1.0,
            normalize_observations=True,
        ),
        network=config_dict.create(policy_hidden=(256, 256), value_hidden=(256, 256),
                                   hm_hidden=(128, 64)),
        eval=config_dict.create(n_envs=256, horizon_steps=500),
        curriculum=default_curriculum_config(),
        start=config_dict.create(stage=0, difficulty=0.0, guide_scale=1.0, push_scale=0.0),
    )
    if preset == "cpu":
        cfg.chunk_timesteps = 100_000
        cfg.total_timesteps = 2_000_000
        cfg.n_tracks = 32
        cfg.ppo.update(num_envs=32, batch_size=32, num_minibatches=4, unroll_length=16)
        cfg.eval.update(n_envs=32, horizon_steps=250)
    elif preset != "gpu":
        raise ValueError(f"unknown preset {preset!r}; expected 'gpu' or 'cpu'")
    return cfg


def make_env(cfg, cs: curr_lib.CurriculumState) -> env_lib.BipedEnv:
    if cfg.policy not in TRAIN_KINDS:
        raise ValueError(f"unknown policy {cfg.policy!r}; expected one of {TRAIN_KINDS}")
    return env_lib.make_env(cfg.policy, cfg.init, curriculum_cfg=cfg.curriculum,
                            n_tracks=cfg.n_tracks, seed=cfg.seed, difficulty=float(cs.difficulty),
                            guide_scale=float(cs.guide_scale), push_scale=float(cs.push_scale))


def _save(run_dir: pathlib.Path, step: int, params, progress: dict) -> pathlib.Path:
    import orbax.checkpoint as ocp
    from flax.training import orbax_utils

    path = run_dir / "checkpoints" / f"{step:012d}"
    ocp.PyTreeCheckpointer().save(path.resolve(), params, force=True,
                                  save_args=orbax_utils.save_args_from_target(params))
    (path / "progress.json").write_text(json.dumps(progress, indent=2))
    return path


def latest_checkpoint(run_dir: pathlib.Path) -> pathlib.Path | None:
    ckpts = sorted(p for p in (run_dir / "checkpoints").glob("[0-9]" * 12) if (p / "progress.json").exists())
    return ckpts[-1] if ckpts else None


def load_checkpoint(path: pathlib.Path):
    """(params, progress dict) of a checkpoint directory written by `train`."""
    from brax.training import checkpoint as brax_ckpt

    return brax_ckpt.load(path.resolve()), json.loads((path / "progress.json").read_text())


def make_inference(cfg, env, params, deterministic: bool = True):
    """A batched policy (obs, rng) -> action from trained parameters."""
    from brax.training.acme import running_statistics

    factory = networks.make_networks_factory(cfg.network, env.cfg.shape.grid_forward
                                             * env.cfg.shape.grid_lateral)
    nets = factory(env.observation_size, env.action_size,
                   preprocess_observations_fn=running_statistics.normalize
                   if cfg.ppo.normalize_observations else lambda x, _: x)
    from brax.training.agents.ppo import networks as ppo_networks

    infer = ppo_networks.make_inference_fn(nets)((params[0], params[1]), deterministic=deterministic)
    return lambda obs, key: infer(obs, key)[0]


def load_policy(ckpt: pathlib.Path, env, deterministic: bool = True):
    """(batched policy, progress dict) of a checkpoint, with the network sizes its run used."""
    params, progress = load_checkpoint(ckpt)
    run_cfg = json.loads((ckpt.parent.parent / "config.json").read_text())
    cfg = default_train_config()
    cfg.network.update(**{k: tuple(v) for k, v in run_cfg["network"].items()})
    cfg.ppo.normalize_observations = run_cfg["ppo"]["normalize_observations"]
    return make_inference(cfg, env, params, deterministic), progress


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


def train(cfg, run_dir: pathlib.Path, max_chunks: int | None = None, print_fn=print,
          env_fn=make_env) -> dict:
    """Trains (or resumes) until `total_timesteps`; returns the last progress record.

    `env_fn(cfg, curriculum_state)` builds each chunk's environment (tests pass a cheap one)."""
    from brax.training.agents.ppo import train as ppo

    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(cfg.to_json_best_effort(indent=2))
    logger = Logger(run_dir)
    ckpt = latest_checkpoint(run_dir)
    params, step, wall_s = None, 0, 0.0
    cs = curr_lib.CurriculumState(**cfg.start)
    if ckpt is not None:
        params, prog = load_checkpoint(ckpt)
        step, wall_s = prog["step"], prog["wall_s"]
        cs = curr_lib.CurriculumState.from_dict(prog["curriculum"])
        logger.drop_after(step)
        print_fn(f"resuming {run_dir} at step {step:,} ({ckpt.name}), curriculum {cs.as_dict()}")
    if cfg.policy == "walk" and int(cs.stage) == 0:
        # flat tracks: difficulty scales nothing, so the terrain stage is moot (also on resume of a
        # run started before this rule)
        cs = cs._replace(difficulty=1.0)
    progress = {}
    chunks = 0
    factory = None
    while step < cfg.total_timesteps and (max_chunks is None or chunks < max_chunks):
        env = env_fn(cfg, cs)
        chunk = int(min(cfg.chunk_timesteps, cfg.total_timesteps - step))
        t_chunk = time.perf_counter()
        last = {"t": t_chunk, "steps": 0, "episode": {}}

        def progress_fn(n, metrics, step0=step, cs=cs):
            # Brax calls this once per epoch with "training/*" metrics, and from its episode-metrics
            # aggregator with "episode/*" (only once episodes complete); report on the former.
            if not any(k.startswith("training/") for k in metrics):
                if "episode/sum_reward" in metrics:
                    last["episode"] = {k: float(v) for k, v in metrics.items() if np.ndim(v) == 0}
                return
            now = time.perf_counter()
            sps = (n - last["steps"]) / max(now - last["t"], 1e-9)
            last.update(t=now, steps=n)
            ep = last["episode"]
            rew, length = ep.get("episode/sum_reward", np.nan), ep.get("episode/length", np.nan)
            left = max(cfg.total_timesteps - step0 - n, 0) / max(sps, 1e-9)  # Brax overshoots a little
            print_fn(f"[{cfg.policy}/{cfg.init}] step {step0 + n:,}  episode reward {rew:.1f}  "
                     f"length {length:.0f}  stage {curr_lib.STAGES[int(cs.stage)]} "
                     f"d={float(cs.difficulty):.2f} guide={float(cs.guide_scale):.2f} "
                     f"push={float(cs.push_scale):.2f}  {sps:,.0f} steps/s  "
                     f"elapsed {(wall_s + now - t_chunk) / 60:.1f} min  left ~{left / 60:.1f} min")
            logger.log(step0 + n, {"train/steps_per_s": sps, **cs._asdict(), **ep} | {
                k: float(v) for k, v in metrics.items() if np.ndim(v) == 0})

        p = cfg.ppo
        factory = factory or networks.make_networks_factory(
            cfg.network, env.cfg.shape.grid_forward * env.cfg.shape.grid_lateral)
        _, params, _ = ppo.train(
            environment=env, num_timesteps=chunk, num_envs=p.num_envs, episode_length=cfg.episode_length,
            batch_size=p.batch_size, num_minibatches=p.num_minibatches, unroll_length=p.unroll_length,
            num_updates_per_batch=p.num_updates_per_batch, learning_rate=p.learning_rate,
            entropy_cost=p.entropy_cost, discounting=p.discounting, gae_lambda=p.gae_lambda,
            clipping_epsilon=p.clipping_epsilon, reward_scaling=p.reward_scaling,
            max_grad_norm=p.max_grad_norm, normalize_observations=p.normalize_observations,
            network_factory=factory, seed=cfg.seed + step, restore_params=params,
            num_evals=cfg.log_per_chunk + 1, run_evals=False, log_training_metrics=True,
            progress_fn=progress_fn)
        train_s = time.perf_counter() - t_chunk
        chunk = last["steps"] or chunk  # Brax rounds a chunk up to whole epochs
        step += chunk
        # Milestone check: deterministic policy, fixed horizon, current curriculum values.
        policy = make_inference(cfg, env, params)
        t_eval = time.perf_counter()
        ev = summarize(jax.jit(functools.partial(rollout, env, policy, n_envs=cfg.eval.n_envs,
                                                 horizon=cfg.eval.horizon_steps))(
            jax.random.PRNGKey(cfg.seed + step)), cfg.eval.horizon_steps)
        eval_s = time.perf_counter() - t_eval
        new_cs = curr_lib.update(cs, ev["reward_per_step"], ev["progress_frac"], cfg.curriculum)
        new_cs = curr_lib.CurriculumState(*(np.asarray(v).item() for v in new_cs))
        wall_s += train_s + eval_s
        progress = {"step": step, "wall_s": wall_s, "chunk_train_s": train_s, "chunk_eval_s": eval_s,
                    "env_steps_per_s": chunk / train_s, "eval": ev,
                    "curriculum_before": cs.as_dict(), "curriculum": new_cs.as_dict(),
                    "device": str(jax.devices()[0]), "n_devices": jax.device_count(),
                    "total_steps": int(cfg.total_timesteps)}  # the run's goal (Table III: finished?)
        path = _save(run_dir, step, params, progress)
        logger.log(step, {f"eval/{k}": v for k, v in ev.items()} | {
            "chunk_env_steps_per_s": chunk / train_s, "wall_s": wall_s} | {
            f"curriculum/{k}": v for k, v in new_cs._asdict().items()})
        print_fn(f"[{cfg.policy}/{cfg.init}] chunk done at step {step:,}: eval reward/step "
                 f"{ev['reward_per_step']:.2f}, fell {ev['fell']:.2f}, distance {ev['distance_m']:.2f} m; "
                 f"curriculum {cs.as_dict()['stage_name']} d={float(cs.difficulty):.2f} -> "
                 f"{new_cs.as_dict()['stage_name']} d={float(new_cs.difficulty):.2f} "
                 f"guide={float(new_cs.guide_scale):.2f} push={float(new_cs.push_scale):.2f}; "
                 f"saved {path}")
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

    def series(key):
        return curve_series(rows, key)

    fig, axes = plt.subplots(1, 3, figsize=(15, 3.6))
    for key, ax in (("episode/sum_reward", axes[0]), ("episode/length", axes[0].twinx())):
        xy = series(key)
        ax.plot(xy[:, 0], xy[:, 1], "-" if "reward" in key else ":", label=key)
        ax.set_ylabel(key)
    axes[0].set_title("training episodes")
    xy = series("eval/reward_per_step")
    axes[1].plot(xy[:, 0], xy[:, 1], "o-")
    axes[1].set_title("milestone rollout: reward per step")
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
    p.add_argument("--preset", default="gpu", choices=("gpu", "cpu"))
    p.add_argument("--total-steps", type=int, default=None)
    p.add_argument("--chunk-steps", type=int, default=None)
    p.add_argument("--max-chunks", type=int, default=None, help="stop after this many chunks")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="runs", help="runs go to OUT/<policy>_<init>")
    p.add_argument("--distributed", action="store_true", help="jax.distributed.initialize() first")
    p.add_argument("--plot", metavar="PNG", help="only plot the run's training curves to PNG")
    a = p.parse_args(argv)
    if a.plot:
        plot_curves(pathlib.Path(a.out) / f"{a.policy}_{a.init}", pathlib.Path(a.plot))
        return 0
    if a.distributed:
        jax.distributed.initialize()
    cfg = default_train_config(a.preset)
    cfg.policy, cfg.init, cfg.seed = a.policy, a.init, a.seed
    if a.total_steps is not None:
        cfg.total_timesteps = a.total_steps
    if a.chunk_steps is not None:
        cfg.chunk_timesteps = a.chunk_steps
    run_dir = pathlib.Path(a.out) / f"{a.policy}_{a.init}"
    print(f"training {a.policy}/{a.init} on {jax.device_count()} {jax.devices()[0].platform} device(s), "
          f"{cfg.total_timesteps:,} steps in chunks of {cfg.chunk_timesteps:,} -> {run_dir}", flush=True)
    train(cfg, run_dir, a.max_chunks, print_fn=functools.partial(print, flush=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Speed figures of the environment as one JSON object (a benchmark, never a timed test).

    python -m biped_switch.bench --batch 256 --kind mixed --json

Rolls a batch of envs (one track each, from a bank) with the scripted standing controller, so all
eight sole spheres stay in contact: the physics does its full contact work every step. Prints
compile_s, control_steps_per_s, physics_steps_per_s, heightmap_share (the heightmap lookup's time as
a fraction of a control step's) and n_boxes (the compiled box slots every step pays for), with the
device and the versions.

    python -m biped_switch.bench --train --backend mujoco --json

Times PPO training (ppo.py) with collection and updates together, at the CPU preset (256 envs x 32
steps per iteration, 4 epochs of 4 minibatches): compile_s once, then env_steps_per_s over
`--iterations` timed iterations, with the time split into collection and update phases, and
cpu_s_per_1k_env_steps (the process's CPU time, all threads: on a CPU shared with other runs
the figure that compares settings, as wall speed depends on each process's share).
`--encoding mlp` measures the paper-sized heightmap encoder (2,400 -> 128 -> 64) against the lean
default (`pool`: 150 pooled values); `--backend mjx` the same trainer on MJX.

    python -m biped_switch.bench --estimator --points 100000 --epochs 3 --json

Times switch-estimator training (the paper spent about an hour per estimator) on random
data of the sweep's shape: epoch 1 compiles, the later epochs give the training speed and the
projected time of the configured 1,500 epochs.
"""

from __future__ import annotations

import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from biped_switch.simulation import env as env_lib
from biped_switch.switching import estimator as est
from biped_switch.learning import ppo
from biped_switch.simulation import terrain
from biped_switch.config import default_estimator_config, default_terrain_config, default_train_config
from biped_switch.simulation.heightmap import heightmap
from biped_switch.learning.trainer import train_env


def _time(fn, *args, reps: int) -> float:
    """Seconds per call of an already compiled fn, blocking on its result."""
    jax.block_until_ready(fn(*args))
    t0 = time.perf_counter()
    out = None
    for _ in range(reps):
        out = fn(*args)
    jax.block_until_ready(out)
    return (time.perf_counter() - t0) / reps


def run(batch: int = 256, kind: str = "mixed", steps: int = 20, seed: int = 0,
        n_artifacts: int | None = None, n_tracks: int = 32, backend: str = "auto") -> dict:
    tcfg = default_terrain_config()
    if n_artifacts is not None:
        tcfg.n_artifacts = n_artifacts
    env = env_lib.make_env(kind, terrain_cfg=tcfg, n_tracks=n_tracks, seed=seed, backend=backend)
    cfg = env.cfg
    keys = jax.random.split(jax.random.PRNGKey(seed), batch)

    reset = jax.jit(jax.vmap(env.reset))
    t0 = time.perf_counter()
    state = jax.block_until_ready(reset(keys))
    reset_compile_s = time.perf_counter() - t0

    step = jax.jit(jax.vmap(env.hold_step))
    t0 = time.perf_counter()
    compiled = step.lower(state).compile()
    compile_s = time.perf_counter() - t0

    # Advance past the settling of the first steps, then time.
    for _ in range(3):
        state = compiled(state)
    step_s = _time(compiled, state, reps=steps)

    com = state.pipeline_state.xipos[:, env.biped.pelvis_body]
    yaw = jnp.zeros(batch)
    hm = jax.jit(jax.vmap(lambda b, p, y: heightmap(b, p, y, cfg.heightmap.depth_m,
                                                    cfg.heightmap.max_boxes)))
    hm_s = _time(hm, state.info["boxes"], com, yaw, reps=steps)

    used = (env.bank.segments[:, :, terrain.SOLID] > 0.5).sum(axis=1)
    dev = jax.devices()[0]
    return {
        "batch": batch,
        "kind": kind,
        "n_artifacts": tcfg.n_artifacts,
        "n_boxes": env.biped.box_capacity,
        "n_boxes_used_mean": float(np.mean(used)),
        "max_geom_pairs": env.model_cfg.max_geom_pairs,
        "n_substeps": env.biped.n_substeps,
        "compile_s": round(compile_s, 2),
        "reset_compile_s": round(reset_compile_s, 2),
        "control_step_ms": round(step_s * 1e3, 3),
        "control_steps_per_s": round(batch / step_s, 1),
        "physics_steps_per_s": round(batch * env.biped.n_substeps / step_s, 1),
        "heightmap_ms": round(hm_s * 1e3, 3),
        "heightmap_share": round(hm_s / step_s, 4),
        "controller": "scripted standing (PD hold at every substep)",
        "backend": env.backend,
        "device": f"{dev.platform}:{getattr(dev, 'device_kind', '')}",
        "n_devices": jax.device_count(),
        "host": platform.node(),
        "cpu_count": __import__("os").cpu_count(),
        "jax": jax.__version__,
    }


def run_train(backend: str = "auto", kind: str = "walk", iterations: int = 5, preset: str = "cpu",
              encoding: str = "pool", seed: int = 0) -> dict:
    """PPO env steps/s (collection + updates) on `backend`, after one compile."""
    cfg = default_train_config(preset)
    cfg.policy, cfg.env.backend, cfg.network.encoding = kind, backend, encoding
    env = train_env(cfg)
    trainer = ppo.make_train(cfg, env)
    curr = jnp.asarray([1.0, 1.0, 0.0], jnp.float32)  # difficulty 1, guides on, no pushes
    ts = trainer.init(jax.random.PRNGKey(seed))
    envs = trainer.reset_envs(jax.random.PRNGKey(seed + 1), curr)
    t0 = time.perf_counter()
    ts, envs, m = jax.block_until_ready(trainer.iteration(ts, envs, jax.random.PRNGKey(seed + 2), curr))
    compile_s = time.perf_counter() - t0
    t0, cpu0 = time.perf_counter(), time.process_time()
    for i in range(iterations):
        ts, envs, m = trainer.iteration(ts, envs, jax.random.PRNGKey(seed + 3 + i), curr)
    jax.block_until_ready(m)
    it_s = (time.perf_counter() - t0) / iterations
    cpu_s = time.process_time() - cpu0  # all threads' CPU time: the fair figure on a shared CPU
    p = cfg.ppo
    dev = jax.devices()[0]
    return {
        "what": "ppo_train", "backend": env.backend, "kind": kind, "preset": preset,
        "encoding": encoding, "num_envs": p.num_envs, "unroll_length": p.unroll_length,
        "epochs": p.num_updates_per_batch, "minibatches": p.num_minibatches,
        "policy_hidden": list(cfg.network.policy_hidden), "action": cfg.env.action,
        "compile_s": round(compile_s, 2), "iteration_s": round(it_s, 3),
        "iterations_timed": iterations,
        "env_steps_per_s": round(trainer.steps_per_iteration / it_s, 1),
        "cpu_s_per_1k_env_steps": round(1000 * cpu_s / (iterations * trainer.steps_per_iteration), 4),
        "device": f"{dev.platform}:{getattr(dev, 'device_kind', '')}", "n_devices": 1,
        "cpu_count": __import__("os").cpu_count(), "jax": jax.__version__,
        "python": platform.python_version(),
    }


def run_estimator(points: int, epochs: int, seed: int = 0) -> dict:
    """Estimator training speed on `points` random (state, heightmap, label) rows."""
    rng = np.random.default_rng(seed)
    data = {"state": rng.normal(size=(points, est.STATE_SIZE)).astype(np.float32),
            "heightmap": rng.uniform(size=(points, est.HM_SIZE)).astype(np.float16),
            "label": rng.integers(0, 2, points).astype(np.int8),
            "sample": np.arange(points) // 5}  # 5 points per switch, as the sweep stores them
    cfg = default_estimator_config()
    cfg.epochs = epochs
    _, m = est.train_estimator(data, cfg, print_fn=lambda *_: None)
    epoch_s = float(np.median(m["history"]["epoch_s"][1:])) if epochs > 1 else float("nan")
    per_epoch = m["train_points"] // m["batch_size"] * m["batch_size"]
    return {"what": "estimator", "points": points, "train_points": m["train_points"],
            "epochs_timed": epochs - 1, "first_epoch_s": round(m["history"]["epoch_s"][0], 2),
            "epoch_s": round(epoch_s, 5), "train_points_per_s": round(per_epoch / epoch_s, 1),
            "projected_s_for_config_epochs": round(epoch_s * default_estimator_config().epochs, 1),
            "config_epochs": int(default_estimator_config().epochs), "batch_size": m["batch_size"],
            "device": str(jax.devices()[0]), "jax": jax.__version__, "python": platform.python_version()}

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

    python -m biped_switch.bench --physics --kind mixed --json

The raw rate of the same physics with no learner and no JAX in the loop: the env's own
`CPhysics.step` (the `mujoco` backend's host side: the same per-env track models, batch, threads,
substeps and numpy control law, with the copies in and out) called in a Python loop on robots held
standing, all soles in contact. `--train` measures it too, in the same process, and prints its
own rate as a fraction of it (`physics_ratio`): the VM's speed varies up to 3x between sittings,
so only that ratio compares days. `--profile` splits one PPO iteration into its parts
(`profile_train`).

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


def _physics_inputs(env, state):
    """The `CPhysics.step` arguments (numpy) of a batch of env states held standing."""
    n = state.obs.shape[0]
    ps = jax.device_get(state.pipeline_state)
    info = jax.device_get(state.info)
    inputs = {"action": np.zeros((n, 12), np.float32), "paused": np.ones(n, np.float32),
              "guide": np.zeros(n, np.float32),
              "q_ref": np.tile(np.asarray(env._stand_q), (n, 1)).astype(np.float32)}
    return (np.asarray(info["track_id"]), np.asarray(info["difficulty"]), ps.qpos, ps.qvel,
            ps.qacc_warmstart, ps.time, np.zeros((n, 6), np.float32), inputs)


def physics_rate(env, state, steps: int) -> dict:
    """Control steps/s of the raw C physics on `env`'s batch `state` (the `mujoco` backend's host
    side in a Python loop, no JAX): the limit a trainer on this env can reach."""
    if env.backend != "mujoco":
        raise ValueError(f"the physics limit is measured on the mujoco backend, not {env.backend!r}")
    track, diff, qpos, qvel, warm, t, xfrc, inputs = _physics_inputs(env, state)
    n = qpos.shape[0]
    for _ in range(3):  # settle, and compile the per-env models
        out = env._native.step(track, diff, qpos, qvel, warm, t, xfrc, inputs)
        qpos, qvel, warm, t = out["qpos"], out["qvel"], out["qacc_warmstart"], out["time"]
    t0 = time.perf_counter()
    for _ in range(steps):
        out = env._native.step(track, diff, qpos, qvel, warm, t, xfrc, inputs)
        qpos, qvel, warm, t = out["qpos"], out["qvel"], out["qacc_warmstart"], out["time"]
    step_s = (time.perf_counter() - t0) / steps
    return {"physics_batch": n, "physics_step_ms": round(step_s * 1e3, 3),
            "physics_control_steps_per_s": round(n / step_s, 1),
            "physics_nthread": env._native.nthread, "n_substeps": env.biped.n_substeps}


def run_physics(batch: int = 256, kind: str = "mixed", steps: int = 50, seed: int = 0,
                n_artifacts: int | None = None) -> dict:
    """`physics_rate` on a batch of `kind` tracks (the env benchmark's tracks), standing."""
    tcfg = default_terrain_config()
    if n_artifacts is not None:
        tcfg.n_artifacts = n_artifacts
    env = env_lib.make_env(kind, terrain_cfg=tcfg, n_tracks=32, seed=seed, backend="mujoco")
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(seed), batch))
    return {"what": "physics", "kind": kind, "n_artifacts": tcfg.n_artifacts,
            **physics_rate(env, state, steps), **_machine()}


def _machine() -> dict:
    dev = jax.devices()[0]
    return {"device": f"{dev.platform}:{getattr(dev, 'device_kind', '')}",
            "cpu_count": __import__("os").cpu_count(), "jax": jax.__version__,
            "python": platform.python_version()}


def _trainer(backend, kind, preset, encoding, seed, epochs=None, minibatches=None):
    cfg = default_train_config(preset)
    cfg.policy, cfg.env.backend, cfg.network.encoding = kind, backend, encoding
    if epochs is not None:
        cfg.ppo.num_updates_per_batch = epochs
    if minibatches is not None:
        cfg.ppo.num_minibatches = minibatches
    env = train_env(cfg)
    trainer = ppo.make_train(cfg, env)
    curr = jnp.asarray([1.0, 1.0, 0.0], jnp.float32)  # difficulty 1, guides on, no pushes
    ts = trainer.init(jax.random.PRNGKey(seed))
    envs = trainer.reset_envs(jax.random.PRNGKey(seed + 1), curr)
    return cfg, env, trainer, curr, ts, envs


def run_train(backend: str = "auto", kind: str = "walk", iterations: int = 5, preset: str = "cpu",
              encoding: str = "pool", seed: int = 0, physics_steps: int = 50,
              epochs: int | None = None, minibatches: int | None = None) -> dict:
    """PPO env steps/s (collection + updates) on `backend`, after one compile, as the trainer's
    loop runs it (metrics fetched every iteration); on `mujoco`, beside the raw physics rate of
    the same env and batch, measured right after in the same process. `epochs` and `minibatches`
    override the preset's update (levers that change the learning)."""
    cfg, env, trainer, curr, ts, envs = _trainer(backend, kind, preset, encoding, seed, epochs,
                                                 minibatches)
    t0 = time.perf_counter()
    ts, envs, m = jax.block_until_ready(trainer.iteration(ts, envs, jax.random.PRNGKey(seed + 2), curr))
    compile_s = time.perf_counter() - t0
    t0, cpu0 = time.perf_counter(), time.process_time()
    for i in range(iterations):
        ts, envs, m = trainer.iteration(ts, envs, jax.random.PRNGKey(seed + 3 + i), curr)
        m = jax.device_get(m)
    it_s = (time.perf_counter() - t0) / iterations
    cpu_s = time.process_time() - cpu0  # all threads' CPU time: the fair figure on a shared CPU
    p = cfg.ppo
    rate = trainer.steps_per_iteration / it_s
    out = {
        "what": "ppo_train", "backend": env.backend, "kind": kind, "preset": preset,
        "encoding": encoding, "num_envs": p.num_envs, "unroll_length": p.unroll_length,
        "epochs": p.num_updates_per_batch, "minibatches": p.num_minibatches,
        "policy_hidden": list(cfg.network.policy_hidden), "action": cfg.env.action,
        "compile_s": round(compile_s, 2), "iteration_s": round(it_s, 3),
        "iterations_timed": iterations,
        "env_steps_per_s": round(rate, 1),
        "cpu_s_per_1k_env_steps": round(1000 * cpu_s / (iterations * trainer.steps_per_iteration), 4),
        "n_devices": 1, **_machine(),
    }
    if env.backend == "mujoco" and physics_steps > 0:
        standing, _, _ = trainer.reset_envs(jax.random.PRNGKey(seed + 1), curr)  # fresh, upright
        phys = physics_rate(env, standing, physics_steps)
        out.update(phys)
        out["physics_ratio"] = round(rate / phys["physics_control_steps_per_s"], 3)
    return out


def _best(fn, *args, reps: int = 3) -> float:
    """Seconds of the fastest of `reps` calls of an already compiled fn (the least disturbed)."""
    jax.block_until_ready(fn(*args))
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return best


def profile_train(kind: str = "mixed", preset: str = "cpu", seed: int = 0, reps: int = 3,
                  physics_steps: int = 50) -> dict:
    """One PPO iteration of the `mujoco` backend split into its parts, in ms per control step of
    the whole batch (each part timed alone, the best of `reps`): the physics callback (C stepping,
    copies in and out: `physics_rate`), the heightmap, the rest of the env step (observation,
    reward, termination; the env step less those two), the policy's forward pass during
    collection (input, normalisation, policy and value networks, sampling), the rest of the
    collection (auto-resets, storing the rollout), GAE and the updates, and host overhead (the
    trainer loop's iteration less collection and update: dispatch and the metrics' fetch)."""
    cfg, env, trainer, curr, ts, envs = _trainer("mujoco", kind, preset, "pool", seed)
    T = int(cfg.ppo.unroll_length)
    state = envs[0]
    hcfg = env.cfg.heightmap
    offsets = env._offsets

    def hm_batch(boxes, qpos):
        com = jax.vmap(lambda q: env._pose(q)[2])(qpos)
        yaw = jax.vmap(lambda q: env._pose(q)[3][0])(qpos)
        return jax.vmap(lambda b, c, y: heightmap(b, c, y, hcfg.depth_m, hcfg.max_boxes, offsets))(
            boxes, com, yaw)

    act = jnp.zeros((state.obs.shape[0], env.action_size))
    env_step = jax.jit(jax.vmap(env.step))
    pol = jax.jit(lambda ts, obs, key: trainer.forward(ts, obs, key))
    key = jax.random.PRNGKey(seed + 5)
    k_it = jax.random.PRNGKey(seed + 6)
    envs2, tr = trainer.collect(ts, envs, k_it, curr)
    parts = {
        "heightmap": _best(jax.jit(hm_batch), state.info["boxes"], state.pipeline_state.qpos,
                           reps=reps),
        "env_step": _best(env_step, state, act, reps=reps),
        "policy_forward": _best(pol, ts, state.obs, key, reps=reps),
        "collect": _best(trainer.collect, ts, envs, k_it, curr, reps=reps) / T,
        "update": _best(trainer.update, ts, tr, key, reps=reps) / T,
    }
    loop = []
    for i in range(reps):
        t0 = time.perf_counter()
        ts, envs, m = trainer.iteration(ts, envs, jax.random.PRNGKey(seed + 9 + i), curr)
        jax.device_get(m)
        loop.append(time.perf_counter() - t0)
    phys = physics_rate(env, state, physics_steps)
    ms = {k: v * 1e3 for k, v in parts.items()}
    it_ms = min(loop) * 1e3 / T
    split = {
        "physics_callback": phys["physics_step_ms"],
        "heightmap": ms["heightmap"],
        "env_rest": ms["env_step"] - phys["physics_step_ms"] - ms["heightmap"],
        "policy_forward": ms["policy_forward"],
        "collect_rest": ms["collect"] - ms["env_step"] - ms["policy_forward"],
        "gae_and_updates": ms["update"],
        "host_overhead": it_ms - ms["collect"] - ms["update"],
    }
    return {"what": "ppo_profile", "kind": kind, "preset": preset, "batch": int(state.obs.shape[0]),
            "unroll_length": T, "ms_per_control_step": {k: round(v, 3) for k, v in split.items()},
            "iteration_ms_per_control_step": round(it_ms, 3),
            "env_steps_per_s": round(state.obs.shape[0] * 1e3 / it_ms, 1),
            "physics_control_steps_per_s": phys["physics_control_steps_per_s"],
            "physics_ratio": round(phys["physics_step_ms"] / it_ms, 3), **_machine()}


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

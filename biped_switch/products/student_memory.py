"""Does the student need a memory? A probe on its own aggregate dataset (`distill --memory-probe`).

The teacher's action depends on its switching state (which policy is active, the artifact last
seen), which the student cannot see. If that state is not a function of the current input, a
memoryless student cannot match the labels, and the past inputs carry what it misses. The probe
fits the same MLP, with the same budget, to the labels from the last k inputs of each env
(k = 1: the student's own input), and compares the error on held-out rows: a drop with k is what
a memory (stacked frames or a GRU) could gain; no drop says the labels are a function of the
present input and the student's gap lies elsewhere.

The buffer (buffer.npz, oldest row first) holds whole collections of `num_envs` envs, row
t * num_envs + e for step t and env e, so env e's previous input is the row `num_envs` earlier.
Across an episode's reset that row is the previous episode's last input (about k in 700 rows).
"""

from __future__ import annotations

import json
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import linen

from biped_switch.learning.networks import swish_mlp
from biped_switch.learning.normalizer import column_stats
from biped_switch.products.student import BUFFER_FILE


def history_index(rows: np.ndarray, k: int, n_envs: int) -> np.ndarray:
    """(len(rows), k) buffer rows of the last k inputs of each row's env, newest first: row r,
    r - n_envs, ..., r - (k-1) n_envs."""
    if k < 1:
        raise ValueError(f"k = {k}: the history holds at least the present input")
    return rows[:, None] - n_envs * np.arange(k)[None, :]


class _Head(linen.Module):
    hidden: tuple
    out_size: int

    @linen.compact
    def __call__(self, x):
        x = swish_mlp(x, self.hidden, jax.nn.initializers.lecun_uniform())
        return linen.Dense(self.out_size)(x)


def fit_history(x: np.ndarray, y: np.ndarray, k: int, n_envs: int, train_rows: np.ndarray,
                test_rows: np.ndarray, hidden=(256, 256), steps: int = 3000, batch: int = 2048,
                lr: float = 3e-4, seed: int = 0, std_floor: float = 1e-3,
                eval_every: int = 0) -> dict:
    """An MLP of `hidden` fitted by Adam (`steps` x `batch`) to y[r] from the k inputs
    x[history_index(r)] of each train row r; its mean squared error on `test_rows` and on the
    train rows (per joint), and every `eval_every` steps on `test_rows` (0: at the end only).
    Inputs normalised per column by train-row statistics."""
    mean, std = column_stats(x[train_rows], std_floor)
    xj = jnp.asarray((x - mean) / std)
    yj = jnp.asarray(y)
    net = _Head(tuple(hidden), y.shape[1])
    params = net.init(jax.random.PRNGKey(seed), jnp.zeros((1, k * x.shape[1])))
    tx = optax.adam(lr)
    opt = tx.init(params)
    offsets = jnp.asarray(n_envs * np.arange(k))

    def inputs(rows):
        return xj[rows[:, None] - offsets[None, :]].reshape(rows.shape[0], -1)

    def loss(p, rows):
        return jnp.mean((net.apply(p, inputs(rows)) - yj[rows]) ** 2)

    @jax.jit
    def step(p, o, rows):
        g = jax.grad(loss)(p, rows)
        u, o = tx.update(g, o, p)
        return optax.apply_updates(p, u), o

    mse = jax.jit(loss)
    def mean_mse(rows):
        chunks = np.array_split(rows, max(1, len(rows) // 16384))
        return float(sum(mse(params, jnp.asarray(c)) * len(c) for c in chunks) / len(rows))

    rng = np.random.default_rng(seed)
    train_j, curve = jnp.asarray(train_rows), []
    for i in range(1, steps + 1):
        params, opt = step(params, opt, train_j[rng.integers(0, len(train_rows), batch)])
        if eval_every and i % eval_every == 0 and i < steps:
            curve.append([i, mean_mse(test_rows)])
    return {"k": k, "steps": steps, "test_mse": mean_mse(test_rows), "test_curve": curve,
            "train_mse": mean_mse(train_rows[rng.choice(len(train_rows), len(test_rows), replace=False)])}


def memory_probe(run_dir: pathlib.Path, cfg, print_fn=print) -> dict:
    """fit_history for each k of `cfg.distill.memory_probe` on the run's buffer.npz, with the
    student's network widths and learning rate: the newest `holdout` of rows held out, the rest
    for fitting, the same rows for every k (those with the longest history)."""
    mp, n_envs = cfg.distill.memory_probe, int(cfg.distill.num_envs)
    ks, holdout = tuple(int(k) for k in mp.ks), float(mp.holdout)
    fit_kw = dict(hidden=tuple(cfg.network.policy_hidden), steps=int(mp.steps),
                  batch=int(mp.batch), lr=float(cfg.distill.learning_rate),
                  eval_every=int(mp.eval_every))
    path = pathlib.Path(run_dir) / BUFFER_FILE
    if not path.exists():
        raise FileNotFoundError(f"no {BUFFER_FILE} in {run_dir}: run `distill` for a chunk first")
    with np.load(path) as f:
        x, y, step = f["x"], f["y"], int(f["step"])
    first = (max(ks) - 1) * n_envs
    n = len(x)
    if n - first < 10 * n_envs:
        raise ValueError(f"{path} holds {n:,} rows, too few for a history of {max(ks)}")
    cut = n - int(round(holdout * (n - first)))
    train_rows, test_rows = np.arange(first, cut), np.arange(cut, n)
    print_fn(f"[memory probe] {path} (step {step:,}): {len(train_rows):,} rows to fit, "
             f"{len(test_rows):,} held out (the newest)")
    results = []
    for k in ks:
        t0 = time.perf_counter()
        r = fit_history(x, y, k, n_envs, train_rows, test_rows, **fit_kw)
        r["wall_s"] = time.perf_counter() - t0
        print_fn(f"[memory probe] k={k}: held-out mse {r['test_mse']:.5f}, train mse "
                 f"{r['train_mse']:.5f} ({r['wall_s']:.0f} s); held-out on the way: "
                 + ", ".join(f"{s:,}: {v:.5f}" for s, v in r["test_curve"]))
        results.append(r)
    return {"buffer": str(path), "buffer_step": step, "n_envs": n_envs, "rows_fit": len(train_rows),
            "rows_held_out": len(test_rows), "fit": fit_kw,
            "results": results}


def write(result: dict, out: pathlib.Path) -> pathlib.Path:
    out.mkdir(parents=True, exist_ok=True)
    path = out / "memory_probe.json"
    path.write_text(json.dumps(result, indent=2, default=str))
    return path

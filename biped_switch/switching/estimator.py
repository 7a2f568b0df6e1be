"""Switch estimators (paper Sec. III-C): when is the robot in the target policy's region of attraction?

    python -m biped_switch.estimator --init stand [--targets jumps gaps stairs] [--epochs N]

One estimator E_i per target policy i (jumps, gaps, stairs), trained on the switch-point sweep's
data of that target (`<data>/<init>/<target>.npz`, written by `python -m biped_switch.sweep`): the
robot state and heightmap around a switch to pi_i, labelled 1 if the switch led to a successful
traversal. E_i is a small MLP with a single sigmoid output, trained with the paper's loss
(E(s) - y)^2, Adam, 1,500 epochs by default, on a 90/10 train/validation split with labels forced
to 50/50 in both. The switcher calls `predict(params, obs)` on the env observation and switches
once the output passes a threshold (0.85 in the paper).

Params are a dict {"net": flax variables, "mean": (2451,), "std": (2451,)}: the input normalisation
statistics (of the training split) travel with the weights, and `predict` reads the input size and
the layer sizes off their shapes, so a checkpoint alone is enough at run time. The input is the
observation's `estimator` columns (`ObsLayout`: robot state, then heightmap). The three estimators of one init
mode have equal sizes; `load_estimator_set` stacks them along a leading axis for `jax.vmap`:

    params, metas = load_estimator_set("stand")             # leaves (3, ...)
    probs = jax.vmap(predict, in_axes=(0, None))(params, obs)  # (3, ...) for targets in order

Differences from the paper (documented choices):
- The split is by switch sample: the 5 near-identical data points of one switch (t-2..t+2) always
  land on the same side, so validation never sees a near-copy of a training point. The paper only
  says "90% / 10%"; a point-wise split would let validation accuracy flatter the estimator.
- Inputs are standardised per column with the training split's mean and std (floored at the
  config's `std_floor`), stored with the params. The paper does not say how inputs were scaled.
- The 50/50 balance subsamples the majority label (at the point level) in each split.
"""

from __future__ import annotations

import functools
import json
import math
import pathlib
import time
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import linen
from flax.training import orbax_utils

from biped_switch.learning import checkpoints as ckpt_lib
from biped_switch.learning import runs as runs_lib
from biped_switch.config import default_env_config, default_estimator_config
from biped_switch.learning.networks import encode, layer_sizes, swish_mlp
from biped_switch.learning.normalizer import column_stats, standardize
from biped_switch.lineups import PAPER_LINEUP, Lineup
from biped_switch.names import ARTIFACT_KINDS
from biped_switch.simulation.observation import STATE_SIZE, layout

TARGETS = ARTIFACT_KINDS  # one estimator per artifact kind: jumps, gaps, stairs


def __getattr__(name):
    """HM_SIZE and IN_SIZE: the heightmap and input widths of the default env config, for callers
    that assume it (the estimator command's meta, the benchmark); resolved when asked for. The
    estimator itself reads its sizes from its data and params."""
    if name in ("HM_SIZE", "IN_SIZE"):
        lay = layout(default_env_config())
        return lay.hm_size if name == "HM_SIZE" else lay.estimator.stop
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class EstimatorNet(linen.Module):
    """Heightmap -> MLP `hm_hidden` (swish), joined with the state -> MLP `hidden` (swish) -> Dense(1)
    -> sigmoid (`networks.encode`, `networks.swish_mlp`). Input: (..., state_size + hm_size)
    normalised columns; output: (...,) probabilities. Layers are named hm_<i>, mlp_<i> and out, so
    the sizes can be read back from the params."""

    hm_hidden: Sequence[int] = (64,)
    hidden: Sequence[int] = (128, 64)
    state_size: int = STATE_SIZE

    @linen.compact
    def __call__(self, x):
        z = encode(x, self.state_size, x.shape[-1] - self.state_size, self.hm_hidden, prefix="hm")
        z = swish_mlp(z, self.hidden, prefix="mlp")
        return jax.nn.sigmoid(linen.Dense(1, name="out")(z)[..., 0])


def module_from_params(net_variables) -> EstimatorNet:
    """The EstimatorNet whose layer sizes match `net_variables` (shapes are static under jit/vmap)."""
    return EstimatorNet(hm_hidden=layer_sizes(net_variables, "hm"),
                        hidden=layer_sizes(net_variables, "mlp"))


def init_params(cfg, key: jax.Array, mean=None, std=None, in_size: int | None = None) -> dict:
    """Fresh params {"net", "mean", "std"} for sizes cfg.hm_hidden / cfg.hidden on `in_size` input
    columns (default: those of `mean`; mean 0, std 1 unless given)."""
    in_size = len(mean) if in_size is None else int(in_size)
    net = EstimatorNet(hm_hidden=tuple(cfg.hm_hidden), hidden=tuple(cfg.hidden))
    mean = np.zeros(in_size, np.float32) if mean is None else mean
    std = np.ones(in_size, np.float32) if std is None else std
    return {"net": net.init(key, jnp.zeros((1, in_size))), "mean": jnp.asarray(mean, jnp.float32),
            "std": jnp.asarray(std, jnp.float32)}


def predict(params: dict, obs: jax.Array) -> jax.Array:
    """Estimated probability (...,) that switching now succeeds. Pure and jittable.

    `obs` (..., >= 2451): robot state (51) then heightmap (2400), the observation's `estimator`
    columns; further columns (the phase clock, the detector one-hot) are ignored. Sizes come from
    the param shapes, so the params of several estimators stacked along a leading axis go through
    `jax.vmap(predict, in_axes=(0, None))`."""
    in_size = params["mean"].shape[-1]
    x = standardize(jnp.asarray(obs)[..., :in_size].astype(jnp.float32), params["mean"],
                    params["std"])
    return module_from_params(params["net"]).apply(params["net"], x)


def stack_params(params_list: Sequence[dict]) -> dict:
    """Params of estimators of equal sizes, stacked along a new leading axis (for jax.vmap)."""
    shapes = [jax.tree.map(np.shape, p) for p in params_list]
    if any(s != shapes[0] for s in shapes[1:]):
        raise ValueError(f"estimators differ in structure or sizes, cannot stack: {shapes}")
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *params_list)


# ---------------------------------------------------------------------------------------- data


def balanced_split(labels, groups, val_frac: float, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(train_idx, val_idx): a split by group, then labels balanced to exactly 50/50 in each split.

    All points of one group (a switch sample's 5 points) go to the same side. About `val_frac` of the
    groups of each label go to validation (stratified by each group's first label; at least one group
    of each label on each side). Then in each split the majority label is subsampled at random to the
    minority's count. Stricter than the paper, which splits points, not samples. Indices are sorted.
    Raises ValueError when a split would hold no point of one label."""
    labels, groups = np.asarray(labels).reshape(-1), np.asarray(groups).reshape(-1)
    if labels.shape != groups.shape:
        raise ValueError(f"labels {labels.shape} and groups {groups.shape} differ in length")
    if not 0.0 < val_frac < 1.0:
        raise ValueError(f"val_frac must be in (0, 1), got {val_frac}")
    if not np.isin(labels, (0, 1)).all():
        raise ValueError(f"labels must be 0 or 1, got values {np.unique(labels)[:10]}")
    uniq, first = np.unique(groups, return_index=True)
    group_label = labels[first]
    val_groups = []
    for lab in (0, 1):
        g = uniq[group_label == lab]
        if len(g) < 2:
            raise ValueError(f"only {len(g)} sample group(s) with label {lab} "
                             f"({int((labels == lab).sum())} point(s)): need at least 2, so that both "
                             f"the training and the validation split hold a point of each label")
        n_val = int(np.clip(round(val_frac * len(g)), 1, len(g) - 1))
        val_groups.append(rng.choice(g, n_val, replace=False))
    in_val = np.isin(groups, np.concatenate(val_groups))

    def balance(idx, name):
        pos, neg = idx[labels[idx] == 1], idx[labels[idx] == 0]
        k = min(len(pos), len(neg))
        if k == 0:
            raise ValueError(f"the {name} split would have no point with label {int(len(pos) == 0)}")
        return np.sort(np.concatenate([rng.choice(pos, k, replace=False),
                                       rng.choice(neg, k, replace=False)]))

    return balance(np.flatnonzero(~in_val), "training"), balance(np.flatnonzero(in_val), "validation")


def roc_auc(scores, labels) -> float:
    """Area under the ROC curve = P(score of a random positive > score of a random negative), ties
    counted half (the Mann-Whitney U statistic from mid-ranks). ValueError if a label is missing."""
    scores = np.asarray(scores, np.float64).reshape(-1)
    labels = np.asarray(labels).reshape(-1).astype(bool)
    n_pos, n_neg = int(labels.sum()), int((~labels).sum())
    if n_pos == 0 or n_neg == 0:
        raise ValueError(f"ROC AUC needs both labels, got {n_pos} positive and {n_neg} negative")
    _, inverse, counts = np.unique(scores, return_inverse=True, return_counts=True)
    starts = np.cumsum(counts) - counts  # 0-based rank of each distinct value's first copy
    midrank = starts + (counts + 1) / 2.0  # 1-based mean rank of the ties
    rank_sum_pos = midrank[inverse][labels].sum()
    return float((rank_sum_pos - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


def load_data(path) -> dict:
    """The arrays of one sweep npz, plus "meta" decoded from JSON (a dict)."""
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    if "meta" in data:
        data["meta"] = json.loads(str(data["meta"]))
    return data


# ------------------------------------------------------------------------------------ training


def _loss(net: EstimatorNet, variables, mean, std, state, hm, y):
    x = standardize(jnp.concatenate([state.astype(jnp.float32), hm.astype(jnp.float32)], -1), mean,
                    std)
    p = net.apply(variables, x)
    return jnp.mean((p - y) ** 2), p


def train_estimator(data: dict, cfg=None, rng_seed: int | None = None, print_fn=print,
                    log_every: int = 50, name: str = "estimator") -> tuple[dict, dict]:
    """Trains one estimator on a sweep's data; returns (params, metrics).

    `data`: the npz arrays (state, heightmap, label, sample; others ignored). `cfg`: an estimator
    config (default_estimator_config()); `rng_seed` (default cfg.seed) drives the split, the init and
    the shuffling. Each epoch is one jitted `lax.scan` over shuffled minibatches (the last partial
    batch of a shuffle is dropped), followed by a validation pass; data stays on the device
    (the heightmap in its stored dtype, float16 from the sweep). Progress goes to `print_fn` every
    `log_every` epochs. metrics: split sizes, final train/val loss, val accuracy (threshold 0.5), val
    ROC AUC, best_val_acc(_epoch), train_s, points_per_s, epochs and `history` (per-epoch train and
    val loss, val accuracy, wall seconds). The params returned are those after the last epoch.

    One function: the jitted epoch closes over the split's shapes, read as split, epochs, metrics."""
    cfg = default_estimator_config() if cfg is None else cfg
    seed = int(cfg.seed if rng_seed is None else rng_seed)
    state = np.asarray(data["state"], np.float32)
    hm = np.asarray(data["heightmap"])
    if state.ndim != 2 or hm.ndim != 2 or state.shape[-1] != STATE_SIZE or len(state) != len(hm):
        raise ValueError(f"expected state (N, {STATE_SIZE}) and heightmap (N, rows * cols), got "
                         f"{state.shape} and {hm.shape}")
    in_size = STATE_SIZE + hm.shape[-1]
    if not np.issubdtype(hm.dtype, np.floating):
        hm = hm.astype(np.float32)
    labels = np.asarray(data["label"]).astype(np.int32)
    groups = np.asarray(data["sample"]) if "sample" in data else np.arange(len(labels))
    tr, va = balanced_split(labels, groups, float(cfg.val_frac), np.random.default_rng(seed))

    # Normalisation statistics of the training split (float64 accumulation).
    mean, std = column_stats(np.concatenate([state[tr], hm[tr].astype(np.float32)], -1),
                             float(cfg.std_floor))

    n_tr, n_va = len(tr), len(va)
    bs = int(min(cfg.batch_size, n_tr))
    n_batches = n_tr // bs
    n_chunks = -(-n_va // min(int(cfg.eval_chunk), n_va))
    chunk = -(-n_va // n_chunks)
    pad = n_chunks * chunk - n_va
    va_pad = np.concatenate([va, np.full(pad, va[0])])
    dev = lambda a: jax.device_put(np.ascontiguousarray(a))  # noqa: E731
    tr_data = (dev(state[tr]), dev(hm[tr]), dev(labels[tr].astype(np.float32)))
    va_data = (dev(state[va_pad].reshape(n_chunks, chunk, -1)),
               dev(hm[va_pad].reshape(n_chunks, chunk, -1)),
               dev(labels[va_pad].astype(np.float32).reshape(n_chunks, chunk)),
               dev((np.arange(n_chunks * chunk) < n_va).astype(np.float32).reshape(n_chunks, chunk)))

    net = EstimatorNet(hm_hidden=tuple(cfg.hm_hidden), hidden=tuple(cfg.hidden))
    key, init_key = jax.random.split(jax.random.PRNGKey(seed))
    variables = net.init(init_key, jnp.zeros((1, in_size)))
    opt = optax.adam(float(cfg.learning_rate))
    opt_state = opt.init(variables)
    mean_d, std_d = jnp.asarray(mean), jnp.asarray(std)
    loss_fn = functools.partial(_loss, net)

    def val_pass(variables, va_data):
        def one(c):
            s, h, y, m = c
            _, p = loss_fn(variables, mean_d, std_d, s, h, y)
            return p, jnp.sum(m * (p - y) ** 2), jnp.sum(m * ((p >= 0.5) == (y > 0.5)))
        probs, sq, hits = jax.lax.map(one, va_data)
        return probs.reshape(-1), sq.sum() / n_va, hits.sum() / n_va

    @jax.jit
    def run_epoch(variables, opt_state, key, tr_data, va_data):
        s_all, h_all, y_all = tr_data
        perm = jax.random.permutation(key, n_tr)[: n_batches * bs].reshape(n_batches, bs)

        def step(carry, idx):
            v, o = carry
            (loss, _), g = jax.value_and_grad(loss_fn, has_aux=True)(
                v, mean_d, std_d, s_all[idx], h_all[idx], y_all[idx])
            upd, o = opt.update(g, o, v)
            return (optax.apply_updates(v, upd), o), loss

        (variables, opt_state), losses = jax.lax.scan(step, (variables, opt_state), perm)
        _, val_loss, val_acc = val_pass(variables, va_data)
        return variables, opt_state, losses.mean(), val_loss, val_acc

    epochs = int(cfg.epochs)
    hist = {"train_loss": [], "val_loss": [], "val_acc": [], "epoch_s": []}
    print_fn(f"[{name}] {n_tr:,} training / {n_va:,} validation points (50/50 labels), "
             f"{n_batches} batches of {bs} per epoch, {epochs} epochs, seed {seed}")
    t0 = t_log = time.perf_counter()
    e_log = 0
    for epoch in range(1, epochs + 1):
        key, k = jax.random.split(key)
        t_e = time.perf_counter()
        variables, opt_state, tl, vl, vacc = run_epoch(variables, opt_state, k, tr_data, va_data)
        tl, vl, vacc = float(tl), float(vl), float(vacc)  # blocks: the epoch's time is all in
        for k_, v_ in zip(hist, (tl, vl, vacc, time.perf_counter() - t_e)):  # epoch 1 compiles
            hist[k_].append(v_)
        if not all(map(math.isfinite, (tl, vl))):
            raise FloatingPointError(f"[{name}] non-finite loss at epoch {epoch}: train {tl}, val {vl}")
        if epoch % max(log_every, 1) == 0 or epoch in (1, epochs):
            now = time.perf_counter()
            pps = (epoch - e_log) * n_batches * bs / max(now - t_log, 1e-9)
            left_s = (epochs - epoch) * (now - t_log) / (epoch - e_log)
            print_fn(f"[{name}] epoch {epoch}/{epochs}  train loss {tl:.4f}  val loss {vl:.4f}  "
                     f"val acc {vacc:.3f}  {pps:,.0f} points/s  left ~{left_s / 60:.1f} min")
            t_log, e_log = now, epoch
    train_s = time.perf_counter() - t0

    params = jax.device_get({"net": variables, "mean": mean, "std": std})
    val_probs = np.asarray(jax.jit(val_pass)(variables, va_data)[0])[:n_va]
    y_va = labels[va]
    metrics = {
        "train_points": n_tr, "val_points": n_va,
        "train_samples": int(len(np.unique(groups[tr]))), "val_samples": int(len(np.unique(groups[va]))),
        "points_total": int(len(labels)), "positive_frac_total": float(labels.mean()),
        "epochs": epochs, "batch_size": bs, "seed": seed,
        "train_loss": hist["train_loss"][-1], "val_loss": hist["val_loss"][-1],
        "val_acc": float(((val_probs >= 0.5) == (y_va == 1)).mean()),
        "val_auc": roc_auc(val_probs, y_va),
        "best_val_acc": float(max(hist["val_acc"])),  # for spotting overfitting; params are the last
        "best_val_acc_epoch": int(np.argmax(hist["val_acc"])) + 1,
        "train_s": train_s, "points_per_s": epochs * n_batches * bs / max(train_s, 1e-9),
        "device": str(jax.devices()[0]),
        "history": hist,
    }
    return params, metrics


# ------------------------------------------------------------------------------- checkpoints


def jsonable(x):
    """json.dumps' `default` for the numpy values and tuples in a model's meta and metrics."""
    if isinstance(x, (np.generic,)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, tuple):
        return list(x)
    raise TypeError(f"not JSON serialisable: {type(x)}")


def save_estimator(path, params: dict, meta: dict) -> pathlib.Path:
    """Orbax checkpoint of `params` (as numpy arrays) at `path`, with `meta` as meta.json inside."""
    path = pathlib.Path(path).resolve()
    params = jax.tree.map(np.asarray, jax.device_get(params))
    path.parent.mkdir(parents=True, exist_ok=True)
    ckpt_lib.write_tree(path, params, save_args=orbax_utils.save_args_from_target(params))
    (path / "meta.json").write_text(json.dumps(meta, indent=2, default=jsonable))
    return path


def load_estimator(path) -> tuple[dict, dict]:
    """(params as numpy arrays, meta dict) of a checkpoint written by `save_estimator`."""
    path = pathlib.Path(path).resolve()
    if not (path / "meta.json").exists():
        raise FileNotFoundError(f"no estimator at {path} (expected an Orbax checkpoint with meta.json); "
                                f"train it with `python -m biped_switch.estimator`")
    params = ckpt_lib.read_tree(path)
    return jax.tree.map(np.asarray, params), runs_lib.read_json(path / "meta.json")


def sweep_name(init: str, context: bool = False, lead_in: bool = False, *,
               lineup: Lineup = PAPER_LINEUP) -> str:
    """The folder and file stem of a sweep's data, and of the estimators and lookup made from it:
    `<init>`, `<init>_context` for a context sweep (`sweep --context`), `<init>_leadin` for a
    lead-in sweep (`sweep --lead-in`); a line-up other than the paper's appends `_<its name>`, so
    its data and tables (other policies and targets) never mix with the paper's."""
    name = f"{init}_leadin" if lead_in else f"{init}_context" if context else init
    return name if lineup == PAPER_LINEUP else f"{name}_{lineup.name}"


def load_estimator_set(init: str, model_dir="models/estimators", targets: Sequence[str] = TARGETS
                       ) -> tuple[dict, list[dict]]:
    """(params stacked along a leading axis of len(targets), metas) of `<model_dir>/<init>_<target>`."""
    paths = []
    for t in targets:
        path = pathlib.Path(model_dir) / f"{init}_{t}"
        if not path.exists():
            raise FileNotFoundError(f"no estimator at {path}; train it with "
                                    f"`python -m biped_switch.estimator --init {init} --targets {t} "
                                    f"--out {model_dir}`")
        paths.append(path)
    return load_estimator_paths(paths)


def load_estimator_paths(paths) -> tuple[dict, list[dict]]:
    """(params stacked along a leading axis, metas) of the estimators at `paths`, in order."""
    loaded = [load_estimator(p) for p in paths]
    return stack_params([p for p, _ in loaded]), [m for _, m in loaded]


def context_estimator_paths(init: str, model_dir="models/estimators",
                            targets: Sequence[str] = TARGETS) -> list[pathlib.Path] | None:
    """Per target, `<init>_context_<t>` (trained on a context sweep) where it exists, else the
    plain `<init>_<t>`: a context sweep may cover only the targets whose switches fail in context.
    None when no context estimator exists, or a target has neither."""
    d = pathlib.Path(model_dir)
    ctx = [d / f"{sweep_name(init, True)}_{t}" for t in targets]
    if not any(p.exists() for p in ctx):
        return None
    paths = [c if c.exists() else d / f"{init}_{t}" for c, t in zip(ctx, targets)]
    return paths if all(p.exists() for p in paths) else None


# -------------------------------------------------------------------------------------- CLI

"""Learning *when* to switch (ours): the `learned` rule of Table II.

    python -m biped_switch.when --init stand [--data runs/sweeps_when] [--out models/switch_when]

The paper's estimator asks "would switching now succeed?" and the rule takes the first step with
E(s) >= 0.85; on our policies that fires on one-step spikes far from the artifact. This model
asks "would switching at the distance d' succeed, given the state now at distance d >= d'?":

    G(x_t, d_t, d') = P(success | switch at d'),  x_t = [target, active policy (one-hots),
                      d_t, phase clock, robot state, forward height profile]

trained on the context sweep's records (`sweep --context --switch-min 0.2`): at the switch
(d' = d_t, "now" rows) and at earlier points of the same approach (`approach_*`, d' < d_t,
"wait" rows), each labelled with the switch's outcome. The rule switches when now is the best
remaining moment:

    score_t = G(x_t, d_t, d_t) - max_{d' on the grid, d' <= d_t - min_gap_m} G(x_t, d_t, d')
    switch once score_t >= margin (no later grid point left: switch)

With a state that carries no information G is the (active, target) success-against-distance
curve, and the rule switches at its maximum: the lookup table. It can only gain where the state
tells a good moment from a bad one (the gait phase, the landing after the last artifact).

Calibration: one model for all targets, trained on the natural label mix with binary cross-
entropy, AdamW weight decay and early stopping on validation *tracks* (held out by track id, so no
near-copy of a training approach is scored); `ensemble` members (seeds) average their logits,
and one temperature, fitted on the validation tracks, scales them. Params: {"net": member
variables stacked (E, ...), "mean", "std" (input columns), "temp"}; the checkpoint codec is the
estimators' (`estimator.save_estimator`).
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import linen

from biped_switch.config import default_detector_config, default_when_config
from biped_switch.learning.networks import layer_sizes, swish_mlp
from biped_switch.learning.normalizer import column_stats, standardize
from biped_switch.names import ARTIFACT_KINDS, POLICY_NAMES
from biped_switch.simulation.observation import STATE_SIZE
from biped_switch.stats import bin_counts
from biped_switch.switching.detector import profile

N_TARGETS, N_SOURCES = len(ARTIFACT_KINDS), len(POLICY_NAMES)
# input columns, in order: the named parts of x (widths; the profile's is the heightmap's rows)
PARTS = ("target", "active", "dist_m", "phase", "state", "profile")


def part_widths(grid: tuple[int, int]) -> dict:
    return {"target": N_TARGETS, "active": N_SOURCES, "dist_m": 1, "phase": 2,
            "state": STATE_SIZE, "profile": int(grid[0])}


def features(target, active, dist_m, phase, state, hm_flat, grid) -> jax.Array:
    """x (..., F): the model's input, `PARTS` in order. `target` (...) artifact code, `active`
    (...) policy index (clamped to the four behaviour policies), `dist_m` (...) [m] to the
    artifact's start, `phase` (..., 2), `state` (..., 51), `hm_flat` (..., rows*cols) the
    heightmap, read as its forward profile (`detector.profile`: the middle columns' median, rows
    behind to ahead, relative to the ground under the feet)."""
    t = jax.nn.one_hot(jnp.asarray(target, jnp.int32), N_TARGETS)
    a = jax.nn.one_hot(jnp.clip(jnp.asarray(active, jnp.int32), 0, N_SOURCES - 1), N_SOURCES)
    prof = profile(jnp.asarray(hm_flat, jnp.float32), grid, default_detector_config())
    return jnp.concatenate([t, a, jnp.asarray(dist_m, jnp.float32)[..., None],
                            jnp.asarray(phase, jnp.float32), jnp.asarray(state, jnp.float32),
                            prof], axis=-1)


class WhenNet(linen.Module):
    """Trunk on the (normalised) input x, then a head per later distance: logit of
    G(x, d_now, d_later). `d_later` (..., G) gives (..., G) logits."""

    trunk_hidden: Sequence[int] = (128, 64)
    head_hidden: Sequence[int] = (64,)

    @linen.compact
    def __call__(self, x, d_now, d_later):
        z = swish_mlp(x, self.trunk_hidden, prefix="trunk")
        d_now = jnp.broadcast_to(jnp.asarray(d_now)[..., None], d_later.shape)
        z = jnp.broadcast_to(z[..., None, :], d_later.shape + z.shape[-1:])
        h = jnp.concatenate([z, d_later[..., None], (d_now - d_later)[..., None]], -1)
        h = swish_mlp(h, self.head_hidden, prefix="head")
        # zero at the start: the model begins as the prior table and learns what the state adds
        return linen.Dense(1, name="out", kernel_init=linen.initializers.zeros)(h)[..., 0]


def module_from_params(net_variables) -> WhenNet:
    """The WhenNet whose sizes match one member's variables."""
    return WhenNet(layer_sizes(net_variables, "trunk"), layer_sizes(net_variables, "head"))


def _member_logits(net_vars, x, d_now, d_later):
    return module_from_params(net_vars).apply(net_vars, x, d_now, d_later)


def prior_logit(params: dict, x, d_later) -> jax.Array:
    """(..., G) the prior table's logit for (target, active policy) of the raw inputs x (...,
    F) at each later distance (..., G) [m], linear between the bins' centres."""
    target = jnp.argmax(x[..., :N_TARGETS], -1)
    active = jnp.argmax(x[..., N_TARGETS:N_TARGETS + N_SOURCES], -1)
    table = jnp.asarray(params["prior"])[target, active]  # (..., bins)
    u = (d_later - params["prior_lo_m"]) / params["prior_bin_m"] - 0.5
    nb = table.shape[-1]
    i0 = jnp.clip(jnp.floor(u), 0, nb - 2).astype(jnp.int32)
    w = jnp.clip(u - i0, 0.0, 1.0)
    lo = jnp.take_along_axis(table, i0, -1)
    hi = jnp.take_along_axis(table, i0 + 1, -1)
    return (1 - w) * lo + w * hi


def logits(params: dict, x, d_now, d_later) -> jax.Array:
    """(..., G) the prior table's logit plus the ensemble's mean correction, before the
    temperature."""
    z = standardize(x, params["mean"], params["std"])
    first = jax.tree.leaves(params["net"])[0]
    members = [jax.tree.map(lambda a, i=i: a[i], params["net"]) for i in range(first.shape[0])]
    net = jnp.mean(jnp.stack([_member_logits(m, z, d_now, d_later) for m in members]), 0)
    return prior_logit(params, x, d_later) + net


def prob(params: dict, x, d_now, d_later) -> jax.Array:
    """G (..., G): the ensemble's calibrated success probability of switching at each `d_later`
    (..., G) [m], from raw inputs x (..., F) at distance `d_now` (...). Pure and jittable."""
    return jax.nn.sigmoid(logits(params, x, d_now, d_later) / params["temp"])


def grid_m(cfg=None) -> np.ndarray:
    """The later distances [m] the rule weighs (host constant)."""
    cfg = cfg or default_when_config()
    start, stop, step = cfg.grid_m
    return np.round(np.arange(start, stop + 1e-9, step), 6).astype(np.float32)


def advantage(p_now, p_grid, grid, d_now, min_gap_m, allowed=True) -> jax.Array:
    """P(now) (...) minus the best P (..., G) at a `grid` distance (G,) [m] at least `min_gap_m`
    nearer than `d_now` (...) and `allowed` (..., G); 1 where no such distance is left (now is
    the last chance)."""
    later = (jnp.asarray(grid) <= jnp.asarray(d_now)[..., None] - min_gap_m) & allowed
    best_later = jnp.max(jnp.where(later, p_grid, -jnp.inf), -1)
    return jnp.where(jnp.any(later, -1), p_now - best_later, 1.0)


def score(params: dict, x, d_now, grid, min_gap_m, later_from: str = "model",
          band_tol: float = 1.0) -> tuple[jax.Array, jax.Array]:
    """(score, P(now)) for inputs x (..., F) at `d_now` (...) [m]: `advantage` of switching now.
    The later moments' P come from the model given the state now (`later_from` "model"), or
    from the prior table alone ("table": the average over the states that follow). With
    `band_tol` < 1 the rule acts only inside the band where the prior table is within `band_tol`
    of its best on the grid, weighing only later moments inside it: before the band the score is
    -1, at its last moment (or past it) 1. The state picks the moment inside the band that the
    pair's statistics allow."""
    d_now = jnp.asarray(d_now, jnp.float32)
    grid = jnp.asarray(grid, jnp.float32)
    later = jnp.broadcast_to(grid, d_now.shape + grid.shape)
    if later_from == "table":
        p_now = prob(params, x, d_now, d_now[..., None])[..., 0]
        p_later = jax.nn.sigmoid(prior_logit(params, x, later))
    elif later_from == "model":
        g = prob(params, x, d_now, jnp.concatenate([d_now[..., None], later], -1))
        p_now, p_later = g[..., 0], g[..., 1:]
    else:
        raise ValueError(f"later_from must be 'model' or 'table', got {later_from!r}")
    if band_tol >= 1.0:
        return advantage(p_now, p_later, grid, d_now, min_gap_m), p_now
    # the band: distances where the pair's table is within band_tol of its best on the grid
    table = jax.nn.sigmoid(prior_logit(params, x, later))
    floor = jnp.max(table, -1) - band_tol
    in_band = table >= floor[..., None]
    now_in = jax.nn.sigmoid(prior_logit(params, x, d_now[..., None])[..., 0]) >= floor
    adv = advantage(p_now, p_later, grid, d_now, min_gap_m, in_band)
    left = jnp.any((grid <= d_now[..., None] - min_gap_m) & in_band, -1)
    # before the band: wait; in it: the best remaining moment in it; past it: now
    return jnp.where(now_in | ~left, adv, -1.0), p_now


class RuleFn(NamedTuple):
    """The learned rule as the switching rollout calls it: `fn(params, obs, active, kind,
    dist_m)` -> (B,) scores (`switching.rules`: switch once score >= the rules' threshold)."""

    fn: object
    reads_context = True  # called after detection, with the active policy and the distance

    def __call__(self, params, obs, active, kind, dist_m):
        return self.fn(params, obs, active, kind, dist_m)


def rule_fn(env, cfg=None) -> RuleFn:
    """The jittable rule for observations of `env` (its named layout, resolved once here)."""
    cfg = cfg or default_when_config()
    lay = env.obs_layout
    grid, gap, later_from = grid_m(cfg), float(cfg.min_gap_m), str(cfg.later_from)
    band_tol = float(cfg.band_tol)

    def fn(params, obs, active, kind, dist_m):
        d = jnp.clip(jnp.nan_to_num(dist_m, posinf=9.0), 0.0, 9.0)
        x = features(jnp.maximum(kind, 0), active, d, obs[..., lay.phase], obs[..., lay.state],
                     obs[..., lay.heightmap], lay.grid)
        return score(params, x, d, grid, gap, later_from, band_tol)[0]

    return RuleFn(fn)


# ----------------------------------------------------------------------- data
class Rows(NamedTuple):
    """Training rows: x (N, F) raw inputs, d_now (N,), d_later (N,) [m], label (N,), track (N,),
    now (N,) bool: a switch-step row (d_later = d_now), else an earlier point of the approach."""

    x: np.ndarray
    d_now: np.ndarray
    d_later: np.ndarray
    label: np.ndarray
    track: np.ndarray
    now: np.ndarray
    source: np.ndarray
    target: np.ndarray


def rows_from_sweep(data: dict, target: str, grid: tuple[int, int]) -> Rows:
    """The rows of one target's context sweep (`sweep --context`, with approach records)."""
    missing = [k for k in ("phase", "approach_state") if k not in data]
    if missing:
        raise ValueError(f"the {target} sweep has no {missing}: make it with this version's "
                         f"`python -m biped_switch.sweep --context --switch-min 0.2`")
    code = ARTIFACT_KINDS.index(target)
    at0 = data["offset"] == 0  # one row per switch sample, in the approach records' order
    sample = {k: data[k][at0] for k in ("source", "switch_dist_m", "label", "track_id")}
    n_now = int(at0.sum())
    feats = jax.jit(features, static_argnums=6)
    x_now = np.asarray(feats(np.full(n_now, code), data["source"][at0], data["switch_dist_m"][at0],
                             data["phase"][at0], data["state"][at0], data["heightmap"][at0], grid))
    parts = [(x_now, data["switch_dist_m"][at0], sample["switch_dist_m"], sample["label"],
              sample["track_id"], np.ones(n_now, bool), sample["source"])]

    def waits(prefix, source, track, switch_m, label):
        """Wait rows: each reached approach record, labelled with its episode's outcome."""
        s_idx, q_idx = np.nonzero(data[f"{prefix}approach_valid"])
        x = np.asarray(feats(np.full(len(s_idx), code), source[s_idx],
                             data[f"{prefix}approach_dist_m"][s_idx, q_idx],
                             data[f"{prefix}approach_phase"][s_idx, q_idx],
                             data[f"{prefix}approach_state"][s_idx, q_idx],
                             data[f"{prefix}approach_heightmap"][s_idx, q_idx], grid))
        return (x, data[f"{prefix}approach_dist_m"][s_idx, q_idx], switch_m[s_idx],
                label[s_idx], track[s_idx], np.zeros(len(s_idx), bool), source[s_idx])

    parts.append(waits("", sample["source"], sample["track_id"], sample["switch_dist_m"],
                       sample["label"]))
    if "lost_source" in data:  # fell while waiting, before the switch distance: a failed wait
        parts.append(waits("lost_", data["lost_source"], data["lost_track_id"],
                           data["lost_switch_at_m"], np.zeros(len(data["lost_source"]))))
    x, d_now, d_later, label, track, now, source = (np.concatenate(c) for c in zip(*parts))
    return Rows(x.astype(np.float32), d_now.astype(np.float32), d_later.astype(np.float32),
                label.astype(np.float32), track, now, source.astype(np.int32),
                np.full(len(label), code, np.int32))


def concat_rows(rows: Sequence[Rows]) -> Rows:
    return Rows(*[np.concatenate([getattr(r, f) for r in rows]) for f in Rows._fields])


def take(rows: Rows, idx) -> Rows:
    return Rows(*[getattr(rows, f)[idx] for f in Rows._fields])


def is_val(track_ids, cfg=None) -> np.ndarray:
    """The validation split: whole tracks (`val_track_mod`), never a switch of a training track."""
    cfg = cfg or default_when_config()
    return np.asarray(track_ids) % int(cfg.val_track_mod) == 0


# ----------------------------------------------------------------------- training
def _pair(rows: Rows) -> np.ndarray:
    """Each row's (target, active policy) pair as one index (setup policies as the last)."""
    return rows.target * N_SOURCES + np.clip(rows.source, 0, N_SOURCES - 1)


def bce(logits, y):
    return jnp.mean(optax.sigmoid_binary_cross_entropy(logits, y))


def fit_prior(rows: Rows, cfg=None) -> dict:
    """The prior table: per (target, active policy, `prior_bin_m` bin of the switch distance)
    the success rate (k + 1) / (n + 2) of every row switching there (switch and approach rows:
    each is an outcome of switching at its d'), as logits. What a rule that knows only the pair
    and the distance knows; the network learns the state's correction to it."""
    cfg = cfg or default_when_config()
    bin_m = float(cfg.prior_bin_m)
    nb = int(round(float(cfg.grid_m[1]) / bin_m))
    k, n = bin_counts(rows.d_later, rows.label, _pair(rows), N_TARGETS * N_SOURCES, bin_m, nb)
    rate = ((k + 1) / (n + 2)).reshape(N_TARGETS, N_SOURCES, nb)
    return {"prior": np.log(rate / (1 - rate)).astype(np.float32),
            "prior_lo_m": np.asarray(0.0, np.float32), "prior_bin_m": np.asarray(bin_m, np.float32)}


def train_member(tr: Rows, va: Rows, mean, std, prior: dict, cfg, seed: int, print_fn=print,
                 name="when"):
    """One ensemble member: AdamW on BCE of (prior logit + network), early stopped on the
    validation tracks' loss. Returns (best variables, history)."""
    net = WhenNet(tuple(cfg.trunk_hidden), tuple(cfg.head_hidden))
    key = jax.random.PRNGKey(seed)
    key, k_init = jax.random.split(key)
    variables = net.init(k_init, jnp.zeros((1, tr.x.shape[1])), jnp.zeros(1), jnp.zeros((1, 1)))
    opt = optax.adamw(float(cfg.learning_rate), weight_decay=float(cfg.weight_decay))
    opt_state = opt.init(variables)
    norm = lambda x: standardize(jnp.asarray(x), mean, std)  # noqa: E731
    tr_x, va_x = norm(tr.x), norm(va.x)
    tr_dn, tr_dl, tr_y = (jnp.asarray(a) for a in (tr.d_now, tr.d_later, tr.label))
    va_dn, va_dl, va_y = (jnp.asarray(a) for a in (va.d_now, va.d_later, va.label))
    tr_p, va_p = (prior_logit(prior, jnp.asarray(r.x), jnp.asarray(r.d_later)[:, None])[:, 0]
                  for r in (tr, va))
    bs = int(cfg.batch_size)
    n_b = max(len(tr.label) // bs, 1)

    def loss_fn(v, x, dn, dl, y, offset):
        return bce(offset + net.apply(v, x, dn, dl[:, None])[:, 0], y)

    @jax.jit
    def epoch(variables, opt_state, k):
        perm = jax.random.permutation(k, len(tr.label))[: n_b * bs].reshape(n_b, bs)

        def step(c, idx):
            v, o = c
            l, g = jax.value_and_grad(loss_fn)(v, tr_x[idx], tr_dn[idx], tr_dl[idx], tr_y[idx],
                                               tr_p[idx])
            u, o = opt.update(g, o, v)
            return (optax.apply_updates(v, u), o), l

        (variables, opt_state), losses = jax.lax.scan(step, (variables, opt_state), perm)
        return variables, opt_state, losses.mean(), loss_fn(variables, va_x, va_dn, va_dl, va_y,
                                                            va_p)

    best, best_loss, best_epoch, hist = variables, math.inf, 0, {"train": [], "val": []}
    t0 = time.perf_counter()
    for e in range(1, int(cfg.epochs) + 1):
        key, k = jax.random.split(key)
        variables, opt_state, tl, vl = epoch(variables, opt_state, k)
        tl, vl = float(tl), float(vl)
        hist["train"].append(tl)
        hist["val"].append(vl)
        if not math.isfinite(tl):
            raise FloatingPointError(f"[{name}] non-finite training loss at epoch {e}")
        if vl < best_loss:
            best, best_loss, best_epoch = variables, vl, e
        if e % 25 == 0 or e == 1:
            print_fn(f"[{name} seed {seed}] epoch {e}  train BCE {tl:.4f}  val BCE {vl:.4f}  "
                     f"(best {best_loss:.4f} at {best_epoch}; {time.perf_counter() - t0:.0f} s)")
        if e - best_epoch >= int(cfg.patience):
            break
    return best, {"best_epoch": best_epoch, "best_val_bce": best_loss, "epochs_run": e,
                  "train_s": round(time.perf_counter() - t0, 1), **hist}


def fit_temperature(logits, y, temps=np.exp(np.linspace(np.log(0.5), np.log(3.0), 61))) -> float:
    """The temperature T (a grid search) minimising the validation BCE of sigmoid(logits / T)."""
    logits, y = np.asarray(logits, np.float64), np.asarray(y, np.float64)
    losses = [np.mean(np.logaddexp(0, -logits / t) * y + np.logaddexp(0, logits / t) * (1 - y))
              for t in temps]
    return float(temps[int(np.argmin(losses))])


def train(rows: Rows, cfg=None, print_fn=print) -> tuple[dict, dict]:
    """(params, metrics) of the ensemble on `rows` (split by `is_val`)."""
    cfg = cfg or default_when_config()
    val = is_val(rows.track, cfg)
    tr, va = take(rows, ~val), take(rows, val)
    if len(va.label) == 0 or len(tr.label) == 0:
        raise ValueError(f"the split by track leaves {len(tr.label)} training and {len(va.label)} "
                         f"validation rows: need both")
    mean, std = column_stats(tr.x, float(cfg.std_floor))
    prior = fit_prior(tr, cfg)
    print_fn(f"[when] {len(tr.label):,} training rows ({int(tr.now.sum()):,} at the switch), "
             f"{len(va.label):,} validation rows on {len(np.unique(va.track))} held-out tracks; "
             f"{100 * tr.label.mean():.1f}% positive")
    members, hists = [], []
    for m in range(int(cfg.ensemble)):
        v, h = train_member(tr, va, mean, std, prior, cfg, int(cfg.seed) + m, print_fn)
        members.append(jax.device_get(v))
        hists.append(h)
    net = jax.tree.map(lambda *xs: np.stack([np.asarray(a) for a in xs]), *members)
    params = {"net": net, "mean": np.asarray(mean), "std": np.asarray(std),
              "temp": np.asarray(1.0, np.float32), **prior}
    logits = raw_logits(params, va.x, va.d_now, va.d_later)
    params["temp"] = np.asarray(fit_temperature(logits, va.label), np.float32)
    metrics = {"train_rows": int(len(tr.label)), "val_rows": int(len(va.label)),
               "val_tracks": int(len(np.unique(va.track))), "temperature": float(params["temp"]),
               "members": [{k: v for k, v in h.items() if k not in ("train", "val")}
                           for h in hists],
               "train_s": round(sum(h["train_s"] for h in hists), 1),
               "history": [{"train": h["train"], "val": h["val"]} for h in hists]}
    return params, metrics


def raw_logits(params, x, d_now, d_later, chunk: int = 8192) -> np.ndarray:
    """The ensemble's mean logit (before the temperature) for rows with one later distance each."""
    f = jax.jit(lambda x, dn, dl: logits(params, x, dn, dl[:, None])[:, 0])
    return np.concatenate([np.asarray(f(x[i:i + chunk], d_now[i:i + chunk], d_later[i:i + chunk]))
                           for i in range(0, len(x), chunk)])


def predict_rows(params, rows: Rows, chunk: int = 8192) -> np.ndarray:
    """P(success) of each row's own (d_now, d_later): `raw_logits` through the temperature."""
    z = raw_logits(params, rows.x, rows.d_now, rows.d_later, chunk) / float(params["temp"])
    return 1.0 / (1.0 + np.exp(-z))


# ----------------------------------------------------------------------- the offline check
OFFLINE_BAND_M = (0.3, 0.9)  # where the decision is made: the rows the offline check scores


def table_predict(tr: Rows, va: Rows, bin_m: float = 0.05) -> np.ndarray:
    """The (target, active policy, distance bin) success table of the training tracks' switch
    rows, (k + 1) / (n + 2) per bin, read at each validation row (an empty bin: the training
    switches' mean): what a rule that knows only the pair and the distance can know."""
    sw = take(tr, tr.now)
    nb = int(np.floor(max(sw.d_now.max(), va.d_now.max()) / bin_m)) + 1  # no bin clipped
    k, n = bin_counts(sw.d_now, sw.label, _pair(sw), N_TARGETS * N_SOURCES, bin_m, nb)
    b = np.floor(va.d_now / bin_m).astype(int)
    k, n = k[_pair(va), b], n[_pair(va), b]
    return np.where(n > 0, (k + 1) / np.maximum(n + 2, 1), sw.label.mean())


def offline_scores(preds: dict, va: Rows, band=OFFLINE_BAND_M) -> list[dict]:
    """AUC, Brier score and ECE of each predictor in `preds` {name: (N,) P(success) of va's rows,
    NaN where it has none}, per target and active policy, on the switch rows within `band` [m]."""
    from biped_switch.stats import brier, ece
    from biped_switch.switching.estimator import roc_auc
    sel = va.now & (va.d_now >= band[0]) & (va.d_now <= band[1])
    out = []
    for t in range(N_TARGETS):
        for s in list(range(N_SOURCES)) + [None]:
            m = sel & (va.target == t) & ((va.source == s) if s is not None else True)
            y = va.label[m]
            if m.sum() < 20 or y.min() == y.max():
                continue
            row = {"target": ARTIFACT_KINDS[t], "source": "all" if s is None else POLICY_NAMES[s],
                   "n": int(m.sum()), "success_pct": round(100 * float(y.mean()), 1)}
            for name, p in preds.items():
                p = np.asarray(p)[m]
                if np.isnan(p).any():
                    continue
                row[name] = {"auc": round(roc_auc(p, y), 3), "brier": round(brier(p, y), 4),
                             "ece": round(ece(p, y), 4)}
            out.append(row)
    return out

"""A learned terrain detector in place of the oracle (the paper's future work).

The paper's switching controller reads "an oracle terrain detector to determine the upcoming
terrain type". This one reads only the robot's own heightmap (60 x 40 cells of 0.025 m, 0.6 m
behind to 0.9 m in front, `simulation/heightmap.py`): the middle columns are averaged into a
forward profile (their median), taken relative to the rows under the body; a small MLP on the
rows ahead of the feet gives the kind, and the profile itself the distance:

  kind    the next artifact within the detection range (jumps, gaps, stairs) or none in view,
          the oracle's rule: the first artifact whose end is still ahead, named once its start is
          within `detect_range_m` (0.9 m), and named while the robot is on it;
  dist_m  the distance [m] from the CoM to the first height change ahead (`first_change_m`),
          which the distance rules (lookup, random, the 1 cm force) act on.

Labels come from the track's artifact table (the oracle, `BipedEnv.detect`). The data is the
robot's own heightmaps along episodes of each stand policy on its own terrain kind and of walk on
flat tracks (no mixed track in training); validation uses held-out seeds of the same and mixed
tracks crossed by the end-to-end policy. `hand_rule` is the simpler baseline it is measured
against: the first height change ahead of the feet, named by its size.

`detect_fn(meta, env)` gives a pure, jittable `(params, obs, yaw) -> {"kind", "dist_m"}` that the
switching rollout calls every control step (no host round trip); the rollout reports a change of
kind once it has held `debounce_steps` steps in a row (chosen on the validation tracks).
"""

from __future__ import annotations

import pathlib
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import linen

from biped_switch.config import default_detector_config
from biped_switch.learning import checkpoints as ckpt_lib
from biped_switch.learning import runs as runs_lib
from biped_switch.names import DETECTOR_CLASSES
from biped_switch.kinds import ARTIFACT_CODE, NO_ARTIFACT, class_of_code, code_of_class
from biped_switch.simulation.rollout import episode_keys, reset_by_track, run_episodes

CLASSES = DETECTOR_CLASSES  # the class of each oracle kind: kinds.CLASS_OF_CODE
DATA_FIELDS = ("profile", "kind", "dist_m", "yaw", "episode", "step")  # what `collect` gives
PROFILE_STATISTIC = "median"  # across the middle columns (`profile`): part of the data's identity


# ----------------------------------------------------------------------- input and network
def hm_slice(env) -> slice:
    """Where the heightmap lies in the env's observation (its named layout)."""
    return env.obs_layout.heightmap


def profile(hm_flat: jax.Array, grid: tuple[int, int], cfg=None) -> jax.Array:
    """(..., rows) forward height profile from flat heightmaps (..., rows*cols): the mean of the
    middle columns, minus its value under the body. Heightmap values grow downwards (0 at the CoM,
    1 at 2 m below or no ground), so > 0 is lower than the ground under the feet, < 0 higher."""
    cfg = cfg or default_detector_config()
    c0, c1 = cfg.lateral_cols
    r0, r1 = cfg.feet_rows
    hm = hm_flat.reshape(hm_flat.shape[:-1] + tuple(grid))
    # the median, not the mean: a yawed or drifting robot sees the track's edge (no ground) in
    # some of these columns, which the mean would read as a gap
    p = jnp.median(hm[..., c0:c1], axis=-1)
    return p - jnp.mean(p[..., r0:r1], axis=-1, keepdims=True)


def row_m(env_cfg=None) -> np.ndarray:
    """(rows,) forward position [m] of each heightmap row's centre (host constant)."""
    from biped_switch.simulation.heightmap import cell_offsets
    if env_cfg is None:
        return cell_offsets()[:, 0, 0]
    return cell_offsets(env_cfg.heightmap, env_cfg.shape)[:, 0, 0]


def _first_change(prof: jax.Array, rows_m, cfg):
    """(any change ahead, index of the first row ahead whose height differs from the feet's by
    more than `min_change_m`)."""
    rows_m = jnp.asarray(rows_m)
    ahead = (rows_m > cfg.ahead_from_m) & (rows_m <= cfg.detect_range_m)
    hit = (jnp.abs(prof) * 2.0 > cfg.min_change_m) & ahead  # heightmap units -> m (1 = 2 m)
    return jnp.any(hit, axis=-1), jnp.argmax(hit, axis=-1)


def first_change_m(prof: jax.Array, rows_m, cfg=None) -> jax.Array:
    """(...,) distance [m] from the CoM to the first row ahead whose height differs from the
    feet's (the start of what lies ahead), inf when none does within the detection range. The
    detector's distance: the heightmap shows where an artifact starts to within a cell (2.5 cm),
    which a regression learned on single-kind tracks did not (it read the artifact behind)."""
    cfg = cfg or default_detector_config()
    rows_m = jnp.asarray(rows_m)
    found, first = _first_change(prof, rows_m, cfg)
    return jnp.where(found, rows_m[first] - 0.5 * (rows_m[1] - rows_m[0]), jnp.inf)


def along_track_m(dist_heading_m: jax.Array, yaw: jax.Array) -> jax.Array:
    """A distance along the body's heading (the heightmap's forward axis) as a distance along the
    track (x), which the switching rules and lookup tables use: x cos(yaw), with the heading from
    the robot's IMU. A robot turned 70 deg sees a gap 0.16 m ahead in x at 0.47 m along its heading.
    Facing across or back down the track (cos < 0.1): inf, nothing ahead."""
    c = jnp.cos(yaw)
    return jnp.where(c > 0.1, dist_heading_m * c, jnp.inf)


class DetectorNet(linen.Module):
    """The profile's rows ahead of the feet -> class logits (none, jumps, gaps, stairs). The rows
    behind are left out: on single-kind training tracks whatever lies behind is the same kind,
    which on a mixed track would name the artifact just crossed."""
    hidden: Sequence[int]
    rows_from: int

    @linen.compact
    def __call__(self, prof):
        x = prof[..., self.rows_from:] * 10.0  # a 0.17 m stair rise is 0.085 in heightmap units
        for n in self.hidden:
            x = linen.swish(linen.Dense(n)(x))
        return linen.Dense(len(CLASSES))(x)


def _net(cfg) -> DetectorNet:
    return DetectorNet(tuple(cfg.hidden), int(cfg.rows_from))


def decode(logits: jax.Array, dist: jax.Array) -> dict:
    """kind (-1: none in view) and the distance [m] to what starts ahead, kept when the class
    says none: the rollout's debounce may hold a kind through a one-step none, and then still
    needs the distance (switching.rules masks it where its kind is none)."""
    return {"kind": code_of_class(jnp.argmax(logits, axis=-1), jnp).astype(jnp.int32),
            "dist_m": dist}


def detect_fn(meta: dict, env):
    """Pure, jittable `(params, obs (B, O), yaw (B,) [rad]) -> {"kind": (B,), "dist_m": (B,)}`
    for `env`'s observation layout (resolved here, on the host, once)."""
    cfg = _cfg(meta)
    net = _net(cfg)
    sl, grid, rows = hm_slice(env), tuple(env.obs_layout.grid), row_m(env.cfg)

    def apply(params, obs, yaw):
        prof = profile(obs[..., sl], grid, cfg)
        return decode(net.apply(params, prof), along_track_m(first_change_m(prof, rows, cfg), yaw))

    apply.debounce_steps = int(cfg.debounce_steps)  # the rollout's filter (switching.rules)
    apply.via_none = bool(cfg.debounce_via_none)
    return apply


def _cfg(meta: dict):
    cfg = default_detector_config()
    for k, v in (meta.get("config") or {}).items():
        if k in cfg:
            cfg[k] = tuple(v) if isinstance(v, list) else v
    return cfg


# ----------------------------------------------------------------------- the simpler baseline
def hand_rule(prof: np.ndarray, yaw: np.ndarray, rows_m: np.ndarray,
              cfg=None) -> tuple[np.ndarray, np.ndarray]:
    """(kind, dist_m) from profiles (N, rows) by a rule: the first change ahead (`first_change_m`)
    names the artifact by its size (`hand_gap_drop_m`, `hand_jump_rise_m`): a deep drop (no
    ground) a gap, a high rise a jumps block, a smaller rise a stair, a smaller drop nothing."""
    cfg = cfg or default_detector_config()
    prof, rows_m = np.asarray(prof), np.asarray(rows_m)
    found, first = (np.asarray(v) for v in _first_change(jnp.asarray(prof), rows_m, cfg))
    rise = -2.0 * prof[np.arange(len(first)), first]  # [m]; a drop < 0
    code = ARTIFACT_CODE
    kind = np.where(rise <= -cfg.hand_gap_drop_m, code["gaps"],
                    np.where(rise >= cfg.hand_jump_rise_m, code["jumps"],
                             np.where(rise > 0, code["stairs"], NO_ARTIFACT)))
    dist = np.where(found, rows_m[first] - 0.5 * (rows_m[1] - rows_m[0]), np.inf)
    along_m = np.asarray(along_track_m(jnp.asarray(dist), jnp.asarray(yaw)))
    return np.where(found, kind, NO_ARTIFACT), along_m


# ----------------------------------------------------------------------- data
def collect(env, act, rng: jax.Array, n_envs: int, horizon: int, every: int = 1) -> dict:
    """Heightmap profiles and oracle labels along `n_envs` episodes of the batched policy
    `act(obs, key)` on `env`'s tracks: profile (N, rows), kind (N,) -1..2, dist_m (N,), episode
    (N,) and step (N,), for the live steps, every `every`-th."""
    cfg = default_detector_config()
    grid, sl = tuple(env.obs_layout.grid), hm_slice(env)
    reset_keys, k_run = episode_keys(rng, n_envs)
    state = reset_by_track(env, reset_keys, jnp.arange(n_envs) % env.bank.size)

    def step_act(c, state, live, key):
        return act(state.obs, key), c, None

    def trace(c, aux, state, nxt, live):
        si = jax.vmap(env.switch_inputs)(state)
        return {"profile": profile(state.obs[:, sl], grid, cfg).astype(jnp.float16),
                "kind": si["detect"]["kind"], "dist_m": si["detect"]["dist_m"], "yaw": si["yaw"],
                "live": live}

    run = jax.jit(lambda s, k: run_episodes(env, s, horizon, step_act, None, trace=trace,
                                            rng=k).trace)
    tr = jax.device_get(run(state, k_run))  # (T, B, ...)
    keep = np.asarray(tr["live"]).copy()
    keep[np.arange(keep.shape[0]) % every != 0] = False
    t_idx, b_idx = np.nonzero(keep)
    return {"profile": np.asarray(tr["profile"])[t_idx, b_idx].astype(np.float32),
            "kind": np.asarray(tr["kind"])[t_idx, b_idx].astype(np.int32),
            "dist_m": np.asarray(tr["dist_m"])[t_idx, b_idx].astype(np.float32),
            "yaw": np.asarray(tr["yaw"])[t_idx, b_idx].astype(np.float32),
            "episode": b_idx.astype(np.int32), "step": t_idx.astype(np.int32)}


def concat(parts: list[dict]) -> dict:
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    # episodes numbered apart across parts
    offs = np.cumsum([0] + [int(p["episode"].max()) + 1 for p in parts[:-1]])
    out["episode"] = np.concatenate([p["episode"] + o for p, o in zip(parts, offs)])
    return out


# ----------------------------------------------------------------------- training
def train(data: dict, val: dict, cfg=None, print_fn=print) -> tuple[dict, dict]:
    """(params, history) of a detector fitted to `data` with early stopping on `val` (both from
    `collect`): class cross-entropy, AdamW; the parameters of the best validation epoch are kept."""
    cfg = cfg or default_detector_config()
    net = _net(cfg)
    rng = np.random.default_rng(cfg.seed)
    x, c = data["profile"], class_of_code(data["kind"], np).astype(np.int32)
    vx, vc = val["profile"], class_of_code(val["kind"], np).astype(np.int32)
    params = net.init(jax.random.PRNGKey(cfg.seed), jnp.zeros((1, x.shape[1])))
    opt = optax.adamw(cfg.learning_rate, weight_decay=cfg.weight_decay)
    opt_state = opt.init(params)

    def loss_fn(p, xb, cb):
        return optax.softmax_cross_entropy_with_integer_labels(net.apply(p, xb), cb).mean()

    @jax.jit
    def update(p, s, xb, cb):
        loss, g = jax.value_and_grad(loss_fn)(p, xb, cb)
        upd, s = opt.update(g, s, p)
        return optax.apply_updates(p, upd), s, loss

    val_loss = jax.jit(loss_fn)
    best, best_params, since = np.inf, params, 0
    hist = {"train_loss": [], "val_loss": []}
    n = len(x)
    for epoch in range(cfg.epochs):
        perm = rng.permutation(n)
        losses = []
        for i in range(0, n - cfg.batch_size + 1, cfg.batch_size):
            j = perm[i:i + cfg.batch_size]
            params, opt_state, loss = update(params, opt_state, x[j], c[j])
            losses.append(float(loss))
        vl = float(val_loss(params, vx, vc))
        hist["train_loss"].append(float(np.mean(losses)))
        hist["val_loss"].append(vl)
        if vl < best - 1e-5:
            best, best_params, since = vl, params, 0
        else:
            since += 1
        if epoch % 10 == 0 or since >= cfg.patience:
            print_fn(f"  epoch {epoch + 1:3d}: train {np.mean(losses):.4f}  val {vl:.4f}")
        if since >= cfg.patience:
            break
    hist["best_epoch"] = int(np.argmin(hist["val_loss"])) + 1
    return best_params, hist


def predict(params, prof: np.ndarray, yaw: np.ndarray, rows_m: np.ndarray,
            cfg=None) -> tuple[np.ndarray, np.ndarray]:
    """(kind, dist_m) of profiles (N, rows) seen at headings `yaw` (N,) [rad], on the host."""
    cfg = cfg or default_detector_config()
    prof = jnp.asarray(prof)
    out = decode(jax.jit(_net(cfg).apply)(params, prof),
                 along_track_m(first_change_m(prof, rows_m, cfg), jnp.asarray(yaw)))
    return np.asarray(out["kind"]), np.asarray(out["dist_m"])


def save(path, params, meta: dict) -> pathlib.Path:
    """The detector's parameters (Orbax, the one codec) and meta.json (config, metrics)."""
    import json
    path = ckpt_lib.write_tree(path, jax.tree.map(np.asarray, jax.device_get(params)))
    (path / "meta.json").write_text(json.dumps(meta, indent=2, default=float))
    return path


def load(path) -> tuple[dict, dict]:
    """(params, meta) of a saved detector; the error names the folder when it is missing."""
    path = pathlib.Path(path)
    if not (path / "meta.json").is_file():
        raise FileNotFoundError(f"no terrain detector at {path}: train it with "
                                f"`python -m biped_switch.detector`")
    return ckpt_lib.read_tree(path), runs_lib.read_json(path / "meta.json")

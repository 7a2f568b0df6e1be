"""`make demo`: the main job until trained policies exist.

Generates a mixed 7-artifact track, rolls the MJX environment out for a few seconds with the
scripted standing controller (PD hold of the standing keyframe), and writes a figure: the track with
the robot's path, the heightmap the robot sees, and its CoM height and foot contacts over time.
No policy is trained yet, so the robot stands at the start; the later issues replace this with the
real pipeline (trained policies, switching, evaluation).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import jax
import numpy as np

from biped_switch import env as env_lib
from biped_switch import terrain
from biped_switch.heightmap import heightmap


def rollout(track: terrain.Track, seconds: float, seed: int = 0):
    """Steps the env on one track with the standing controller; returns per-step records."""
    cfg = env_lib.default_env_config()
    cfg.kind = track.kind
    env = env_lib.BipedEnv(cfg, tracks=[track])
    reset, step = jax.jit(env.reset), jax.jit(env.hold_step)
    t0 = time.perf_counter()
    state = reset(jax.random.PRNGKey(seed))
    state = jax.block_until_ready(step(state))
    compile_s = time.perf_counter() - t0
    n = int(round(seconds / env.dt))
    rec = {k: [] for k in ("t_s", "com", "contact", "reward", "done")}
    obs0 = np.asarray(state.obs)
    t0 = time.perf_counter()
    for _ in range(n):
        state = step(state)
        rec["t_s"].append(float(state.info["time_s"]))
        rec["com"].append(np.asarray(state.pipeline_state.xipos[env.biped.pelvis_body]))
        rec["contact"].append(np.asarray(state.obs[env_lib.STATE_SLICES["contact"]]))
        rec["reward"].append(float(state.reward))
        rec["done"].append(float(state.done))
    run_s = time.perf_counter() - t0
    out = {k: np.asarray(v) for k, v in rec.items()}
    out["heightmap0"] = obs0[env_lib.STATE_SIZE:env_lib.STATE_SIZE + 2400].reshape(60, 40)
    out["metrics"] = {k: float(v) for k, v in state.metrics.items()}
    out["compile_s"], out["run_s"], out["dt_s"] = compile_s, run_s, env.dt
    return out


def plot(track: terrain.Track, rec: dict, path: pathlib.Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(16, 7))
    grid = fig.add_gridspec(2, 4, height_ratios=[1.0, 1.6])
    ax_track = fig.add_subplot(grid[0, :])
    terrain.plot_track(track, ax_track, path_xz=rec["com"][:, [0, 2]])
    ax_track.plot(rec["com"][0, 0], rec["com"][0, 2], "o", color="tab:blue", ms=5)
    kind, x0, _ = track.artifacts[0]
    pos = np.array([x0 - 0.4, 0.0, rec["com"][0, 2]])
    grids = [(rec["heightmap0"], "heightmap at reset"),
             (np.asarray(heightmap(track.boxes, pos, 0.0)), f"0.4 m before the first artifact ({kind})")]
    for col, (grid_hm, title) in enumerate(grids):
        ax_hm = fig.add_subplot(grid[1, col])
        im = ax_hm.imshow(grid_hm, origin="lower", cmap="viridis", vmin=0, vmax=1,
                          extent=[0.5, -0.5, -0.6, 0.9], aspect="equal")
        ax_hm.set_xlabel("left <- lateral [m] -> right")
        ax_hm.set_ylabel("forward [m]")
        ax_hm.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax_hm, fraction=0.046, label="0 = CoM height, 1 = 2 m below")
    ax_h = fig.add_subplot(grid[1, 2])
    ax_h.plot(rec["t_s"], rec["com"][:, 2], color="tab:red")
    ax_h.set_xlabel("t [s]")
    ax_h.set_ylabel("pelvis CoM z [m]")
    ax_h.set_title("CoM height")
    ax_c = fig.add_subplot(grid[1, 3])
    ax_c.imshow(rec["contact"].T, aspect="auto", cmap="Greys", interpolation="nearest",
                extent=[rec["t_s"][0], rec["t_s"][-1], 8.5, -0.5])
    ax_c.set_yticks(range(9), ["L fl", "L fr", "L bl", "L br", "R fl", "R fr", "R bl", "R br", "none"])
    ax_c.set_xlabel("t [s]")
    ax_c.set_title("foot contacts (black = touching)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.demo", description=__doc__.split("\n")[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--out", default="experiments/results/demo")
    a = p.parse_args(argv)
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"demo: mixed 7-artifact track (seed {a.seed}), {a.seconds:g} s of the scripted standing "
          f"controller on {jax.devices()[0]}; takes about a minute on 2 CPU cores (mostly compiling).")
    track = terrain.generate_track(a.seed, "mixed")
    print("artifacts:", ", ".join(f"{k} [{x0:.2f}, {x1:.2f}] m" for k, x0, x1 in track.artifacts))
    rec = rollout(track, a.seconds, a.seed)
    png = out / "demo_track.png"
    plot(track, rec, png)
    summary = {
        "track_seed": a.seed, "n_boxes": int(len(track.boxes)), "width_m": round(track.width_m, 3),
        "seconds": a.seconds, "compile_s": round(rec["compile_s"], 1),
        "rollout_wall_s": round(rec["run_s"], 2),
        "fell": bool(rec["done"].max() > 0),
        "com_z_min_max_m": [round(float(rec["com"][:, 2].min()), 3),
                            round(float(rec["com"][:, 2].max()), 3)],
        "all_soles_in_contact_frac": round(float(rec["contact"][:, :8].all(axis=1).mean()), 3),
        "final_metrics": rec["metrics"],
        "figure": str(png),
    }
    (out / "demo_summary.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary, indent=2))
    print("Note: no policy is trained yet; the robot stands under the scripted controller.")
    return 0


if __name__ == "__main__":
    sys.exit(main())

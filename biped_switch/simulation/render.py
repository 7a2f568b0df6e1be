"""Render a rollout to a GIF (or MP4) with MuJoCo's offscreen renderer.

    python -m biped_switch.render --policy stairs [--init stand] [--seconds 8] [--out clip.gif]
    python -m biped_switch.render --scripted --kind mixed        # the scripted standing controller
    python -m biped_switch.render --policy stairs --seconds 70 --track-seed 10000 \
        --size 360x240 --every 3 --colors 64 --out models/policies/stairs_stand/stairs_stand_success.gif

The rollout runs in the environment (physics `--backend`, and the env overrides the policy was
trained with); its joint trajectory is then replayed on a CPU MuJoCo model compiled with that
episode's boxes and drawn by a camera that follows the pelvis. Needs an OpenGL backend: EGL on a
GPU host, OSMesa on a CPU host (`MUJOCO_GL=osmesa`, Debian's libosmesa6; `make render-deps`
installs it). A `.mp4` output needs imageio-ffmpeg; `.gif` needs only Pillow.

MuJoCo fixes its OpenGL backend when it is first imported, so nothing that loads mujoco (model,
env, runs, policies) is imported at this module's top: those imports sit inside the functions,
after `_gl_default()` (the demo imports this module first for the same reason).
"""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from biped_switch.simulation import terrain
from biped_switch.simulation import _gl_default  # noqa: F401  (set when the package is imported)


def record(env, act, seconds: float, seed: int = 0, track_id: int = 0, reset_key=None,
           batch: int = 1):
    """(qpos per control step (T, nq), boxes (C, 6), metrics) of one episode; `act` None = scripted.

    `reset_key` (default PRNGKey(seed)) draws the initial state. A policy runs in the one
    episode loop (`rollout.run_episodes`) on `batch` copies of the episode, and the first is
    drawn: the policy's matmuls round differently at another batch size, and a trajectory is
    chaotic enough that a track Table I (batch 100) fell on can succeed in a lone rollout, so a
    replay of a Table I trial runs at Table I's batch (measured: stairs track
    10,018 fell at 11.2 m in every copy at batch 100, and reached the finish at batch 1 and 4)."""
    from biped_switch.simulation.rollout import reset_by_track, run_episodes

    horizon = int(round(seconds / env.dt))
    key = jax.random.PRNGKey(seed) if reset_key is None else reset_key
    if act is None:  # the scripted stand: env.hold_step, no policy
        reset = jax.jit(lambda k: env.reset(k, track_id=track_id))
        step = jax.jit(env.hold_step)
        state = reset(key)
        qpos = [np.asarray(state.pipeline_state.qpos)]
        for _ in range(horizon):
            state = step(state)
            qpos.append(np.asarray(state.pipeline_state.qpos))
            if float(state.done) > 0:
                break
        return (np.stack(qpos), np.asarray(state.info["boxes"]),
                {k: float(v) for k, v in state.metrics.items()})

    def policy(carry, state, live, k):
        return act(state.obs, k), carry, None

    def trace(carry, aux, state, nxt, live):
        return nxt.pipeline_state.qpos[0]

    @jax.jit
    def run(key, rng):
        state = reset_by_track(env, jnp.stack([key] * batch), jnp.full((batch,), track_id, jnp.int32))
        ep = run_episodes(env, state, horizon, policy, None, trace=trace, rng=rng)
        return state.pipeline_state.qpos[0], state.info["boxes"][0], ep

    q0, boxes, ep = jax.device_get(run(key, jax.random.PRNGKey(seed + 1)))
    n = int(ep.length[0])  # live steps; the trace runs on past a fall
    qpos = np.concatenate([np.asarray(q0)[None], np.asarray(ep.trace)[:n]])
    return qpos, np.asarray(boxes), {k: float(v[0]) for k, v in ep.metrics.items()}


def track_boxes(boxes: np.ndarray) -> np.ndarray:
    """The rows of an env's box slots that hold terrain. Padding rows are parked at x = 1e6 or far
    below; left in, they set the model's extent, hence the near clipping plane, to kilometres and
    every frame renders as empty sky."""
    boxes = np.asarray(boxes)
    keep = (np.abs(boxes[:, 0]) < 0.5 * terrain.FAR_X_M) & (boxes[:, 2] > terrain.PARK_Z_M + 1.0)
    return boxes[keep]


def frames(qpos: np.ndarray, boxes: np.ndarray, width: int = 480, height: int = 320,
           every: int = 2) -> list[np.ndarray]:
    """RGB frames of a qpos trajectory on a CPU model holding `boxes`, side-on tracking camera.
    Call `_gl_default()` (or set MUJOCO_GL) before mujoco is first imported."""
    import mujoco  # lazy: after _gl_default (module docstring)

    from biped_switch.simulation.model import compile_mj_model

    m = compile_mj_model(None, track_boxes(boxes))
    d = mujoco.MjData(m)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.distance, cam.azimuth, cam.elevation = 3.2, 90.0, -12.0
    out = []
    renderer = mujoco.Renderer(m, height, width)
    try:
        for q in qpos[::every]:
            d.qpos[:] = q
            mujoco.mj_forward(m, d)
            cam.lookat[:] = [q[0] + 0.3, 0.0, 0.6]
            renderer.update_scene(d, camera=cam)
            out.append(renderer.render().copy())
    finally:
        renderer.close()
    return out


def write(images: list[np.ndarray], path: pathlib.Path, fps: float, colors: int = 256) -> None:
    """A GIF with `colors` palette entries (64 keeps a 70 s trial near 3 MB at 360 x 240 and
    every 3rd step: the size to commit), or an MP4."""
    if not 2 <= colors <= 256:
        raise ValueError(f"colors={colors}: a GIF palette holds 2-256 colours")
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".mp4":
        import imageio.v2 as imageio  # lazy: optional, and needs imageio-ffmpeg

        imageio.mimwrite(path, images, fps=fps)
        return
    from PIL import Image  # lazy: only a GIF needs it

    pics = [Image.fromarray(im).quantize(colors) if colors < 256 else Image.fromarray(im)
            for im in images]
    # duration [ms], rounded: a GIF keeps 10 ms units, and int() made 60 ms (every 3rd step) 50
    pics[0].save(path, save_all=True, append_images=pics[1:], duration=round(1000 / fps), loop=0)


def contact_sheet(images: list[np.ndarray], path: pathlib.Path, n: int = 24, cols: int = 6) -> None:
    """`n` frames spread evenly over the clip, in a grid, as one PNG: a whole trial at a glance,
    to look for sliding, tunnelling or flying without playing the GIF."""
    from PIL import Image  # lazy, as in write()

    if not images:
        raise ValueError("contact_sheet: no frames")
    idx = np.linspace(0, len(images) - 1, min(n, len(images))).round().astype(int)
    h, w = images[0].shape[:2]
    rows = -(-len(idx) // cols)
    sheet = np.full((rows * h, cols * w, 3), 255, np.uint8)
    for j, i in enumerate(idx):
        r, c = divmod(j, cols)
        sheet[r * h:(r + 1) * h, c * w:(c + 1) * w] = images[i][..., :3]
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(sheet).save(path)

"""Offscreen rendering: the frames show the robot and the track, not empty sky."""

from __future__ import annotations

import ctypes.util
import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

from biped_switch.simulation import render
from biped_switch import render as render_cli
from biped_switch.simulation import terrain


def test_track_boxes_drops_padding_rows():
    far = [terrain.FAR_X_M, 0.0, 0.5, 0.1, 0.1, 0.1]  # padding artifact slot
    parked = [0.0, 0.0, terrain.PARK_Z_M, 0.1, 0.1, 0.1]  # a hole's box, parked below
    real = [[1.0, 0.0, -0.05, 0.5, 0.7, 0.05], [2.2, 0.0, 0.1, 0.2, 0.7, 0.2]]
    out = render.track_boxes(np.array([real[0], far, parked, real[1]]))
    np.testing.assert_array_equal(out, real)


_SCRIPT = textwrap.dedent("""
    import json, sys
    import numpy as np
    from biped_switch.simulation import render
    render._gl_default()
    from biped_switch.simulation import model as model_lib
    from biped_switch.simulation import terrain
    from biped_switch.config import default_model_config
    track = terrain.generate_track(30000, "mixed", 1.0)
    cap = default_model_config().box_capacity
    pad = np.tile([[terrain.FAR_X_M, 0, terrain.PARK_Z_M, 0.1, 0.1, 0.1]], (cap - len(track.boxes), 1))
    m = model_lib.compile_mj_model(None, track.boxes)
    q0 = m.key_qpos[0].copy()
    q1 = q0.copy(); q1[0] += 1.0  # the robot 1 m further on: the camera follows, the track moves
    ims = render.frames(np.stack([q0, q1]), np.concatenate([track.boxes, pad]), 160, 120, every=1)
    px = [im.reshape(-1, 3).astype(int) for im in ims]
    sky = np.median(px[0][:160], axis=0)  # the top row is sky
    print(json.dumps({"n": len(ims), "shape": list(ims[0].shape),
                      "non_sky": [float((np.abs(p - sky).sum(1) > 60).mean()) for p in px],
                      "differ": float(np.abs(px[0] - px[1]).sum(1).mean())}))
""")


def _require_gl() -> None:
    """An OpenGL backend must be there (`make test` installs OSMesa with `make render-deps`; a GPU
    host renders with EGL): without one this test fails, unless BIPED_SWITCH_SKIP_RENDER=1 asks to skip."""
    if ctypes.util.find_library("OSMesa") or os.path.exists("/dev/nvidia0"):
        return
    if os.environ.get("BIPED_SWITCH_SKIP_RENDER") == "1":
        pytest.skip("BIPED_SWITCH_SKIP_RENDER=1 and no OpenGL backend (libOSMesa or a GPU for EGL)")
    pytest.fail("no OpenGL backend: libOSMesa not found and no GPU for EGL. Install it with "
                "`make render-deps` (apt, as root; `make test` does), or set BIPED_SWITCH_SKIP_RENDER=1 "
                "to skip this test")


def test_frames_show_the_robot_and_track():
    """The env pads its box slots with rows at x = 1e6; they once stretched the model's extent
    (so the near plane) to kilometres and every frame was sky. Runs in a subprocess: MUJOCO_GL
    must be set before mujoco is first imported."""
    import json

    _require_gl()
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    r = subprocess.run([sys.executable, "-c", _SCRIPT], capture_output=True, text=True, env=env,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["n"] == 2 and out["shape"] == [120, 160, 3]
    assert all(f > 0.2 for f in out["non_sky"]), out  # robot and terrain fill a good part
    assert out["differ"] > 1.0, out  # consecutive frames are not the same picture


def test_main_runs_the_policy_in_the_env_it_was_trained_for(tmp_path, monkeypatch):
    """`render --policy P` builds its env with the policy's env overrides (here the paper's torque
    actions without a phase clock, not today's defaults) on the chosen backend; the drawing is
    patched out (no OpenGL needed)."""
    from biped_switch.simulation import env as env_lib
    from policy_runs import fake_policy_run

    fake_policy_run(tmp_path / "runs", "walk", env={"action": "torque", "phase_obs": False})
    seen = {}
    record = render.record

    def spy_record(env, act, seconds, seed=0, track_id=0, **kw):
        seen["env"] = env
        return record(env, act, seconds, seed, track_id, **kw)

    def fake_frames(qpos, boxes, *args, **kw):
        seen["qpos"] = qpos
        return [np.zeros((4, 4, 3), np.uint8)] * 2

    monkeypatch.setattr(render, "_gl_default", lambda: None)
    monkeypatch.setattr(render, "record", spy_record)
    monkeypatch.setattr(render, "frames", fake_frames)
    out = tmp_path / "clip.gif"
    assert render_cli.main(["--policy", "walk", "--runs", str(tmp_path / "runs"), "--seconds", "0.1",
                        "--backend", "mujoco", "--out", str(out)]) == 0
    env = seen["env"]
    assert (env.cfg.action, env.cfg.phase_obs, env.backend) == ("torque", False, "mujoco")
    # the reset state and 5 steps, all in the standing pause (nothing falls)
    assert seen["qpos"].shape == (6, env.biped.mj_model.nq)
    assert out.stat().st_size > 0
    assert env_lib.BACKENDS == ("mujoco", "mjx")  # render's --backend choices spell these out


def test_gif_palette_and_frame_rate(tmp_path):
    """`colors` quantises each frame to at most that many colours (the committed GIFs use 64), at
    the given frame rate; a palette outside 2-256 is named."""
    from PIL import Image

    rng = np.random.default_rng(0)
    ims = [rng.integers(0, 256, (24, 32, 3), dtype=np.uint8) for _ in range(3)]
    path = tmp_path / "clip.gif"
    render.write(ims, path, fps=50 / 3, colors=16)
    with Image.open(path) as g:
        assert g.n_frames == 3 and g.size == (32, 24)
        assert g.info["duration"] == 60  # ms: round(1000 / (50 / 3)); int() gave 59, stored as 50
        for i in range(3):
            g.seek(i)
            assert len(g.convert("RGB").getcolors(4096)) <= 16
    with pytest.raises(ValueError, match="colors=300"):
        render.write(ims, path, fps=10, colors=300)


def test_contact_sheet_spreads_frames_over_the_clip(tmp_path):
    """Frame i is filled with value i: the sheet's tiles are the first, evenly spaced and last
    frames, in reading order, and empty tiles stay white."""
    from PIL import Image

    ims = [np.full((4, 6, 3), i, np.uint8) for i in range(11)]
    render.contact_sheet(ims, tmp_path / "s.png", n=5, cols=3)
    sheet = np.asarray(Image.open(tmp_path / "s.png"))
    assert sheet.shape == (8, 18, 3)
    tiles = [int(sheet[r * 4, c * 6, 0]) for r in range(2) for c in range(3)]
    assert tiles == [0, 2, 5, 8, 10, 255]  # linspace(0, 10, 5) rounded; one tile left white


def test_a_table1_trial_replays_to_the_float(tmp_path):
    """`render --table1 J --trial I` reruns Table I's trial I: on its own one-track env, with
    the reset key Table I gave it (random init, so the key matters) and Table I's batch size
    (which changes the policy's rounding), the final distance equals the batch rollout's."""
    import functools

    from biped_switch.simulation import env as env_lib
    from biped_switch.evaluation import single as table1
    from biped_switch.learning.policies import load_policy
    from biped_switch.simulation.rollout import rollout
    from policy_runs import fake_policy_run

    ckpt = fake_policy_run(tmp_path / "runs", "jumps", init="random")
    seed, batch, trials, track_seed, seconds = 3, 2, 3, 10_000, 0.6
    env = env_lib.make_env("jumps", "random", n_tracks=trials, seed=track_seed, backend="mujoco")
    act = load_policy(ckpt, env)[0]
    run = jax.jit(functools.partial(rollout, env, act, n_envs=batch, horizon=int(round(seconds / env.dt))))
    dist = np.concatenate([np.asarray(run(table1.batch_key(seed, s), track_ids=(np.arange(s, s + batch) % trials))["distance_m"])
                           for s in range(0, trials, batch)])[:trials]
    # by hand: trial 2 is the first of the second batch, whose key is PRNGKey(seed + 2)
    np.testing.assert_array_equal(table1.trial_reset_key(seed, batch, 2),
                                  jax.random.split(jax.random.split(jax.random.PRNGKey(5))[0], 2)[0])
    for trial in (1, 2):
        one = env_lib.make_env("jumps", "random", n_tracks=1, seed=track_seed + trial, backend="mujoco")
        key = table1.trial_reset_key(seed, batch, trial)
        _, _, m = render.record(one, load_policy(ckpt, one)[0], seconds, reset_key=key, batch=batch)
        assert m["distance_m"] == dist[trial], (trial, m["distance_m"], dist)
    _, _, other = render.record(one, load_policy(ckpt, one)[0], seconds, reset_key=jax.random.PRNGKey(99),
                                batch=batch)
    assert other["distance_m"] != dist[2]  # another initial state: another trajectory


@pytest.mark.parametrize("argv, want", [
    (["--scripted", "--track-seed", "-5"], "--track-seed: must be >= 0, got '-5'"),
    (["--scripted", "--seed", "-1"], "--seed: must be >= 0, got '-1'"),
    (["--scripted", "--seconds", "0"], "--seconds: must be > 0, got '0'")])
def test_cli_refuses_bad_numbers_before_any_work(capsys, argv, want):
    """An argparse error naming the flag and value, not a traceback from numpy's seeding."""
    with pytest.raises(SystemExit) as e:
        render_cli.main(argv)
    assert e.value.code == 2
    assert want in capsys.readouterr().err

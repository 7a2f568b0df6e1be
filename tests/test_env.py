"""The MJX environment (biped_switch.env) on one shared batch of 4 `mixed` tracks (conftest.py):
shapes, the 51-element state layout against CPU MuJoCo and numpy references, standing, falling,
success, the pause, the reward, the detector, no recompilation, init modes and config errors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from biped_switch.simulation import env as env_lib
from biped_switch.simulation import heightmap as hm
from biped_switch.simulation import model as model_lib
from biped_switch.simulation import terrain
from biped_switch.config import default_curriculum_config

from conftest import B, DIFFICULTIES, MJX_TORQUE, TRACK_IDS, actions, index
from helpers import edge_mask, quat_to_pitch_roll_yaw, terrain_height_np

SL = env_lib.STATE_SLICES
OBS = env_lib.STATE_SIZE + 60 * 40


def _solid(boxes):
    return boxes[boxes[:, 2] > -10.0]


def _stand_reference(bm):
    """CPU MuJoCo: pelvis CoM height of the keyframe with the lowest sole sphere 1 mm above z = 0."""
    d = mujoco.MjData(bm.mj_model)
    d.qpos[:] = bm.stand_qpos
    mujoco.mj_kinematics(bm.mj_model, d)
    lowest = d.geom_xpos[bm.sole_geoms.reshape(-1), 2].min() - 0.02
    return d.xipos[bm.pelvis_body, 2] - lowest + 1e-3, d.xipos[bm.pelvis_body, 2]


def _first(mask):
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def _teleport(state, dx):
    """Shift each env's robot by dx[i] metres along x (it keeps its pose and height)."""
    ps = state.pipeline_state
    qpos = np.array(ps.qpos)
    qpos[:, 0] += np.asarray(dx, np.float32)
    return state.replace(pipeline_state=ps.replace(qpos=qpos.astype(np.float32)))


# ----------------------------------------------------------------------------- shapes
def test_unbatched_shapes(env):
    s = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
    s2 = jax.eval_shape(env.step, s, jnp.zeros(12))
    s3 = jax.eval_shape(env.hold_step, s)
    for st in (s, s2, s3):
        assert st.obs.shape == (OBS,) == (env.observation_size,)
        assert st.obs.dtype == jnp.float32
        assert st.reward.shape == () and st.done.shape == ()
        assert set(st.metrics) >= {"distance_m", "progress_frac", "artifacts_passed", "success",
                                   "fell", "fail_kind", "detected_kind"}
        assert all(v.shape == () for v in st.metrics.values())
        assert st.info["boxes"].shape == (96, 6)
    assert env.action_size == 12 and env.dt == pytest.approx(0.02)
    # step returns a state of exactly the type it takes (a scan carry in training)
    assert jax.tree.structure(s2) == jax.tree.structure(s)
    assert jax.tree.leaves(s2) == jax.tree.leaves(s)


def test_batch_shapes_and_finite(batch0, hold_traj, fall_traj):
    for st in (batch0, hold_traj[-1], fall_traj[10], fall_traj[-1]):
        assert st.obs.shape == (B, OBS)
        assert st.reward.shape == (B,) and st.done.shape == (B,)
        assert np.isfinite(st.obs).all() and np.isfinite(st.reward).all()
        for v in st.metrics.values():
            assert v.shape == (B,) and np.isfinite(v).all()
    hmap = batch0.obs[:, 51:]
    assert hmap.min() >= 0.0 and hmap.max() <= 1.0


# ----------------------------------------------------------------------------- reset
def test_reset_standing_keyframe(env, batch0):
    bm = env.biped
    h_ref, _ = _stand_reference(bm)
    obs = batch0.obs
    np.testing.assert_allclose(obs[:, SL["joint_pos"]], np.tile(bm.stand_qpos[bm.qpos_adr], (B, 1)),
                               atol=1e-6)
    np.testing.assert_allclose(obs[:, SL["joint_vel"]], 0.0)
    np.testing.assert_allclose(obs[:, SL["pitch"]], 0.0, atol=1e-5)
    np.testing.assert_allclose(obs[:, SL["roll"]], 0.0, atol=1e-5)
    np.testing.assert_allclose(obs[:, SL["com_height"]][:, 0], h_ref, atol=1e-4)
    assert h_ref == pytest.approx(1.0936, abs=1e-3)
    ps = batch0.pipeline_state
    soles = ps.geom_xpos[:, bm.sole_geoms.reshape(-1)]
    np.testing.assert_allclose(soles[..., 2].min(axis=1) - 0.02, 1e-3, atol=2e-5)  # on flat z = 0
    np.testing.assert_allclose(ps.qpos[:, :2], 0.0, atol=1e-6)
    np.testing.assert_allclose(batch0.info["start_x"], ps.xipos[:, bm.pelvis_body, 0])
    for k in ("distance_m", "progress_frac", "artifacts_passed", "success", "fell"):
        np.testing.assert_allclose(batch0.metrics[k], 0.0, atol=1e-6)
    np.testing.assert_array_equal(batch0.metrics["detected_kind"], -1)
    np.testing.assert_array_equal(batch0.done, 0.0)
    # Brax's EpisodeWrapper counts episode steps in info["steps"]; an env key of that name doubled
    # its count and cut every training episode to half its length.
    assert not env_lib.BRAX_WRAPPER_KEYS & set(batch0.info)
    np.testing.assert_array_equal(batch0.info["time_s"], 0.0)


def test_reset_tracks_match_generated_tracks(env, batch0):
    """The boxes and artifacts that reset lays out in jnp at a traced difficulty equal those of
    generate_track(seed, 'mixed', difficulty) on the host."""
    info = batch0.info
    np.testing.assert_array_equal(info["track_id"], TRACK_IDS)
    np.testing.assert_allclose(info["difficulty"], DIFFICULTIES)
    for i, (tid, d) in enumerate(zip(TRACK_IDS, DIFFICULTIES)):
        t = terrain.generate_track(int(tid), "mixed", float(d))
        np.testing.assert_allclose(_solid(info["boxes"][i]), t.boxes, atol=5e-5)
        np.testing.assert_allclose(info["art_x0"][i], [a[1] for a in t.artifacts], atol=5e-5)
        np.testing.assert_allclose(info["art_x1"][i], [a[2] for a in t.artifacts], atol=5e-5)
        np.testing.assert_array_equal(info["art_kind"][i], t.artifact_codes)
        assert info["finish_x"][i] == pytest.approx(t.finish_x_m, abs=5e-5)


def test_batch_envs_have_different_tracks(batch0):
    boxes = batch0.info["boxes"]
    for i in range(B):
        for j in range(i + 1, B):
            assert not np.allclose(boxes[i], boxes[j]), (i, j)
    np.testing.assert_allclose((boxes[3, :, 2] + boxes[3, :, 5])[boxes[3, :, 2] > -10], 0.0,
                               atol=1e-6)  # difficulty 0: flat


def test_random_track_choice(env):
    """reset without a track id picks tracks at random from the bank (only the id is computed)."""
    s = jax.jit(jax.vmap(lambda k: env.reset(k).info["track_id"]))(
        jax.random.split(jax.random.PRNGKey(5), 64))
    ids = np.asarray(s)
    assert set(ids.tolist()) == {0, 1, 2, 3}


# ----------------------------------------------------------------------------- state layout
def _pelvis_kinematics(bm, qpos):
    """CPU MuJoCo's pelvis CoM and rotation matrix for one qpos (the env observes the returned qpos,
    while mjx.step's stored xipos/xmat are from before its last integration)."""
    d = mujoco.MjData(bm.mj_model)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(bm.mj_model, d)
    return d.xipos[bm.pelvis_body].copy(), d.xmat[bm.pelvis_body].reshape(3, 3).copy()


def _pitch_roll_of_mat(xmat):
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(xmat, np.float64).reshape(-1))
    return quat_to_pitch_roll_yaw(q)[:2]


def _check_layout(env, state, i):
    """Slices of the 51-element state against the pipeline state the env returns and CPU MuJoCo.

    Pitch, roll and CoM height are checked against CPU MuJoCo's kinematics of the returned qpos."""
    bm = env.biped
    obs = state.obs[i]
    ps = index(state.pipeline_state, i)
    np.testing.assert_allclose(obs[SL["joint_pos"]], ps.qpos[bm.qpos_adr], atol=1e-6)
    np.testing.assert_allclose(obs[SL["joint_vel"]], ps.qvel[bm.dof_adr], atol=1e-6)
    # CoM velocities against CPU MuJoCo's object velocity of the pelvis (at its CoM, world frame)
    m = bm.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = ps.qpos
    d.qvel[:] = ps.qvel
    mujoco.mj_forward(m, d)
    vel = np.zeros(6)
    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, bm.pelvis_body, vel, 0)
    np.testing.assert_allclose(obs[SL["com_ang_vel"]], vel[:3], atol=2e-3, rtol=1e-3)
    np.testing.assert_allclose(obs[SL["com_lin_vel"]], vel[3:], atol=5e-3, rtol=1e-3)
    pitch, roll = _pitch_roll_of_mat(d.xmat[bm.pelvis_body])  # kinematics of the returned qpos
    assert obs[SL["pitch"]][0] == pytest.approx(pitch, abs=1e-5)
    assert obs[SL["roll"]][0] == pytest.approx(roll, abs=1e-5)
    com = np.asarray(d.xipos[bm.pelvis_body], np.float64)
    ground = terrain_height_np(_solid(state.info["boxes"][i]), com[:2])
    assert obs[SL["com_height"]][0] == pytest.approx(np.clip(com[2] - ground, -2, 2), abs=1e-5)
    return vel


def test_state_layout_against_references(env, hold_traj, fall_traj):
    moving = 0
    for st in (hold_traj[10], fall_traj[5], fall_traj[12], fall_traj[20]):
        for i in range(B):
            vel = _check_layout(env, st, i)
            moving += np.abs(vel).max() > 0.1
    assert moving >= 8  # velocities were not all ~0


def test_observation_kinematics_match_returned_qpos(env, fall_traj):
    """Pitch, roll and CoM height in the observation describe the pose in the returned qpos (mjx.step
    evaluates positions before integrating qpos; env._step refreshes kinematics after its scan)."""
    bm = env.biped
    m = bm.mj_model
    d = mujoco.MjData(m)
    for st in (fall_traj[8], fall_traj[12], fall_traj[16]):
        for i in range(B):
            d.qpos[:] = st.pipeline_state.qpos[i]
            mujoco.mj_kinematics(m, d)
            pitch, roll = _pitch_roll_of_mat(d.xmat[bm.pelvis_body])
            com = d.xipos[bm.pelvis_body]
            ground = terrain_height_np(_solid(st.info["boxes"][i]), com[:2])
            got = st.obs[i, SL["pitch"]][0], st.obs[i, SL["roll"]][0], st.obs[i, SL["com_height"]][0]
            assert got == pytest.approx((pitch, roll, com[2] - ground), abs=1e-4)


def test_contact_slices(env, hold_traj, fall_traj):
    ids = env.biped.sole_geoms.reshape(-1)
    for traj in (hold_traj, fall_traj):
        prev = None
        for st in traj:
            c = st.obs[:, SL["contact"]]
            assert set(np.unique(c)) <= {0.0, 1.0}
            np.testing.assert_array_equal(c[:, 8], (c[:, :8].sum(axis=1) == 0).astype(np.float32))
            np.testing.assert_array_equal(st.info["contact_prev"], c)
            if prev is None:
                np.testing.assert_array_equal(st.obs[:, SL["contact_prev"]], c)
            else:
                np.testing.assert_array_equal(st.obs[:, SL["contact_prev"]], prev)
            prev = c
            con = st.pipeline_state._impl.contact
            for i in range(B):
                pairs = con.geom[i][con.dist[i] < 1e-3]  # (n, 2) geom ids of touching pairs
                touching = set(pairs.reshape(-1).tolist())
                np.testing.assert_array_equal(c[i, :8], [float(k in touching) for k in ids])
    # both values occur: feet on the ground while standing, off it while falling
    assert hold_traj[-1].obs[:, SL["contact"]][:, :8].min() == 1.0
    assert any(st.obs[:, 32].max() == 1.0 for st in fall_traj)


def test_heightmap_part_matches_raycast(env, hold_traj, fall_traj):
    bm = env.biped
    for st, i in ((hold_traj[-1], 0), (fall_traj[15], 2), (hold_traj[5], 3)):
        ps = index(st.pipeline_state, i)
        solid = _solid(st.info["boxes"][i])
        m = model_lib.compile_mj_model(None, solid.astype(np.float64))
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)
        com, xm = _pelvis_kinematics(bm, ps.qpos)
        yaw = np.arctan2(xm[1, 0], xm[0, 0])
        ref = hm.heightmap_raycast(m, d, com, yaw)
        ours = st.obs[i, 51:].reshape(60, 40)
        keep = ~edge_mask(solid, np.asarray(hm.cell_xy(jnp.asarray(com), yaw)))
        np.testing.assert_allclose(ours[keep], ref[keep], atol=1e-4)


def test_euler_angles_against_quaternion_reference():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, q)
        yaw, pitch, roll = (float(v) for v in env_lib._euler(jnp.asarray(mat.reshape(3, 3))))
        rp, rr, ry = quat_to_pitch_roll_yaw(q)
        assert (pitch, roll, yaw) == pytest.approx((rp, rr, ry), abs=1e-4)


# ----------------------------------------------------------------------------- standing / falling
def test_hold_step_stands_for_one_second(env, hold_traj):
    h_ref, _ = _stand_reference(env.biped)
    for t, st in enumerate(hold_traj[1:], 1):
        np.testing.assert_array_equal(st.done, 0.0)
        np.testing.assert_array_equal(st.metrics["fell"], 0.0)
        assert np.all(np.abs(st.obs[:, SL["pitch"]]) < 0.05)
        assert np.all(np.abs(st.obs[:, SL["com_height"]] - h_ref) < 0.02)
        if t >= 10:
            np.testing.assert_array_equal(st.obs[:, SL["contact"]], [[1.0] * 8 + [0.0]] * B)
        np.testing.assert_allclose(st.info["time_s"], 0.02 * t, atol=1e-5)
    last = hold_traj[-1]
    assert np.all(np.abs(last.metrics["distance_m"]) < 0.05)
    np.testing.assert_allclose(last.obs[:, SL["joint_pos"]],
                               np.tile(env.biped.stand_qpos[env.biped.qpos_adr], (B, 1)), atol=0.05)


def test_zero_torque_falls(env, fall_traj):
    done = np.array([st.done for st in fall_traj[1:]])
    fell = np.array([st.metrics["fell"] for st in fall_traj[1:]])
    for i in range(B):
        k = _first(done[:, i] > 0)
        assert k is not None, f"env {i} never fell in 2 s of zero torque"
        assert fell[k, i] == 1.0
        st = fall_traj[k + 1]
        assert st.metrics["success"][i] == 0.0
        assert st.metrics["fail_kind"][i] == -1  # fell on the start flats: no artifact to blame
        assert (st.obs[i, 50] < 0.55) or (abs(st.obs[i, 48]) > 1.0) or (abs(st.obs[i, 49]) > 1.0)
        before = fall_traj[k]
        assert before.metrics["fell"][i] == 0.0 and before.done[i] == 0.0
        assert st.reward[i] < before.reward[i] - 0.5 * env.cfg.reward.fall  # the fall penalty


def test_fall_into_gap_blames_gaps(env, fns, batch0):
    """Dropped over the first hole of a gaps artifact, the robot falls below z = -0.2: done, fell,
    fail_kind = gaps; the other envs keep standing."""
    i = 0  # track 0 at difficulty 1 has a gaps artifact
    seg = env.bank.segments[TRACK_IDS[i]]
    x0, x1, _ = terrain.layout(seg, float(DIFFICULTIES[i]), env.bank.x_origin_m[TRACK_IDS[i]])
    kinds = batch0.info["art_kind"][i]
    g = int(np.flatnonzero(kinds == terrain.ARTIFACT_KINDS.index("gaps"))[0])
    first_seg = env.bank.artifact_segments[TRACK_IDS[i], g, 0]
    assert seg[first_seg, terrain.SOLID] == 0.0  # gaps start with a hole
    hole_c = 0.5 * (x0[first_seg] + x1[first_seg])
    dx = np.zeros(B)
    dx[i] = hole_c - batch0.info["start_x"][i]
    s = _teleport(batch0, dx)
    states = []
    for _ in range(45):
        s = fns["hold"](s)
        states.append(jax.device_get(s))
    done = np.array([st.done for st in states])
    k = _first(done[:, i] > 0)
    assert k is not None
    st = states[k]
    assert st.metrics["fell"][i] == 1.0 and st.metrics["success"][i] == 0.0
    assert st.metrics["fail_kind"][i] == terrain.ARTIFACT_KINDS.index("gaps")
    assert st.pipeline_state.xipos[i, env.biped.pelvis_body, 2] < env.cfg.fall_z_m
    assert st.obs[i, 50] == pytest.approx(2.0)  # nothing beneath: height clipped to the depth
    assert done[:, 1:].max() == 0.0


def test_teleport_to_finish_is_success(env, fns, batch0):
    dx = batch0.info["finish_x"] + 0.3 - batch0.info["start_x"]
    s = jax.device_get(fns["hold"](_teleport(batch0, dx)))
    np.testing.assert_array_equal(s.done, 1.0)
    np.testing.assert_array_equal(s.metrics["success"], 1.0)
    np.testing.assert_array_equal(s.metrics["fell"], 0.0)
    np.testing.assert_array_equal(s.metrics["fail_kind"], -1.0)
    np.testing.assert_allclose(s.metrics["progress_frac"], 1.0)
    np.testing.assert_array_equal(s.metrics["artifacts_passed"], 7.0)
    np.testing.assert_allclose(s.metrics["distance_m"], dx, atol=0.02)
    np.testing.assert_array_equal(s.metrics["detected_kind"], -1.0)  # past the last artifact


@pytest.mark.parametrize("back, seen", [(0.5, True), (0.95, False)])
def test_teleport_before_fourth_artifact(env, fns, batch0, back, seen):
    info = batch0.info
    dx = info["art_x0"][:, 3] - back - info["start_x"]
    s = jax.device_get(fns["hold"](_teleport(batch0, dx)))
    np.testing.assert_array_equal(s.done, 0.0)
    np.testing.assert_array_equal(s.metrics["artifacts_passed"], 3.0)
    np.testing.assert_allclose(s.metrics["distance_m"], dx, atol=0.02)
    frac = dx / (info["finish_x"] - info["start_x"])
    np.testing.assert_allclose(s.metrics["progress_frac"], frac, atol=0.002)
    expected = info["art_kind"][:, 3] if seen else -np.ones(B)
    np.testing.assert_array_equal(s.metrics["detected_kind"], expected)
    np.testing.assert_allclose(s.obs[:, SL["com_height"]][:, 0], _stand_reference(env.biped)[0],
                               atol=0.02)


# ----------------------------------------------------------------------------- pause and reward
@pytest.fixture(scope="module")
def pause_runs(fns, batch0):
    """27 control steps from reset with all actions +1, and with all actions -1."""
    runs = {}
    for a in (1.0, -1.0):
        s, out = batch0, []
        for _ in range(27):
            s = fns["step"](s, actions(a))
            out.append(jax.device_get(s))
        runs[a] = out
    return runs


def test_stand_pause_ignores_actions(pause_runs, hold_traj):
    plus, minus = pause_runs[1.0], pause_runs[-1.0]
    for t in range(24):  # steps that start at time_s <= 0.46 s < 0.5 s
        np.testing.assert_array_equal(plus[t].pipeline_state.qpos, minus[t].pipeline_state.qpos)
        np.testing.assert_array_equal(plus[t].obs, minus[t].obs)
        np.testing.assert_array_equal(plus[t].done, minus[t].done)
        # during the pause a step is the scripted PD hold
        np.testing.assert_allclose(plus[t].pipeline_state.qpos, hold_traj[t + 1].pipeline_state.qpos,
                                   atol=1e-4)
    # the step starting at 0.52 s is not paused: the actions now act
    assert np.abs(plus[-1].obs[:, SL["joint_vel"]] - minus[-1].obs[:, SL["joint_vel"]]).max() > 0.1


def _reward_reference(env, st, action, paused, h_ref):
    """The documented reward, from the observation and the pipeline state, weights from the config."""
    w = env.cfg.reward
    obs = st.obs
    bm = env.biped
    kin = [_pelvis_kinematics(bm, q) for q in st.pipeline_state.qpos]
    xm = np.stack([k[1] for k in kin])
    yaw = np.arctan2(xm[:, 1, 0], xm[:, 0, 0])
    y = np.array([k[0][1] for k in kin])
    vx, pitch, roll, h = obs[:, 42], obs[:, 48], obs[:, 49], obs[:, 50]
    target = 0.0 if paused else env.cfg.target_speed_mps
    a = 0.0 if paused else np.clip(action, -1, 1)  # ignored actions cost nothing in the pause
    ones = np.ones_like(vx)
    return {"progress": w.progress * np.minimum(vx, target),
            "speed": w.speed * np.exp(-(vx - target) ** 2 / w.speed_width), "alive": w.alive * ones,
            "upright": w.upright * np.cos(pitch) * np.cos(roll),
            "height": w.height * np.exp(-(h - h_ref) ** 2 / w.height_width),
            "lateral": -w.lateral * (np.abs(y) + np.abs(yaw)),
            "torque": -w.torque * np.mean(a ** 2) * ones, "fall": -w.fall * st.metrics["fell"]}


def _check_reward(st, ref):
    """The reward and each logged reward/<term> metric against the reference terms."""
    np.testing.assert_allclose(st.reward, sum(ref.values()), atol=1e-4)
    assert {k for k in st.metrics if k.startswith("reward/")} == {f"reward/{k}" for k in ref}
    for k, v in ref.items():
        np.testing.assert_allclose(st.metrics[f"reward/{k}"], v, atol=1e-4, err_msg=k)


def test_reward_against_reference(env, hold_traj, fall_traj, pause_runs):
    _, h_ref = _stand_reference(env.biped)  # the keyframe's pelvis CoM height
    for st in hold_traj[1::7]:
        _check_reward(st, _reward_reference(env, st, 0.0, True, h_ref))
    for st in fall_traj[1:40:3]:
        _check_reward(st, _reward_reference(env, st, 0.0, False, h_ref))
    for t in (3, 26):
        st = pause_runs[1.0][t]
        _check_reward(st, _reward_reference(env, st, 1.0, t < 25, h_ref))
    fall_steps = [st for st in fall_traj if np.any(st.metrics["fell"] > 0)]
    assert fall_steps  # the fall term is exercised: checked at the first fall
    _check_reward(fall_steps[0], _reward_reference(env, fall_steps[0], 0.0, False, h_ref))
    # standing still scores about alive + speed(0) + upright + height
    w = env.cfg.reward
    np.testing.assert_allclose(hold_traj[-1].reward, w.alive + w.speed + w.upright + w.height,
                               atol=0.1)


# ----------------------------------------------------------------------------- no recompilation
def test_no_recompilation_across_tracks_and_difficulties(fns, traces, backend_compiles, batch0,
                                                         hold_traj, fall_traj):
    """New tracks, difficulties and states (from reset, step, hold_step, or the host) reuse the one
    compiled reset/step/hold_step: no new trace and no XLA compile.

    (`_cache_size()` is not the measure: it counts C++ dispatch entries, which grow when the same
    shapes arrive once as numpy arrays and once as jax Arrays, without any compile.)"""
    keys = jax.random.split(jax.random.PRNGKey(3), B)
    diffs = jnp.asarray([0.1, 0.9, 0.0, 0.7], jnp.float32)
    ids = jnp.asarray([3, 2, 1, 0], jnp.int32)
    a1, a2, a0 = actions(0.3), actions(-0.2), actions(0.0)
    jax.block_until_ready((keys, diffs, ids, a1, a2, a0))
    n0 = len(backend_compiles)
    other = fns["reset"](keys, diffs, ids)
    s = fns["step"](other, a1)
    s = fns["hold"](s)
    s = fns["step"](s, a2)
    fns["hold"](jax.device_get(s))
    fns["step"](fall_traj[-1], a0)  # a fallen state, from the host
    last = fns["hold"](batch0)
    jax.block_until_ready(last)
    assert len(backend_compiles) == n0
    for name in ("reset", "step", "hold"):
        assert traces[name] == 1, name
    np.testing.assert_array_equal(np.asarray(other.info["track_id"]), [3, 2, 1, 0])
    np.testing.assert_allclose(np.asarray(other.info["difficulty"]), [0.1, 0.9, 0.0, 0.7])
    assert not np.allclose(np.asarray(other.info["boxes"]), batch0.info["boxes"])


# ----------------------------------------------------------------------------- detector
def _info(x0, x1, kinds):
    return {"art_x0": jnp.asarray(x0, jnp.float32), "art_x1": jnp.asarray(x1, jnp.float32),
            "art_kind": jnp.asarray(kinds, jnp.int32)}


F = terrain.FAR_X_M


@pytest.mark.parametrize("x, index, kind, dist", [
    (0.0, 0, -1, 2.0),     # next artifact 2 m ahead: not yet in range
    (1.0, 0, -1, 1.0),     # 1.0 m > 0.9 m
    (1.2, 0, 0, 0.8),      # within 0.9 m: kind shows
    (2.5, 0, 0, -0.5),     # on the artifact: still the next one not yet passed
    (3.0, 0, 0, -1.0),     # at its end (x1 >= x): not yet passed
    (3.5, 1, -1, 1.5),     # past it: the next one, out of range
    (4.3, 1, 1, 0.7),
    (9.5, 2, 2, -0.5),
    (10.5, -1, -1, np.inf),  # past the last artifact (padding slot has kind -1)
])
def test_detect_hand_made(env, x, index, kind, dist):
    info = _info([2.0, 5.0, 9.0, F], [3.0, 6.0, 10.0, F], [0, 1, 2, -1])
    det = env.detect(info, jnp.float32(x))
    assert int(det["index"]) == index
    assert int(det["kind"]) == kind
    assert float(det["dist_m"]) == pytest.approx(dist, abs=1e-5)


def test_detect_past_last_without_padding_and_on_walk(env):
    det = env.detect(_info([2.0, 5.0], [3.0, 6.0], [2, 0]), jnp.float32(7.0))
    assert (int(det["index"]), int(det["kind"])) == (-1, -1) and np.isinf(float(det["dist_m"]))
    walk = _info([F] * 7, [F] * 7, [-1] * 7)
    for x in (0.0, 5.0, 30.0):
        det = env.detect(walk, jnp.float32(x))
        assert (int(det["index"]), int(det["kind"])) == (-1, -1)


def test_detect_matches_metrics(env, batch0):
    """At reset, the detected kind in the metrics is env.detect of the info at the CoM x."""
    for i in range(B):
        info = {k: jnp.asarray(batch0.info[k][i]) for k in ("art_x0", "art_x1", "art_kind")}
        det = env.detect(info, jnp.asarray(batch0.pipeline_state.xipos[i, env.biped.pelvis_body, 0]))
        assert float(batch0.metrics["detected_kind"][i]) == int(det["kind"])
        assert int(det["index"]) == 0 and float(det["dist_m"]) > 2.0


# ----------------------------------------------------------------------------- other configs
@pytest.fixture(scope="module")
def random_env():
    return env_lib.make_env("mixed", init="random", n_tracks=2, **MJX_TORQUE)


@pytest.fixture(scope="module")
def random_resets(random_env):
    reset = jax.jit(random_env.reset)
    return [jax.device_get(reset(jax.random.PRNGKey(k))) for k in range(4)]


def test_random_init(random_env, random_resets):
    bm = random_env.biped
    lo, hi = bm.joint_range[:, 0], bm.joint_range[:, 1]
    qs = []
    for s in random_resets:
        q = s.pipeline_state.qpos[bm.qpos_adr]
        assert np.all(q >= lo - 1e-6) and np.all(q <= hi + 1e-6)
        # within random_joint_scale (0.5) of half the range around the keyframe
        assert np.all(np.abs(q - bm.stand_qpos[bm.qpos_adr]) <= 0.25 * (hi - lo) + 1e-5)
        np.testing.assert_allclose(s.obs[SL["joint_pos"]], q, atol=1e-6)
        soles = s.pipeline_state.geom_xpos[bm.sole_geoms.reshape(-1)]
        ground = terrain_height_np(_solid(s.info["boxes"]), soles[:, :2])
        assert np.min(soles[:, 2] - 0.02 - ground) == pytest.approx(1e-3, abs=2e-5)
        assert np.isfinite(s.obs).all()
        qs.append(q)
    for i in range(len(qs)):
        for j in range(i + 1, len(qs)):
            assert np.abs(qs[i] - qs[j]).max() > 0.05


@pytest.mark.slow
def test_random_init_has_no_pause(random_env, random_resets):
    step = jax.jit(random_env.step)
    a = step(random_resets[0], jnp.ones(12))
    b = step(random_resets[0], -jnp.ones(12))
    assert np.abs(np.asarray(a.pipeline_state.qvel) - np.asarray(b.pipeline_state.qvel)).max() > 0.1


def test_detector_one_hot(batch0):
    env1 = env_lib.make_env("mixed", n_tracks=1, detector_one_hot=True, **MJX_TORQUE)
    assert env1.observation_size == OBS + 3
    s = jax.eval_shape(env1.reset, jax.random.PRNGKey(0))
    assert s.obs.shape == (OBS + 3,)
    assert jax.eval_shape(env1.step, s, jnp.zeros(12)).obs.shape == (OBS + 3,)
    # the appended 3 are the one-hot of the detected kind (zeros when none)
    data = jax.tree.map(jnp.asarray, index(batch0.pipeline_state, 0))
    com_x = float(batch0.pipeline_state.xipos[0, env1.biped.pelvis_body, 0])
    contact = jnp.asarray(batch0.obs[0, SL["contact"]])
    observe = jax.jit(lambda info: env1._observe(data, info, contact)[0])
    base = {"boxes": jnp.asarray(batch0.info["boxes"][0])}
    for start, kind, expected in ((0.5, 2, [0, 0, 1]), (0.3, 0, [1, 0, 0]), (2.0, 1, [0, 0, 0])):
        info = dict(base, **_info([com_x + start] + [F] * 6, [com_x + start + 1] + [F] * 6,
                                  [kind] + [-1] * 6))
        obs = np.asarray(observe(info))
        np.testing.assert_array_equal(obs[-3:], expected)
        np.testing.assert_allclose(obs[:OBS], batch0.obs[0], atol=1e-6)


def test_config_errors():
    with pytest.raises(ValueError, match="'sideways'"):
        env_lib.make_env(init="sideways")
    with pytest.raises(ValueError, match=r"2\.0"):
        env_lib.make_env(difficulty=2.0)
    with pytest.raises(ValueError, match="'hills'"):
        env_lib.make_env("hills", n_tracks=1)
    with pytest.raises(ValueError, match="n_tracks must be >= 1, got 0"):
        env_lib.make_env(n_tracks=0)
    with pytest.raises(KeyError, match="no_such_key"):
        env_lib.make_env(no_such_key=1)


def test_blame_kind_hand_cases():
    """Two artifacts with 1.2 m of flat between them (shorter than 0.9 m detection + 1.0 m after):
    a fall in the overlap is the next artifact's, where the detector already names it."""
    x0 = np.array([5.0, 7.0, terrain.FAR_X_M])
    x1 = np.array([5.8, 8.0, terrain.FAR_X_M])
    kind = np.array([1, 2, -1])  # gaps, then stairs, then padding
    cases = {0.0: -1,    # start flats
             4.2: 1,     # 0.8 m before the gaps: in its detection zone
             5.5: 1,     # on the gaps
             6.05: 1,    # 0.25 m past the gaps, stairs 0.95 m ahead (not detected yet)
             6.2: 2,     # 0.8 m before the stairs: theirs, though within 1 m of the gaps' end
             8.9: 2,     # 0.9 m past the stairs
             9.1: -1}    # past every artifact's window
    for x, want in cases.items():
        got = int(env_lib.blame_kind(jnp.float32(x), x0, x1, kind, 0.9, 1.0))
        assert got == want, (x, got, want)


def test_kinds_met_hand_cases():
    """Kinds whose detection zone (0.9 m before the start) the CoM has entered, in
    (jumps, gaps, stairs) order; padding (kind -1) never counts."""
    x0 = np.array([5.0, 7.0, 9.0, terrain.FAR_X_M])
    kind = np.array([1, 2, 1, -1])  # gaps, stairs, gaps, padding
    cases = {0.0: [0, 0, 0],
             4.05: [0, 0, 0],   # 0.95 m before the gaps
             4.15: [0, 1, 0],   # 0.85 m before: in its zone
             6.2: [0, 1, 1],    # 0.8 m before the stairs
             20.0: [0, 1, 1],   # the second gaps add nothing; no jumps on this track
             1e9: [0, 1, 1]}    # beyond the padding's x: padding is not a kind
    for x, want in cases.items():
        got = np.asarray(env_lib.kinds_met(jnp.float32(x), x0, kind, 0.9)).tolist()
        assert got == want, (x, got, want)


def _pushes(e, n=20_000, scale=0.5):
    """`e._push` from rest on n keys: (started (n,), force (n, 3) [N], time left (n,) [s])."""
    info = {"rng": jax.random.split(jax.random.PRNGKey(3), n),
            "push_left_s": jnp.zeros(n), "push_scale": jnp.full(n, scale, jnp.float32),
            "push_force": jnp.zeros((n, 3))}
    _, force, left = jax.jit(jax.vmap(e._push))(info)
    return np.asarray(left) > 0, np.asarray(force), np.asarray(left)


def test_push_draws(env):
    """From rest a push starts with probability dt / interval (0.02 / 2 = 1%: about 200 of
    20,000, sd 14), horizontal, in every direction; "uniform" forces spread over (0, 0.5 * 150 N]
    with mean 37.5 N (sd of the mean ~1.5 N), "max" ones are all 75 N. A running push keeps its
    force and counts down; push_scale 0 never pushes."""
    c = env.curriculum_cfg
    assert (c.push_magnitude, c.max_push_N, c.push_interval_s, env.dt) == ("uniform", 150.0, 2.0,
                                                                           pytest.approx(0.02))
    started, force, left = _pushes(env)
    assert 140 <= started.sum() <= 260
    np.testing.assert_allclose(left[started], c.push_duration_s)
    np.testing.assert_array_equal(force[~started], 0.0)
    np.testing.assert_array_equal(force[:, 2], 0.0)
    mag = np.linalg.norm(force[started], axis=1)
    assert mag.max() <= 75.0 + 1e-3 and mag.min() < 10.0 and mag.max() > 65.0
    assert abs(mag.mean() - 37.5) < 6.0
    angle = np.arctan2(force[started, 1], force[started, 0])
    assert np.histogram(angle, bins=4, range=(-np.pi, np.pi))[0].min() > 20  # all four quadrants

    cfg_max = default_curriculum_config()
    cfg_max.push_magnitude = "max"
    e_max = env_lib.make_env("walk", n_tracks=1, curriculum_cfg=cfg_max, **MJX_TORQUE)
    started_m, force_m, _ = _pushes(e_max)
    np.testing.assert_array_equal(started_m, started)  # the same keys start the same pushes
    np.testing.assert_allclose(np.linalg.norm(force_m[started_m], axis=1), 75.0, rtol=1e-5)

    running = {"rng": jax.random.PRNGKey(0), "push_left_s": jnp.float32(0.1),
               "push_scale": jnp.float32(0.5), "push_force": jnp.array([10.0, -5.0, 0.0])}
    _, f, t = env._push(running)
    np.testing.assert_allclose(f, [10.0, -5.0, 0.0])
    assert float(t) == pytest.approx(0.1 - env.dt)
    assert not _pushes(env, scale=0.0)[0].any()


def test_push_magnitude_error():
    c = default_curriculum_config()
    c.push_magnitude = "huge"
    with pytest.raises(ValueError, match="push_magnitude 'huge'"):
        env_lib.make_env(n_tracks=1, curriculum_cfg=c)


@pytest.mark.parametrize("interval_s", [0.0, -2.0])
def test_push_interval_error(interval_s):
    c = default_curriculum_config()
    c.push_interval_s = interval_s
    with pytest.raises(ValueError, match=f"push_interval_s must be > 0 s .*got {interval_s}"):
        env_lib.make_env(n_tracks=1, curriculum_cfg=c)

"""Terrain slots and contacts (biped_switch.model, env.sole_contacts): the culled broad phase
(max_geom_pairs = 32) finds the same sole-box contacts as all 8 x 96 pairs, on many random
feet-on-terrain poses, and both agree with CPU MuJoCo on a model compiled with the real boxes."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from biped_switch.simulation import env as env_lib
from biped_switch.simulation import model as model_lib
from biped_switch.simulation import terrain
from biped_switch.config import default_model_config

from helpers import env_boxes, quat_yaw, terrain_height_np

N_POSES = 128
TOUCH_M = 1e-3


@pytest.fixture(scope="module")
def models():
    culled = model_lib.build_model()
    cfg = default_model_config()
    cfg.max_geom_pairs = 0
    full = model_lib.build_model(cfg)
    return culled, full


def _contact_fn(bm):
    d0 = mjx.make_data(bm.mj_model, impl="jax")

    def f(qpos, boxes):
        m = model_lib.with_boxes(bm.mjx_model, bm.box_start, boxes)
        d = mjx.collision(m, mjx.kinematics(m, d0.replace(qpos=qpos)))
        c = d._impl.contact
        return c.geom, c.dist, env_lib.sole_contacts(d, bm.sole_geoms)

    return jax.jit(jax.vmap(f))


def make_poses(bm, n, seed):
    """Random joints near the standing keyframe, small random yaw, on random tracks of all kinds at
    random x (half of them with one sole sphere within 3 cm of a box edge: stair edges, jump blocks,
    gap rims), lowered so the lowest sole sphere above a box penetrates it by 0.1..4 mm."""
    rng = np.random.default_rng(seed)
    m = bm.mj_model
    d = mujoco.MjData(m)
    sole_ids = bm.sole_geoms.reshape(-1)
    qs, slots, tracks = [], [], []
    i = 0
    while len(qs) < n:
        i += 1
        kind = terrain.KINDS[i % len(terrain.KINDS)]
        diff = 1.0 if rng.random() < 0.75 else float(rng.uniform(0.2, 1.0))
        t = terrain.generate_track(int(rng.integers(100_000)), kind, diff)
        q = bm.stand_qpos.copy()
        q[bm.qpos_adr] = np.clip(q[bm.qpos_adr] + rng.uniform(-0.3, 0.3, 12),
                                 bm.joint_range[:, 0], bm.joint_range[:, 1])
        q[3:7] = quat_yaw(rng.uniform(-0.3, 0.3))
        q[:3] = 0.0, 0.0, 1.0
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        soles = d.geom_xpos[sole_ids].copy()
        solid = t.boxes
        if t.artifacts and i % 2 == 0:
            _, a0, a1 = t.artifacts[rng.integers(len(t.artifacts))]
            near = solid[(solid[:, 0] > a0 - 0.5) & (solid[:, 0] < a1 + 0.5)]
            b = near[rng.integers(len(near))]
            edge = b[0] + rng.choice([-1.0, 1.0]) * b[3]
            x = edge - soles[rng.integers(8), 0] + rng.uniform(-0.03, 0.03)
        elif t.artifacts:
            _, a0, a1 = t.artifacts[rng.integers(len(t.artifacts))]
            x = rng.uniform(a0 - 0.3, a1 + 0.3)
        else:
            x = rng.uniform(0.0, t.finish_x_m)
        half_w = 0.5 * t.width_m
        y = rng.uniform(-0.2, 0.2) if i % 4 else rng.choice([-1, 1]) * (half_w - rng.uniform(0.1, 0.2))
        ground = terrain_height_np(solid, soles[:, :2] + [x, y])
        over = ground > -100.0
        if not over.any():
            continue
        clearance = np.min(soles[over, 2] - 0.02 - ground[over])
        q[0], q[1] = x, y
        q[2] = 1.0 - clearance - rng.uniform(1e-4, 4e-3)
        qs.append(q)
        slots.append(env_boxes(t))
        tracks.append(t)
    return np.array(qs), np.array(slots), tracks


@pytest.fixture(scope="module")
def poses(models):
    return make_poses(models[0], N_POSES, seed=0)


@pytest.fixture(scope="module")
def contact_fns(models):
    """jit(vmap) contact functions of the culled and the full model (batch of N_POSES)."""
    return [_contact_fn(bm) for bm in models]


@pytest.fixture(scope="module")
def results(contact_fns, poses):
    q, slots, _ = poses
    args = jnp.asarray(q, jnp.float32), jnp.asarray(slots, jnp.float32)
    return [jax.device_get(f(*args)) for f in contact_fns]


def _touching(geom, dist):
    on = dist < TOUCH_M
    return {(int(a), int(b)): float(c) for (a, b), c in zip(geom[on], dist[on])}


def test_contact_array_sizes(results):
    (g32, d32, _), (g0, d0, _) = results
    assert g32.shape == (N_POSES, 32, 2)
    assert g0.shape == (N_POSES, 8 * 96, 2)


def test_culled_contacts_equal_all_pairs(models, results):
    culled, _ = models
    (g32, d32, _), (g0, d0, _) = results
    soles = set(culled.sole_geoms.reshape(-1).tolist())
    boxes = set(range(culled.box_start, culled.box_start + culled.box_capacity))
    n_touch, n_both_feet, n_multi_box = 0, 0, 0
    for i in range(N_POSES):
        a, b = _touching(g32[i], d32[i]), _touching(g0[i], d0[i])
        assert set(a) == set(b), (i, sorted(set(b) - set(a)), sorted(set(a) - set(b)))
        for k in a:
            assert a[k] == pytest.approx(b[k], abs=1e-5)
            assert k[0] in soles and k[1] in boxes
        n_touch += bool(a)
        feet = {int(g in culled.sole_geoms[1]) for g, _ in a}
        n_both_feet += len(feet) == 2
        n_multi_box += len({bx for _, bx in a}) > 1
    # the poses do exercise contacts: most touch, several with both feet or on two boxes at once
    assert n_touch >= 0.9 * N_POSES
    assert n_both_feet >= 10
    assert n_multi_box >= 10


def test_sole_contacts_equal(models, results):
    (_, _, s32), (_, _, s0) = results
    np.testing.assert_array_equal(s32, s0)
    assert s32.shape == (N_POSES, 8)
    assert set(np.unique(s32)) <= {0.0, 1.0}
    assert 0 < s32.mean() < 1


def test_sole_contacts_from_contact_list(models, results):
    """env.sole_contacts(i) == 1 iff some pair with sole sphere i has dist < 1 mm."""
    culled, _ = models
    g, dist, s = results[1]
    ids = culled.sole_geoms.reshape(-1)
    for i in range(0, N_POSES, 7):
        touching = {a for a, _ in _touching(g[i], dist[i])}
        np.testing.assert_array_equal(s[i], [float(k in touching) for k in ids])


def test_lowest_sole_penetrates(models, poses, results):
    """The pose generator did what it says: the deepest contact is 0.1..4 mm deep in every pose."""
    _, dist, _ = results[1]
    deepest = dist.min(axis=1)
    assert np.all(deepest < 0.0)
    assert np.all(deepest > -0.03)


def test_mjx_contacts_match_cpu_mujoco(models, poses, results):
    """On 16 poses, the penetrating sole-box pairs and depths equal CPU MuJoCo's on a model compiled
    with the real boxes (the C collision pipeline: BVH midphase, its own sphere-box code)."""
    q, _, tracks = poses
    g, dist, _ = results[0]
    compared = 0
    for i in range(16):
        m = model_lib.compile_mj_model(None, tracks[i].boxes)
        d = mujoco.MjData(m)
        d.qpos[:] = q[i]
        mujoco.mj_forward(m, d)
        assert m.geom(0).name == "box0"  # box ids are 0..95, below the robot's geom ids
        ref = {(int(max(c.geom)), int(min(c.geom))): float(c.dist) for c in d.contact[: d.ncon]}
        ours = {k: v for k, v in _touching(g[i], dist[i]).items() if v < 0}
        # MJX slots hold every segment (holes parked); the CPU model holds only the solid boxes
        seg_solid = np.flatnonzero(tracks[i].segments[:, terrain.SOLID] > 0.5)
        slot_to_cpu = {int(s): j for j, s in enumerate(seg_solid)}
        ours = {(a, slot_to_cpu[b]): v for (a, b), v in ours.items()}
        amb = 2e-5  # pairs right at zero depth may round either way in float32
        assert {k for k, v in ours.items() if v < -amb} <= set(ref)
        assert {k for k, v in ref.items() if v < -amb} <= set(ours)
        for k in set(ours) & set(ref):
            assert ours[k] == pytest.approx(ref[k], abs=2e-5)
            compared += 1
    assert compared >= 16


def test_sole_contacts_count_touching_not_hovering_spheres(models, contact_fns):
    """env.sole_contacts counts a sole as touching when it penetrates (signed distance < 0): MJX's
    sphere-box collider reports dist = 1.0 for every separated pair, so a sole 0.5 mm above the
    ground (0.5 mm by CPU MuJoCo's mj_geomDistance) reads 0, and 0.5 mm into it reads 1."""
    culled, _ = models
    t = terrain.generate_track(0, "walk")
    q = culled.stand_qpos.copy()
    m = culled.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    ids = culled.sole_geoms.reshape(-1)
    q[2] += 0.5e-3 - (d.geom_xpos[ids, 2].min() - 0.02)  # all 8 soles 0.5 mm above z = 0
    cpu = model_lib.compile_mj_model(None, t.boxes)
    dc = mujoco.MjData(cpu)
    dc.qpos[:] = q
    mujoco.mj_forward(cpu, dc)
    b = t.boxes  # box i is geom i in the CPU model; take the box under each sole
    under = [int(np.flatnonzero(np.abs(dc.geom_xpos[g, 0] - b[:, 0]) <= b[:, 3])[0]) for g in ids]
    gap = [mujoco.mj_geomDistance(cpu, dc, int(g), k, 0.01, None) for g, k in zip(ids, under)]
    np.testing.assert_allclose(gap, 0.5e-3, atol=2e-5)
    args = (jnp.asarray(np.tile(q, (N_POSES, 1)), jnp.float32),
            jnp.asarray(np.tile(env_boxes(t), (N_POSES, 1, 1)), jnp.float32))
    for f in contact_fns:
        _, _, soles = jax.device_get(f(*args))
        np.testing.assert_array_equal(soles[0], np.zeros(8))
    q[2] -= 1e-3  # now 0.5 mm into the ground
    args = (jnp.asarray(np.tile(q, (N_POSES, 1)), jnp.float32), args[1])
    for f in contact_fns:
        _, _, soles = jax.device_get(f(*args))
        np.testing.assert_array_equal(soles[0], np.ones(8))


# ----------------------------------------------------------------------------- model slots
def test_with_boxes_matches_compiled_model():
    t = terrain.generate_track(3, "mixed")
    slots = env_boxes(t)
    bm = model_lib.build_model()
    m = model_lib.with_boxes(bm.mjx_model, bm.box_start, jnp.asarray(slots, jnp.float32))
    # compile_mj_model fills slots with the same boxes (holes/padding parked likewise)
    ref = model_lib.compile_mj_model(None, slots)
    sl = slice(bm.box_start, bm.box_start + bm.box_capacity)
    np.testing.assert_allclose(np.asarray(m.geom_pos)[sl], ref.geom_pos[sl], atol=1e-5)
    np.testing.assert_allclose(np.asarray(m.geom_size)[sl], ref.geom_size[sl], atol=1e-6)
    np.testing.assert_allclose(np.asarray(m.geom_rbound)[sl], ref.geom_rbound[sl], atol=1e-6)
    # the robot's geoms are untouched
    rest = np.ones(bm.mj_model.ngeom, bool)
    rest[sl] = False
    np.testing.assert_array_equal(np.asarray(m.geom_pos)[rest], np.asarray(bm.mjx_model.geom_pos)[rest])


def test_build_model_indices():
    bm = model_lib.build_model()
    m = bm.mj_model
    assert bm.sole_geoms.shape == (2, 4)
    for s, row in zip("lr", bm.sole_geoms):
        assert [m.geom(int(g)).name for g in row] == [f"{s}_sole_{c}" for c in model_lib.SOLE_CORNERS]
    assert m.body(bm.pelvis_body).name == "pelvis"
    for n, qa, da in zip(model_lib.JOINT_NAMES, bm.qpos_adr, bm.dof_adr):
        j = m.joint(n)
        assert m.jnt_qposadr[j.id] == qa and m.jnt_dofadr[j.id] == da
    np.testing.assert_array_equal(bm.gear, [60, 150, 200, 250, 100, 60] * 2)
    assert bm.dt_s == pytest.approx(0.02)
    np.testing.assert_array_equal(m.geom_group[bm.box_start: bm.box_start + 96], 2)
    assert (m.geom_group[bm.sole_geoms.reshape(-1)] == 0).all()

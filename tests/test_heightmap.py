"""The body-frame heightmap (biped_switch.heightmap): hand-computed grids, the mj_ray oracle on
generated tracks, and the nearest-`max_boxes` preselection it relies on."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from biped_switch.simulation import heightmap as hm
from biped_switch.simulation import model as model_lib
from biped_switch.simulation import terrain

from helpers import edge_mask, env_boxes, rect_distance, terrain_height_np

ROWS, COLS = 60, 40


def box(x0, x1, y0, y1, top, thick=0.3):
    return [0.5 * (x0 + x1), 0.5 * (y0 + y1), top - 0.5 * thick,
            0.5 * (x1 - x0), 0.5 * (y1 - y0), 0.5 * thick]


def hmap(boxes, pos, yaw=0.0, **kw):
    return np.asarray(hm.heightmap(jnp.asarray(boxes, jnp.float32), jnp.asarray(pos, jnp.float32),
                                   jnp.float32(yaw), **kw))


# ----------------------------------------------------------------------------- grid geometry
def test_cell_offsets_by_hand():
    off = hm.cell_offsets()
    assert off.shape == (ROWS, COLS, 2)
    assert off[0, 0, 0] == pytest.approx(-0.5875) and off[59, 0, 0] == pytest.approx(0.8875)
    assert off[0, 0, 1] == pytest.approx(-0.4875) and off[0, 39, 1] == pytest.approx(0.4875)
    np.testing.assert_allclose(np.diff(off[:, 0, 0]), 0.025)
    np.testing.assert_allclose(np.diff(off[0, :, 1]), 0.025)
    assert hm.grid_radius_m() == pytest.approx(np.hypot(0.8875, 0.4875))


def test_cell_xy_rotates_with_yaw():
    pos = jnp.array([2.0, -1.0, 1.0])
    xy0 = np.asarray(hm.cell_xy(pos, 0.0))
    np.testing.assert_allclose(xy0[59, 39], [2.8875, -0.5125], atol=1e-6)
    xy90 = np.asarray(hm.cell_xy(pos, np.pi / 2))
    # facing +y: forward offset f goes to +y, a left offset l goes to -x
    np.testing.assert_allclose(xy90[59, 39], [2.0 - 0.4875, -1.0 + 0.8875], atol=1e-6)


def test_bad_grid_config_is_rejected():
    from biped_switch.config import default_env_config
    cfg = default_env_config()
    cfg.shape.grid_forward = 50
    with pytest.raises(ValueError, match="50x40"):
        hm.cell_offsets(cfg.heightmap, cfg.shape)


# ----------------------------------------------------------------------------- hand-computed values
def test_flat_box_under_robot_is_half_everywhere():
    out = hmap([box(-5, 5, -5, 5, 0.0)], [0.0, 0.0, 1.0])
    assert out.shape == (ROWS, COLS)
    np.testing.assert_allclose(out, 0.5, atol=1e-6)
    np.testing.assert_allclose(hmap([box(-5, 5, -5, 5, 0.0)], [0.0, 0.0, 1.0], depth_m=1.0), 1.0)


def test_nothing_below_is_one():
    np.testing.assert_allclose(hmap([box(10, 11, -5, 5, 0.0)], [0.0, 0.0, 1.0]), 1.0)
    # a box covering only x <= 0.3: cells ahead of 0.3 m see nothing
    out = hmap([box(-5, 0.3, -5, 5, 0.0)], [0.0, 0.0, 1.0])
    fwd = -0.6 + 0.025 * (np.arange(ROWS) + 0.5)
    np.testing.assert_allclose(out[fwd < 0.3], 0.5, atol=1e-6)
    np.testing.assert_allclose(out[fwd > 0.3], 1.0)


def test_box_above_com_is_zero():
    np.testing.assert_allclose(hmap([box(-5, 5, -5, 5, 1.5)], [0.0, 0.0, 1.0]), 0.0)
    # 0.4 m below a CoM at 1.0 m: (1.0 - 0.6) / 2 = 0.2
    np.testing.assert_allclose(hmap([box(-5, 5, -5, 5, 0.6)], [0.0, 0.0, 1.0]), 0.2, atol=1e-6)


def test_highest_of_overlapping_boxes_wins():
    out = hmap([box(-5, 5, -5, 5, 0.0), box(-5, 5, -5, 5, 0.4), box(-5, 5, -5, 5, 0.2)],
               [0.0, 0.0, 1.0])
    np.testing.assert_allclose(out, 0.3, atol=1e-6)


def test_box_ahead_shows_in_high_rows_only():
    # forward offsets of rows 44..51 are 0.5125 .. 0.6875, the only ones inside [0.5, 0.7]
    out = hmap([box(0.5, 0.7, -5, 5, 0.3)], [0.0, 0.0, 1.0])
    rows = np.where((out < 1.0).any(axis=1))[0]
    np.testing.assert_array_equal(rows, np.arange(44, 52))
    np.testing.assert_allclose(out[44:52], 0.35, atol=1e-6)
    # the same box behind the robot shows in low rows
    out = hmap([box(-0.5, -0.3, -5, 5, 0.3)], [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(np.where((out < 1.0).any(axis=1))[0], np.arange(4, 12))


def test_box_on_the_left_shows_in_high_columns_only():
    # lateral offsets of columns 28..35 are 0.2125 .. 0.3875, the only ones inside [0.2, 0.4]
    out = hmap([box(-5, 5, 0.2, 0.4, 0.0)], [0.0, 0.0, 1.0])
    cols = np.where((out < 1.0).any(axis=0))[0]
    np.testing.assert_array_equal(cols, np.arange(28, 36))
    np.testing.assert_allclose(out[:, 28:36], 0.5, atol=1e-6)


def test_yaw_quarter_turn():
    # facing +y, a box at +y is ahead: high rows, all columns
    out = hmap([box(-5, 5, 0.5, 0.7, 0.3)], [0.0, 0.0, 1.0], yaw=np.pi / 2)
    np.testing.assert_array_equal(np.where((out < 1.0).any(axis=1))[0], np.arange(44, 52))
    assert (out[44:52] < 1.0).all()
    # facing +y, a box at -x is on the robot's left: high columns
    out = hmap([box(-0.4, -0.2, -5, 5, 0.0)], [0.0, 0.0, 1.0], yaw=np.pi / 2)
    np.testing.assert_array_equal(np.where((out < 1.0).any(axis=0))[0], np.arange(28, 36))
    # facing -x (yaw = pi), a box at +x is behind: low rows
    out = hmap([box(0.3, 0.5, -5, 5, 0.0)], [0.0, 0.0, 1.0], yaw=np.pi)
    np.testing.assert_array_equal(np.where((out < 1.0).any(axis=1))[0], np.arange(4, 12))


def test_follows_body_position():
    b = [box(3.5, 3.7, -5, 5, 0.3), box(-10, 10, -5, 5, 0.0)]
    out = hmap(b, [3.0, 0.0, 1.3])
    np.testing.assert_array_equal(np.where((out < 0.65 - 1e-3).any(axis=1))[0], np.arange(44, 52))
    np.testing.assert_allclose(out[44:52], 0.5, atol=1e-6)  # (1.3 - 0.3) / 2
    np.testing.assert_allclose(out[:44], 0.65, atol=1e-6)  # (1.3 - 0) / 2


def test_terrain_height():
    b = jnp.asarray([box(0, 1, -1, 1, 0.2), box(0.5, 2, -1, 1, 0.5)], jnp.float32)
    xy = jnp.array([[0.25, 0.0], [0.75, 0.0], [1.5, 0.9], [3.0, 0.0], [1.0, 1.5]])
    np.testing.assert_allclose(np.asarray(hm.terrain_height(b, xy)),
                               [0.2, 0.5, 0.5, hm.NO_GROUND_Z_M, hm.NO_GROUND_Z_M], atol=1e-6)


# ----------------------------------------------------------------------------- against mj_ray
@pytest.fixture(scope="module")
def hmap_batch():
    return jax.jit(jax.vmap(hm.heightmap, in_axes=(None, 0, 0)))


@pytest.mark.parametrize("kind, seed, difficulty", [("stairs", 1, 1.0), ("jumps", 2, 1.0),
                                                    ("gaps", 3, 1.0), ("mixed", 4, 1.0),
                                                    ("mixed", 5, 0.6)])
def test_matches_raycast_oracle(hmap_batch, kind, seed, difficulty):
    track = terrain.generate_track(seed, kind, difficulty)
    boxes = track.boxes
    m = model_lib.compile_mj_model(None, boxes)
    d = mujoco.MjData(m)
    rng = np.random.default_rng(seed)
    d.qpos[:3] = [rng.uniform(0, 20), 0.3, 1.0]  # the robot anywhere: the oracle only sees group 2
    mujoco.mj_forward(m, d)
    n = 6
    starts = np.array([a[1] for a in track.artifacts])
    x = rng.uniform(0.0, track.finish_x_m, n)
    x[:3] = starts[:3] - rng.uniform(0.0, 0.6, 3)  # just before artifacts: stairs/blocks/gaps ahead
    x[3] = starts[1] + 0.2  # on an artifact
    pos = np.stack([x, rng.uniform(-0.3, 0.3, n), rng.uniform(0.25, 1.5, n)], axis=-1)
    pos[0, 2] = 1.0
    yaw = rng.uniform(-np.pi, np.pi, n)
    yaw[0], yaw[1] = 0.0, np.pi / 2
    ours = np.asarray(hmap_batch(jnp.asarray(boxes, jnp.float32), jnp.asarray(pos, jnp.float32),
                                 jnp.asarray(yaw, jnp.float32)))
    informative = 0
    for i in range(n):
        ref = hm.heightmap_raycast(m, d, pos[i], yaw[i])
        xy = np.asarray(hm.cell_xy(jnp.asarray(pos[i]), yaw[i]))
        keep = ~edge_mask(boxes, xy)
        assert keep.mean() > 0.9
        np.testing.assert_allclose(ours[i][keep], ref[keep], atol=1e-4, err_msg=f"pose {i}")
        informative += len(np.unique(np.round(ref[keep], 3))) > 1
    assert informative >= 3  # the poses saw more than one height


def test_raycast_oracle_ignores_the_robot():
    """The oracle's rays skip the robot's geoms (group 0) even when the robot stands in the grid."""
    boxes = np.array([box(-3, 3, -1, 1, 0.0)])
    m = model_lib.compile_mj_model(None, boxes)
    d = mujoco.MjData(m)
    d.qpos[:] = m.key("stand").qpos
    mujoco.mj_forward(m, d)
    ref = hm.heightmap_raycast(m, d, np.array([0.0, 0.0, 1.0]), 0.0)
    np.testing.assert_allclose(ref, 0.5, atol=1e-6)
    all_groups = hm.heightmap_raycast(m, d, np.array([0.0, 0.0, 1.0]), 0.0, geomgroup=None)
    assert (all_groups < 0.5 - 1e-3).any()  # without the group filter the robot shows up


# ----------------------------------------------------------------------------- max_boxes preselection
R = hm.grid_radius_m()


def _max_boxes_in_disc(boxes, xs):
    return int((rect_distance(boxes, np.stack([xs, np.zeros_like(xs)], -1)) <= R).sum(-1).max())


@pytest.mark.parametrize("difficulty", [1.0, 0.5, 0.0])
@pytest.mark.parametrize("kind", terrain.KINDS)
def test_at_most_12_boxes_within_grid_radius(kind, difficulty):
    """For the solid boxes of a track, and for the env's slots (solid boxes + parked holes), anywhere
    along the track up to the finish line, at most 12 boxes reach into the grid's disc."""
    worst_solid = worst_slots = 0
    for s in range(200):
        t = terrain.generate_track(s, kind, difficulty)
        xs = np.arange(t.x_origin_m, t.end_x_m, 0.05)
        worst_solid = max(worst_solid, _max_boxes_in_disc(t.boxes, xs))
        slots = env_boxes(t, pad=False)  # holes parked in place (zero-length at difficulty 0)
        xf = xs[xs <= t.finish_x_m]
        worst_slots = max(worst_slots, _max_boxes_in_disc(slots, xf))
    assert worst_solid <= 12
    assert worst_slots <= 12
    assert worst_solid >= 5  # the disc does hold several boxes: the test can fail


def test_nearest_boxes_keeps_all_when_k_is_large():
    b = jnp.asarray(np.random.default_rng(0).uniform(-1, 1, (5, 6)), jnp.float32)
    assert hm.nearest_boxes(b, jnp.zeros(2), 5) is b
    sel = np.asarray(hm.nearest_boxes(b, jnp.zeros(2), 2))
    d = rect_distance(np.asarray(b, np.float64), np.zeros(2))
    np.testing.assert_allclose(sel, np.asarray(b)[np.argsort(d)[:2]])


@pytest.fixture(scope="module")
def both_lookups():
    return jax.jit(jax.vmap(lambda b, p, y: (hm.heightmap(b, p, y, max_boxes=12),
                                             hm.heightmap(b, p, y, max_boxes=None))))


@pytest.mark.parametrize("kind", terrain.KINDS)
def test_max_boxes_12_equals_all_boxes(both_lookups, kind):
    """heightmap(max_boxes=12) == heightmap(max_boxes=None) on the env's 96 slots (parked holes and
    padding included), anywhere up to the finish line, at any yaw and at difficulty 1 and 0."""
    rng = np.random.default_rng(1)
    B, P, Y = [], [], []
    for s in range(6):
        for d in (1.0, 0.0):
            t = terrain.generate_track(s, kind, d)
            slots = env_boxes(t)
            for x in np.linspace(t.x_origin_m + 0.5, t.finish_x_m, 24):
                B.append(slots)
                P.append([x, rng.uniform(-0.3, 0.3), rng.uniform(0.4, 1.3)])
                Y.append(rng.uniform(-np.pi, np.pi))
    B, P, Y = (jnp.asarray(np.array(a), jnp.float32) for a in (B, P, Y))
    a, b = jax.device_get(both_lookups(B, P, Y))
    np.testing.assert_array_equal(a, b)
    assert (b < 1.0).mean() > 0.3


def test_heightmap_matches_numpy_reference_on_slots():
    """The jnp lookup on the env's slots equals a plain numpy lookup of the solid boxes."""
    t = terrain.generate_track(8, "mixed")
    slots = env_boxes(t)
    rng = np.random.default_rng(2)
    for _ in range(5):
        pos = np.array([rng.uniform(0, t.finish_x_m), rng.uniform(-0.4, 0.4), rng.uniform(0.3, 1.2)])
        yaw = rng.uniform(-np.pi, np.pi)
        ours = hmap(slots, pos, yaw)
        xy = np.asarray(hm.cell_xy(jnp.asarray(pos), yaw))
        ref = np.clip((pos[2] - terrain_height_np(t.boxes, xy)) / 2.0, 0.0, 1.0)
        keep = ~edge_mask(t.boxes, xy)
        np.testing.assert_allclose(ours[keep], ref[keep], atol=1e-5)


def test_grid_height_is_terrain_height_bit_for_bit():
    """The heightmap's box-by-box pass makes the same comparisons as `terrain_height`: equal bit
    for bit, on cells that lie exactly on box edges too (where a reordered test would differ)."""
    rng = np.random.default_rng(3)
    boxes = rng.uniform(-1, 1, (12, 6)).astype(np.float32)
    boxes[:, 3:] = np.abs(boxes[:, 3:]) * 0.5
    lo = boxes[:, :2] - boxes[:, 3:5]
    hi = boxes[:, :2] + boxes[:, 3:5]
    xy = rng.uniform(-1.5, 1.5, (60, 40, 2)).astype(np.float32)
    xy[0, :12] = lo  # on the lower corners
    xy[1, :12] = hi  # on the upper corners
    b, p = jnp.asarray(boxes), jnp.asarray(xy)
    ref = np.asarray(hm.terrain_height(b, p))
    np.testing.assert_array_equal(np.asarray(hm.grid_height(b, p)), ref)
    assert (ref[0, :12] > hm.NO_GROUND_Z_M).all() and (ref > hm.NO_GROUND_Z_M).mean() > 0.2

"""Track generation (biped_switch.terrain): geometry rules over many seeds, difficulty scaling,
determinism, numpy/jnp agreement, stacking, the CLI and its errors. Pure numpy: fast."""

from __future__ import annotations

import json
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_switch import kinds
from biped_switch.simulation import model as model_lib
from biped_switch.simulation import terrain
from biped_switch import terrain as terrain_cli
from biped_switch.config import default_model_config, default_terrain_config

from helpers import box_intervals_x, env_boxes

SEEDS = range(200)
ARTS = terrain.ARTIFACT_KINDS
ALL_ARTS = kinds.ALL_ARTIFACT_KINDS  # the paper's three and `stones` (kinds.py: paper=False)
TOL = 1e-9
STONE = dict(length=0.30, top=0.15, hole=0.45)  # config.py's stone sizes at difficulty 1, by hand


def _lays(kind, art):
    return art in kinds.KIND[kind].artifacts


def _tracks(kind, difficulty=1.0, seeds=SEEDS):
    return [terrain.generate_track(s, kind, difficulty) for s in seeds]


@pytest.fixture(scope="module")
def all_tracks():
    return {k: _tracks(k) for k in terrain.KINDS}


def _boxes_in(track, x0, x1):
    """Solid boxes whose x-extent lies inside [x0, x1], sorted by x."""
    b = track.boxes
    sel = b[(b[:, 0] - b[:, 3] >= x0 - 1e-9) & (b[:, 0] + b[:, 3] <= x1 + 1e-9)]
    return sel[np.argsort(sel[:, 0])]


def _tops(b):
    return b[:, 2] + b[:, 5]


def _lengths(b):
    return 2 * b[:, 3]


# ----------------------------------------------------------------------------- geometry per seed
@pytest.mark.parametrize("kind", terrain.KINDS)
def test_width_and_box_shapes(all_tracks, kind):
    for t in all_tracks[kind]:
        assert 1.1 <= t.width_m <= 1.7
        b = t.boxes
        assert b.shape[1] == 6 and len(b) == int(t.segments[:, terrain.SOLID].sum())
        np.testing.assert_allclose(b[:, 1], 0.0)
        np.testing.assert_allclose(b[:, 4], 0.5 * t.width_m)
        np.testing.assert_allclose(b[:, 5], 0.15)  # every box is a 0.3 m slab under its top
        assert t.n_segments <= default_model_config().box_capacity


@pytest.mark.parametrize("kind", terrain.KINDS)
def test_track_tiles_x_without_overlap(all_tracks, kind):
    """Boxes start at x = -1 (1 m behind the robot), never overlap, and leave only gap holes open."""
    for t in all_tracks[kind]:
        iv = box_intervals_x(t.boxes)
        assert iv[0, 0] == pytest.approx(-1.0)
        space = iv[1:, 0] - iv[:-1, 1]
        assert np.all(space > -1e-9), "boxes overlap"
        holes = space[space > 1e-9]
        # only gap holes, 0.7 m, and the holes between stones, 0.45 m, at difficulty 1
        allowed = [h for a, h in (("gaps", 0.7), ("stones", STONE["hole"])) if _lays(kind, a)]
        assert all(np.isclose(h, allowed, atol=1e-9).any() for h in holes), holes
        if not allowed:
            assert holes.size == 0
        assert iv[-1, 1] == pytest.approx(t.end_x_m)


@pytest.mark.parametrize("kind", terrain.KINDS)
def test_flat_and_stair_run_lengths(all_tracks, kind):
    for t in all_tracks[kind]:
        seg = t.segments
        solid = seg[:, terrain.SOLID] > 0.5
        block = solid & np.isclose(seg[:, terrain.LEN0], 0.16) & np.isclose(seg[:, terrain.TOP_D], 0.3)
        stone = (solid & np.isclose(seg[:, terrain.LEN0], STONE["length"])
                 & np.isclose(seg[:, terrain.TOP_D], STONE["top"]))
        assert _lays(kind, "stones") or not stone.any()
        runs = seg[solid & ~block & ~stone]
        assert np.all((runs[:, terrain.LEN0] >= 0.36) & (runs[:, terrain.LEN0] <= 0.44))
        np.testing.assert_array_equal(runs[:, terrain.LEN_D], 0.0)
        # the same on the boxes: every box is either a 0.16 m jump block or 0.36..0.44 m long
        lengths = _lengths(t.boxes)
        ok = ((lengths >= 0.36 - TOL) & (lengths <= 0.44 + TOL)) | np.isclose(lengths, 0.16)
        ok |= _lays(kind, "stones") & np.isclose(lengths, STONE["length"])
        assert ok.all(), lengths[~ok]


@pytest.mark.parametrize("kind", terrain.KINDS)
def test_artifact_count_and_segments(all_tracks, kind):
    for t in all_tracks[kind]:
        arts = t.artifacts
        assert len(arts) == (0 if kind == "walk" else 7)
        assert len(t.artifact_codes) == len(arts) and t.artifact_segments.shape == (len(arts), 2)
        n = t.artifact_segments[:, 1] - t.artifact_segments[:, 0] + 1
        assert np.all((n >= 4) & (n <= 9))
        xs = [x for _, a0, a1 in arts for x in (a0, a1)]
        assert xs == sorted(xs) and all(a1 > a0 for _, a0, a1 in arts)
        if kind == "walk":
            assert t.finish_x_m == pytest.approx(t.end_x_m - 2.0)
            assert np.all(_tops(t.boxes) == 0.0)
        else:
            assert t.finish_x_m == pytest.approx(arts[-1][2] + 1.0)
            # >= 2 m of flat after the last artifact
            assert t.end_x_m - arts[-1][2] >= 2.0 - TOL
            np.testing.assert_allclose(_tops(_boxes_in(t, arts[-1][2], t.end_x_m)), 0.0)


@pytest.mark.parametrize("kind", terrain.KINDS)
def test_flat_runup_before_every_artifact(all_tracks, kind):
    """At least 0.9 m of flat (solid, top z == 0), without holes, ends exactly at every artifact start."""
    for t in all_tracks[kind]:
        b = t.boxes
        flat = b[np.abs(_tops(b)) < 1e-12]
        iv = box_intervals_x(flat)
        for name, a0, _ in t.artifacts:
            # walk back from a0 through touching flat boxes
            covered_from = a0
            while True:
                touching = iv[np.abs(iv[:, 1] - covered_from) < 1e-9]
                if not len(touching):
                    break
                covered_from = touching[0, 0]
            assert a0 - covered_from >= 0.9, (t.seed, name, a0, covered_from)
        if t.artifacts:  # the robot (x = 0) starts >= 1 m of flat before the first artifact's run-up
            assert t.artifacts[0][1] >= 1.0 + 0.9


@pytest.mark.parametrize("kind", ["mixed", "mixed4"])
def test_mixed_never_repeats_a_kind(all_tracks, kind):
    seen = set()
    for t in all_tracks[kind]:
        names = [a[0] for a in t.artifacts]
        assert all(a != b for a, b in zip(names, names[1:])), names
        seen.update(names)
    assert seen == set(ARTS) | ({"stones"} if kind == "mixed4" else set())


@pytest.mark.parametrize("kind", ALL_ARTS)
def test_single_kind_tracks_contain_only_their_kind(all_tracks, kind):
    for t in all_tracks[kind]:
        assert {a[0] for a in t.artifacts} == {kind}
        np.testing.assert_array_equal(t.artifact_codes, ALL_ARTS.index(kind))


def test_stairs_at_difficulty_1(all_tracks):
    for t in all_tracks["stairs"] + all_tracks["mixed"]:
        for name, a0, a1 in t.artifacts:
            if name != "stairs":
                continue
            b = _boxes_in(t, a0, a1)
            n = len(b)
            assert 4 <= n <= 9
            assert b[0, 0] - b[0, 3] == pytest.approx(a0) and b[-1, 0] + b[-1, 3] == pytest.approx(a1)
            k = _tops(b) / 0.17
            np.testing.assert_allclose(k, np.round(k), atol=1e-9)  # multiples of the 0.17 m rise
            expected = [min(i, n + 1 - i) for i in range(1, n + 1)]  # up, then down
            np.testing.assert_array_equal(np.round(k).astype(int), expected)
            lengths = _lengths(b)
            assert np.all((lengths >= 0.36 - TOL) & (lengths <= 0.44 + TOL))


def test_jumps_at_difficulty_1(all_tracks):
    for t in all_tracks["jumps"] + all_tracks["mixed"]:
        for (name, a0, a1), (s0, s1) in zip(t.artifacts, t.artifact_segments):
            if name != "jumps":
                continue
            b = _boxes_in(t, a0, a1)
            assert len(b) == s1 - s0 + 1
            is_block = np.arange(len(b)) % 2 == 0  # starts with a block, then alternates
            np.testing.assert_allclose(_tops(b)[is_block], 0.3)
            np.testing.assert_allclose(_lengths(b)[is_block], 0.16)
            np.testing.assert_allclose(_tops(b)[~is_block], 0.0)
            assert np.all((_lengths(b)[~is_block] >= 0.36 - TOL) & (_lengths(b)[~is_block] <= 0.44 + TOL))
            assert b[0, 0] - b[0, 3] == pytest.approx(a0)


def _each_artifact(tracks, kind):
    """(track, its boxes' x intervals, a0, a1, segments) of every `kind` artifact on `tracks`."""
    for t in tracks:
        iv_all = box_intervals_x(t.boxes)
        for (name, a0, a1), (s0, s1) in zip(t.artifacts, t.artifact_segments):
            if name == kind:
                yield t, iv_all, a0, a1, s1 - s0 + 1


def _check_holes(iv_all, a0, a1, n_boxes, n_holes, hole_m):
    """Inside the artifact [a0, a1]: `n_boxes` boxes, and every space between them (and its ends)
    one hole of exactly `hole_m`."""
    inside = iv_all[(iv_all[:, 1] > a0 + 1e-9) & (iv_all[:, 0] < a1 - 1e-9)]
    assert len(inside) == n_boxes
    holes = np.concatenate([inside[:, 0], [a1]]) - np.concatenate([[a0], inside[:, 1]])
    holes = holes[holes > 1e-9]
    assert len(holes) == n_holes
    np.testing.assert_allclose(holes, hole_m, atol=1e-9)


def test_gaps_at_difficulty_1(all_tracks):
    for t, iv_all, a0, a1, n in _each_artifact(all_tracks["gaps"] + all_tracks["mixed"], "gaps"):
        n_holes, n_plat = (n + 1) // 2, n // 2  # starts with a hole, alternates
        plat = _boxes_in(t, a0, a1)
        assert len(plat) == n_plat
        np.testing.assert_allclose(_tops(plat), 0.0)
        # the hole at the start: nothing between a0 and a0 + 0.7
        assert plat[0, 0] - plat[0, 3] == pytest.approx(a0 + 0.7)
        _check_holes(iv_all, a0, a1, n_plat, n_holes, 0.7)


def test_stones_at_difficulty_1(all_tracks):
    """A hole, then a raised stone, alternating: stones 0.3 m long with tops 0.15 m up, holes
    0.45 m, nothing else inside the artifact."""
    for t, iv_all, a0, a1, n in _each_artifact(all_tracks["stones"] + all_tracks["mixed4"],
                                               "stones"):
        n_holes, n_stones = (n + 1) // 2, n // 2
        b = _boxes_in(t, a0, a1)
        assert len(b) == n_stones >= 2
        np.testing.assert_allclose(_tops(b), STONE["top"])
        np.testing.assert_allclose(_lengths(b), STONE["length"])
        assert b[0, 0] - b[0, 3] == pytest.approx(a0 + STONE["hole"])
        _check_holes(iv_all, a0, a1, n_stones, n_holes, STONE["hole"])


@pytest.mark.parametrize("d", [0.0, 0.3, 0.75])
def test_stones_scale_with_difficulty(d):
    """The stones' tops and the holes between them scale by d; stone lengths and the layout's
    draws stay, so each artifact is 0.45 (1 - d) m shorter per hole."""
    for s in range(20):
        t1, td = terrain.generate_track(s, "stones", 1.0), terrain.generate_track(s, "stones", d)
        b1, bd = t1.boxes, td.boxes
        assert b1.shape == bd.shape
        np.testing.assert_allclose(_tops(bd), d * _tops(b1), atol=1e-12)
        np.testing.assert_allclose(_lengths(bd), _lengths(b1), atol=1e-12)
        assert np.unique(np.round(_tops(bd), 12)).tolist() == sorted({0.0, round(STONE["top"] * d, 12)})
        sp = box_intervals_x(bd)
        sp = sp[1:, 0] - sp[:-1, 1]
        np.testing.assert_allclose(sp[sp > 1e-9], STONE["hole"] * d, atol=1e-9)
        for (k1, a0, a1), (kd, h0, h1), (s0, s1) in zip(t1.artifacts, td.artifacts,
                                                         t1.artifact_segments):
            assert k1 == kd == "stones"
            assert h1 - h0 == pytest.approx(a1 - a0 - STONE["hole"] * (1 - d) * ((s1 - s0 + 2) // 2))


def test_stone_sizes_are_the_configs():
    """The test's hand-written sizes are config.py's (a changed size must change both)."""
    cfg = default_terrain_config()
    assert (cfg.stone_length_m, cfg.stone_height_m, cfg.stone_hole_m) == tuple(STONE.values())
    assert cfg.stone_height_m < cfg.step_height_m and cfg.stone_hole_m < cfg.gap_length_m


# ----------------------------------------------------------------------------- difficulty
@pytest.mark.parametrize("kind", terrain.KINDS)
def test_difficulty_zero_is_flat(kind):
    for s in range(40):
        t = terrain.generate_track(s, kind, 0.0)
        b = t.boxes
        np.testing.assert_allclose(_tops(b), 0.0, atol=1e-12)
        iv = box_intervals_x(b)
        np.testing.assert_allclose(iv[1:, 0], iv[:-1, 1], atol=1e-9)  # gap length 0: no holes
        # same artifacts (kinds, count) as at difficulty 1
        t1 = terrain.generate_track(s, kind, 1.0)
        assert [a[0] for a in t.artifacts] == [a[0] for a in t1.artifacts]


@pytest.mark.parametrize("kind", ["stairs", "jumps", "gaps", "mixed"])
def test_difficulty_half_halves_heights_and_gaps(kind):
    for s in range(40):
        t1 = terrain.generate_track(s, kind, 1.0)
        th = terrain.generate_track(s, kind, 0.5)
        b1, bh = t1.boxes, th.boxes
        assert b1.shape == bh.shape
        np.testing.assert_allclose(_tops(bh), 0.5 * _tops(b1), atol=1e-12)
        np.testing.assert_allclose(_lengths(bh), _lengths(b1), atol=1e-12)  # box lengths fixed
        # each box shifts back by 0.35 m per (0.7 -> 0.35 m) gap before it
        iv1 = np.stack([b1[:, 0] - b1[:, 3], b1[:, 0] + b1[:, 3]], -1)
        space = np.concatenate([[0.0], iv1[1:, 0] - iv1[:-1, 1]])
        holes_before = np.cumsum(space > 1e-9)
        np.testing.assert_allclose(bh[:, 0] - b1[:, 0], -0.35 * holes_before, atol=1e-9)
        ivh = np.stack([bh[:, 0] - bh[:, 3], bh[:, 0] + bh[:, 3]], -1)
        sp_h = ivh[1:, 0] - ivh[:-1, 1]
        np.testing.assert_allclose(sp_h[sp_h > 1e-9], 0.35, atol=1e-9)
        for (k1, a1_0, a1_1), (kh, ah0, ah1) in zip(t1.artifacts, th.artifacts):
            assert k1 == kh
            assert ah0 <= a1_0 + 1e-9 and ah1 <= a1_1 + 1e-9
        # artifact lengths: gaps lose 0.35 m per hole, others keep their length
        for (name, a0, a1), (_, h0, h1), (s0, s1) in zip(t1.artifacts, th.artifacts, t1.artifact_segments):
            n_holes = (s1 - s0 + 2) // 2 if name == "gaps" else 0
            assert (h1 - h0) == pytest.approx((a1 - a0) - 0.35 * n_holes)


def test_stair_and_block_heights_scale_with_difficulty():
    for d in (0.25, 0.6):
        t = terrain.generate_track(3, "stairs", d)
        k = _tops(t.boxes) / (0.17 * d)
        np.testing.assert_allclose(k, np.round(k), atol=1e-9)
        assert _tops(t.boxes).max() >= 2 * 0.17 * d - 1e-9
        j = terrain.generate_track(3, "jumps", d)
        np.testing.assert_allclose(np.unique(np.round(_tops(j.boxes), 12)), [0.0, 0.3 * d])


# ----------------------------------------------------------------------------- determinism
@pytest.mark.parametrize("kind", terrain.KINDS)
def test_same_seed_same_track_different_seed_different(kind):
    for s in range(5):
        a, b = terrain.generate_track(s, kind), terrain.generate_track(s, kind)
        np.testing.assert_array_equal(a.boxes, b.boxes)
        assert a.artifacts == b.artifacts and a.width_m == b.width_m
        assert a.to_json() == b.to_json()
        c = terrain.generate_track(s + 1000, kind)
        assert a.width_m != c.width_m
        assert a.boxes.shape != c.boxes.shape or not np.allclose(a.boxes, c.boxes)


def test_kind_changes_the_layout():
    a = terrain.generate_track(7, "stairs")
    b = terrain.generate_track(7, "jumps")
    assert a.width_m != b.width_m


# ----------------------------------------------------------------------------- numpy vs jnp
@pytest.mark.parametrize("kind", terrain.KINDS)
def test_layout_jnp_equals_numpy(kind):
    t = terrain.generate_track(11, kind)
    seg_j = jnp.asarray(t.segments, jnp.float32)

    @jax.jit
    def f(d):
        x0, x1, top = terrain.layout(seg_j, d, t.x_origin_m, xp=jnp)
        boxes = terrain.segment_boxes(seg_j, d, t.x_origin_m, t.width_m, t.thickness_m, xp=jnp)
        ext = terrain.artifact_extents(seg_j, jnp.asarray(t.artifact_codes),
                                       jnp.asarray(t.artifact_segments), d, t.x_origin_m,
                                       t.finish_after_m, xp=jnp)
        return x0, x1, top, boxes, ext

    for d in (0.0, 0.3, 1.0):
        x0, x1, top, boxes, (a0, a1, fin) = jax.device_get(f(jnp.float32(d)))
        rx0, rx1, rtop = terrain.layout(t.segments, d, t.x_origin_m)
        np.testing.assert_allclose(x0, rx0, atol=5e-5)
        np.testing.assert_allclose(x1, rx1, atol=5e-5)
        np.testing.assert_allclose(top, rtop, atol=1e-6)
        ref = terrain.segment_boxes(t.segments, d, t.x_origin_m, t.width_m, t.thickness_m)
        np.testing.assert_allclose(boxes, ref, atol=5e-5)
        td = terrain.generate_track(11, kind, d)
        np.testing.assert_allclose(boxes[t.segments[:, terrain.SOLID] > 0.5], td.boxes, atol=5e-5)
        np.testing.assert_allclose(a0[: len(td.artifacts)], [a[1] for a in td.artifacts], atol=5e-5)
        np.testing.assert_allclose(a1[: len(td.artifacts)], [a[2] for a in td.artifacts], atol=5e-5)
        assert fin == pytest.approx(td.finish_x_m, abs=5e-5)


def test_layout_batched_over_tracks_matches_each():
    tracks = [terrain.generate_track(s, k) for s, k in enumerate(terrain.KINDS)]
    bank = terrain.stack_tracks(tracks, 96, 7)
    x0, x1, top = terrain.layout(bank.segments, 1.0, bank.x_origin_m[:, None])
    for i, t in enumerate(tracks):
        rx0, rx1, rtop = terrain.layout(t.segments, 1.0, t.x_origin_m)
        n = t.n_segments
        np.testing.assert_allclose(x0[i, :n], rx0)
        np.testing.assert_allclose(x1[i, :n], rx1)
        np.testing.assert_allclose(x1[i, n:], rx1[-1])  # padding rows: zero-length at the end
        a0, a1, fin = terrain.artifact_extents(bank.segments[i], bank.artifact_codes[i],
                                               bank.artifact_segments[i], 1.0, t.x_origin_m,
                                               t.finish_after_m)
        assert fin == pytest.approx(t.finish_x_m)
        na = len(t.artifacts)
        np.testing.assert_allclose(a0[:na], [a[1] for a in t.artifacts])
        np.testing.assert_array_equal(a0[na:], terrain.FAR_X_M)


# ----------------------------------------------------------------------------- stacking
def test_stack_tracks_pads_and_parks():
    tracks = [terrain.generate_track(0, "walk"), terrain.generate_track(1, "gaps")]
    bank = terrain.stack_tracks(tracks, 96, 7)
    assert bank.size == 2 and bank.segments.shape == (2, 96, 4)
    np.testing.assert_array_equal(bank.artifact_codes[0], terrain.NO_ARTIFACT)
    np.testing.assert_array_equal(bank.artifact_codes[1], ARTS.index("gaps"))
    boxes = env_boxes(tracks[1])
    solid = tracks[1].segments[:, terrain.SOLID] > 0.5
    n = tracks[1].n_segments
    np.testing.assert_allclose(boxes[:n][solid], tracks[1].boxes)
    parked = np.concatenate([boxes[:n][~solid], boxes[n:]])
    np.testing.assert_allclose(parked[:, 2], terrain.PARK_Z_M)
    np.testing.assert_allclose(parked[:, 3:], terrain.PARK_HALF_M)


# ----------------------------------------------------------------------------- CLI
def test_cli_json(capsys):
    assert terrain_cli.main(["--kind", "mixed", "--seed", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {"boxes", "artifacts", "width"} <= set(out)
    t = terrain.generate_track(0, "mixed")
    np.testing.assert_allclose(np.array(out["boxes"]), t.boxes, atol=1e-6)
    assert [a["kind"] for a in out["artifacts"]] == [a[0] for a in t.artifacts]
    assert out["width"] == pytest.approx(t.width_m)
    assert out["finish_x"] == pytest.approx(t.finish_x_m, abs=1e-6)


def test_cli_difficulty_and_kind(capsys):
    assert terrain_cli.main(["--kind", "stairs", "--seed", "4", "--difficulty", "0.5", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["difficulty"] == 0.5 and out["kind"] == "stairs"
    np.testing.assert_allclose(np.array(out["boxes"]),
                               terrain.generate_track(4, "stairs", 0.5).boxes, atol=1e-6)


def test_cli_png(tmp_path, capsys):
    path = tmp_path / "track.png"
    assert terrain_cli.main(["--kind", "jumps", "--seed", "2", "--png", str(path)]) == 0
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert path.stat().st_size > 1000


@pytest.mark.parametrize("argv, word", [(["--kind", "hills"], "hills"),
                                         (["--difficulty", "1.5"], "1.5"),
                                         (["--seed", "-5"], "--seed: must be >= 0, got '-5'")])
def test_cli_errors(capsys, argv, word):
    with pytest.raises(SystemExit) as e:
        terrain_cli.main(argv + ["--json"])
    assert e.value.code == 2
    assert word in capsys.readouterr().err


# ----------------------------------------------------------------------------- errors
def test_unknown_kind():
    with pytest.raises(ValueError, match="'hills'"):
        terrain.generate_track(0, "hills")


@pytest.mark.parametrize("d, text", [(1.5, "1.5"), (-0.1, "-0.1"), (float("nan"), "nan"),
                                     (float("inf"), "inf")])
def test_bad_difficulty(d, text):
    with pytest.raises(ValueError, match=re.escape(text)):
        terrain.generate_track(0, "stairs", d)


def test_stack_tracks_capacity_too_small():
    t = terrain.generate_track(5, "stairs")
    with pytest.raises(ValueError, match=rf"{t.n_segments} boxes.*capacity is 20"):
        terrain.stack_tracks([t], 20, 7)
    with pytest.raises(ValueError, match="7 artifacts"):
        terrain.stack_tracks([t], 96, 3)
    with pytest.raises(ValueError):
        terrain.stack_tracks([], 96, 7)
    cfg = default_terrain_config()
    cfg.slab_thickness_m = 0.4
    thick = terrain.generate_track(5, "stairs", cfg=cfg)
    with pytest.raises(ValueError, match="thickness"):
        terrain.stack_tracks([t, thick], 96, 7)


def test_compile_mj_model_too_many_boxes():
    cfg = default_model_config()
    cfg.box_capacity = 8
    boxes = terrain.generate_track(0, "walk").boxes
    with pytest.raises(ValueError, match=rf"{len(boxes)} boxes exceed.*capacity 8"):
        model_lib.compile_mj_model(cfg, boxes)
    cfg.box_capacity = 0
    with pytest.raises(ValueError, match="box_capacity must be >= 1, got 0"):
        model_lib.compile_mj_model(cfg)


def test_sequence_track_follows_the_kinds_and_refuses_bad_ones():
    cfg = default_terrain_config(3)
    t = terrain.sequence_track(5, ["stairs", "gaps", "stairs"], 1.0, cfg)
    assert [k for k, _, _ in t.artifacts] == ["stairs", "gaps", "stairs"]
    x = [(a, b) for _, a, b in t.artifacts]
    assert all(b0 + cfg.flat_before_m <= a1 for (_, b0), (a1, _) in zip(x, x[1:]))  # flat between
    again = terrain.sequence_track(5, ["stairs", "gaps", "stairs"], 1.0, cfg)
    np.testing.assert_array_equal(t.segments, again.segments)
    with pytest.raises(ValueError, match="walk"):
        terrain.sequence_track(5, ["walk"], 1.0, cfg)
    with pytest.raises(ValueError, match="4 kinds"):
        terrain.sequence_track(5, ["gaps"] * 4, 1.0, cfg)

"""The learned terrain detector: its input profile and the hand rule on hand-made heightmaps, the
onset index against a Python loop, the onset metric on a hand-made approach, and the switching
rollout acting on a detector's output instead of the oracle's."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_switch.config import default_detector_config
from biped_switch.reports import detector as report
from biped_switch.simulation.heightmap import cell_offsets
from biped_switch.switching import detector as det
from biped_switch.switching import rules as sw

from conftest import B, TRACK_IDS

ROWS, COLS = 60, 40
ROW_M = cell_offsets()[:, 0, 0]  # -0.5875 .. 0.8875 m


def _hm(ground_m_by_row: np.ndarray, com_height_m: float = 0.9) -> np.ndarray:
    """A flat (rows*cols,) heightmap of a laterally uniform terrain: heights per row [m] (NaN: no
    ground), as simulation/heightmap.py encodes them (0 at the CoM, 1 at 2 m below, clipped)."""
    v = np.where(np.isnan(ground_m_by_row), 1.0,
                 np.clip((com_height_m - np.nan_to_num(ground_m_by_row)) / 2.0, 0, 1))
    return np.repeat(v[:, None], COLS, axis=1).reshape(-1).astype(np.float32)


def test_profile_is_height_relative_to_the_feet():
    ground = np.zeros(ROWS)
    ground[ROW_M >= 0.5] = 0.17  # a stair 0.17 m up, 0.5 m ahead
    prof = np.asarray(det.profile(jnp.asarray(_hm(ground))[None], (ROWS, COLS)))[0]
    # heightmap units: 1 = 2 m, growing downwards; under the feet 0
    np.testing.assert_allclose(prof[ROW_M < 0.5], 0.0, atol=1e-6)
    np.testing.assert_allclose(prof[ROW_M >= 0.5], -0.085, atol=1e-6)


def test_hand_rule_names_each_kind_by_its_height_change():
    cases = {"gaps": (np.nan, 1), "jumps": (0.30, 0), "stairs": (0.17, 2)}
    for name, (h, code) in cases.items():
        ground = np.zeros(ROWS)
        ground[ROW_M >= 0.6] = h
        prof = np.asarray(det.profile(jnp.asarray(_hm(ground))[None], (ROWS, COLS)))
        kind, dist = det.hand_rule(prof, np.zeros(1), ROW_M)
        assert kind[0] == code, name
        assert dist[0] == pytest.approx(0.6, abs=0.03), name
    flat = np.asarray(det.profile(jnp.asarray(_hm(np.zeros(ROWS)))[None], (ROWS, COLS)))
    assert det.hand_rule(flat, np.zeros(1), ROW_M)[0][0] == -1


def test_distance_is_the_first_change_ahead_by_hand():
    """A 0.17 m stair from row 44 on (cells -0.6 + 0.025 i .. +0.025: row 44 spans 0.5-0.525 m):
    the first row ahead whose height differs is row 44, so the distance is its start, 0.5 m."""
    ground = np.zeros(ROWS)
    ground[44:] = 0.17
    prof = det.profile(jnp.asarray(_hm(ground))[None], (ROWS, COLS))
    assert float(det.first_change_m(prof, ROW_M)[0]) == pytest.approx(ROW_M[44] - 0.0125)
    assert ROW_M[44] - 0.0125 == pytest.approx(0.5)
    # turned 60 deg: 0.5 m along the heading is 0.25 m along the track; turned back: nothing
    d = det.first_change_m(prof, ROW_M)
    assert float(det.along_track_m(d, jnp.float32(np.pi / 3))[0]) == pytest.approx(0.25, abs=1e-6)
    assert np.isinf(float(det.along_track_m(d, jnp.float32(np.pi))[0]))
    # a change behind the feet, or beyond 0.9 m, is not ahead
    behind = np.zeros(ROWS)
    behind[:20] = 0.3
    prof = det.profile(jnp.asarray(_hm(behind))[None], (ROWS, COLS))
    assert np.isinf(float(det.first_change_m(prof, ROW_M)[0]))
    # a median over the columns: the track's edge in a few columns is not a gap
    hm = _hm(np.zeros(ROWS)).reshape(ROWS, COLS)
    hm[40:, 10:14] = 1.0  # no ground in 4 of the 20 middle columns
    prof = det.profile(jnp.asarray(hm.reshape(-1))[None], (ROWS, COLS))
    assert np.isinf(float(det.first_change_m(prof, ROW_M)[0]))


def test_decode_maps_class_zero_to_nothing_in_view():
    logits = jnp.asarray([[5.0, 0, 0, 0], [0, 0, 5.0, 0]])
    out = det.decode(logits, jnp.asarray([0.3, 0.4]))
    np.testing.assert_array_equal(np.asarray(out["kind"]), [-1, 1])
    np.testing.assert_allclose(np.asarray(out["dist_m"]), [0.3, 0.4])  # masked by the rollout


def test_onset_index_counts_like_a_python_loop():
    kinds = [-1, -1, 1, 1, -1, 1, 2, 2, -1, -1, 0]
    ss = sw.init_state(1)
    got = []
    for k in kinds:  # steps=1: no debounce, the index alone
        ss, kind, idx = sw.learned_detection(ss, jnp.asarray([k], jnp.int32), 1)
        assert int(kind[0]) == k
        got.append(int(idx[0]))
    # the loop: a new artifact whenever something is named after nothing was
    want, count, prev = [], 0, False
    for k in kinds:
        seen = k >= 0
        count += int(seen and not prev)
        want.append(count if seen else -1)
        prev = seen
    assert got == want == [-1, -1, 1, 1, -1, 2, 2, 2, -1, -1, 3]


def test_onset_metric_on_a_hand_made_approach():
    # one episode: the oracle names a gap (1) from 0.88 m; the detector from 0.84 m, after
    # naming stairs (2) for a step
    d = np.array([1.2, 1.0, 0.92, 0.88, 0.86, 0.84, 0.5, 0.0, -0.3, np.inf], np.float32)
    k = np.array([-1, -1, -1, 1, 1, 1, 1, 1, 1, -1], np.int32)
    p = np.array([-1, -1, -1, -1, 2, 1, 1, 1, -1, -1], np.int32)
    data = {"episode": np.zeros(10, np.int32), "step": np.arange(10), "kind": k, "dist_m": d}
    m = report.onsets(data, p)
    assert m["approaches"] == 1 and m["missed"] == 0 and m["wrong_first"] == 1
    np.testing.assert_allclose(m["onset_error_cm"], [-4.0], atol=1e-4)
    conf = report.confusion(k, p)
    assert conf.sum() == 10 and conf[2, 2] == 3 and conf[2, 3] == 1 and conf[2, 0] == 2


def _apply(p, obs):  # zero torque from every policy: the scripted guides walk the robot
    return jnp.zeros((obs.shape[0], 12)) * p


def test_rollout_acts_on_the_detector_not_the_oracle(env):
    """A detector that names a gap 0.5 m ahead at every step: the `detection` rule switches walk
    -> gaps once, at the first step, and the switch is logged at the oracle's distance to the
    first artifact (where the robot really was)."""
    def always_gap(params, obs, yaw):
        n = obs.shape[0]
        return {"kind": jnp.full(n, 1, jnp.int32), "dist_m": jnp.full(n, 0.5) + params}

    run = jax.jit(lambda rules, rng: sw.multi_rollout(
        env, _apply, jnp.arange(4.0), None, None, rules, rng, B, 60,
        track_ids=jnp.asarray(TRACK_IDS), guide_scale=1.0, det_apply=always_gap,
        det_params=jnp.float32(0.0)))
    out = jax.device_get(run(sw.make_rules("detection"), jax.random.PRNGKey(0)))
    np.testing.assert_array_equal(out["n_switches"], np.ones(B))
    ahead = out["switch_ahead_m"]
    assert np.all(np.isfinite(ahead[:, 0])) and np.all(np.isnan(ahead[:, 1:]))
    # the robot starts 1 m of run-up and >= 0.9 m of flat before the first artifact
    assert np.all(ahead[:, 0] > 0.9)


def test_detect_fn_reads_the_heightmap_of_the_observation():
    """The jittable detector on observations laid out as the env's (state | heightmap | phase):
    a 0.17 m stair 0.5 m ahead, seen straight on and turned 60 deg."""
    from types import SimpleNamespace

    from biped_switch.config import default_env_config
    from biped_switch.simulation.observation import layout

    cfg = default_detector_config()
    net = det.DetectorNet(tuple(cfg.hidden), cfg.rows_from)
    params = net.init(jax.random.PRNGKey(0), jnp.zeros((1, ROWS)))
    env_cfg = default_env_config()
    env = SimpleNamespace(cfg=env_cfg, obs_layout=layout(env_cfg))
    f = jax.jit(det.detect_fn({"config": cfg.to_dict()}, env))
    ground = np.zeros(ROWS)
    ground[44:] = 0.17
    lay = env.obs_layout
    obs = np.zeros((2, lay.heightmap.stop + 2), np.float32)
    obs[:, lay.heightmap] = _hm(ground)
    obs[:, :lay.heightmap.start] = 0.3  # the robot state: not read
    out = f(params, jnp.asarray(obs), jnp.asarray([0.0, np.pi / 3]))
    prof = det.profile(jnp.asarray(obs[:, lay.heightmap]), (ROWS, COLS), cfg)
    np.testing.assert_array_equal(np.asarray(out["kind"]),
                                  np.asarray(jnp.argmax(net.apply(params, prof), -1) - 1))
    np.testing.assert_allclose(np.asarray(out["dist_m"]), [0.5, 0.25], atol=1e-6)


@pytest.mark.parametrize("via_none", [False, True])
@pytest.mark.parametrize("steps", [1, 2, 3])
def test_debounce_in_the_rollout_matches_the_reference(steps, via_none):
    """switching.rules.learned_detection, stepped like the rollout, against reports.detector.debounce
    (a Python loop) on a hand-made sequence with one-step misreadings."""
    raw = np.array([-1, 1, -1, 1, 1, 1, 2, 1, 1, -1, -1, -1, 0, 0, 2, 2, 2, -1], np.int32)
    ref = report.debounce({"episode": np.zeros(len(raw), np.int32), "step": np.arange(len(raw))},
                          raw, steps, via_none)
    ss = sw.init_state(1)
    got = []
    for k in raw:
        ss, kind, _ = sw.learned_detection(ss, jnp.asarray([k], jnp.int32), steps, via_none)
        got.append(int(kind[0]))
    np.testing.assert_array_equal(got, ref)
    if via_none and steps == 1:  # 2 after 1, and 2 after 0, are held back until a none
        np.testing.assert_array_equal(
            ref, [-1, 1, -1, 1, 1, 1, 1, 1, 1, -1, -1, -1, 0, 0, 0, 0, 0, -1])
        return
    if via_none and steps == 2:  # the run of three 2s after the 0s never gets through
        assert 2 not in ref and list(ref[12:]) == [-1, 0, 0, 0, 0, 0]
        return
    if steps == 1:
        np.testing.assert_array_equal(ref, raw)
    if steps == 3:  # the lone 2 among the 1s and the two 0s never get through
        assert 0 not in ref and list(ref[3:9]) == [-1, -1, 1, 1, 1, 1]

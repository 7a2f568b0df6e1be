"""Switch sweeps: the 5-sample window against a Python loop, touchdown labelling on hand-made
contact sequences, and one small sweep batch on the shared env checked step by step against a
reference loop of the shared jitted env step."""

from __future__ import annotations

import json
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_switch.switching import estimator
from biped_switch.learning import policies as pol
from biped_switch.switching import labels, sweep
from biped_switch.kinds import ARTIFACT_KINDS
from biped_switch.switching import lookup
from biped_switch.simulation.observation import ObsLayout
from biped_switch import sweep as sweep_cli

from conftest import B, TRACK_IDS, batch_reset


def _window_ref(obs_seq, t_switch, t_end):
    """obs t-2..t+2 around the switch, clamped to the start (t-2 < 0 repeats obs 0) and to the
    episode's last observation."""
    idx = np.clip(np.arange(t_switch - 2, t_switch + 3), 0, t_end)
    return obs_seq[idx]


@pytest.mark.parametrize("t_switch,t_end", [(5, 20), (0, 20), (1, 20), (10, 11), (10, 10), (12, 12)])
def test_window_matches_python_loop(t_switch, t_end):
    obs_seq = np.arange(21 * 3, dtype=np.float32).reshape(21, 3)
    w = labels.window_init(jnp.asarray(obs_seq[0]))
    update = jax.jit(labels.window_update)
    switched = False
    for t in range(t_end + 1):  # the episode's observations 0..t_end
        now = t == t_switch
        w = update(w, jnp.asarray(obs_seq[t]), jnp.bool_(now), jnp.bool_(switched))
        switched = switched or now
    got = np.asarray(labels.window_fill(w))
    np.testing.assert_array_equal(got, _window_ref(obs_seq, t_switch, t_end))


def test_window_follows_the_configured_offsets():
    """A window of other step offsets (-1 .. +2) records those around the switch; offsets that are
    not consecutive are refused."""
    obs_seq = np.arange(21 * 3, dtype=np.float32).reshape(21, 3)
    w = labels.window_init(jnp.asarray(obs_seq[0]), (-1, 0, 1, 2))
    switched = False
    for t in range(21):
        now = t == 5
        w = labels.window_update(w, jnp.asarray(obs_seq[t]), jnp.bool_(now), jnp.bool_(switched))
        switched = switched or now
    np.testing.assert_array_equal(labels.window_fill(w), obs_seq[4:8])
    assert labels.N_WINDOW == len(sweep_cli.default_sweep_config().window) == 5
    with pytest.raises(ValueError, match="consecutive"):
        labels.window_init(jnp.zeros(3), (-2, 0, 2))


def _c(left, right):
    return jnp.asarray([left] * 4 + [right] * 4, jnp.float32)


def test_touchdowns_and_steps_past_by_hand():
    # left lands (was in the air), right stays down: one touchdown, the left one
    td = labels.touchdowns(_c(1, 1), _c(0, 1))
    assert td.tolist() == [True, False]
    # a single sole landing counts as the foot landing
    now = jnp.zeros(8).at[2].set(1.0)
    assert labels.touchdowns(now, jnp.zeros(8)).tolist() == [True, False]
    soles_x = jnp.asarray([2.0] * 4 + [1.0] * 4)  # left foot past x = 1.5, right foot not
    L, R, N = labels.LEFT, labels.RIGHT, labels.NO_FOOT
    count = jax.jit(labels.count_steps_past)
    assert [int(v) for v in count(0, N, _c(1, 1), _c(0, 0), soles_x, 1.5)] == [1, L]
    assert [int(v) for v in count(1, L, _c(1, 1), _c(1, 1), soles_x, 1.5)] == [1, L]  # no landing
    # L lands past, R lands short of the end, L lands past again (same foot: no new step),
    # R lands past, both land together (one step), L lands past
    states = [_c(0, 1), _c(1, 1), _c(1, 0), _c(1, 1), _c(0, 1), _c(1, 1), _c(1, 0), _c(1, 1),
              _c(0, 0), _c(1, 1), _c(0, 1), _c(1, 1)]
    right_x = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 2.4, 2.4, 2.4, 2.4, 2.4]
    steps, last = 0, N
    got = []
    for k in range(1, len(states)):
        x = jnp.asarray([2.0] * 4 + [right_x[k]] * 4)
        steps, last = count(steps, last, states[k], states[k - 1], x, 1.5)
        got.append((int(steps), int(last)))
    assert got == [(1, L), (1, L), (1, L), (1, L), (1, L), (1, L), (2, R), (2, R), (3, N), (3, N),
                   (4, L)]


_label_step = jax.jit(labels.label_step, static_argnames="steps_past")


def _label_trace(events, t_switch=1, horizon=50, steps_past=2, art_end_x=1.5):
    """Runs the label rule on a hand-made episode, a dict {control step: event} with events
    "L", "R", "LR" (those feet land past the end), "l" / "r" (lands short of it), "fall",
    "success", "done" or a "+"-joined mix ("R+fall": R lands and that step falls).
    Returns (label, fell, fell_before, steps past the end, the step the record ended or None)."""
    lab = labels.labelling_init()
    switched = False
    for t in range(60):
        ev = events.get(t, "").split("+")
        land = [any(e in ev for e in ("L", "LR", "l")), any(e in ev for e in ("R", "LR", "r"))]
        feet_x = [art_end_x - 0.3 if s in ev else art_end_x + 0.2 for s in ("l", "r")]
        contact_prev = _c(*[0.0 if f else 1.0 for f in land])
        soles_x = jnp.asarray([feet_x[0]] * 4 + [feet_x[1]] * 4)
        live = labels.is_live(lab, jnp.int32(t), horizon)
        now = bool(live) and t == t_switch
        lab = _label_step(lab, live, jnp.bool_(switched), jnp.bool_(switched or now), _c(1, 1),
                          contact_prev, soles_x, jnp.float32(art_end_x), jnp.bool_("fall" in ev),
                          jnp.bool_("success" in ev), jnp.bool_("done" in ev or "fall" in ev
                                                                or "success" in ev),
                          steps_past=steps_past)
        switched = switched or now
        if bool(lab.ended) and not bool(live):
            break
        end = t if bool(lab.ended) else None
    return bool(lab.label), bool(lab.fell), bool(lab.fell_before), int(lab.steps), end


@pytest.mark.parametrize("events,expect", [
    # left then right past the end: labelled on the right foot's landing
    ({3: "L", 6: "R"}, (True, False, False, 2, 6)),
    ({3: "R", 6: "LR"}, (True, False, False, 2, 6)),
    # a fall before the second step
    ({3: "L", 5: "fall", 6: "R"}, (False, True, False, 1, 5)),
    # the same foot landing twice (a bounce) is one step; the episode times out at the horizon
    ({3: "L", 5: "L", 7: "L"}, (False, False, False, 1, None)),
    # a fall on the same step as the second touchdown
    ({3: "L", 6: "R+fall"}, (False, True, False, 2, 6)),
    # a fall after the two steps does not undo the label
    ({3: "L", 6: "R", 7: "fall"}, (True, False, False, 2, 6)),
    # reaching the finish line, one step past the end
    ({3: "L", 8: "success"}, (True, False, False, 1, 8)),
    # the env's episode ends otherwise
    ({3: "L", 8: "done", 9: "R"}, (False, False, False, 1, 8)),
    # landings short of the end, or up to the switch step (1), do not count
    ({0: "L", 1: "R", 3: "r", 4: "L", 5: "r"}, (False, False, False, 1, None)),
    ({0: "L", 1: "R", 3: "r", 4: "L", 5: "r", 6: "R"}, (True, False, False, 2, 6)),
    # both feet landing together (after a hop) is one step; the next landing of either is two
    ({3: "LR"}, (False, False, False, 1, None)),
    ({3: "LR", 5: "L"}, (True, False, False, 2, 5)),
    # a fall before the switch: no sample
    ({0: "fall"}, (False, True, True, 0, 0)),
])
def test_label_rule_on_hand_made_traces(events, expect):
    assert _label_trace(events) == expect


def test_label_rule_horizon_and_steps_past():
    # the second step on the last control step within the horizon counts, one later does not
    assert _label_trace({3: "L", 9: "R"}, horizon=10)[0]
    assert _label_trace({3: "L", 10: "R"}, horizon=10) == (False, False, False, 1, None)
    # steps_past = 3: left, right, left; a second right is no third step
    assert _label_trace({3: "L", 5: "R", 7: "L"}, steps_past=3)[::4] == (True, 7)
    assert _label_trace({3: "L", 5: "R", 7: "R"}, steps_past=3)[::3] == (False, 2)


# Steps count past the artifact's end moved 3.5 m back: the guided robot stops at the artifacts, and
# behind the robot the labels of this batch are 1 (two tracks: two steps made after the switch)
# and 0 (one: the horizon comes one step after it).
END_OFFSET_M = -3.5


@pytest.fixture(scope="module")
def guided_batch(env):
    """One sweep batch on the shared env (mixed tracks 0..3; the first artifact is the target's):
    zero-torque policies walked by the scripted guide forces, switching to `gaps`."""
    def apply(p, obs):  # every "policy" applies p * 0 torque: the guides walk the robot
        return jnp.zeros((obs.shape[0], 12)) * p

    params = jnp.arange(4, dtype=jnp.float32)
    src = jnp.asarray([0, 1, 3, 0], jnp.int32)
    run = jax.jit(lambda rng, tidx: sweep.sweep_rollout(
        env, apply, params, rng, jnp.asarray(TRACK_IDS), src, pol.POLICY_INDEX["gaps"],
        switch_max_m=0.9, steps_past=2, horizon=300, guide_scale=1.0,
        end_offset_m=END_OFFSET_M, target_index=tidx, approach_queries=2))
    first = jax.device_get(run(jax.random.PRNGKey(3), jnp.zeros(B, jnp.int32)))
    # the same batch switching before each track's 2nd artifact (a context sweep), which the
    # guided robot, stopped at the 1st, never gets near: no switch, so no sample
    second = jax.device_get(run(jax.random.PRNGKey(3), jnp.ones(B, jnp.int32)))
    return {**first, "second_artifact": second}


def test_context_switch_waits_for_the_target_artifact(guided_batch):
    out = guided_batch["second_artifact"]
    assert guided_batch["valid"].any()  # the same robots do switch before the 1st artifact
    assert not out["valid"].any() and not out["label"].any()
    assert np.isnan(out["switch_dist_m"]).all()


def test_context_plan_by_hand():
    """Sources cycle over the target's others; an artifact source crosses its own artifact first
    (switch before the 2nd), walk switches before the 1st (the 2nd cycles over the other kinds)."""
    kinds, src, tidx = sweep.context_plan("gaps", 6)
    names = [pol.POLICY_NAMES[j] for j in src]
    assert names == ["walk", "jumps", "stairs"] * 2
    assert kinds == [["gaps", "jumps"], ["jumps", "gaps"], ["stairs", "gaps"],
                     ["gaps", "stairs"], ["jumps", "gaps"], ["stairs", "gaps"]]
    assert tidx.tolist() == [0, 1, 1, 0, 1, 1]
    for k, t in zip(kinds, tidx):  # the switch is always into the target's own artifact
        assert k[t] == "gaps"


def test_context_env_lays_out_the_plan():
    kinds, _, _ = sweep.context_plan("stairs", 5)
    env = sweep.make_context_env(kinds, "stand", backend="mujoco")
    codes = [[ARTIFACT_KINDS[c] for c in row] for row in env.bank.artifact_codes]
    assert codes == kinds
    assert env.bank.artifact_codes.shape == (5, 2)


def _label_ref(contact, soles_x, art_end_x, t_switch, fell, success, done, horizon, steps_past=2):
    """(label, control steps run, steps past the end) by a Python loop over the episode.

    contact / soles_x: (T + 1, 8) sole flags and x of observation k; fell / success / done: (T,)
    of the env step from observation k. Landings (a foot with no sole down in observation k - 1
    and some in k, its centre past the end) count from the observation after the switch; a
    landing of the same foot as the one before is no new step, both feet together are one."""
    seq = []
    for k in range(t_switch, horizon):
        if k > t_switch:
            down_now = contact[k].reshape(2, 4).max(axis=1) > 0.5
            down_before = contact[k - 1].reshape(2, 4).max(axis=1) > 0.5
            land = down_now & ~down_before & (soles_x[k].reshape(2, 4).mean(axis=1) > art_end_x)
            if land.any():
                seq.append("B" if land.all() else "LR"[int(np.argmax(land))])
        steps = sum(1 for i, f in enumerate(seq) if f == "B" or i == 0 or seq[i - 1] != f)
        if fell[k] > 0.5:
            return False, k + 1, steps
        if steps >= steps_past or success[k] > 0.5:
            return True, k + 1, steps
        if done[k] > 0.5:
            return False, k + 1, steps
    return False, horizon, steps


def test_sweep_batch_window_and_label_against_reference_loop(env, fns, guided_batch):
    out = guided_batch
    assert out["window"].shape == (B, 5, env.observation_size)
    s = batch_reset(fns, difficulties=np.ones(B, np.float32))
    info = dict(s.info)
    info["guide_scale"] = jnp.ones(B, jnp.float32)
    s = s.replace(info=info)
    sole_geoms = np.asarray(env.biped.sole_geoms).reshape(-1)
    contact = slice(sweep.env_lib.STATE_SLICES["contact"].start,
                    sweep.env_lib.STATE_SLICES["contact"].start + 8)
    obs, x, fell, success, done = [np.asarray(s.obs)], [], [], [], []
    soles_x = [np.asarray(s.pipeline_state.geom_xpos)[:, sole_geoms, 0]]
    start_x = np.asarray(s.info["start_x"])
    x.append(np.asarray(s.metrics["distance_m"]) + start_x)
    for _ in range(300):
        s = fns["step"](s, jnp.zeros((B, 12), jnp.float32))
        obs.append(np.asarray(s.obs))
        soles_x.append(np.asarray(s.pipeline_state.geom_xpos)[:, sole_geoms, 0])
        x.append(np.asarray(s.metrics["distance_m"]) + start_x)
        fell.append(np.asarray(s.metrics["fell"]))
        success.append(np.asarray(s.metrics["success"]))
        done.append(np.asarray(s.done))
    obs, x, fell, soles_x = np.stack(obs), np.stack(x), np.stack(fell), np.stack(soles_x)
    success, done = np.stack(success), np.stack(done)
    a0 = np.asarray(s.info["art_x0"])[:, 0]
    a1 = np.asarray(s.info["art_x1"])[:, 0]
    n_valid, labels = 0, []
    for b in range(B):
        d = a0[b] - x[:, b]
        fell_at = int(np.argmax(fell[:, b] > 0.5)) + 1 if np.any(fell[:, b] > 0.5) else 10**9
        hits = np.flatnonzero((d <= 0.9) & (d <= out["switch_at_m"][b]))
        t = int(hits[0]) if len(hits) else None
        valid = t is not None and t < fell_at
        assert bool(out["valid"][b]) == valid, b
        if not valid:
            assert not out["label"][b]
            continue
        n_valid += 1
        assert out["switch_dist_m"][b] == pytest.approx(d[t], abs=1e-4)
        label, n_steps, steps_past = _label_ref(obs[:, b, contact], soles_x[:, b],
                                                a1[b] + END_OFFSET_M, t, fell[:, b],
                                                success[:, b], done[:, b], 300)
        assert (bool(out["label"][b]), int(out["steps"][b]), int(out["steps_past"][b])) == (
            label, n_steps, steps_past), b
        labels.append(label)
        # the window ends at the last observation acted on (the label, a fall or the horizon)
        np.testing.assert_allclose(out["window"][b], _window_ref(obs[:, b], t, n_steps - 1),
                                   atol=1e-4)
        # each approach record: the first observation within its distance, at or before the switch
        for k in range(2):
            q = float(out["approach_at_m"][b, k])
            assert out["switch_at_m"][b] <= q <= 0.9
            t_k = int(np.flatnonzero((d <= 0.9) & (d <= q))[0])
            assert t_k <= t and out["approach_valid"][b, k]
            assert out["approach_dist_m"][b, k] == pytest.approx(d[t_k], abs=1e-4)
            np.testing.assert_allclose(out["approach_obs"][b, k], obs[t_k, b], atol=1e-4)
    assert n_valid >= 2  # the guided robot reaches the switch point on most tracks
    assert set(labels) == {False, True}, labels  # both labels checked against the reference


def test_split_keeps_exactly_state_heightmap_and_phase():
    """The estimator's inputs are the robot state (51) and the heightmap (2400); the phase clock
    is kept apart, and the detector one-hot that an env may append after it is left out."""
    s, hm = sweep.env_lib.STATE_SIZE, 60 * 40
    obs = np.arange(2 * 5 * (s + hm + 2 + 3), dtype=np.float32).reshape(2, 5, -1) % 1000
    state, heightmap, phase = sweep._split(obs, ObsLayout((60, 40), 2, 3))
    assert state.shape == (2, 5, s) and heightmap.shape == (2, 5, hm) and phase.shape == (2, 5, 2)
    np.testing.assert_array_equal(state, obs[..., :s])
    np.testing.assert_array_equal(heightmap, obs[..., s:s + hm].astype(np.float16))
    np.testing.assert_array_equal(phase, obs[..., s + hm:s + hm + 2])


# ----------------------------------------------------------------------- resuming (no MJX)
class _Clock:
    """A fake time.perf_counter: setup costs 1 s, each batch 10 s."""

    def __init__(self):
        self.t = 0.0

    def perf_counter(self):
        return self.t


@pytest.fixture
def fake_sweep(monkeypatch):
    """run_sweep with the env, the policies and the jitted batch replaced by stand-ins: track i
    gives a valid sample unless i % 3 == 0, labelled i % 2 == 0. `calls` lists the batch index of
    every batch run; `fail_at` makes the n-th batch call raise (an interrupted session)."""
    clock, calls, fail_at, env_kw = _Clock(), [], [], []
    batch = 6
    overrides = {"action": "pd", "phase_obs": True}

    def make_env(target, init, n_tracks, difficulty, **kw):
        clock.t += 1.0
        env_kw.append(kw)
        return types.SimpleNamespace(obs_layout=ObsLayout((2, 2)))  # the windows' 51 + 4 columns

    def suite_env_overrides(init, runs, stand_in=None, names=pol.POLICY_NAMES):
        return dict(overrides)

    def load_suite(init, env, runs, stand_in=None, names=pol.POLICY_NAMES):
        return pol.PolicySuite(None, None, tuple(f"ckpt_{n}" for n in names), overrides)

    def make_runner(env, apply, target, cfg, guide_scale=0.0, target_index=None, lead_m=None):
        def run(params, rng, ids, src):
            ids = np.asarray(ids)
            calls.append(int(ids[0]) // batch)  # ids = sample index while n_tracks >= samples
            clock.t += 10.0
            if fail_at and len(calls) == fail_at[0]:
                raise KeyboardInterrupt
            o = sweep.env_lib.STATE_SIZE + 4
            n = len(ids)
            return {"valid": ids % 3 != 0, "label": ids % 2 == 0, "source": np.asarray(src),
                    "window": ids[:, None, None] + np.arange(5 * o).reshape(1, 5, o) / 1e3,
                    "switch_dist_m": (ids % 90) / 100 + 0.005, "track_id": ids,
                    "approach_obs": np.zeros((n, 2, o)), "approach_dist_m": np.ones((n, 2)),
                    "approach_valid": np.ones((n, 2), bool), "fell_before": ids % 3 == 0,
                    "lead_dist_m": np.full(n, np.nan),
                    "switch_at_m": np.full(n, 0.5)}
        return run

    monkeypatch.setattr(sweep, "time", type("T", (), {"perf_counter": clock.perf_counter}))
    monkeypatch.setattr(sweep, "make_env", make_env)
    monkeypatch.setattr(sweep.pol, "load_suite", load_suite)
    monkeypatch.setattr(sweep.pol, "suite_env_overrides", suite_env_overrides)
    monkeypatch.setattr(sweep, "make_runner", make_runner)

    def cfg(n_points):
        c = sweep_cli.default_sweep_config()
        c.n_points, c.batch = n_points, batch
        return c

    return {"calls": calls, "fail_at": fail_at, "cfg": cfg, "batch": batch, "env_kw": env_kw}


def _meta(path):
    return json.loads((path / "meta.json").read_text())


def test_resume_makes_only_missing_points_and_sums_wall_time(fake_sweep, tmp_path):
    calls, cfg = fake_sweep["calls"], fake_sweep["cfg"]
    # uninterrupted: 4 valid samples (20 points) per batch of 6, 50 points -> 3 batches
    ref = sweep.run_sweep("stand", "gaps", cfg(50), tmp_path / "a", n_tracks=1000,
                          print_fn=lambda *a: None)
    assert calls == [0, 1, 2]
    assert ref.points_new == 60 and ref.loop_s == 30 and ref.session_s == 31
    assert (ref.steady_points, ref.steady_s) == (40, 20)
    assert ref.wall_s_total == 31 and _meta(tmp_path / "a/stand/gaps")["wall_s_total"] == 31
    # the env is built with the suite's env overrides and the physics backend, both recorded
    assert fake_sweep["env_kw"] == [{"backend": "auto", "action": "pd", "phase_obs": True}]
    meta = _meta(tmp_path / "a/stand/gaps")
    assert meta["env_overrides"] == {"action": "pd", "phase_obs": True}
    assert meta["backend"] == sweep.env_lib.resolve_backend("auto")
    # interrupted in its second batch: one part made, 11 s so far
    calls.clear()
    fake_sweep["fail_at"].append(2)
    with pytest.raises(KeyboardInterrupt):
        sweep.run_sweep("stand", "gaps", cfg(50), tmp_path / "b", n_tracks=1000)
    part_dir = tmp_path / "b/stand/gaps"
    assert len(list(part_dir.glob("part_*.npz"))) == 1
    assert _meta(part_dir)["wall_s_total"] == 21  # setup 1 s, a part 10 s, a lost batch 10 s
    # resumed: only the missing batches, then the same data as the uninterrupted sweep
    calls.clear()
    fake_sweep["fail_at"].clear()
    run = sweep.run_sweep("stand", "gaps", cfg(50), tmp_path / "b", n_tracks=1000,
                          print_fn=lambda *a: None)
    assert calls == [1, 2]
    assert run.points_new == 40 and run.loop_s == 20
    assert (run.steady_points, run.steady_s) == (20, 10)
    assert run.wall_s_total == 21 + 21 and _meta(part_dir)["wall_s_total"] == 42
    a, b = estimator.load_data(ref.path), estimator.load_data(run.path)
    for k in a:
        if k != "meta":
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert len(a["label"]) == 60 and set(a["sample"][::5]) == {1, 2, 4, 5, 7, 8, 10, 11, 13,
                                                              14, 16, 17}
    # nothing missing: no batch, and no time added
    calls.clear()
    again = sweep.run_sweep("stand", "gaps", cfg(50), tmp_path / "b", n_tracks=1000)
    assert calls == [] and again.points_new == 0 and again.wall_s_total == 42


def test_resume_extends_to_more_points_and_refuses_other_track_banks(fake_sweep, tmp_path):
    calls, cfg = fake_sweep["calls"], fake_sweep["cfg"]
    sweep.run_sweep("stand", "jumps", cfg(30), tmp_path, n_tracks=1000)
    assert calls == [0, 1]
    calls.clear()
    c = cfg(90)
    c.lookup_bin_m = 0.02  # binning the merged data is no reason to refuse
    run = sweep.run_sweep("stand", "jumps", c, tmp_path, n_tracks=1000)
    assert calls == [2, 3, 4] and run.points_new == 60
    assert len(estimator.load_data(run.path)["label"]) == 100
    assert _meta(tmp_path / "stand/jumps")["config"]["n_points"] == 90
    for kw, what in [({"n_tracks": 999}, "n_tracks"), ({"n_tracks": 1000, "seed": 1}, "seed")]:
        with pytest.raises(RuntimeError, match=what):
            sweep.run_sweep("stand", "jumps", cfg(200), tmp_path, **kw)
    c = cfg(200)
    c.switch_max_m = 0.5
    with pytest.raises(RuntimeError, match="config.switch_max_m"):
        sweep.run_sweep("stand", "jumps", c, tmp_path, n_tracks=1000)
    assert calls == [2, 3, 4]


def test_main_keeps_the_stats_of_targets_swept_before(fake_sweep, tmp_path):
    out, res = tmp_path / "sweeps", tmp_path / "lookup"
    argv = ["--points", "30", "--batch", "6", "--tracks", "1000", "--out", str(out),
            "--results", str(res), "--targets"]
    assert sweep_cli.main(argv + ["jumps"]) == 0
    first = json.loads((res / "lookup_stand.json").read_text())["meta"]["sweeps"]
    assert set(first) == {"jumps"}
    j = first["jumps"]  # 2 batches of 20 points: 21 s in all, 20 s in the loop
    assert (j["points"], j["points_new"], j["wall_s"], j["loop_s"]) == (40, 40, 21, 20)
    assert j["points_per_s"] == 2.0 and j["points_per_s_steady"] == 2.0
    # a later command sweeps gaps, then extends gaps: jumps' entry stays, gaps' time adds up
    assert sweep_cli.main(argv + ["gaps"]) == 0
    assert sweep_cli.main(argv[:1] + ["50"] + argv[2:] + ["gaps"]) == 0
    sweeps = json.loads((res / "lookup_stand.json").read_text())["meta"]["sweeps"]
    assert set(sweeps) == {"jumps", "gaps"} and sweeps["jumps"] == j
    g = sweeps["gaps"]
    assert (g["points"], g["points_new"], g["wall_s"], g["loop_s"]) == (60, 20, 21 + 11, 10)
    assert g["points_per_s"] == 2.0 and g["points_per_s_steady"] is None
    # rerun when the points are all there: nothing made, the recorded speed and time stay
    assert sweep_cli.main(argv[:1] + ["50"] + argv[2:] + ["gaps"]) == 0
    again = json.loads((res / "lookup_stand.json").read_text())["meta"]["sweeps"]["gaps"]
    assert again == g


def test_main_reads_the_lookup_when_it_ends_not_when_it_starts(fake_sweep, tmp_path, monkeypatch):
    """Two targets swept side by side (two commands, one core each): the one that ends last must
    keep the other's entry as that command wrote it, not the lookup as it was when it started."""
    out, res = tmp_path / "sweeps", tmp_path / "lookup"
    argv = ["--points", "30", "--batch", "6", "--tracks", "1000", "--out", str(out),
            "--results", str(res), "--targets"]
    inner = sweep.run_sweep

    def jumps_ends_during_gaps(init, target, *args, **kw):
        if target == "gaps":  # the jumps command starts after gaps' and ends before it
            monkeypatch.setattr(sweep, "run_sweep", inner)
            assert sweep_cli.main(argv + ["jumps"]) == 0
            monkeypatch.setattr(sweep, "run_sweep", jumps_ends_during_gaps)
        return inner(init, target, *args, **kw)

    monkeypatch.setattr(sweep, "run_sweep", jumps_ends_during_gaps)
    assert sweep_cli.main(argv + ["gaps"]) == 0
    sweeps = json.loads((res / "lookup_stand.json").read_text())["meta"]["sweeps"]
    j = sweeps["jumps"]  # as the jumps command measured it: 2 batches of 20 points, 21 s
    assert (j["points"], j["points_new"], j["wall_s"], j["loop_s"]) == (40, 40, 21, 20)
    assert j["points_per_s"] == 2.0 and j["points_per_s_steady"] == 2.0
    assert sweeps["gaps"]["points_new"] == 40


def test_main_keeps_the_table_of_a_target_whose_data_is_gone(fake_sweep, tmp_path):
    """Sweep data is too large to commit, so a later session may sweep gaps without jumps'
    npz: jumps' table (rates, counts, best distances), stats and policies stay in the lookup."""
    out, res = tmp_path / "sweeps", tmp_path / "lookup"
    argv = ["--points", "30", "--batch", "6", "--tracks", "1000", "--out", str(out),
            "--results", str(res), "--targets"]
    assert sweep_cli.main(argv + ["jumps"]) == 0
    first = json.loads((res / "lookup_stand.json").read_text())
    import shutil

    shutil.rmtree(out)  # a fresh machine: no sweep data
    assert sweep_cli.main(argv + ["gaps"]) == 0
    doc = json.loads((res / "lookup_stand.json").read_text())
    assert doc["tables"]["jumps"] == first["tables"]["jumps"] and "gaps" in doc["tables"]
    assert doc["meta"]["sweeps"]["jumps"] == first["meta"]["sweeps"]["jumps"]
    assert doc["meta"]["policies"]["jumps"] == first["meta"]["policies"]["jumps"]
    for k, v in first["best_m"].items():
        if k.endswith("->jumps"):
            assert doc["best_m"][k] == v
    # by hand: a row's best bin is the highest rate, ties to the farthest bin; the target's row is NaN
    t = lookup.table_from_rates([[0.5, 1.0, 1.0, np.nan], [0.0, 0.0, 0.0, 0.0], [1.0, 0, 0, 0],
                                [0.0, 0.2, 0.1, 0.3]], [[2, 1, 1, 0], [0, 0, 0, 0], [1, 1, 1, 1],
                                                       [1, 1, 1, 1]], "jumps", 0.1)
    np.testing.assert_allclose(t["best_m"], [0.25, np.nan, 0.05, 0.35])


def test_leadin_plan_by_hand():
    """Sources cycle as in the context plan; an artifact source's track starts with nothing or
    each other kind (in ARTIFACT_KINDS order: jumps, gaps, stairs) before its own artifact, and
    the switch is before the target's (the last)."""
    kinds, src, tidx = sweep.leadin_plan("gaps", 9)
    names = [pol.POLICY_NAMES[j] for j in src]
    assert names == ["walk", "jumps", "stairs"] * 3
    assert kinds == [["gaps", "jumps"], ["jumps", "gaps"], ["stairs", "gaps"],
                     ["gaps", "stairs"], ["gaps", "jumps", "gaps"], ["jumps", "stairs", "gaps"],
                     ["gaps", "jumps"], ["stairs", "jumps", "gaps"], ["gaps", "stairs", "gaps"]]
    assert tidx.tolist() == [0, 1, 1, 0, 2, 2, 0, 2, 2]
    for k, t in zip(kinds, tidx):
        assert k[t] == "gaps" and all(a != b for a, b in zip(k, k[1:]))  # no kind twice in a row


@pytest.mark.slow  # a compile of its own (about a minute here): kept out of the default suite
def test_leadin_hands_over_at_the_table_distance(env):
    """Walk leads in on every episode: before an earlier artifact it hands over to that
    artifact's policy at lead_m[walk, kind] (within one control step's travel), and with the
    target's artifact first there is no lead-in; the switch then leaves walk."""
    def apply(p, obs):
        return jnp.zeros((obs.shape[0], 12)) * p

    lead_m = np.full((len(pol.POLICY_NAMES), 3), 0.5, np.float32)
    src = jnp.asarray([1, 2, 3, 1], jnp.int32)  # what the lead-in should leave acting
    run = jax.jit(lambda tidx: sweep.sweep_rollout(
        env, apply, jnp.arange(4, dtype=jnp.float32), jax.random.PRNGKey(3),
        jnp.asarray(TRACK_IDS), src, pol.POLICY_INDEX["gaps"], switch_max_m=0.9, steps_past=2,
        horizon=300, guide_scale=1.0, end_offset_m=END_OFFSET_M, target_index=tidx,
        lead_m=jnp.asarray(lead_m)))
    first = jax.device_get(run(jnp.zeros(B, jnp.int32)))
    assert np.isnan(first["lead_dist_m"]).all()
    switched = ~np.isnan(first["switch_dist_m"])
    assert switched.any()
    assert (first["switch_left"][switched] == pol.POLICY_INDEX["walk"]).all()
    assert (first["switch_left"][~switched] == -1).all()
    second = jax.device_get(run(jnp.ones(B, jnp.int32)))
    led = ~np.isnan(second["lead_dist_m"])
    assert led.any()  # the guided robot comes within 0.5 m of its 1st artifact
    assert (second["lead_dist_m"][led] <= 0.5).all() and (second["lead_dist_m"][led] > 0.4).all()


def test_resume_key_of_a_leadin_sweep_survives_its_json_and_older_sweeps_keep_theirs():
    cfg = sweep_cli.default_sweep_config()
    meta = {"policies": {"walk": "a"}, "seed": 0, "config": cfg.to_dict(), "guide_scale": 0.0,
            "n_tracks": 4, "track_seed": 20000, "context": True, "lead_in": True,
            "lead_m": [[None, 0.89, 0.8], [0.3, None, 0.4]]}  # NaN pairs as None: JSON-equal
    assert sweep.resume_key(json.loads(json.dumps(meta))) == sweep.resume_key(meta)
    old = {k: v for k, v in meta.items() if k not in ("lead_in", "lead_m")}
    old["config"] = {k: v for k, v in old["config"].items() if k != "lead_jitter_m"}
    new = {**old, "config": cfg.to_dict(), "lead_in": False, "lead_m": None}
    assert sweep.resume_key(old) == sweep.resume_key(new)  # a context sweep made before lead-ins

"""Switch sweeps: the 5-sample window against a Python loop, touchdown labelling on hand-made
contact sequences, and one small sweep batch on the shared env checked step by step against a
reference loop of the shared jitted env step."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_switch import policies as pol
from biped_switch import sweep

from conftest import B, TRACK_IDS, batch_reset


def _window_ref(obs_seq, t_switch, t_end):
    """obs t-2..t+2 around the switch, clamped to the start (t-2 < 0 repeats obs 0) and to the
    episode's last observation."""
    idx = np.clip(np.arange(t_switch - 2, t_switch + 3), 0, t_end)
    return obs_seq[idx]


@pytest.mark.parametrize("t_switch,t_end", [(5, 20), (0, 20), (1, 20), (10, 11), (10, 10), (12, 12)])
def test_window_matches_python_loop(t_switch, t_end):
    obs_seq = np.arange(21 * 3, dtype=np.float32).reshape(21, 3)
    w = sweep.window_init(jnp.asarray(obs_seq[0]))
    update = jax.jit(sweep.window_update)
    switched = False
    for t in range(t_end + 1):  # the episode's observations 0..t_end
        now = t == t_switch
        w = update(w, jnp.asarray(obs_seq[t]), jnp.bool_(now), jnp.bool_(switched))
        switched = switched or now
    got = np.asarray(sweep.window_fill(w))
    np.testing.assert_array_equal(got, _window_ref(obs_seq, t_switch, t_end))


def _c(left, right):
    return jnp.asarray([left] * 4 + [right] * 4, jnp.float32)


def test_touchdowns_and_steps_past_by_hand():
    # left lands (was in the air), right stays down: one touchdown, the left one
    td = sweep.touchdowns(_c(1, 1), _c(0, 1))
    assert td.tolist() == [True, False]
    # a single sole landing counts as the foot landing
    now = jnp.zeros(8).at[2].set(1.0)
    assert sweep.touchdowns(now, jnp.zeros(8)).tolist() == [True, False]
    soles_x = jnp.asarray([2.0] * 4 + [1.0] * 4)  # left foot past x = 1.5, right foot not
    assert int(sweep.count_steps_past(0, _c(1, 1), _c(0, 0), soles_x, 1.5)) == 1
    assert int(sweep.count_steps_past(1, _c(1, 1), _c(1, 1), soles_x, 1.5)) == 1  # no landing
    # walk: L lands past, R lands short of the end, R lands past -> 2 steps past the end
    states = [_c(0, 1), _c(1, 1), _c(1, 0), _c(1, 1), _c(1, 0), _c(1, 1)]
    right_x = [1.0, 1.0, 1.0, 1.0, 2.4, 2.4]
    count = 0
    for k in range(1, len(states)):
        x = jnp.asarray([2.0] * 4 + [right_x[k]] * 4)
        count = sweep.count_steps_past(count, states[k], states[k - 1], x, 1.5)
        assert int(count) == [1, 1, 1, 1, 2][k - 1]
    assert int(count) == 2


@pytest.fixture(scope="module")
def guided_batch(env):
    """One sweep batch on the shared env (mixed tracks 0..3; the first artifact is the target's):
    zero-torque policies walked by the scripted guide forces, switching to `gaps`."""
    def apply(p, obs):  # every "policy" applies p * 0 torque: the guides walk the robot
        return jnp.zeros((obs.shape[0], 12)) * p

    params = jnp.arange(4, dtype=jnp.float32)
    src = jnp.asarray([0, 1, 3, 0], jnp.int32)
    run = jax.jit(lambda rng: sweep.sweep_rollout(
        env, apply, params, rng, jnp.asarray(TRACK_IDS), src, pol.POLICY_INDEX["gaps"],
        switch_max_m=0.9, steps_past=2, horizon=300, guide_scale=1.0))
    return jax.device_get(run(jax.random.PRNGKey(3)))


def test_sweep_batch_window_and_label_against_reference_loop(env, fns, guided_batch):
    out = guided_batch
    assert out["window"].shape == (B, 5, env.observation_size)
    s = batch_reset(fns, difficulties=np.ones(B, np.float32))
    info = dict(s.info)
    info["guide_scale"] = jnp.ones(B, jnp.float32)
    s = s.replace(info=info)
    obs, x, fell = [np.asarray(s.obs)], [], []
    start_x = np.asarray(s.info["start_x"])
    x.append(np.asarray(s.metrics["distance_m"]) + start_x)
    for _ in range(300):
        s = fns["step"](s, jnp.zeros((B, 12), jnp.float32))
        obs.append(np.asarray(s.obs))
        x.append(np.asarray(s.metrics["distance_m"]) + start_x)
        fell.append(np.asarray(s.metrics["fell"]))
    obs, x, fell = np.stack(obs), np.stack(x), np.stack(fell)
    a0 = np.asarray(s.info["art_x0"])[:, 0]
    n_valid = 0
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
        end = min(fell_at, len(obs) - 1)
        np.testing.assert_allclose(out["window"][b], _window_ref(obs[:, b], t, end), atol=1e-4)
        if out["label"][b]:  # success: no fall, and the CoM got past the artifact's end
            a1 = np.asarray(s.info["art_x1"])[b, 0]
            assert fell_at > out["steps"][b] and np.any(x[: out["steps"][b] + 1, b] > a1)
    assert n_valid >= 2  # the guided robot reaches the switch point on most tracks

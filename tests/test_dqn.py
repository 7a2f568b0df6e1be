"""The DQN selector baseline (biped_switch.dqn): its pure pieces against hand-computed cases, the
collection step, rollout and the resumable trainer on a cheap scripted env, and one jitted
collection + update call on the real MJX env (the only expensive compile of this file)."""

import csv
import functools
import json
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import Env, State

from biped_switch.learning import dqn
from biped_switch.learning import dqn_train as dqn_train
from biped_switch.learning import policies as pol
from biped_switch.learning import runs as runs_lib
from biped_switch.config import default_dqn_config
from biped_switch.learning import normalizer
from biped_switch.simulation.observation import STATE_SIZE, ObsLayout, layout
from biped_switch.reports import curves

GRID = (2, 2)  # the fake env's heightmap
P_OBS = STATE_SIZE + GRID[0] * GRID[1]  # 55 policy columns
Q_IN = P_OBS + 3  # 58 Q-input columns


def kind_at(t):
    """The fake env's scripted detection: -1, -1, 0, 0, 1, 1, 2, 2, -1, ... (two steps each)."""
    return (t // 2) % 4 - 1


class FakeEnv(Env):
    """Scripted: x grows by the mean action, reward 1 per step, success after `end_step` steps.
    obs[0] = track id, obs[1] = t, obs[2] = x; detection follows `kind_at(t)`."""

    def __init__(self, end_step=5, n_tracks=5):
        self.cfg = types.SimpleNamespace(shape=types.SimpleNamespace(grid_forward=GRID[0],
                                                                     grid_lateral=GRID[1]))
        self.obs_layout = ObsLayout(GRID)
        self.bank = types.SimpleNamespace(size=n_tracks)
        self.end_step = end_step

    observation_size = P_OBS
    policy_observation_size = P_OBS
    action_size = 12
    backend = "fake"
    dt = 0.02

    def _metrics(self, t, x, done):
        z = jnp.zeros(())
        return {"distance_m": x, "progress_frac": t / self.end_step, "success": done, "fell": z,
                "fail_kind": z - 1, "detected_kind": kind_at(t).astype(jnp.float32)}

    def reset(self, rng, track_id=None, guide_scale=None):
        if track_id is None:
            track_id = jax.random.randint(rng, (), 0, self.bank.size)
        t = jnp.zeros((), jnp.int32)
        obs = jnp.zeros(P_OBS).at[0].set(track_id)
        z = jnp.zeros(())
        return State(pipeline_state=jnp.zeros(()), obs=obs, reward=z, done=z,
                     metrics=self._metrics(t, z, z), info={"t": t})

    def step(self, state, action):
        t = state.info["t"] + 1
        x = state.pipeline_state + jnp.mean(action)
        done = (t >= self.end_step).astype(jnp.float32)
        obs = state.obs.at[1].set(t).at[2].set(x)
        return state.replace(pipeline_state=x, obs=obs, reward=jnp.ones(()), done=done,
                             metrics=self._metrics(t, x, done), info={"t": t})


def index_suite():
    """Policy i outputs torque i everywhere, so the fake env's x sums the chosen indices."""
    return pol.PolicySuite(lambda p, obs: jnp.ones((obs.shape[0], 12)) * p, jnp.arange(4.0),
                           ("fake",) * 4)


def oracle_q(params, x):
    """Q that prefers the detected artifact's policy (walk when the one-hot is empty)."""
    oh = x[..., -3:]
    return jnp.concatenate([1.0 - oh.sum(-1, keepdims=True), oh], axis=-1)


def walk_q(params, x):
    return jnp.zeros(x.shape[:-1] + (4,)).at[..., 0].set(1.0)


# ----------------------------------------------------------------------- pure pieces
def test_double_dqn_targets_hand_case():
    q_on = jnp.array([[1.0, 3.0, 2.0], [5.0, 0.0, 1.0]])  # online argmax: 1, 0
    q_tg = jnp.array([[10.0, 4.0, 20.0], [7.0, 9.0, 0.0]])  # target's own argmax: 2, 1
    y = dqn.double_dqn_targets(q_on, q_tg, jnp.array([1.0, 2.0]), jnp.array([0.0, 1.0]), 0.5)
    # env 0: 1 + 0.5 * Q_target(s', 1) = 1 + 0.5 * 4 (not the target's max 20: 1 + 10);
    # env 1 is done: the reward alone
    np.testing.assert_allclose(y, [3.0, 2.0])
    y2 = dqn.double_dqn_targets(q_on, q_tg, jnp.array([1.0, 2.0]), jnp.array([0.0, 0.0]), 0.5)
    np.testing.assert_allclose(y2, [3.0, 2.0 + 0.5 * 7.0])


def test_oracle_bonus_hand_cases():
    choice = jnp.array([0, 1, 0, 2, 3, 3, 0])
    det = jnp.array([-1, 0, 0, 1, 2, -1.0, 2])  # float, as in env metrics
    np.testing.assert_allclose(dqn.oracle_bonus(choice, det, 2.5), [2.5, 2.5, 0, 2.5, 2.5, 0, 0])


def test_q_input_appends_one_hot_of_detection():
    obs = jnp.arange(2 * (P_OBS + 3), dtype=jnp.float32).reshape(2, -1)  # an env with a one-hot
    x = dqn.q_input(obs, jnp.array([-1.0, 2.0]), P_OBS)
    assert x.shape == (2, Q_IN)
    np.testing.assert_array_equal(x[:, :P_OBS], obs[:, :P_OBS])
    np.testing.assert_array_equal(x[:, P_OBS:], [[0, 0, 0], [0, 0, 1]])


def test_epsilon_schedule_and_greedy():
    e = lambda s: float(dqn.epsilon_at(s, 1.0, 0.05, 1000))  # noqa: E731
    assert e(0) == pytest.approx(1.0)
    assert e(500) == pytest.approx(0.525)
    assert e(1000) == pytest.approx(0.05)
    assert e(10_000) == pytest.approx(0.05)
    q = np.random.default_rng(0).normal(size=(4000, 4)).astype(np.float32)
    greedy_of = jax.jit(dqn.epsilon_greedy)  # one compile for all three epsilons
    np.testing.assert_array_equal(greedy_of(jax.random.PRNGKey(1), q, 0.0), np.argmax(q, -1))
    rand = np.asarray(greedy_of(jax.random.PRNGKey(2), q, 1.0))
    freq = np.bincount(rand, minlength=4) / len(rand)
    np.testing.assert_allclose(freq, 0.25, atol=0.04)
    half = np.asarray(greedy_of(jax.random.PRNGKey(3), q, 0.5))
    # greedy with prob 0.5 + 0.5 / 4 = 0.625
    assert np.mean(half == np.argmax(q, -1)) == pytest.approx(0.625, abs=0.04)


def _rows(ids, obs_size):
    ids = np.asarray(ids, np.float32)
    obs = np.tile(ids[:, None], (1, obs_size)) + np.arange(obs_size)[None]  # small ints: exact in f16
    return {"obs": jnp.asarray(obs), "next_obs": jnp.asarray(obs + 1000),
            "action": jnp.asarray(ids % 4, jnp.int32), "reward": jnp.asarray(ids * 0.5),
            "done": jnp.asarray(ids % 2)}


def test_buffer_wraps_and_overwrites_the_oldest():
    size = STATE_SIZE + 2
    buf = dqn_train.buffer_init(5, size)
    assert buf["obs_f32"].dtype == jnp.float32 and buf["obs_f16"].dtype == jnp.float16
    assert buf["obs_f32"].shape == (5, STATE_SIZE) and buf["obs_f16"].shape == (5, 2)
    buf = dqn_train.buffer_add(buf, _rows([0, 1, 2], size))
    assert int(buf["ptr"]) == 3 and int(buf["size"]) == 3
    buf = jax.jit(dqn_train.buffer_add)(buf, _rows([3, 4, 5], size))
    assert int(buf["ptr"]) == 1 and int(buf["size"]) == 5
    rows = dqn_train.buffer_rows(buf, jnp.arange(5))
    want = [5, 1, 2, 3, 4]  # transition 0 (the oldest) overwritten by transition 5
    np.testing.assert_array_equal(rows["obs"], _rows(want, size)["obs"])
    np.testing.assert_array_equal(rows["next_obs"], _rows(want, size)["next_obs"])
    for k in ("action", "reward", "done"):
        np.testing.assert_array_equal(rows[k], _rows(want, size)[k])
    with pytest.raises(ValueError):
        dqn_train.buffer_add(buf, _rows(range(6), size))


def test_buffer_samples_only_filled_rows():
    size = STATE_SIZE + 3
    buf = dqn_train.buffer_add(dqn_train.buffer_init(8, size), _rows([10, 11], size))
    s = dqn_train.buffer_sample(buf, jax.random.PRNGKey(0), 300)
    assert s["obs"].shape == (300, size) and s["next_obs"].shape == (300, size)
    assert s["obs"].dtype == jnp.float32 and s["action"].shape == (300,)
    ids = np.asarray(s["obs"][:, 0])
    assert set(np.unique(ids)) == {10.0, 11.0}  # never an empty (zero) row, both filled rows drawn
    np.testing.assert_array_equal(s["next_obs"][:, 0], ids + 1000)  # rows stay whole
    np.testing.assert_array_equal(s["reward"], ids * 0.5)


def test_input_norm_layout():
    x = np.random.default_rng(0).normal(size=(500, Q_IN)).astype(np.float32) * 3.0 + 1.0
    x[:, 0] = 2.0  # a constant state column: std floored
    x[:, P_OBS:] = np.eye(4, 3, -1)[np.arange(500) % 4]  # none, jumps, gaps, stairs
    n = jax.jit(normalizer.frozen_stats, static_argnums=(1, 2))(x, 0.01, P_OBS - STATE_SIZE)
    np.testing.assert_allclose(n["mean"][1:STATE_SIZE], np.mean(np.asarray(x)[:, 1:STATE_SIZE], 0), rtol=1e-4)
    np.testing.assert_allclose(n["std"][0], 0.01)
    hm = np.asarray(x)[:, STATE_SIZE:P_OBS]
    np.testing.assert_allclose(n["mean"][STATE_SIZE:P_OBS], hm.mean(), rtol=1e-4)  # one shared value
    np.testing.assert_allclose(n["std"][STATE_SIZE:P_OBS], hm.std(), rtol=1e-4)
    np.testing.assert_array_equal(n["mean"][P_OBS:], 0.0)
    np.testing.assert_array_equal(n["std"][P_OBS:], 1.0)


def test_input_norm_leaves_the_phase_clock_untouched():
    """With the policies' phase clock (2 columns after the heightmap), the heightmap's shared
    statistics cover exactly the heightmap columns, and the clock, like the one-hot, is left as
    it is (mean 0, std 1)."""
    n_policy = P_OBS + 2
    x = np.random.default_rng(1).normal(size=(300, n_policy + 3)).astype(np.float32) * 2.0 + 0.5
    x[:, P_OBS:n_policy] = np.stack([np.sin(np.arange(300)), np.cos(np.arange(300))], axis=1) * 9
    n = normalizer.frozen_stats(jnp.asarray(x), 0.01, P_OBS - STATE_SIZE)
    hm = x[:, STATE_SIZE:P_OBS]
    np.testing.assert_allclose(n["mean"][STATE_SIZE:P_OBS], hm.mean(), rtol=1e-4)
    np.testing.assert_allclose(n["std"][STATE_SIZE:P_OBS], hm.std(), rtol=1e-4)
    np.testing.assert_array_equal(n["mean"][P_OBS:], 0.0)
    np.testing.assert_array_equal(n["std"][P_OBS:], 1.0)
    assert n["mean"].shape == (n_policy + 3,)


def test_sizes_follow_the_env_phase_clock():
    """The policies read env.policy_observation_size columns (with the phase clock); the Q-network
    reads those and the one-hot, and its heightmap encoder exactly the 2400 heightmap values. The
    env's layout is its config's, and names every column range."""
    from biped_switch.simulation import env as env_lib

    for phase in (True, False):
        env = env_lib.make_env("mixed", n_tracks=1, phase_obs=phase, detector_one_hot=True)
        p = STATE_SIZE + 2400 + (2 if phase else 0)
        lay = layout(env)
        assert lay == layout(env.cfg) == ObsLayout((60, 40), 2 if phase else 0, 3)
        assert lay.policy_size == env.policy_observation_size == p
        assert lay.hm_size == 2400 and lay.estimator == slice(0, 2451)
        assert (lay.state, lay.heightmap) == (slice(0, 51), slice(51, 2451))
        assert lay.phase == slice(2451, p) and lay.one_hot == slice(p, p + 3)
        assert dqn.q_input_size(env) == p + 3 == env.observation_size == lay.size
        parts = lay.split(np.arange(lay.size))
        assert [len(x) for x in parts] == [51, 2400, lay.size - 2451]


def test_sync_target():
    t, o = {"w": jnp.zeros(3)}, {"w": jnp.ones(3) * 4.0}
    np.testing.assert_allclose(dqn.sync_target(t, o, jnp.asarray(False), 1.0)["w"], 0.0)
    np.testing.assert_allclose(dqn.sync_target(t, o, jnp.asarray(True), 1.0)["w"], 4.0)
    np.testing.assert_allclose(dqn.sync_target(t, o, jnp.asarray(True), 0.25)["w"], 1.0)


def test_dqn_loss_uses_online_argmax_and_target_value():
    """Linear Q = x[:, :4] @ W: online W = I, target W reverses the actions."""
    q_apply = lambda p, x: x[:, :4] @ p["net"]["W"]  # noqa: E731
    online, target = {"net": {"W": jnp.eye(4)}}, {"net": {"W": jnp.eye(4)[::-1]}}
    batch = {"obs": jnp.array([[5.0, 0, 0, 0]]), "action": jnp.array([0]), "reward": jnp.array([1.0]),
             "next_obs": jnp.array([[1.0, 3, 2, 0]]), "done": jnp.array([0.0])}
    (loss, q_mean), grad = jax.value_and_grad(dqn.dqn_loss, has_aux=True)(
        online["net"], online, target, batch, q_apply, 0.5, 1.0)
    # online argmax at s' = 1; the target's value of action 1 = 2 (its own max would be 3), so
    # y = 1 + 0.5 * 2 = 2; Q(s, 0) = 5; Huber(3, delta 1) = 0.5 + 2 = 2.5
    assert float(q_mean) == pytest.approx(5.0)
    assert float(loss) == pytest.approx(2.5)
    want = np.zeros((4, 4))
    want[0, 0] = 5.0  # only through Q(s, a): d huber = 1 (clipped), d Q / d W[0, 0] = x_0
    np.testing.assert_allclose(grad["W"], want)


def test_dqn_update_learns_synthetic_transitions():
    """Rewards r = 3 * obs[a] - 1, half the transitions terminal, a fixed target net: the Huber loss
    of 200 Adam steps falls and stays finite."""
    net = types.SimpleNamespace(hm_hidden=(8,), hidden=(32,))
    q_init, q_apply = dqn.make_q(net, P_OBS - STATE_SIZE)
    cfg = types.SimpleNamespace(max_grad_norm=10.0, learning_rate=1e-3)
    opt = dqn.make_optimizer(cfg)
    update = dqn.make_update(q_apply, opt, 0.9, 1.0)
    params = jax.jit(q_init, static_argnums=1)(jax.random.PRNGKey(0), Q_IN)
    target = params
    rng, n = np.random.default_rng(1), 256
    obs = rng.normal(size=(n, Q_IN)).astype(np.float32)
    act = rng.integers(0, 4, n).astype(np.int32)
    batch = {"obs": obs, "action": act, "reward": 3.0 * obs[np.arange(n), act] - 1.0,
             "next_obs": rng.normal(size=(n, Q_IN)).astype(np.float32),
             "done": (rng.uniform(size=n) < 0.5).astype(np.float32)}

    def body(c, _):
        p, s = c
        p, s, m = update(p, target, s, batch)
        return (p, s), m["loss"]

    (params2, _), losses = jax.jit(lambda p: jax.lax.scan(body, (p, opt.init(p["net"])), None,
                                                          length=200))(params)
    losses = np.asarray(losses)
    assert np.all(np.isfinite(losses))
    assert losses[-30:].mean() < 0.3 * losses[:30].mean(), (losses[:30].mean(), losses[-30:].mean())
    changed = jax.tree.map(lambda a, b: bool(np.any(np.asarray(a) != np.asarray(b))), params["net"],
                           params2["net"])
    assert all(jax.tree.leaves(changed))
    np.testing.assert_array_equal(params2["norm"]["std"], params["norm"]["std"])  # not trained


# ----------------------------------------------------------------------- collection on the fake env
COLLECT_ENV = FakeEnv(end_step=5)


@functools.cache
def _collect_pool():
    return dqn_train.reset_pool(COLLECT_ENV, jax.random.PRNGKey(7), COLLECT_ENV.bank.size)


@jax.jit
def _collect(col, key, oracle, max_steps):
    """One collect_step on the fake env (eps 0, bonus 2, scale 0.5); Q = the oracle where
    `oracle` is 1, else always walk. One compile serves both collection tests."""
    suite = index_suite()
    q = lambda prm, x: prm * oracle_q(None, x) + (1.0 - prm) * walk_q(None, x)  # noqa: E731
    return dqn_train.collect_step(COLLECT_ENV, suite.apply, suite.params, q, oracle, col, _collect_pool(),
                            key, 0.0, 2.0, 0.5, max_steps)


def _collector(max_steps, oracle):
    col = dqn_train.collector_init(_collect_pool(), 4)
    return col, lambda c, key: _collect(c, key, jnp.float32(oracle), jnp.int32(max_steps))


def test_collect_step_rewards_bonus_done_and_auto_reset():
    col, step = _collector(max_steps=100, oracle=1.0)  # episodes end (success) after 5 steps
    tracks, trans, stats = [], [], []
    for i in range(12):
        col, tr, st = step(col, jax.random.PRNGKey(i))
        trans.append(jax.device_get(tr))
        stats.append(jax.device_get(st))
        if i in (0, 5, 10):  # first steps of episodes
            tracks.append(tuple(np.asarray(tr["obs"][:, 0]).tolist()))
    for i, tr in enumerate(trans):
        t = [0, 1, 2, 3, 4, 0, 1, 2, 3, 4, 0, 1][i]  # step index within the episode
        np.testing.assert_array_equal(tr["obs"][:, 1], t)  # obs holds t; episodes restart at 0
        np.testing.assert_array_equal(tr["action"], kind_at(np.int32(t)) + 1)  # greedy oracle Q
        np.testing.assert_allclose(tr["reward"], 0.5 * (1.0 + 2.0))  # scale * (env + bonus)
        np.testing.assert_array_equal(tr["done"], float(t == 4))
        np.testing.assert_array_equal(tr["next_obs"][:, 1], t + 1)  # the terminal obs, not a reset's
        onehot = np.zeros(3) if kind_at(t) < 0 else np.eye(3)[kind_at(t)]
        np.testing.assert_array_equal(tr["obs"][:, P_OBS:], np.tile(onehot, (4, 1)))
        assert stats[i]["episodes"] == (4.0 if t == 4 else 0.0)
    ended = stats[4]
    assert ended["return"] == pytest.approx(4 * 5 * 3.0)  # 4 episodes of 5 steps of (1 + 2)
    assert ended["env_return"] == pytest.approx(4 * 5.0)
    assert ended["length"] == pytest.approx(4 * 5) and ended["success"] == pytest.approx(4.0)
    assert ended["correct_choice"] == pytest.approx(1.0)
    # every new episode starts on a random pool track (pool: one reset state per bank track)
    assert len(set(tracks)) == 3 and set(np.ravel(tracks)) <= set(range(5))
    assert len(set(np.ravel(tracks))) > 2
    # the time-out is a traced argument: the other collection test reuses this compile
    assert _collect._cache_size() == 1


def test_collect_step_time_out_bootstraps_and_bonus_needs_the_right_policy():
    col, step = _collector(max_steps=3, oracle=0.0)  # always walk; time-out before the finish
    trs, sts = [], []
    for i in range(4):
        col, tr, st = step(col, jax.random.PRNGKey(i))
        trs.append(jax.device_get(tr))
        sts.append(jax.device_get(st))
    for i, tr in enumerate(trs):
        np.testing.assert_array_equal(tr["done"], 0.0)  # a time-out is not a terminal state
        np.testing.assert_array_equal(tr["action"], 0)
    # walk is right only while nothing is detected (t = 0, 1), not at t = 2 (jumps detected)
    np.testing.assert_allclose([tr["reward"][0] for tr in trs], [1.5, 1.5, 0.5, 1.5])
    assert [s["episodes"] for s in sts] == [0.0, 0.0, 4.0, 0.0]
    np.testing.assert_array_equal(trs[3]["obs"][:, 1], 0.0)  # restarted after the time-out
    assert sts[2]["success"] == 0.0 and sts[2]["return"] == pytest.approx(4 * (1.5 + 1.5 + 0.5) / 0.5)


def test_dqn_rollout_on_fake_env():
    env = FakeEnv(end_step=7)
    suite = index_suite()
    run = jax.jit(lambda rng, ids, horizon: dqn_train.dqn_rollout(
        env, suite.apply, suite.params, oracle_q, None, rng, 3, horizon, track_ids=ids, chunk=3),
        static_argnums=2)
    res = jax.device_get(run(jax.random.PRNGKey(0), jnp.array([0, 1, 2]), 20))
    # choices by t: walk, walk, jumps, jumps, gaps, gaps, stairs -> 3 switches counted from walk
    np.testing.assert_array_equal(res["length"], 7)
    np.testing.assert_array_equal(res["done"], 1)
    np.testing.assert_array_equal(res["n_switches"], 3)
    np.testing.assert_allclose(res["distance_m"], 0 + 0 + 1 + 1 + 2 + 2 + 3)
    np.testing.assert_allclose(res["success"], 1.0)
    assert set(res) == set(env.reset(jax.random.PRNGKey(0)).metrics) | {"length", "done", "n_switches"}
    short = jax.device_get(run(jax.random.PRNGKey(0), jnp.array([0, 1, 2]), 4))  # the horizon cuts
    np.testing.assert_array_equal(short["length"], 4)
    np.testing.assert_array_equal(short["done"], 0)
    np.testing.assert_array_equal(short["n_switches"], 1)
    np.testing.assert_allclose(short["distance_m"], 2.0)


# ----------------------------------------------------------------------- the trainer
def _tiny_cfg(**kw):
    cfg = default_dqn_config("cpu")
    cfg.update(num_envs=4, log_every=5, chunk_env_steps=40, total_env_steps=120, learning_starts=20,
               replay_capacity=200, batch_size=16, updates_per_collect=1, target_update_period=4,
               max_episode_s=0.2, eval_envs=3)
    cfg.epsilon.decay_steps = 10_000
    cfg.network.update(hm_hidden=(4,), hidden=(16,))
    cfg.update(**kw)
    return cfg


def test_default_configs():
    gpu, cpu = default_dqn_config("gpu"), default_dqn_config("cpu")
    assert cpu.num_envs < gpu.num_envs and cpu.total_env_steps < gpu.total_env_steps
    for c in (gpu, cpu):
        assert c.learning_starts <= c.replay_capacity and c.oracle_bonus > 0
        assert c.epsilon.end < c.epsilon.start
    with pytest.raises(ValueError):
        default_dqn_config("tpu")


def test_train_dqn_checkpoints_resumes_and_loads(tmp_path):
    env, suite = FakeEnv(end_step=6), index_suite()
    cfg = _tiny_cfg()
    lines = []
    p1 = dqn_train.train_dqn(cfg, tmp_path, stand_in="walk", max_chunks=1, print_fn=lines.append,
                       env=env, suite=suite)
    # one chunk = 2 calls of 5 iterations of 4 envs; the buffer holds >= 20 from iteration 5 on
    assert p1["step"] == 40 and p1["n_updates"] == 6 and p1["norm_ready"]
    assert p1["stand_in"] == "walk" and p1["policies"] == ["fake"] * 4 and p1["wall_s"] > 0
    assert p1["buffer_saved"] is False and p1["q_input_size"] == Q_IN
    # an unfinished run shows it: step 40 of the planned 120; the saved epsilon is the schedule's
    # value at the saved step (1 -> 0.05 over 10,000 env steps)
    assert p1["total_env_steps"] == 120 and p1["epsilon"] == pytest.approx(1.0 - 0.95 * 40 / 10_000)
    assert 0 < p1["setup_s_total"] == p1["session_setup_s"] < p1["wall_s"]
    last = p1["last"]  # iterations 6..10: every env finishes its episode (6 steps) at iteration 6
    assert np.isfinite(last["loss"]) and np.isfinite(last["q_mean"])
    assert last["episodes"] == 4 and last["episode_length"] == 6 and last["episode_success"] == 1
    # the greedy evaluation after the chunk: 3 fixed tracks, each ends in success at step 6 (the
    # fake env's finish), whatever the selector picks
    assert p1["eval"] == {"eval_success": 1.0, "eval_fell": 0.0, "eval_progress": 1.0,
                          "eval_switches": p1["eval"]["eval_switches"], "eval_episodes": 3}
    assert 0 <= p1["eval"]["eval_switches"] <= 6
    assert any("greedy, 3 training tracks: success 1.00" in ln for ln in lines)
    ckpt = tmp_path / "checkpoints" / f"{40:012d}"
    saved = json.loads((ckpt / "progress.json").read_text())
    assert saved["step"] == 40 and saved["total_env_steps"] == 120
    assert p1["backend"] == "fake" and p1["env_overrides"] == {}
    _, q1 = dqn_train.load_dqn(tmp_path, Q_IN)
    assert not np.allclose(np.asarray(q1["norm"]["std"]), 1.0)  # the frozen normaliser was saved
    with pytest.raises(ValueError, match=f"reads {Q_IN} input columns, the env gives {Q_IN + 2}"):
        dqn_train.load_dqn(tmp_path, Q_IN + 2)  # e.g. a suite with the phase clock
    p2 = dqn_train.train_dqn(cfg, tmp_path, print_fn=lines.append, env=env, suite=suite)
    # resumed: 2 more chunks; the empty buffer refills (4 iterations) before updates resume
    assert p2["step"] == 120 and p2["n_updates"] == 6 + (20 - 4) and p2["wall_s"] > p1["wall_s"]
    assert p2["total_env_steps"] == p2["step"]  # finished
    assert p2["epsilon"] == pytest.approx(1.0 - 0.95 * 120 / 10_000)
    # the resumed session's setup is added (its last chunk is not its first: no setup of its own)
    assert p2["session_setup_s"] == 0 and p1["setup_s_total"] < p2["setup_s_total"] < p2["wall_s"]
    x = np.linspace(-1, 1, 3 * Q_IN, dtype=np.float32).reshape(3, Q_IN)
    _check_resumed_run(tmp_path, cfg, env, suite.apply, lines, 120, q1, x)
    assert dqn_train.train_dqn(cfg, tmp_path, print_fn=lines.append, env=env, suite=suite) == {}  # done
    # the committed copy (models/baselines/ in the CLI): the latest checkpoint only, the curves;
    # a fresh run folder resumes from it
    out = runs_lib.commit_run(tmp_path, tmp_path / "committed" / "dqn_stand", curves.dqn_curves)
    assert [c.name for c in (out / "checkpoints").iterdir()] == [f"{120:012d}"]
    with (out / "metrics.csv").open() as f:  # one greedy evaluation per chunk
        assert [int(r["step"]) for r in csv.DictReader(f) if r.get("eval_success")] == [40, 80, 120]
    assert (out / "curves.png").stat().st_size > 10_000 and (out / "metrics.csv").exists()
    fresh = tmp_path / "fresh" / "dqn_stand"
    runs_lib.restore_committed(fresh, lines.append, tmp_path / "committed")
    assert runs_lib.read_progress(runs_lib.latest_checkpoint(fresh))["step"] == 120
    assert "resuming from the committed" in lines[-1]
    assert dqn_train.train_dqn(cfg, fresh, print_fn=lines.append, env=env, suite=suite) == {}


def test_run_loop_syncs_target_every_period_and_follows_epsilon():
    """The jitted loop, one iteration (4 env steps, 3 updates) per `run` call, 260 calls (1,040
    env steps, 768 updates): the target is a hard copy of the online net exactly when n_updates is
    a multiple of 4, and frozen between syncs; each iteration acts with the epsilon of the linear
    schedule (1 -> 0.05 over 600 env steps) at its own step; the loss stays finite."""
    env, suite = FakeEnv(end_step=6), index_suite()
    cfg = _tiny_cfg(log_every=1, updates_per_collect=3, target_update_period=4)
    cfg.epsilon.update(start=1.0, end=0.05, decay_steps=600)
    fns = dqn_train.make_train_fns(cfg, env, suite.apply)
    pool = fns.reset_pool(jax.random.PRNGKey(1))
    ts = fns.init(jax.random.PRNGKey(0), pool)
    net = lambda p: jax.tree.leaves(jax.device_get(p["net"]))  # noqa: E731
    same = lambda a, b: all(np.array_equal(x, y) for x, y in zip(a, b))  # noqa: E731
    target_prev, n_prev = net(ts.target), 0
    seen = {"synced": 0, "apart": 0, "frozen": 0, "mid_call_sync": 0}
    for i in range(260):
        ts, sums = fns.run(ts, suite.params, pool)
        sums = jax.device_get(sums)
        online, target, n = net(ts.params), net(ts.target), int(ts.n_updates)
        # the buffer holds 4 * (i + 1) transitions after iteration i: updates from 20 on
        assert n == (3 * (i - 3) if i >= 4 else 0) and int(ts.env_steps) == 4 * (i + 1)
        assert sums["learned"] == float(i >= 4) and np.isfinite(sums["loss"])
        if n % 4 == 0:
            assert same(target, online), (i, n)
            seen["synced"] += 1
        else:
            assert not same(target, online), (i, n)
            seen["apart"] += 1
        syncs = [k for k in range(n_prev + 1, n + 1) if k % 4 == 0]
        if not syncs:  # no sync during this call: the target did not move
            assert same(target, target_prev), (i, n)
            seen["frozen"] += 1
        elif syncs[-1] < n:  # synced mid-call, then the online net moved on
            assert not same(target, target_prev), (i, n)
            seen["mid_call_sync"] += 1
        eps = lambda s: 1.0 + min(s / 600, 1.0) * (0.05 - 1.0)  # noqa: E731
        assert sums["epsilon_used"] == pytest.approx(eps(4 * i), abs=1e-6)
        assert sums["epsilon"] == pytest.approx(eps(4 * (i + 1)), abs=1e-6)
        target_prev, n_prev = target, n
    assert n_prev == 768 and min(seen.values()) >= 50, seen


def _check_resumed_run(run_dir, cfg, env, apply, lines, final_step, q1, x):
    """What a DQN run resumed to its end shows: progress lines, one compiled call, metrics rows in
    step order, and a saved Q-net trained on from the first chunk's `q1` with its normaliser kept."""
    assert any(line.startswith("resuming") for line in lines)
    assert any("steps/s" in line and "left ~" in line for line in lines)
    fns = dqn_train.make_train_fns(cfg, env, apply)
    assert fns.run._cache_size() == 1  # the resumed run reused the compiled call
    rows = (run_dir / "metrics.csv").read_text().splitlines()
    steps = [float(r.split(",")[0]) for r in rows[1:]]
    assert steps == sorted(steps) and steps[-1] == final_step
    q_apply, q2 = dqn_train.load_dqn(run_dir)
    q_apply = jax.jit(q_apply)
    out = np.asarray(q_apply(q2, x))
    assert out.shape == (x.shape[0], 4) and np.all(np.isfinite(out))
    assert not np.allclose(q_apply(q1, x), out)  # trained on after the resume
    np.testing.assert_array_equal(q2["norm"]["mean"], q1["norm"]["mean"])  # frozen across resume


# ----------------------------------------------------------------------- the real env
@pytest.mark.slow  # about 60 s on 2 cores; the fake-env tests above cover the same logic
def test_collection_and_update_on_the_real_env(env, fns, batch0, traces):
    """Three collection steps and a few updates on the real MJX env, stepped by conftest's jitted
    batched step (compiled once per session, shared: the physics adds no compile here), with
    conftest's reset states of tracks 0..3 as the pool and zero-torque policies. conftest's env
    has no one-hot: the DQN appends its own from metrics["detected_kind"]."""
    p = layout(env).policy_size
    assert env.observation_size == p
    zero = pol.PolicySuite(lambda prm, obs: jnp.zeros((obs.shape[0], 12)) * prm, jnp.arange(4.0), ())
    fns["step"](batch0, jnp.zeros((4, 12), jnp.float32))  # the fixture's own argument types
    q_init, q_apply = dqn.make_q(types.SimpleNamespace(hm_hidden=(4,), hidden=(16,)), p - STATE_SIZE)
    params = jax.jit(q_init, static_argnums=1)(jax.random.PRNGKey(0), p + 3)
    act = jax.jit(lambda col, key: dqn_train.collect_act(env, zero.apply, zero.params, q_apply, params,
                                                   col, batch0, key, 0.5))
    record = jax.jit(lambda col, rec, nxt: dqn_train.collect_record(env, col, rec, nxt, 1.0, 0.1, 3000))
    add = jax.jit(dqn_train.buffer_add)
    buf = jax.jit(dqn_train.buffer_init, static_argnums=(0, 1))(16, p + 3)
    col = dqn_train.collector_init(batch0, 4)
    for i in range(3):
        col, rec, action = act(col, jax.random.PRNGKey(i))
        col, tr, st = record(col, rec, fns["step"](col.state, action))
        buf = add(buf, tr)
        assert st["episodes"] == 0 and st["detected"] == 0.0
    assert traces["step"] == 1  # collection states have exactly the env's own types: no retrace
    assert np.all(np.isin(np.asarray(col.state.info["track_id"]), [0, 1, 2, 3]))
    np.testing.assert_allclose(np.asarray(col.state.info["time_s"]), 0.06, atol=1e-5)  # 3 steps
    np.testing.assert_array_equal(col.ep_len, 3)
    rows = jax.device_get(dqn_train.buffer_rows(buf, jnp.arange(12)))
    assert rows["obs"].shape == (12, p + 3)
    assert np.all(np.isfinite(rows["obs"])) and np.all(np.isfinite(rows["next_obs"]))
    # nothing is in detection range at the start: an empty one-hot; walk (0) earns the bonus
    np.testing.assert_array_equal(rows["obs"][:, p:], 0.0)
    assert np.all(rows["done"] == 0) and np.all(rows["reward"] > 0)
    assert float(st["correct_choice"]) == pytest.approx(np.mean(rows["action"][8:] == 0))
    # consecutive transitions of one env chain: next obs of step t is the obs of step t + 1
    np.testing.assert_array_equal(rows["next_obs"][:8], rows["obs"][4:])
    hm = rows["obs"][:, STATE_SIZE:p]
    assert hm.min() >= 0 and hm.max() <= 1 and hm.std() > 0  # heightmap values survive float16
    # the first transitions start from the pool: reset states of tracks 0..3 (pool index = track)
    start = np.asarray(batch0.obs)[np.asarray(col.state.info["track_id"])]
    np.testing.assert_array_equal(rows["obs"][:4, :STATE_SIZE], start[:, :STATE_SIZE])
    np.testing.assert_allclose(rows["obs"][:4, STATE_SIZE:p], start[:, STATE_SIZE:], atol=5e-4)
    # a few Double-DQN updates on these transitions, with the normaliser from them
    params = {**params, "norm": normalizer.frozen_stats(jnp.asarray(rows["obs"]), 1e-2, p - STATE_SIZE)}
    opt = dqn.make_optimizer(types.SimpleNamespace(max_grad_norm=10.0, learning_rate=1e-3))
    update = jax.jit(dqn.make_update(q_apply, opt, 0.99, 1.0))
    opt_state, losses, target = opt.init(params["net"]), [], params
    batch = dqn_train.buffer_sample(buf, jax.random.PRNGKey(0), 8)
    for i in range(5):
        params, opt_state, m = update(params, target, opt_state, batch)
        losses.append(float(m["loss"]))
    assert np.all(np.isfinite(losses)) and losses[-1] < losses[0]


@pytest.mark.slow
def test_train_dqn_on_the_real_env_checkpoints_resumes_and_loads(env, batch0, tmp_path):
    """The whole trainer on the real MJX env: conftest's env (mixed tracks 0..3, no one-hot: the DQN
    appends its own) with its reset states as the pool, so a full test session compiles nothing
    here but the jitted collection + update (once: the resumed run reuses it). Zero-torque
    policies; 2 envs; episodes time out after 10 steps (0.2 s, in the standing pause)."""
    p_obs = layout(env).policy_size
    assert env.observation_size == p_obs  # the one-hot comes from metrics["detected_kind"]
    zero = pol.PolicySuite(lambda prm, obs: jnp.zeros((obs.shape[0], 12)) * prm, jnp.arange(4.0),
                           ("zero",) * 4)
    cfg = _tiny_cfg(num_envs=2, log_every=3, chunk_env_steps=12, total_env_steps=36,
                    learning_starts=4, replay_capacity=16, batch_size=4, max_episode_s=0.2)
    pool = jax.tree.map(jnp.asarray, batch0)
    lines = []
    p1 = dqn_train.train_dqn(cfg, tmp_path, stand_in="walk", max_chunks=1, print_fn=lines.append,
                       env=env, suite=zero, pool=pool)
    # one chunk = 2 calls of 3 iterations of 2 envs; the buffer holds >= 4 from iteration 2 on
    assert p1["step"] == 12 and p1["n_updates"] == 5 and p1["norm_ready"]
    assert p1["stand_in"] == "walk" and p1["policies"] == ["zero"] * 4 and p1["wall_s"] > 0
    assert p1["buffer_saved"] is False and p1["q_input_size"] == p_obs + 3
    assert np.isfinite(p1["last"]["loss"]) and np.isfinite(p1["last"]["q_mean"])
    assert p1["last"]["episodes"] == 0 and p1["last"]["detected_frac"] == 0.0
    ckpt = tmp_path / "checkpoints" / f"{12:012d}"
    assert json.loads((ckpt / "progress.json").read_text())["step"] == 12
    _, q1 = dqn_train.load_dqn(tmp_path)
    assert not np.allclose(np.asarray(q1["norm"]["std"]), 1.0)  # the frozen normaliser was saved

    p2 = dqn_train.train_dqn(cfg, tmp_path, print_fn=lines.append, env=env, suite=zero, pool=pool)
    # resumed: 2 more chunks; the empty buffer refills (1 iteration) before updates resume
    assert p2["step"] == 36 and p2["n_updates"] == 5 + (12 - 1) and p2["wall_s"] > p1["wall_s"]
    last = p2["last"]  # iterations 10..12 after the resume: both envs time out at step 10
    assert last["episodes"] == 2 and last["episode_length"] == 10
    assert last["episode_fell"] == 0 and last["episode_success"] == 0
    assert last["episode_env_return"] > 0
    # nothing is detected at the start: walk earns the bonus, so return - env return = bonus * n
    assert 0 <= last["episode_return"] - last["episode_env_return"] <= 10 * cfg.oracle_bonus + 1e-4
    print(f"\nreal env, {cfg.num_envs} envs: last chunk {p2['env_steps_per_s']:.0f} env steps/s "
          f"(collection + updates), first session {p1['wall_s']:.0f} s incl. compile")
    x = np.asarray(jax.tree.map(lambda a: a[:2], batch0).obs)
    x = np.concatenate([x, np.zeros((2, 3), np.float32)], axis=1)
    _check_resumed_run(tmp_path, cfg, env, zero.apply, lines, 36, q1, x)
    assert dqn_train.train_dqn(cfg, tmp_path, print_fn=lines.append, env=env, suite=zero, pool=pool) == {}

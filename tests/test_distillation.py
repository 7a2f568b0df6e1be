"""The DAgger distillation (learning/distillation.py, products/student.py): the loss and the mixing
schedule by hand, the aggregate buffer's ring, the teacher's labels along the student's own
trajectory against the controller stepped by hand in Python, and a resumed run."""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_switch.config import default_distill_config
from biped_switch.kinds import POLICY_OF_CODE
from biped_switch.learning import distillation as dist
from biped_switch.learning import policies as pol
from biped_switch.learning import runs as runs_lib


def test_distill_loss_by_hand():
    """MSE over samples and joints of a linear 'network' x @ w."""
    x = jnp.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    w = jnp.array([[1.0, 2.0], [0.0, -1.0]])  # means [[1, 2], [0, -1], [1, 1]]
    label = jnp.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    loss, info = dist.distill_loss({"w": w}, x, label, lambda p, v: v @ p["w"])
    # squared errors: (0, 4), (0, 1), (1, 0): 6 over 6 entries
    assert float(loss) == pytest.approx(1.0)
    assert float(info["loss/action_mse"]) == pytest.approx(1.0)
    g = jax.grad(lambda w_: dist.distill_loss({"w": w_}, x, label, lambda p, v: v @ p["w"])[0])(w)
    # d/dw of mean((xw - y)^2) = 2 x^T (xw - y) / 6
    np.testing.assert_allclose(g, 2 * x.T @ (x @ w - label) / 6, rtol=1e-6)


def test_mix_schedule_by_hand():
    assert dist.mix_at(0, 1.0, 0.0, 4_000_000) == 1.0
    assert dist.mix_at(1_000_000, 1.0, 0.0, 4_000_000) == pytest.approx(0.75)
    assert dist.mix_at(3_000_000, 1.0, 0.2, 4_000_000) == pytest.approx(0.4)
    assert dist.mix_at(4_000_000, 1.0, 0.0, 4_000_000) == 0.0
    assert dist.mix_at(9_000_000, 1.0, 0.1, 4_000_000) == pytest.approx(0.1)
    assert dist.mix_at(5, 1.0, 0.3, 0) == pytest.approx(0.3)  # no decay: the end value


def test_memory_probe_reads_each_envs_own_past():
    """history_index by hand; and a label that is env e's previous input: the probe must fit it
    from k = 2 and not from k = 1. Offsets of 1 row (the previous env) instead of n_envs rows,
    or a history taken forward in time, leave k = 2 no better than k = 1."""
    from biped_switch.products.student_memory import fit_history, history_index

    np.testing.assert_array_equal(history_index(np.array([8, 9]), 3, 4), [[8, 4, 0], [9, 5, 1]])
    n_envs, n = 4, 6000
    x = np.random.default_rng(0).normal(size=(n, 3)).astype(np.float32)
    y = np.zeros((n, 1), np.float32)
    y[n_envs:, 0] = x[:-n_envs, 0]  # row r's label: its env's input one step earlier
    rows = np.arange(n_envs, n)
    train, test = rows[:5000], rows[5000:]
    fit = dict(hidden=(32,), steps=600, batch=256, lr=1e-2)
    one = fit_history(x, y, 1, n_envs, train, test, **fit)
    two = fit_history(x, y, 2, n_envs, train, test, **fit)
    assert one["test_mse"] > 0.8  # Var(label) = 1: the present input says nothing of it
    assert two["test_mse"] < 0.1 * one["test_mse"]


def test_memory_probe_reads_its_run_and_config(tmp_path):
    """memory_probe on a run's buffer.npz with the config's envs, histories and fit settings: the
    same previous-input label, fitted from k = 2 and not from k = 1; a run without a buffer is
    named in the error."""
    from biped_switch.products.student_memory import memory_probe

    n_envs, n = 4, 6000
    x = np.random.default_rng(0).normal(size=(n, 3)).astype(np.float32)
    y = np.zeros((n, 1), np.float32)
    y[n_envs:, 0] = x[:-n_envs, 0]
    np.savez(tmp_path / "buffer.npz", step=np.int64(123), x=x, y=y)
    cfg = default_distill_config()
    cfg.distill.num_envs, cfg.distill.learning_rate = n_envs, 1e-2
    cfg.network.policy_hidden = (32,)
    cfg.distill.memory_probe.update(ks=(1, 2), steps=600, batch=256, holdout=0.15, eval_every=300)
    res = memory_probe(tmp_path, cfg, print_fn=lambda *a: None)
    one, two = res["results"]
    assert (res["buffer_step"], one["k"], two["k"]) == (123, 1, 2)
    assert res["rows_held_out"] == round(0.15 * (n - n_envs)) and len(one["test_curve"]) == 1
    assert one["test_mse"] > 0.8 and two["test_mse"] < 0.1 * one["test_mse"]
    with pytest.raises(FileNotFoundError, match="no buffer.npz"):
        memory_probe(tmp_path / "empty", cfg)


def test_buffer_ring_and_its_file_order():
    buf = dist.Buffer(jnp.zeros((5, 2)), jnp.zeros((5, 1)), jnp.int32(0), jnp.int32(0))
    rows = np.arange(16, dtype=np.float32).reshape(8, 2)
    buf = dist.buffer_append(buf, jnp.asarray(rows[:3]), jnp.asarray(rows[:3, :1]))
    assert int(buf.count) == 3 and int(buf.ptr) == 3
    buf = dist.buffer_append(buf, jnp.asarray(rows[3:6]), jnp.asarray(rows[3:6, :1]))
    # 6 rows into 5: row 5 overwrote row 0, at index 0
    assert int(buf.count) == 5 and int(buf.ptr) == 1
    np.testing.assert_array_equal(np.asarray(buf.x)[0], rows[5])
    out = dist.buffer_arrays(buf)  # oldest first: rows 1..5
    np.testing.assert_array_equal(out["x"], rows[1:6])
    np.testing.assert_array_equal(out["y"], rows[1:6, :1])
    empty = dist.Buffer(jnp.zeros((5, 2)), jnp.zeros((5, 1)), jnp.int32(0), jnp.int32(0))
    back = dist.buffer_from_arrays(empty, out["x"], out["y"])
    np.testing.assert_array_equal(dist.buffer_arrays(back)["x"], rows[1:6])
    with pytest.raises(ValueError, match="buffer rows of shape"):
        dist.buffer_from_arrays(empty, np.zeros((2, 3)), np.zeros((2, 1)))


def _small_cfg(tmp_runs="runs"):
    cfg = default_distill_config()
    cfg.n_tracks = 4
    cfg.distill.update(num_envs=4, unroll_length=40, horizon_s=3.0, buffer_size=1024,
                       batch_size=64, updates_per_iteration=2, chunk_env_steps=160,
                       total_env_steps=320, teacher_runs=tmp_runs)
    return cfg


def _reference_rule(active, art, kind, index, dist_m, lookup_m, setup_of, handover_m, force_m):
    """lookup_context_setup's decision for one env, in plain Python (switching/rules.py's rule
    read off its docstring): into a setup policy at detection, out of it at its hand-over
    distance, else at the lookup distance, always at the forced distance."""
    if kind < 0:
        return active, art
    target = POLICY_OF_CODE[kind]
    if target == active:
        return active, index
    setup = setup_of[active, kind]
    if setup >= 0 and dist_m > handover_m[kind]:
        return int(setup), index
    fire = dist_m <= (handover_m[kind] if active >= 4 else lookup_m[active, kind])
    return (target if fire or dist_m <= force_m else active), index


@pytest.fixture(scope="module")
def teacher_parts():
    from biped_switch.products import student
    cfg = _small_cfg()
    setup = student.teacher_setup(cfg)
    teacher = student.make_teacher(setup, cfg.distill.teacher)
    return cfg, setup, teacher


def test_labels_follow_the_controller_along_the_students_path(teacher_parts):
    """Collect 170 steps with the teacher acting 90% of the time, episodes of at most 150 steps
    (each env restarts; the first artifact comes into the detector's range after about 2 s), then
    replay the executed actions step by step in Python: at each state the
    label is the action of the policy that the rule, carried by hand from the episode's start,
    has active, computed by that policy's own checkpoint (not the stacked suite); the executed
    action is the label where the teacher acted, else the saved student's."""
    cfg, setup, teacher = teacher_parts
    env = setup.env
    cfg.distill.unroll_length = 170
    dag = dist.make_dagger(cfg, env, teacher)
    ds = dag.init(jax.random.PRNGKey(3))
    envs = dag.reset_envs(jax.random.PRNGKey(4))
    fresh = dag.reset_envs(jax.random.PRNGKey(5))
    _, tr = jax.jit(dag.collect)(ds, envs, jax.random.PRNGKey(6), jnp.float32(0.9), fresh)
    tr = jax.device_get(tr)
    assert tr["by_teacher"].any() and (~tr["by_teacher"]).any()

    rules, _ = setup.rules_for(cfg.distill.teacher)
    lookup_m, setup_of = np.asarray(rules.lookup_m), np.asarray(rules.setup_of)
    handover_m, force_m = np.asarray(rules.handover_m), float(rules.force_m)
    ckpts = pol.find_suite("stand", cfg.distill.teacher_runs, names=setup.policy_names)
    acts = [jax.jit(pol.load_policy(ckpts[n], env)[0]) for n in setup.policy_names]
    student_apply = jax.jit(pol.policy_apply(cfg, env))
    tree = dist.checkpoint_tree(ds, -1.0)
    student_params = {"params": tree["params"], "norm": tree["norm"]}
    step = jax.jit(jax.vmap(env.step))
    inputs = jax.jit(jax.vmap(env.switch_inputs))
    horizon = int(round(cfg.distill.horizon_s / env.dt))

    state, n = envs.state, cfg.distill.num_envs
    active, art, t_ep = [0] * n, [-1] * n, [0] * n
    n_switch = n_reset = 0
    for t in range(cfg.distill.unroll_length):
        det = jax.device_get(inputs(state)["detect"])
        before = list(active)
        for i in range(n):
            active[i], art[i] = _reference_rule(active[i], art[i], int(det["kind"][i]),
                                                int(det["index"][i]), float(det["dist_m"][i]),
                                                lookup_m, setup_of, handover_m, force_m)
        n_switch += sum(a != b for a, b in zip(active, before))
        np.testing.assert_array_equal(tr["active"][t], active, err_msg=f"step {t}")
        obs = state.obs
        ref = np.stack([np.asarray(acts[active[i]](obs[i:i + 1], None))[0] for i in range(n)])
        np.testing.assert_allclose(tr["label"][t], ref, atol=2e-5, err_msg=f"step {t}")
        own = np.asarray(student_apply(student_params, obs))
        want = np.where(tr["by_teacher"][t][:, None], ref, own)
        np.testing.assert_allclose(tr["action"][t], want, atol=2e-5, err_msg=f"step {t}")
        nxt = step(state, jnp.asarray(tr["action"][t]))
        done = np.asarray(nxt.done) > 0.5
        t_ep = [k + 1 for k in t_ep]
        end = done | (np.asarray(t_ep) >= horizon)
        np.testing.assert_array_equal(tr["end"][t], end, err_msg=f"step {t}")
        state = jax.tree.map(lambda f, s: jnp.where(
            jnp.asarray(end).reshape((-1,) + (1,) * (jnp.ndim(s) - 1)), f, s), fresh.state, nxt)
        for i in np.flatnonzero(end):
            active[i], art[i], t_ep[i] = 0, -1, 0
            n_reset += 1
    assert n_reset >= n  # every env restarted: the teacher's state was reset with its episode
    assert n_switch >= 1  # the window holds switches, so the carried rule state was exercised


@pytest.mark.slow
def test_a_run_resumes_with_its_buffer(tmp_path, capsys):
    """Two chunks with a stop between: the second call resumes at the first's step, with the
    buffer it saved; the checkpoint loads as a policy (Table II's one-policy suite)."""
    from biped_switch.products import student
    cfg = _small_cfg()
    run_dir = tmp_path / "student_stand"
    with runs_lib.no_committed_copy():  # not from models/policies/student_stand
        p1 = student.train(cfg, run_dir, max_chunks=1)
        assert p1["step"] == 160 and p1["buffer_rows"] == 160
        p2 = student.train(cfg, run_dir, max_chunks=1)
    out = capsys.readouterr().out
    assert "resuming" in out and "buffer 160 rows" in out
    assert p2["step"] == 320 and p2["buffer_rows"] == 320
    assert (run_dir / student.BUFFER_FILE).exists()
    rows = runs_lib.Logger(run_dir).rows()
    assert max(float(r["step"]) for r in rows) == 320
    env = student.teacher_setup(cfg).env
    suite = pol.load_suite("stand", env, tmp_path, names=("student",))
    a = pol.all_actions(suite.apply, suite.params, env.reset(jax.random.PRNGKey(0)).obs[None])
    assert a.shape == (1, 1, 12) and np.all(np.abs(np.asarray(a)) <= 1.0)
    assert pathlib.Path(run_dir / "config.json").exists()

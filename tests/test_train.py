"""The trainer: PPO pieces against Python references, and the chunk / checkpoint / resume loop on
the real env (the `mujoco` backend compiles the whole PPO iteration in seconds)."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_switch.simulation import env as env_lib
from biped_switch.learning import networks
from biped_switch.learning import ppo
from biped_switch.learning import checkpoints as ckpt_lib
from biped_switch.learning import runs as runs_lib
from biped_switch.learning import trainer as train_lib
from biped_switch import train as train_cli
from biped_switch.config import default_train_config
from biped_switch.learning.policies import load_policy
from biped_switch.simulation.rollout import rollout, summarize
from biped_switch.reports import curves
from helpers import FakeEnv


def test_rollout_freezes_each_episode_at_its_end():
    env = FakeEnv(end_step=3)
    res = rollout(env, lambda obs, k: jnp.ones((obs.shape[0], 12)), jax.random.PRNGKey(0), 4, 10)
    np.testing.assert_allclose(res["reward"], 15.0)  # 3 live steps of reward 5, none after
    np.testing.assert_allclose(res["length"], 3.0)
    np.testing.assert_allclose(res["done"], 1.0)
    np.testing.assert_allclose(res["distance_m"], 3.0)  # metrics of the last live step
    s = summarize(res, 10)
    assert s["reward_per_step"] == pytest.approx(1.5)


def test_summary_splits_falls_by_kind_and_names_them():
    """4 episodes: fell at gaps, fell at gaps, fell on flat ground, finished; a mixed track's
    episodes met jumps 1/4, gaps 3/4, stairs 2/4."""
    res = {"reward": jnp.full(4, 10.0), "fell": jnp.array([1.0, 1.0, 1.0, 0.0]),
           "fail_kind": jnp.array([1.0, 1.0, -1.0, -1.0]),
           "met_jumps": jnp.array([0.0, 0.0, 0.0, 1.0]), "met_gaps": jnp.array([1.0, 1.0, 0.0, 1.0]),
           "met_stairs": jnp.array([0.0, 0.0, 1.0, 1.0])}
    s = summarize(res, 10)
    assert (s["fell_at/jumps"], s["fell_at/gaps"], s["fell_at/stairs"], s["fell_at/flat"]) == (
        0.0, 0.5, 0.0, 0.25)
    assert train_lib.fell_where(s) == " (gaps 0.50, flat 0.25)"
    assert train_lib.met_text(s) == "; met jumps 0.25, gaps 0.75, stairs 0.50"
    one_kind = {**s, "met_jumps": 0.0, "met_stairs": 0.0, "fell_at/flat": 0.0}
    assert train_lib.fell_where(one_kind) == " (gaps 0.50)" and train_lib.met_text(one_kind) == ""


def test_normalizer_matches_numpy_over_all_batches():
    rng = np.random.default_rng(0)
    batches = [rng.normal(3.0, 2.0, size=(n, 5)).astype(np.float32) for n in (7, 50, 3)]
    norm = ppo.Normalizer(jnp.zeros(5), jnp.ones(5), jnp.asarray(1e-8))
    for b in batches:
        norm = ppo.update_normalizer(norm, jnp.asarray(b))
    allb = np.concatenate(batches)
    np.testing.assert_allclose(norm.mean, allb.mean(0), rtol=1e-4)
    np.testing.assert_allclose(norm.var, allb.var(0), rtol=1e-3)
    assert float(norm.count) == pytest.approx(60.0)


def test_heightmap_pooling_is_the_block_mean():
    hm = np.arange(60 * 40, dtype=np.float32).reshape(60, 40) / 2400.0
    out = np.asarray(networks.encode_heightmap(jnp.asarray(hm.reshape(1, -1)), (60, 40), (2, 8)))
    assert out.shape == (1, 150)
    ref = [hm[2 * i:2 * i + 2, 8 * j:8 * j + 8].mean() for i in range(30) for j in range(5)]
    np.testing.assert_allclose(out[0], ref, rtol=1e-6)
    with pytest.raises(ValueError, match=r"\(7, 8\)"):
        networks.encode_heightmap(jnp.asarray(hm.reshape(1, -1)), (60, 40), (7, 8))


def _tiny_cfg(policy="gaps"):
    cfg = default_train_config("cpu")
    cfg.policy = policy  # gaps starts the terrain stage at difficulty 0 (walk starts at 1: flat)
    cfg.n_tracks = 2
    cfg.total_timesteps, cfg.chunk_timesteps, cfg.log_every = 128, 128, 1
    cfg.ppo.update(num_envs=8, num_minibatches=2, unroll_length=8)
    cfg.network.update(policy_hidden=(16,), value_hidden=(16,))
    cfg.eval.update(n_envs=4, horizon_steps=30)
    cfg.episode_length = 10  # episodes end (truncated) within each 16-step chunk
    cfg.env.backend = "mujoco"
    return cfg


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Two chunks on the real env, the second one resumed from the first's checkpoint."""
    run_dir = tmp_path_factory.mktemp("run") / "gaps_stand"
    mp = pytest.MonkeyPatch()  # never resume from a committed models/policies/gaps_stand
    mp.setattr(runs_lib, "COMMITTED_DIR", run_dir.parent / "committed")
    cfg = _tiny_cfg()
    cfg.curriculum.reward_milestone = 0.0  # every chunk advances the curriculum one notch
    lines = []
    first = train_lib.train(cfg, run_dir, print_fn=lines.append)
    ckpt1 = runs_lib.latest_checkpoint(run_dir)
    saved1 = jax.tree.map(np.asarray, ckpt_lib.load_checkpoint(ckpt1)[0])
    cfg.total_timesteps = 256
    resumed = []
    second = train_lib.train(cfg, run_dir, print_fn=lines.append,
                             on_restore=lambda ts: resumed.append(jax.tree.map(np.asarray, ts)))
    mp.undo()
    return {"dir": run_dir, "cfg": cfg, "first": first, "second": second, "lines": lines,
            "saved1": saved1, "resumed": resumed}


def test_chunk_checkpoint_records_progress(trained):
    prog = trained["first"]
    assert prog["step"] == 128 and prog["total_steps"] == 128
    assert prog["backend"] == "mujoco"
    assert prog["curriculum_before"]["difficulty"] == 0.0
    assert prog["curriculum"]["difficulty"] == pytest.approx(0.1)  # one notch of the milestone
    assert np.isfinite(prog["eval"]["reward_per_step"])
    compiled = [ln for ln in trained["lines"] if "compiled the PPO iteration" in ln]
    assert len(compiled) == 2  # once per run (process), never per chunk
    cfg_json = json.loads((trained["dir"] / "config.json").read_text())
    assert cfg_json["env"]["action"] == "torque" and cfg_json["network"]["encoding"] == "pool"


def test_resume_restores_optimiser_normaliser_and_curriculum(trained):
    saved, (resumed,) = trained["saved1"], trained["resumed"]
    # the optimiser's moments: Adam's mu/nu are non-zero after a chunk, and come back exactly
    adam = [x for x in jax.tree.leaves(saved["opt_state"]) if x.ndim > 0]
    assert adam and any(np.abs(x).max() > 0 for x in adam)
    for a, b in zip(jax.tree.leaves(saved["opt_state"]), jax.tree.leaves(resumed.opt_state)):
        np.testing.assert_array_equal(a, b)
    for k in ("mean", "var", "count"):
        np.testing.assert_array_equal(saved["norm"][k], getattr(resumed.norm, k))
    assert float(resumed.norm.count) > 100  # it has seen the first chunk's observations
    for a, b in zip(jax.tree.leaves(saved["params"]), jax.tree.leaves(resumed.params)):
        np.testing.assert_array_equal(a, b)
    second = trained["second"]
    assert any(ln.startswith("resuming") for ln in trained["lines"])
    assert second["step"] == 256
    assert second["curriculum_before"]["difficulty"] == pytest.approx(0.1)  # restored, not reset
    assert second["curriculum"]["difficulty"] == pytest.approx(0.2)
    assert second["wall_s"] > trained["first"]["wall_s"]
    # train.log keeps both sessions' progress lines, each part under a dated header
    log = (trained["dir"] / "train.log").read_text().splitlines()
    assert sum(ln.endswith("UTC: a session starts") for ln in log) == 2
    assert [ln for ln in log if not ln.startswith("# ")] == trained["lines"]


def test_metrics_log_and_curves(trained):
    run_dir = trained["dir"]
    rows = (run_dir / "metrics.csv").read_text().splitlines()
    header = rows[0].split(",")
    steps = [float(r.split(",")[header.index("step")]) for r in rows[1:]]
    assert steps == sorted(steps)
    for key in ("eval/reward_per_step", "loss/policy", "episode/sum_reward", "train/steps_per_s"):
        assert key in header
    terms = [f"reward/{k}" for k in env_lib.REWARD_TERMS]
    assert set(terms) <= set(header)
    for r in rows[1:]:  # the logged terms are per-step means of the same batch as the reward
        cells = r.split(",")
        if cells[header.index("train/reward_per_step")]:
            total = sum(float(cells[header.index(k)]) for k in terms)
            assert abs(total - float(cells[header.index("train/reward_per_step")])) < 1e-3
        if cells[header.index("eval/reward_per_step")]:  # the milestone rollout's, likewise
            total = sum(float(cells[header.index(f"eval/{k}")]) for k in terms)
            assert abs(total - float(cells[header.index("eval/reward_per_step")])) < 1e-3
    losses = [r.split(",")[header.index("loss/value")] for r in rows[1:]]
    assert [v for v in losses if v] and all(np.isfinite(float(v)) for v in losses if v)
    curves.ppo_curves(run_dir, run_dir / "curves.png")
    assert (run_dir / "curves.png").stat().st_size > 10_000


def test_committed_copy_resumes_a_fresh_machine(trained, tmp_path, monkeypatch):
    """With runs/ absent, train resumes from the committed models/policies/<run>/ copy."""
    committed = tmp_path / "models" / "policies"
    monkeypatch.setattr(runs_lib, "COMMITTED_DIR", committed)
    out = runs_lib.commit_run(trained["dir"], plot_fn=curves.ppo_curves)
    assert out == committed / "gaps_stand"
    assert [p.name for p in (out / "checkpoints").iterdir()] == [f"{256:012d}"]  # only the latest
    assert (out / "curves.png").exists() and (out / "config.json").exists()
    assert (out / "train.log").read_text() == (trained["dir"] / "train.log").read_text()
    cfg = trained["cfg"]
    cfg.total_timesteps = 256  # already there: nothing to train, but it must find the run
    lines = []
    prog = train_lib.train(cfg, tmp_path / "runs" / "gaps_stand", print_fn=lines.append)
    assert any("resuming from the committed" in ln for ln in lines)
    assert runs_lib.latest_checkpoint(tmp_path / "runs" / "gaps_stand").name == f"{256:012d}"
    assert prog == {}  # no chunk ran: the goal was already reached
    log = (tmp_path / "runs" / "gaps_stand" / "train.log").read_text().splitlines()
    assert sum(ln.endswith("a session starts") for ln in log) == 3  # the committed log goes on


def test_loaded_policy_acts_like_the_trainer(trained):
    ckpt = runs_lib.latest_checkpoint(trained["dir"])
    env = train_lib.train_env(trained["cfg"])
    act, progress = load_policy(ckpt, env)
    state = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 3))
    a = np.asarray(act(state.obs, None))
    assert a.shape == (3, 12) and np.all(np.abs(a) <= 1.0)
    tree, _ = ckpt_lib.load_checkpoint(ckpt)
    pol = ppo.make_policy(trained["cfg"].network, env)
    norm = ppo.Normalizer(**{k: jnp.asarray(v) for k, v in tree["norm"].items()})
    ref = np.clip(np.asarray(pol(tree["params"], norm, state.obs, None, True)), -1, 1)
    np.testing.assert_allclose(a, ref, rtol=1e-5, atol=1e-6)
    pd_env = train_lib.env_lib.make_env("gaps", n_tracks=1, action="pd")
    with pytest.raises(ValueError, match="action"):
        load_policy(ckpt, pd_env)


def test_probe_guides_is_the_curriculum_check_at_other_levels(trained):
    """`--probe-guides`: the check of the latest checkpoint at each guide level, one rng, at the
    difficulty and pushes it trained at; each row matches the same episodes rolled out through
    the other loader (policies.load_policy), and a level outside [0, 1] is named."""
    run = trained["dir"]
    doc = train_lib.probe_guides(run, [0.0, 0.5], seed=3)
    ckpt = runs_lib.latest_checkpoint(run)
    prog = json.loads((ckpt / runs_lib.PROGRESS).read_text())
    assert doc["checkpoint"] == str(ckpt) and doc["trained_at"] == prog["curriculum_before"]
    assert [r["guide_scale"] for r in doc["rows"]] == [0.0, 0.5]
    cfg = runs_lib.run_config(run)
    env = train_lib.train_env(cfg)
    act, _ = load_policy(ckpt, env)
    d, p = prog["curriculum_before"]["difficulty"], prog["curriculum_before"]["push_scale"]
    for row in doc["rows"]:
        ev = train_lib.summarize(train_lib.milestone_rollout(
            env, act, jax.random.PRNGKey(3), cfg.eval, (d, row["guide_scale"], p)),
            cfg.eval.horizon_steps)
        for k in ("fell", "reward_per_step", "distance_m"):
            assert row[k] == pytest.approx(ev[k], rel=1e-4, abs=1e-5), k
    with pytest.raises(ValueError, match="1.5"):
        train_lib.probe_guides(run, [1.5])
    assert "| 0.5 |" in train_lib.probe_markdown(doc)


def test_the_push_stage_ends_with_a_milestone_at_full_pushes(tmp_path, monkeypatch):
    """curriculum_done: pushes at 1 and one more milestone there; not before. Training then stops
    short of total_timesteps (and a rerun trains nothing) unless stop_when_done is off."""
    monkeypatch.setattr(runs_lib, "COMMITTED_DIR", tmp_path / "committed")  # not the real walk
    cfg = _tiny_cfg("walk")
    cfg.total_timesteps = 128 * 6
    cfg.start.update(stage=2, difficulty=1.0, guide_scale=0.0, push_scale=0.9)
    cfg.curriculum.reward_milestone = 0.0
    prog = train_lib.train(cfg, tmp_path / "walk_stand", max_chunks=1, print_fn=lambda *a: None)
    assert prog["curriculum"]["push_scale"] == pytest.approx(1.0) and not prog["curriculum_done"]
    lines = []
    prog = train_lib.train(cfg, tmp_path / "walk_stand", print_fn=lines.append)
    assert prog["curriculum_before"]["push_scale"] == pytest.approx(1.0) and prog["curriculum_done"]
    assert prog["step"] == 256 and "the curriculum finished at step 256" in lines[-1]
    # finished short of total_timesteps, a ceiling only: nothing flags it (Table III, the demo)
    assert runs_lib.run_notes(tmp_path / "walk_stand") == []
    lines = []
    again = train_lib.train(cfg, tmp_path / "walk_stand", print_fn=lines.append)
    assert again["step"] == 256 and "nothing to train" in lines[-1]
    cfg.stop_when_done = False
    on = train_lib.train(cfg, tmp_path / "walk_stand", max_chunks=1, print_fn=lambda *a: None)
    assert on["step"] == 384 and on["curriculum_done"]


@pytest.mark.slow  # 2-3 min; the plateau rule itself: test_curriculum.test_push_plateau_by_hand
def test_the_push_stage_ends_on_a_plateau(tmp_path, monkeypatch):
    """No milestone at push 0.5 for push_plateau_steps env steps: the curriculum ends there,
    holding push 0.4, and says so in progress.json and the log. A checkpoint from
    before session 11 (no push_high in progress.json) replays metrics.csv to the same end."""
    monkeypatch.setattr(runs_lib, "COMMITTED_DIR", tmp_path / "committed")
    cfg = _tiny_cfg("walk")
    cfg.total_timesteps = 128 * 8
    cfg.start.update(stage=2, difficulty=1.0, guide_scale=0.0, push_scale=0.5)
    cfg.curriculum.update(reward_milestone=100.0, regress_fell=1.0, push_plateau_steps=256)
    quiet = lambda *a: None  # noqa: E731
    for old in (False, True):
        run = tmp_path / f"walk_stand_{old}"
        first = train_lib.train(cfg, run, max_chunks=1, print_fn=quiet)
        assert (first["push_high"], first["push_high_step"], first["curriculum_done"]) == (0.5, 128, False)
        if old:
            ck = runs_lib.latest_checkpoint(run) / runs_lib.PROGRESS
            prog = json.loads(ck.read_text())
            for k in ("push_high", "push_high_step", "curriculum_end", "push_held"):
                del prog[k]
            ck.write_text(json.dumps(prog))
        lines = []
        last = train_lib.train(cfg, run, print_fn=lines.append)
        assert last["step"] == 384 and last["curriculum_done"]
        assert last["curriculum_end"] == "push plateau" and last["push_held"] == pytest.approx(0.4)
        assert any("ends on a plateau, holding push 0.40" in ln for ln in lines)
        assert "the curriculum finished at step 384" in lines[-1]
        # finished: the demo and Table III do not count it as in training
        assert runs_lib.run_notes(run) == [] == runs_lib.run_notes(run, step_goal=False)


def test_unknown_policy_and_preset_are_named():
    cfg = default_train_config("cpu")
    cfg.policy = "hop"
    with pytest.raises(ValueError, match="'hop'"):
        train_lib.train_env(cfg)
    with pytest.raises(ValueError, match="'tpu'"):
        default_train_config("tpu")
    cfg = _tiny_cfg()
    cfg.ppo.num_minibatches = 5
    with pytest.raises(ValueError, match="5 minibatches"):
        ppo.make_train(cfg, train_lib.train_env(cfg))


def test_gae_masks_truncated_steps_like_a_python_loop():
    """ppo's GAE recursion against a hand loop: a termination cuts the bootstrap, a truncation
    zeroes its own delta and the recursion through it (Brax's rule)."""
    rew = np.array([1.0, 2.0, 0.5, 1.0, 3.0])
    val = np.array([0.3, 0.1, 0.4, 0.2, 0.6])
    v_next = np.array([0.1, 0.4, 0.2, 0.6, 0.9])
    term = np.array([0, 1, 0, 0, 0.0])
    trunc = np.array([0, 0, 0, 1, 0.0])
    g, lam = 0.9, 0.8
    ref, acc = np.zeros(5), 0.0
    for t in reversed(range(5)):
        keep = 1 - trunc[t]
        delta = (rew[t] + g * (1 - term[t]) * v_next[t] - val[t]) * keep
        acc = delta + g * lam * (1 - term[t]) * keep * acc
        ref[t] = acc
    out = np.asarray(ppo.gae(jnp.asarray(rew), jnp.asarray(val), jnp.asarray(v_next),
                             jnp.asarray(term), jnp.asarray(trunc), g, lam))
    np.testing.assert_allclose(out, ref, rtol=1e-6)
    assert out[3] == 0.0 and out[1] == pytest.approx(2.0 - 0.1)


@pytest.mark.slow  # 75-100 s alone on a busy 2-core machine: two compiles, 20k env steps
def test_train_real_env_learns_to_walk_further_across_a_resume(tmp_path):
    """PPO learns on the real env (`mujoco` backend), through train()'s chunk / checkpoint /
    resume loop: flat walk tracks, no guide forces, the curriculum held still. After 512 env steps
    the deterministic policy falls within 0.2 m of its start; 20k steps later (resumed from that
    checkpoint) it gets more than 0.4 m, and 0.3 m further than before. Measured on seeds 0-3:
    0.53-0.75 m further; with the learning rate at 1e-12 (only the normaliser moving) 0.12 m
    further, which fails this test."""
    from biped_switch.config import default_train_config

    cfg = default_train_config("cpu")
    cfg.policy, cfg.seed, cfg.n_tracks = "walk", 0, 2
    cfg.total_timesteps, cfg.chunk_timesteps, cfg.log_every = 512, 512, 10
    cfg.ppo.update(num_envs=32, num_minibatches=4, unroll_length=16)  # 512 env steps per iteration
    cfg.network.update(policy_hidden=(32,), value_hidden=(32,))
    cfg.eval.update(n_envs=16, horizon_steps=100)
    cfg.episode_length = 100
    cfg.env.backend = "mujoco"
    cfg.start.update(stage=1, difficulty=1.0, guide_scale=0.0, push_scale=0.0)
    cfg.curriculum.reward_milestone = 1.0  # never met (reward per step <= its maximum): no notch
    run_dir = tmp_path / "ppo_learns"  # a name with no committed copy under models/policies/
    lines = []
    first = train_lib.train(cfg, run_dir, print_fn=lines.append)
    cfg.total_timesteps, cfg.chunk_timesteps = 20_480, 20_480 - 512
    last = train_lib.train(cfg, run_dir, print_fn=lines.append)
    assert any(ln.startswith(f"resuming {run_dir} at step 512") for ln in lines)
    assert first["step"] == 512 and last["step"] == 20_480
    assert last["curriculum"] == first["curriculum_before"]  # the curriculum did not move
    e0, e1 = first["eval"], last["eval"]
    assert e0["distance_m"] < 0.2, e0
    assert e1["distance_m"] > 0.4 and e1["distance_m"] > e0["distance_m"] + 0.3, (e0, e1)
    assert e1["reward_per_step"] > e0["reward_per_step"], (e0, e1)


def test_warm_start_names_resolve_to_checkpoints(trained):
    run_dir = trained["dir"]
    latest = runs_lib.latest_checkpoint(run_dir)
    assert runs_lib.resolve_checkpoint(str(latest)) == latest  # a checkpoint folder
    assert runs_lib.resolve_checkpoint(str(run_dir)) == latest  # a run folder: its latest
    assert runs_lib.resolve_checkpoint("gaps_stand", run_dir.parent) == latest  # a run name
    with pytest.raises(FileNotFoundError, match="no_such_run"):
        runs_lib.resolve_checkpoint("no_such_run", run_dir.parent)


def test_a_resume_keeps_the_runs_own_settings(tmp_path, monkeypatch):
    """A flag's value (learning rate, guide notch) comes from runs/<run>/config.json, else the
    committed copy's; none: None."""
    committed = tmp_path / "models" / "policies"
    monkeypatch.setattr(runs_lib, "COMMITTED_DIR", committed)
    run = tmp_path / "runs" / "jumps_stand"
    assert train_lib.saved_setting(run, "ppo", "learning_rate") is None
    (committed / "jumps_stand").mkdir(parents=True)
    (committed / "jumps_stand" / "config.json").write_text(json.dumps(
        {"ppo": {"learning_rate": 2e-4}, "curriculum": {"guide_notch": 0.25}}))
    assert train_lib.saved_setting(run, "ppo", "learning_rate") == pytest.approx(2e-4)
    assert train_lib.saved_setting(run, "curriculum", "guide_notch") == pytest.approx(0.25)
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"ppo": {"learning_rate": 1e-4}}))
    assert train_lib.saved_setting(run, "ppo", "learning_rate") == pytest.approx(1e-4)
    assert train_lib.saved_setting(run, "curriculum", "guide_notch") is None
    (run / "config.json").write_text(json.dumps({"chunk_timesteps": 250_000, "ppo": {}}))
    assert train_lib.saved_setting(run, None, "chunk_timesteps") == 250_000
    assert train_lib.saved_setting(run, None, "total_timesteps") is None


def test_guide_notch_flag_names_a_bad_value(capsys):
    with pytest.raises(SystemExit):
        train_cli.main(["--policy", "mixed", "--guide-notch", "1.0"])
    assert "--guide-notch must be in (0, 1), got 1.0" in capsys.readouterr().err


def test_action_std_cap_projects_the_log_std_after_updates_and_on_resume():
    """`ppo.max_action_std`: a fresh policy starts at the cap when its initial std is above it;
    a restored log std above the cap (a run resumed under a new cap) is cut to it before the
    rollout and stays there through the updates, and the joints below the cap move only by
    Adam's steps (at most lr per update, 8 updates here)."""
    cfg = _tiny_cfg()
    cfg.ppo.update(max_action_std=0.3, init_action_std=0.5)
    env = train_lib.train_env(cfg)
    trainer = ppo.make_train(cfg, env)
    ts = trainer.init(jax.random.PRNGKey(0))
    np.testing.assert_allclose(np.exp(ts.params["log_std"]), 0.3, rtol=1e-6)
    before = np.log(np.linspace(0.05, 1.2, 12)).astype(np.float32)  # 0.05, 0.155, ...: 9 above 0.3
    ts = ts._replace(params={**ts.params, "log_std": jnp.asarray(before)})
    curr = jnp.asarray((0.0, 1.0, 0.0), jnp.float32)
    envs = trainer.reset_envs(jax.random.PRNGKey(1), curr)
    ts2, _, metrics = trainer.iteration(ts, envs, jax.random.PRNGKey(2), curr)
    after = np.asarray(ts2.params["log_std"])
    above = before > np.log(0.3)
    assert above.sum() == 9
    n_updates = cfg.ppo.num_minibatches * cfg.ppo.num_updates_per_batch
    max_move = 1.01 * cfg.ppo.learning_rate * n_updates  # Adam: about lr per update, at most
    # cut to the cap, then free to move down from it by the updates, never up past it
    assert np.all(after[above] <= np.log(0.3) + 1e-6)
    assert np.all(after[above] >= np.log(0.3) - max_move)
    assert np.all(np.abs(after[~above] - before[~above]) <= max_move)
    assert float(metrics["train/action_std_max"]) == pytest.approx(np.exp(after.max()), rel=1e-5)
    assert float(metrics["train/action_std_max"]) <= 0.3 * (1 + 1e-6)
    assert float(metrics["train/action_std"]) == pytest.approx(np.mean(np.exp(after)), rel=1e-5)


def test_action_std_flag_names_a_bad_value(capsys):
    with pytest.raises(SystemExit):
        train_cli.main(["--policy", "mixed", "--max-action-std", "-0.1"])
    assert "--max-action-std must be >= 0 (0: no cap), got -0.1" in capsys.readouterr().err


def test_run_config_reads_back_what_the_run_was_made_with(tmp_path):
    """A run's config.json comes back over today's defaults: the CPU preset's track bank and
    curriculum-check size, a changed curriculum value; a key the run predates (push_magnitude,
    session 9) keeps today's default; an unknown saved key is ignored."""
    saved = default_train_config("cpu")
    saved.curriculum.max_push_N = 100.0
    d = json.loads(saved.to_json_best_effort())
    del d["curriculum"]["push_magnitude"]
    d["curriculum"]["no_longer_a_key"] = 1
    (tmp_path / "config.json").write_text(json.dumps(d))
    cfg = runs_lib.run_config(tmp_path)
    assert (cfg.n_tracks, cfg.eval.n_envs, cfg.eval.horizon_steps) == (32, 64, 1000)
    assert default_train_config().n_tracks == 256 and default_train_config().eval.n_envs == 256
    assert cfg.curriculum.max_push_N == 100.0 and cfg.curriculum.push_magnitude == "uniform"
    assert "no_longer_a_key" not in cfg.curriculum


# ----------------------------------------------------------------------------- the PPO loss
def _loss_by_hand(w_pi, w_vf, log_std, mb, eps, c_v, c_e):
    """ppo_loss in numpy with linear networks: the clipped surrogate over the learner's
    non-truncated steps, advantages standardised over the learner's steps."""
    x = mb["x"]
    mean, v = x @ w_pi, (x @ w_vf)[:, 0]
    std = np.exp(log_std)
    logp = np.sum(-0.5 * ((mb["action"] - mean) / std) ** 2 - log_std - 0.5 * np.log(2 * np.pi), 1)
    ratio = np.exp(logp - mb["logp"])
    lm = mb["learner"]
    a = mb["adv"]
    am = (a * lm).sum() / lm.sum()
    a = (a - am) / (np.sqrt((lm * (a - am) ** 2).sum() / lm.sum()) + 1e-8)
    surr = np.minimum(ratio * a, np.clip(ratio, 1 - eps, 1 + eps) * a)
    w = mb["mask"] * lm
    pg = -(surr * w).sum() / w.sum()
    v_loss = 0.5 * np.mean((v - mb["target"]) ** 2)
    ent = np.sum(log_std + 0.5 * np.log(2 * np.pi * np.e))
    return pg + c_v * v_loss - c_e * ent, pg, v_loss


def test_ppo_loss_against_a_hand_computation():
    """`ppo_loss` equals the formula computed by hand, on a minibatch where the learner mask, the
    truncation mask and the clipping all bite: dropping either mask, or flipping the surrogate's
    sign, changes the policy loss by far more than the tolerance."""
    rng = np.random.default_rng(0)
    n, i, a_dim = 16, 5, 3
    w_pi, w_vf = rng.normal(size=(i, a_dim)) * 0.3, rng.normal(size=(i, 1))
    log_std = np.log(np.array([0.3, 0.5, 0.8]))
    x = rng.normal(size=(n, i))
    mb = {"x": x, "action": x @ w_pi + rng.normal(size=(n, a_dim)) * 0.4,
          "logp": rng.normal(-1.0, 1.5, n), "adv": rng.normal(size=n), "target": rng.normal(size=n),
          "mask": (np.arange(n) % 5 != 0).astype(float), "learner": (np.arange(n) % 3 != 0).astype(float)}
    hp = ppo.LossParams(0.2, 0.5, 0.01)
    params = {"policy": jnp.asarray(w_pi, jnp.float32), "value": jnp.asarray(w_vf, jnp.float32),
              "log_std": jnp.asarray(log_std, jnp.float32)}
    total, info = ppo.ppo_loss(params, jax.tree.map(lambda v: jnp.asarray(v, jnp.float32), mb),
                               lambda p, z: z @ p, lambda p, z: z @ p, hp)
    ref_total, ref_pg, ref_v = _loss_by_hand(w_pi, w_vf, log_std, mb, 0.2, 0.5, 0.01)
    np.testing.assert_allclose(float(info["loss/policy"]), ref_pg, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(float(info["loss/value"]), ref_v, rtol=1e-4)
    np.testing.assert_allclose(float(total), ref_total, rtol=1e-4, atol=1e-5)
    assert 0.0 < float(info["loss/clip_frac"]) < 1.0  # the clip is active on some steps
    no_mask = dict(mb, mask=np.ones(n))
    no_learner = dict(mb, learner=np.ones(n))
    for wrong in (no_mask, no_learner):
        assert abs(_loss_by_hand(w_pi, w_vf, log_std, wrong, 0.2, 0.5, 0.01)[1] - ref_pg) > 1e-2
    assert abs(ref_pg) > 1e-2  # a flipped sign would show


def test_pooled_network_input_is_the_same_function_of_the_observation():
    """The trainer's networks on `policy_input` (heightmap pooled at collection, 1 x 1 pool in
    the network) give the policy's actions and values on the full observation, with the same
    parameters: the rollout can store 203 columns instead of 2,453."""
    cfg = default_train_config("cpu")
    env = env_lib.make_env("mixed", n_tracks=2, phase_obs=True)
    obs_size = env.policy_observation_size
    rng = np.random.default_rng(1)
    obs = rng.normal(size=(6, obs_size)).astype(np.float32)
    lay = env.obs_layout
    obs[:, lay.heightmap] = rng.uniform(size=(6, lay.hm_size))
    pi_full, vf_full = ppo.make_networks(cfg.network, env)
    pi_pool, vf_pool = ppo.make_networks(cfg.network, env, pooled_input=True)
    params = {"policy": pi_full.init(jax.random.PRNGKey(0), jnp.zeros((1, obs_size))),
              "value": vf_full.init(jax.random.PRNGKey(1), jnp.zeros((1, obs_size)))}
    norm = ppo.Normalizer(jnp.asarray(rng.normal(size=obs_size), jnp.float32),
                          jnp.asarray(rng.uniform(0.5, 2.0, obs_size), jnp.float32), jnp.asarray(10.0))
    mask = jnp.asarray(ppo.norm_mask(env))
    full_in = ppo.normalize(norm, jnp.asarray(obs), mask)
    policy_input, cols, in_mask = ppo.policy_input_fn(cfg.network, env)
    assert len(cols) == lay.state_size + 150 + lay.n_phase
    x = policy_input(jnp.asarray(obs))
    xn = ppo.normalize(ppo.Normalizer(norm.mean[cols], norm.var[cols], norm.count), x,
                       jnp.asarray(in_mask))
    np.testing.assert_allclose(pi_pool.apply(params["policy"], xn),
                               pi_full.apply(params["policy"], full_in), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(vf_pool.apply(params["value"], xn),
                               vf_full.apply(params["value"], full_in), rtol=1e-5, atol=1e-6)


def test_normalizer_update_of_some_columns_leaves_the_others():
    rng = np.random.default_rng(2)
    norm = ppo.Normalizer(jnp.asarray(rng.normal(size=6), jnp.float32),
                          jnp.asarray(rng.uniform(1, 2, 6), jnp.float32), jnp.asarray(5.0))
    cols, mask = np.array([0, 2, 2, 5]), np.array([1, 1, 0, 1], np.float32)
    batch = jnp.asarray(rng.normal(size=(9, 4)), jnp.float32)
    out = ppo.update_normalizer_cols(norm, batch, cols, mask)
    b = np.asarray(batch)
    full = ppo.update_normalizer(norm, jnp.asarray(b[:, [0, 0, 1, 0, 0, 3]]))
    mean, var, old = (np.asarray(a) for a in (out.mean, out.var, norm.mean))
    np.testing.assert_allclose(mean[[0, 2, 5]], np.asarray(full.mean)[[0, 2, 5]], rtol=1e-6)
    np.testing.assert_allclose(var[[0, 2, 5]], np.asarray(full.var)[[0, 2, 5]], rtol=1e-6)
    np.testing.assert_array_equal(mean[[1, 3, 4]], old[[1, 3, 4]])
    assert float(out.count) == 14.0


def test_a_committed_checkpoint_chosen_short_of_the_ceiling_is_not_in_training(tmp_path):
    """commit_run with a chosen checkpoint (one picked on tuning tracks, not the latest) writes
    chosen.json, and run_notes then does not count the step goal; committing the latest again
    removes it, and the note comes back."""
    run = tmp_path / "student_stand"
    for step in (100, 200):
        ck = run / "checkpoints" / f"{step:012d}"
        ck.mkdir(parents=True)
        (ck / runs_lib.PROGRESS).write_text(json.dumps({"step": step, "total_steps": 400}))
    out = tmp_path / "committed"
    runs_lib.commit_run(run, out_dir=out, ckpt=run / "checkpoints" / f"{100:012d}")
    assert [c.name for c in runs_lib.checkpoints(out)] == [f"{100:012d}"]
    assert json.loads((out / runs_lib.CHOSEN_FILE).read_text())["step"] == 100
    assert runs_lib.run_notes(out) == []
    assert runs_lib.run_notes(run) == ["at step 200 of 400"]  # the run itself: short of its goal
    runs_lib.commit_run(run, out_dir=out)
    assert not (out / runs_lib.CHOSEN_FILE).exists()
    assert runs_lib.run_notes(out) == ["at step 200 of 400"]
    with pytest.raises(FileNotFoundError, match="no progress.json"):
        runs_lib.commit_run(run, out_dir=out, ckpt=tmp_path / "nowhere")


def test_update_flags_set_the_ppo_update_and_a_resume_keeps_its_own(tmp_path, monkeypatch, capsys):
    """`--update-epochs` / `--minibatches` reach the trainer's config; without them a resumed run
    keeps the update in its config.json (a run never changes learner when resumed), and a fresh
    run takes the preset's. A bad value is named."""
    seen = []
    monkeypatch.setattr(train_lib, "train", lambda cfg, run_dir, *a, **k: seen.append(
        (cfg.ppo.num_updates_per_batch, cfg.ppo.num_minibatches)))
    argv = ["--policy", "walk", "--preset", "cpu", "--out", str(tmp_path), "--name", "w"]  # no committed copy
    preset = default_train_config("cpu").ppo
    train_cli.main(argv)
    saved = default_train_config("cpu")
    saved.ppo.update(num_updates_per_batch=2, num_minibatches=8)
    (tmp_path / "w").mkdir()
    (tmp_path / "w" / "config.json").write_text(saved.to_json_best_effort())
    train_cli.main(argv)
    train_cli.main(argv + ["--update-epochs", "1", "--minibatches", "16"])
    assert seen == [(preset.num_updates_per_batch, preset.num_minibatches), (2, 8), (1, 16)]
    with pytest.raises(SystemExit):
        train_cli.main(argv + ["--update-epochs", "0"])
    assert "--update-epochs must be >= 1, got 0" in capsys.readouterr().err

"""Switch estimators: the balanced group split, ROC AUC, predict, training, checkpoints and the CLI."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from biped_switch.simulation import env as env_lib
from biped_switch.simulation.observation import layout
from biped_switch.switching import estimator as est
from biped_switch import estimator as estimator_cli
from biped_switch.config import default_env_config, default_estimator_config

IN_SIZE = layout(default_env_config()).estimator.stop  # state (51) + heightmap (2400)


def synthetic_data(n_samples: int = 400, seed: int = 0, pos_quantile: float = 0.6) -> dict:
    """Sweep-shaped data: 5 points per switch sample (rows shuffled, sample ids not contiguous),
    labelled 1 when the sample's state[0] is above its `pos_quantile` quantile (40% positive).
    Heightmaps are terrain-like (a step edge at a random row per point, unrelated to the label):
    i.i.d. noise in 2400 columns would let the net tell every sample apart and memorise labels."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(n_samples, est.STATE_SIZE)).astype(np.float32)
    label = (base[:, 0] > np.quantile(base[:, 0], pos_quantile)).astype(np.int8)
    n = 5 * n_samples
    state = np.repeat(base, 5, 0) + 0.01 * rng.normal(size=(n, est.STATE_SIZE)).astype(np.float32)
    order = rng.permutation(n)
    return {
        "state": state[order].astype(np.float32),
        "heightmap": heightmaps(rng.integers(0, 60, n), rng.uniform(0.1, 0.3, n)),
        "label": np.repeat(label, 5)[order],
        "sample": np.repeat(7 * np.arange(n_samples, dtype=np.int32) + 3, 5)[order],
        "offset": np.tile(np.arange(-2, 3, dtype=np.int8), n_samples)[order],
        "source": np.zeros(n, np.int8),
        "switch_dist_m": np.repeat(rng.uniform(0, 0.9, n_samples), 5)[order].astype(np.float32),
        "meta": np.array(json.dumps({"synthetic": True, "seed": seed})),
    }


def heightmaps(edge_row, rise, rows=60, cols=40) -> np.ndarray:
    """(n, rows*cols) float16: 0.5 behind row `edge_row`, 0.5 - rise from it on (a step up)."""
    hm = np.where(np.arange(rows)[None, :, None] >= edge_row[:, None, None],
                  0.5 - rise[:, None, None], 0.5) * np.ones((1, 1, cols))
    return hm.reshape(len(edge_row), -1).astype(np.float16)


def small_cfg(**kw):
    cfg = default_estimator_config()
    cfg.update(dict(hm_hidden=(8,), hidden=(16,), epochs=8, batch_size=64, learning_rate=3e-3,
                    val_frac=0.2, seed=0) | kw)
    return cfg


def random_params(seed: int, cfg=None) -> dict:
    """Untrained params with non-trivial normalisation statistics."""
    cfg = small_cfg() if cfg is None else cfg
    rng = np.random.default_rng(seed)
    return est.init_params(cfg, jax.random.PRNGKey(seed),
                           mean=rng.normal(size=IN_SIZE).astype(np.float32),
                           std=rng.uniform(0.5, 2.0, IN_SIZE).astype(np.float32))


def random_obs(n: int, extra: int = 0, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(n, IN_SIZE + extra)).astype(np.float32)


def test_input_layout_matches_env():
    assert est.STATE_SIZE == env_lib.STATE_SIZE
    assert IN_SIZE == 51 + 60 * 40 == 2451
    # the default layout's sizes, for callers that assume it (resolved when asked for)
    assert est.HM_SIZE == 60 * 40 and est.IN_SIZE == IN_SIZE


# ------------------------------------------------------------------------------ balanced_split


def grouped_labels(n_groups=2000, pos_frac=0.3, seed=0):
    rng = np.random.default_rng(seed)
    g_label = (rng.uniform(size=n_groups) < pos_frac).astype(np.int8)
    ids = rng.choice(10**6, n_groups, replace=False)
    order = rng.permutation(5 * n_groups)
    return np.repeat(g_label, 5)[order], np.repeat(ids, 5)[order]


@pytest.mark.parametrize("val_frac", [0.1, 0.25])
def test_balanced_split_groups_balance_and_fraction(val_frac):
    labels, groups = grouped_labels()
    tr, va = est.balanced_split(labels, groups, val_frac, np.random.default_rng(0))
    assert len(np.intersect1d(tr, va)) == 0
    assert len(np.unique(tr)) == len(tr) and len(np.unique(va)) == len(va)
    assert len(np.intersect1d(groups[tr], groups[va])) == 0  # no sample straddles the split
    for idx in (tr, va):
        assert labels[idx].sum() * 2 == len(idx)  # exactly 50/50
    assert abs(len(va) / (len(tr) + len(va)) - val_frac) < 0.02
    # only the majority label (0) is subsampled: every positive point is used
    assert np.array_equal(np.sort(np.concatenate([tr, va])[labels[np.concatenate([tr, va])] == 1]),
                          np.flatnonzero(labels == 1))
    # deterministic for a given generator state
    tr2, va2 = est.balanced_split(labels, groups, val_frac, np.random.default_rng(0))
    assert np.array_equal(tr, tr2) and np.array_equal(va, va2)


def test_balanced_split_errors_when_a_label_is_missing():
    labels, groups = grouped_labels(n_groups=50)
    with pytest.raises(ValueError, match="label 1"):
        est.balanced_split(np.zeros_like(labels), groups, 0.1, np.random.default_rng(0))
    with pytest.raises(ValueError, match="label 0"):
        est.balanced_split(np.ones_like(labels), groups, 0.1, np.random.default_rng(0))
    # one positive sample (5 points): it cannot be on both sides
    one = np.zeros_like(labels)
    one[groups == groups[0]] = 1
    with pytest.raises(ValueError, match="label 1"):
        est.balanced_split(one, groups, 0.1, np.random.default_rng(0))
    # two positive samples: one on each side, balanced
    two = one.copy()
    two[groups == groups[groups != groups[0]][0]] = 1
    tr, va = est.balanced_split(two, groups, 0.1, np.random.default_rng(0))
    assert two[tr].sum() == 5 and two[va].sum() == 5
    assert len(tr) == len(va) == 10


# -------------------------------------------------------------------------------------- roc_auc


def test_roc_auc_hand_computed():
    assert est.roc_auc([0.1, 0.2, 0.8, 0.9], [0, 0, 1, 1]) == 1.0
    assert est.roc_auc([0.9, 0.8, 0.2, 0.1], [0, 0, 1, 1]) == 0.0
    assert est.roc_auc([0.3, 0.3, 0.3], [1, 0, 1]) == 0.5
    # positives 0.5 and 0.8, negatives 0.5 and 0.2: pairs (0.5,0.5) tie = 1/2, the others win: 3.5/4
    assert est.roc_auc([0.5, 0.5, 0.2, 0.8], [1, 0, 0, 1]) == pytest.approx(0.875)
    # positives 0.1, 0.4; negatives 0.4, 0.35, 0.9: wins (0.4>0.35), tie (0.4,0.4): 1.5 / 6
    assert est.roc_auc([0.1, 0.4, 0.4, 0.35, 0.9], [1, 1, 0, 0, 0]) == pytest.approx(0.25)
    with pytest.raises(ValueError):
        est.roc_auc([0.1, 0.2], [1, 1])


def test_roc_auc_matches_pairwise_count():
    rng = np.random.default_rng(3)
    for n in (7, 300):
        scores = np.round(rng.uniform(size=n), 1)  # many ties
        labels = rng.uniform(size=n) < 0.4
        labels[:2] = [True, False]
        pos, neg = scores[labels], scores[~labels]
        brute = ((pos[:, None] > neg[None]).sum() + 0.5 * (pos[:, None] == neg[None]).sum()) / (
            len(pos) * len(neg))
        assert est.roc_auc(scores, labels) == pytest.approx(brute, abs=1e-12)


# -------------------------------------------------------------------------------------- predict


def test_predict_ignores_trailing_columns_and_normalises():
    params = random_params(0)
    obs = random_obs(6, extra=3)
    p = jax.jit(est.predict)(params, obs)
    assert p.shape == (6,)
    np.testing.assert_allclose(p, est.predict(params, obs[:, : IN_SIZE]), rtol=0, atol=1e-6)
    other = obs.copy()
    other[:, IN_SIZE:] = 1e3
    np.testing.assert_allclose(p, est.predict(params, other), rtol=0, atol=1e-6)
    # the stored statistics are applied: same as the bare net on (obs - mean) / std
    net = est.EstimatorNet(hm_hidden=(8,), hidden=(16,))
    x = (obs[:, : IN_SIZE] - params["mean"]) / params["std"]
    np.testing.assert_allclose(p, net.apply(params["net"], x), rtol=1e-5, atol=1e-6)
    assert np.all((np.asarray(p) > 0) & (np.asarray(p) < 1))
    # any leading shape; a single observation gives a scalar
    assert est.predict(params, obs.reshape(2, 3, -1)).shape == (2, 3)
    assert est.predict(params, obs[0]).shape == ()


def test_module_sizes_read_from_params():
    cfg = small_cfg(hm_hidden=(5, 4), hidden=(7, 6, 3))
    net = est.module_from_params(est.init_params(cfg, jax.random.PRNGKey(0), in_size=IN_SIZE)["net"])
    assert tuple(net.hm_hidden) == (5, 4) and tuple(net.hidden) == (7, 6, 3)


def test_vmap_over_stacked_params_equals_each():
    p1, p2 = random_params(1), random_params(2)
    obs = random_obs(5, extra=3)
    stacked = est.stack_params([p1, p2])
    assert stacked["mean"].shape == (2, IN_SIZE)
    both = jax.jit(jax.vmap(est.predict, in_axes=(0, None)))(stacked, obs)
    assert both.shape == (2, 5)
    e1, e2 = est.predict(p1, obs), est.predict(p2, obs)
    assert not np.allclose(e1, e2, atol=1e-3)  # the estimators differ, so the test can tell them apart
    np.testing.assert_allclose(both[0], e1, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(both[1], e2, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="cannot stack"):
        est.stack_params([p1, random_params(3, small_cfg(hidden=(32,)))])


def test_sizes_come_from_the_data_and_params_not_the_default_grid():
    """An estimator of another heightmap grid (2 x 2) is trained on and reads its own columns:
    nothing fixes the default 60 x 40 grid."""
    data = synthetic_data(n_samples=200)
    data["heightmap"] = data["heightmap"][:, :4]
    params, _ = est.train_estimator(data, small_cfg(epochs=2), print_fn=lambda *_: None)
    assert params["mean"].shape == (est.STATE_SIZE + 4,)
    obs = random_obs(3)[:, :est.STATE_SIZE + 4 + 3]  # a phase clock or a one-hot after: ignored
    p = est.predict(params, obs)
    assert p.shape == (3,)
    np.testing.assert_array_equal(p, est.predict(params, obs[:, :est.STATE_SIZE + 4]))


# -------------------------------------------------------------------------------------- training


def test_training_learns_a_state_threshold():
    data = synthetic_data(n_samples=2000)  # fewer samples: the net memorises them (group split)
    lines = []
    params, m = est.train_estimator(data, small_cfg(epochs=6, batch_size=128), rng_seed=0,
                                    print_fn=lines.append, log_every=3)
    assert m["val_acc"] > 0.9 and m["val_auc"] > 0.95
    assert m["epochs"] == 6 and len(m["history"]["train_loss"]) == 6 and len(m["history"]["val_acc"]) == 6
    hist = np.array([m["history"][k] for k in ("train_loss", "val_loss", "val_acc")])
    assert np.all(np.isfinite(hist))
    assert m["history"]["train_loss"][-1] < m["history"]["train_loss"][0]
    assert m["val_acc"] == pytest.approx(m["history"]["val_acc"][-1], abs=1e-6)
    assert m["best_val_acc"] >= m["val_acc"] and 1 <= m["best_val_acc_epoch"] <= 6
    assert m["train_points"] % 2 == 0 and m["val_points"] % 2 == 0
    assert 0.1 < m["val_points"] / (m["train_points"] + m["val_points"]) < 0.3
    assert m["train_s"] > 0 and m["points_per_s"] > 0
    assert any("epoch 6/6" in s and "val acc" in s and "points/s" in s for s in lines)
    # the returned params work with predict on raw observations (normalisation inside)
    obs = np.concatenate([data["state"], data["heightmap"].astype(np.float32)], -1)
    acc = np.mean((np.asarray(est.predict(params, obs)) >= 0.5) == (data["label"] == 1))
    assert acc > 0.9
    assert params["mean"].shape == params["std"].shape == (IN_SIZE,)
    assert np.all(params["std"] >= default_estimator_config().std_floor)


# ---------------------------------------------------------------------------------- checkpoints


def test_save_load_round_trip(tmp_path):
    params = random_params(4)
    meta = {"target": "gaps", "init": "stand", "metrics": {"val_acc": np.float32(0.75)},
            "config": small_cfg().to_dict()}
    path = est.save_estimator(tmp_path / "stand_gaps", params, meta)
    loaded, meta2 = est.load_estimator(path)
    assert meta2["target"] == "gaps" and meta2["metrics"]["val_acc"] == pytest.approx(0.75)
    assert meta2["config"]["hidden"] == [16]
    assert jax.tree.structure(loaded) == jax.tree.structure(jax.device_get(params))
    obs = random_obs(8, extra=3)
    np.testing.assert_array_equal(est.predict(loaded, obs), est.predict(params, obs))
    with pytest.raises(FileNotFoundError):
        est.load_estimator(tmp_path / "nothing_here")


# ----------------------------------------------------------------------------------------- CLI


def test_cli_end_to_end(tmp_path, capsys):
    data_dir, out, res = tmp_path / "sweeps", tmp_path / "models", tmp_path / "results"
    (data_dir / "stand").mkdir(parents=True)
    for i, t in enumerate(("jumps", "gaps")):
        np.savez_compressed(data_dir / "stand" / f"{t}.npz", **synthetic_data(n_samples=60, seed=i))
    rc = estimator_cli.main(["--init", "stand", "--targets", "jumps", "gaps", "--data", str(data_dir),
                   "--out", str(out), "--results", str(res), "--epochs", "2", "--batch-size", "64",
                   "--log-every", "1"])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "| target |" in printed and "| jumps | 300 (" in printed and "| gaps |" in printed
    for t in ("jumps", "gaps"):
        r = json.loads((res / f"stand_{t}.json").read_text())
        assert r["target"] == t and r["init"] == "stand" and r["metrics"]["epochs"] == 2
        assert "history" not in r["metrics"] and 0 <= r["metrics"]["val_auc"] <= 1
        assert r["data_file"].endswith(f"stand/{t}.npz")
        assert (res / f"stand_{t}.png").stat().st_size > 0
        hist_csv = (res / f"stand_{t}_history.csv").read_text().splitlines()
        assert len(hist_csv) == 3 and hist_csv[0] == "epoch,train_loss,val_loss,val_acc,epoch_s"
        assert json.loads((out / f"stand_{t}" / "meta.json").read_text())["sweep_meta"]["synthetic"]
    stacked, metas = est.load_estimator_set("stand", model_dir=out, targets=("jumps", "gaps"))
    assert [m["target"] for m in metas] == ["jumps", "gaps"]
    assert stacked["std"].shape == (2, IN_SIZE)
    obs = random_obs(4, extra=3)
    both = jax.vmap(est.predict, in_axes=(0, None))(stacked, obs)
    for i, t in enumerate(("jumps", "gaps")):
        single, _ = est.load_estimator(out / f"stand_{t}")
        np.testing.assert_allclose(both[i], est.predict(single, obs), rtol=1e-5, atol=1e-6)
    with pytest.raises(FileNotFoundError, match="stand_stairs"):
        est.load_estimator_set("stand", model_dir=out)


def test_cli_names_the_sweep_command_for_missing_data(tmp_path, capsys):
    rc = estimator_cli.main(["--init", "random", "--targets", "stairs", "--data", str(tmp_path),
                   "--out", str(tmp_path / "m"), "--results", str(tmp_path / "r"), "--epochs", "1"])
    assert rc != 0
    err = capsys.readouterr().err
    assert "python -m biped_switch.sweep --init random --targets stairs" in err
    assert not (tmp_path / "m").exists()


def test_estimator_benchmark_cli_prints_one_json_record(capsys):
    """`python -m biped_switch.bench --estimator --json` (`make bench-estimator`) trains on `points`
    random rows and prints one JSON record of what it trained and how fast. The timings are the
    command's output, not assertions here: on a busy machine their order is not guaranteed."""
    from biped_switch.evaluation import bench
    from biped_switch import bench as bench_cli

    assert bench_cli.main(["--estimator", "--points", "500", "--epochs", "3", "--json"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1  # --json: the record alone, on one line
    r = json.loads(out[0])
    n = r["train_points"]
    assert r["what"] == "estimator" and r["points"] == 500 and r["epochs_timed"] == 2
    # ~90% of 500 rows in 5-point groups, then balanced 50/50 (an even count, never all 500)
    assert n % 2 == 0 and 350 < n <= 450
    assert r["batch_size"] == n  # fewer points than the configured batch: one batch per epoch
    assert r["config_epochs"] == default_estimator_config().epochs
    for k in ("first_epoch_s", "epoch_s", "train_points_per_s", "projected_s_for_config_epochs"):
        assert np.isfinite(r[k]) and r[k] >= 0, (k, r[k])
    assert r["epoch_s"] > 0 and r["train_points_per_s"] > 0
    # one epoch would time nothing (the first one compiles): refused, as too few points are
    for argv in (["--epochs", "1"], ["--points", "50"]):
        with pytest.raises(SystemExit) as e:
            bench_cli.main(["--estimator", *argv])
        assert e.value.code == 2
    assert "--estimator needs" in capsys.readouterr().err


def test_bench_train_update_levers_reach_run_train(monkeypatch, capsys):
    """`bench --train --epochs E --minibatches M` times PPO under that update (the levers measured
    against the physics limit in docs/speed.md); without them the preset's stands, and `--epochs`
    still means the estimator's epochs under `--estimator`."""
    from biped_switch.evaluation import bench
    from biped_switch import bench as bench_cli

    seen = []
    monkeypatch.setattr(bench, "run_train", lambda *a, **k: seen.append(k) or {"what": "ppo_train"})
    monkeypatch.setattr(bench, "run_estimator", lambda points, epochs, seed: seen.append(epochs) or {})
    assert bench_cli.main(["--train", "--epochs", "2", "--minibatches", "8", "--json"]) == 0
    assert bench_cli.main(["--train", "--json"]) == 0
    assert bench_cli.main(["--estimator", "--json"]) == 0
    assert seen == [{"epochs": 2, "minibatches": 8}, {"epochs": None, "minibatches": None}, 3]

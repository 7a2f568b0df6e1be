"""Training on two local devices (XLA's forced host devices), in a subprocess so that the rest of
the suite keeps one device: the envs split over both, and the run's state stays one copy."""

import json
import os
import pathlib
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import json
    import jax, numpy as np
    from biped_switch.learning import ppo
    from biped_switch.learning import trainer as train
    from biped_switch.config import default_train_config
    assert jax.local_device_count() == 2, jax.devices()
    cfg = default_train_config("cpu")
    cfg.policy, cfg.n_tracks, cfg.episode_length = "walk", 2, 10
    cfg.total_timesteps = cfg.chunk_timesteps = 256
    cfg.ppo.update(num_envs=8, num_minibatches=2, unroll_length=8)
    cfg.network.update(policy_hidden=(16,), value_hidden=(16,))
    cfg.eval.update(n_envs=4, horizon_steps=20)
    env = train.train_env(cfg)
    tr = ppo.make_train(cfg, env)
    ts = tr.init(jax.random.PRNGKey(0))
    envs = tr.reset_envs(jax.random.PRNGKey(1), jax.numpy.asarray([1.0, 1.0, 0.0]))
    ts2, envs, m = tr.iteration(ts, envs, jax.random.PRNGKey(2), jax.numpy.asarray([1.0, 1.0, 0.0]))
    shard_shape = envs[0].obs.shape
    leaves = jax.tree.leaves(ts2.params)
    print(json.dumps({"steps_per_iteration": tr.steps_per_iteration, "shard": list(shard_shape),
                      "param_shape": list(leaves[0].shape), "count": float(ts2.norm.count),
                      "finite": bool(all(np.all(np.isfinite(np.asarray(x))) for x in leaves)),
                      "changed": bool(any(np.any(np.asarray(a) != np.asarray(b)) for a, b in
                                          zip(leaves, jax.tree.leaves(ts.params))))}))
""")


def test_training_splits_envs_over_two_devices():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu")
    root = pathlib.Path(__file__).resolve().parent.parent
    out = subprocess.run([sys.executable, "-c", SCRIPT], cwd=root, env=env,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["steps_per_iteration"] == 64  # 8 envs x 8 steps, over both devices
    assert res["shard"][:2] == [2, 4]  # (devices, envs per device, obs)
    assert res["param_shape"][0] != 2  # the train state is one copy, not one per device
    assert abs(res["count"] - 64) < 0.01  # both devices' observations (2 x 32), not one's
    assert res["finite"] and res["changed"]  # one real update of the one copy

"""The DQN selector baseline (paper Sec. IV-C, Table II "DQN", Table III): a discrete Q-network
that picks, at every control step, which pre-trained policy of the suite acts.

    python -m biped_switch.dqn --preset cpu|gpu [--total-steps N] [--chunk-steps N] [--runs runs]
                               [--out runs/dqn_stand] [--stand-in walk]

Unlike the switch estimators, the DQN is trained on the test domain: `mixed` tracks (7 artifacts of
every kind; training tracks have seeds `seed .. seed + n_tracks - 1`, evaluation tracks 30,000..).

Input: the Q-network sees what the behaviour policies see -- the robot state (51), the heightmap
(2400) and, when the suite was trained with it, the gait phase clock (2): the `policy` columns of
the env's `ObsLayout` -- and the oracle detector's artifact kind as a one-hot (3):
`q_input(obs, detected_kind, n_policy_obs)`. The one-hot is rebuilt from
`state.metrics["detected_kind"]` (the very value the env's `detector_one_hot` appends), so the
DQN runs on an env made with or without `detector_one_hot`; `make_dqn_env` (the suite's env
overrides, `detector_one_hot=True`) is what the CLI uses. The behaviour policies always get the
first `env.policy_observation_size` columns (they were trained without the one-hot).
Output: Q-values of the 4 policies (index = policies.POLICY_INDEX: walk, jumps, gaps, stairs).

Reward per step: the env's reward (the one each policy was trained on) plus an oracle bonus
`oracle_bonus` for choosing the policy of the detected artifact (walk while nothing is detected),
both multiplied by `reward_scale`. The paper found that the DQN fails to learn without the bonus,
and gives no value; ours is 1.0 per step (before scaling), about a fifth of the best env reward per
step (5.4), so the bonus leads at first and the env reward still separates good from bad timing.

Learning: Double DQN (van Hasselt et al.): target r + gamma (1 - done) Q_target(s', argmax_a
Q_online(s', a)), Huber loss on the chosen action, Adam (Optax) with gradient clipping, a target
network synced every `target_update_period` updates (tau = 1: hard copy; tau < 1: Polyak step),
epsilon-greedy exploration with epsilon linear in env steps from `epsilon.start` to `epsilon.end`
over `epsilon.decay_steps`. Collection is vectorised over `num_envs` envs (either physics
backend, `--backend`): per iteration each env takes one step (Q picks a policy, the suite gives
the actions), the `num_envs` transitions go into the replay buffer, then `updates_per_collect`
gradient updates on uniform samples of `batch_size`. Episodes end on a fall or the finish
(done = 1: no bootstrap) or after `max_episode_s` (a time-out: bootstrapped); an ended env starts
its next episode, at the start of the next iteration, from a random state of a pool of reset
states (`reset_pool`: one per bank track, so a random track; with the `stand` init a reset
depends on the track alone, so this is exactly a fresh reset, for the price of a gather instead
of a forward pass of every env whenever any env ends). `log_every` iterations run as one jitted
`lax.scan` (one progress line). Training runs on one device (the first); `dqn_rollout` can be
split over devices with `rollout.over_devices` as `evaluate multi` does.

Input scaling: the Q-network normalises its input with statistics frozen when the buffer first
holds `learning_starts` transitions (`normalizer.frozen_stats` of `norm_rows` of them: the state
per column, the heightmap with one shared mean and std, the phase clock and the one-hot
untouched; std floored at `norm_std_floor`; the normalised input clipped to +-`norm_clip`). They are part of the params (`params["norm"]`), so a checkpoint (with the
run's `config.json` for the layer sizes) is enough to run the network.

Replay buffer: a pytree of fixed-size arrays (a ring). Observations are stored split: the 51 state
columns as float32, the heightmap, phase clock and one-hot as float16 (heightmap values lie in
[0, 1], the clock's in [-1, 1]; float16 keeps them to 5e-4), about 5 kB per observation and
10 kB per transition (obs and next obs): the GPU preset's 500,000 transitions take about 5 GB.

Greedy evaluation: after each chunk the greedy selector (no epsilon) runs `eval_envs` episodes of
`max_episode_s` on fixed training tracks spread over the bank, the same starts every time
(`greedy_eval`, `dqn_rollout`); their mean success, progress, falls and switches go to the progress
line, `metrics.csv` (`eval_*`), progress.json (`eval`) and the fourth panel of `curves.png`. Its
time counts in the chunk's (`wall_s`, `env_steps_per_s`), as PPO's milestone rollout does.

Checkpoints: every `chunk_env_steps` env steps, an Orbax checkpoint `checkpoints/<step>/` of the
online and target params and the optimiser state, with `progress.json` (step, `total_env_steps`:
the target this session was asked to reach, so step < total_env_steps marks an unfinished run;
epsilon: the schedule's value at `step`, the one the next iteration acts with; n_updates, wall_s,
env steps/s, the policies used incl. any stand-in, their env overrides and the physics
backend); a rerun resumes from the latest one.
NOT saved: the replay buffer and the envs' states. After a resume the envs start new episodes and
the buffer refills: no gradient update happens until it again holds `learning_starts` transitions
(those env steps count towards the total). Step counts are rounded up to whole jitted calls
(`log_every * num_envs` env steps). Metrics go to stdout, `metrics.csv` and TensorBoard (`tb/`).

`wall_s` is what a retraining-cost table (Table III) reads. Summed over all sessions, it counts
each session's setup (from the `train_dqn` call: config, env and bank build, policy loading,
reset-pool draw, learner init, checkpoint restore: `session_setup_s`, summed over sessions in
`setup_s_total`, None when a session predates that key) and every saved chunk's collection and
updates, compiles included. It does NOT count process start and imports, checkpoint writing, or a
chunk cut off before its checkpoint (its steps are lost too). The PPO trainer's `wall_s` leaves
session setup out: subtract `setup_s_total` to compare the two.

Evaluation: `load_dqn(run_dir)` -> (q_apply, q_params); `dqn_rollout(...)` plays the greedy
choice on given tracks and returns the same per-episode keys as `switching.multi_rollout`.
"""

from __future__ import annotations


import jax
import jax.numpy as jnp
import optax

from biped_switch.config import default_dqn_config
from biped_switch.kinds import policy_of_code
from biped_switch.learning import policies as pol
from biped_switch.learning.networks import EncodedMLP
from biped_switch.learning.normalizer import standardize
from biped_switch.simulation.observation import ONE_HOT_SIZE, layout

N_KINDS = ONE_HOT_SIZE  # artifact kinds the detector names (jumps, gaps, stairs)
N_ACTIONS = len(pol.POLICY_NAMES)  # 4 policies: walk, jumps, gaps, stairs


# ----------------------------------------------------------------------- pure pieces
def q_input_size(env) -> int:
    """Q-network input columns: the policies' observation and the detector one-hot."""
    return layout(env).policy_size + N_KINDS


def q_input(obs: jax.Array, detected_kind: jax.Array, n_policy_obs: int) -> jax.Array:
    """(..., n_policy_obs + 3): the policies' observation (state, heightmap, phase clock if any),
    and the one-hot of the detected kind (-1: none)."""
    one_hot = jax.nn.one_hot(jnp.asarray(detected_kind).astype(jnp.int32), N_KINDS, dtype=obs.dtype)
    return jnp.concatenate([obs[..., :n_policy_obs], one_hot], axis=-1)


def oracle_bonus(choice: jax.Array, detected_kind: jax.Array, bonus) -> jax.Array:
    """`bonus` where the chosen policy is the detected artifact's (kinds.POLICY_OF_CODE; walk's
    when nothing is detected, kind -1), else 0."""
    want = policy_of_code(jnp.asarray(detected_kind).astype(jnp.int32), jnp)
    match = jnp.asarray(choice).astype(jnp.int32) == want
    return jnp.where(match, jnp.asarray(bonus, jnp.float32), 0.0)


def double_dqn_targets(q_next_online, q_next_target, reward, done, gamma) -> jax.Array:
    """r + gamma (1 - done) Q_target(s', argmax_a Q_online(s', a)) for (B, A) Q-values."""
    a_star = jnp.argmax(q_next_online, axis=-1)
    v = jnp.take_along_axis(q_next_target, a_star[..., None], axis=-1)[..., 0]
    return reward + gamma * (1.0 - done) * v


def epsilon_at(step, start: float, end: float, decay_steps: int) -> jax.Array:
    """Linear from `start` at step 0 to `end` at `decay_steps` env steps, then constant."""
    frac = jnp.clip(jnp.asarray(step, jnp.float32) / max(decay_steps, 1), 0.0, 1.0)
    return jnp.asarray(start + frac * (end - start), jnp.float32)


def epsilon_greedy(key: jax.Array, q: jax.Array, epsilon) -> jax.Array:
    """(B,) int32: argmax of q (B, A), or with probability epsilon a uniform random action."""
    k_explore, k_action = jax.random.split(key)
    n, a = q.shape
    explore = jax.random.uniform(k_explore, (n,)) < epsilon
    rand = jax.random.randint(k_action, (n,), 0, a)
    return jnp.where(explore, rand, jnp.argmax(q, axis=-1)).astype(jnp.int32)


# ----------------------------------------------------------------------- Q-network
def make_q(net_cfg, hm_size: int, n_actions: int = N_ACTIONS, norm_clip: float | None = None):
    """(init(key, in_size) -> params, apply(params, x (B, in_size)) -> (B, n_actions)).

    The network is the policies' EncodedMLP (heightmap encoder `hm_hidden`, joined with the state
    and the one-hot, MLP `hidden`, swish) behind a frozen input normaliser `params["norm"]`; the
    normalised input is clipped to +-`norm_clip` (default: the DQN config's)."""

    clip = default_dqn_config().norm_clip if norm_clip is None else norm_clip
    module = EncodedMLP(out_size=n_actions, hidden=tuple(net_cfg.hidden),
                        hm_hidden=tuple(net_cfg.hm_hidden), hm_size=hm_size)

    def init(key, in_size: int) -> dict:
        return {"net": module.init(key, jnp.zeros((1, in_size))),
                "norm": {"mean": jnp.zeros(in_size), "std": jnp.ones(in_size)}}

    def apply(params, x):
        norm = params["norm"]
        return module.apply(params["net"], standardize(x, norm["mean"], norm["std"], clip))

    return init, apply


def dqn_loss(net_params, params, target, batch, q_apply, gamma, huber_delta):
    """Huber loss of Q(s, a) against the Double-DQN target; (loss, mean Q(s, a)).

    One online forward pass serves s and s' (the online Q(s') only picks the argmax, which has no
    gradient); the target's values are computed from `target` and get no gradient either."""
    online = {**params, "net": net_params}
    n = batch["obs"].shape[0]
    q_both = q_apply(online, jnp.concatenate([batch["obs"], batch["next_obs"]], axis=0))
    q, q_next_online = q_both[:n], jax.lax.stop_gradient(q_both[n:])
    q_a = jnp.take_along_axis(q, batch["action"][:, None], axis=-1)[:, 0]
    y = double_dqn_targets(q_next_online, q_apply(target, batch["next_obs"]), batch["reward"],
                           batch["done"], gamma)
    loss = jnp.mean(optax.huber_loss(q_a, jax.lax.stop_gradient(y), delta=huber_delta))
    return loss, jnp.mean(q_a)


def make_optimizer(cfg) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), optax.adam(cfg.learning_rate))


def make_update(q_apply, optimizer, gamma: float, huber_delta: float):
    """One gradient step: (params, target, opt_state, batch) -> (params, opt_state, metrics)."""

    def update(params, target, opt_state, batch):
        (loss, q_mean), grads = jax.value_and_grad(dqn_loss, has_aux=True)(
            params["net"], params, target, batch, q_apply, gamma, huber_delta)
        updates, opt_state = optimizer.update(grads, opt_state, params["net"])
        net = optax.apply_updates(params["net"], updates)
        return {**params, "net": net}, opt_state, {"loss": loss, "q": q_mean}

    return update


def sync_target(target, online, do_sync, tau: float):
    """target <- tau * online + (1 - tau) * target where `do_sync` (traced bool), else unchanged."""
    return jax.tree.map(lambda t, o: jnp.where(do_sync, tau * o + (1.0 - tau) * t, t), target, online)



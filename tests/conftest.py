"""Session-wide fixtures: one small env, its reset/step/hold_step jitted (and vmapped over a batch of
4 envs) exactly once, and a few trajectories that several tests read.

Compiling an MJX step takes 10-30 s on a 2-core CPU, so everything that needs the env shares these.
Every call into the jitted functions passes arrays of fixed dtypes (float32 difficulties, int32 track
ids, float32 actions), so the test of "no recompilation" can demand exactly one trace per function.
"""

from __future__ import annotations

import collections
import sys
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from biped_switch.simulation import env as env_lib  # noqa: E402

B = 4  # envs in the shared batch
MJX_TORQUE = {"backend": "mjx", "action": "torque", "phase_obs": False}
TRACK_IDS = np.array([0, 1, 2, 3], np.int32)
DIFFICULTIES = np.array([1.0, 0.5, 1.0, 0.0], np.float32)


@pytest.fixture(scope="session")
def env():
    """`mixed` tracks, seeds 0..3, stand init (0.5 s pause), default configs but for the MJX
    backend and the paper's torque actions without a phase clock, which these tests were written
    for (test_backends.py runs the `mujoco` backend against this one)."""
    return env_lib.make_env("mixed", n_tracks=4, **MJX_TORQUE)


@pytest.fixture(scope="session")
def traces():
    """How many times each shared jitted function was traced (== compiled) this session."""
    return collections.Counter()


@pytest.fixture(scope="session")
def backend_compiles():
    """A list that grows by one entry per XLA backend compile (any function) from now on."""
    from jax import monitoring

    events = []

    def listener(name, duration_s, **kwargs):
        if name == "/jax/core/compile/backend_compile_duration":
            events.append(duration_s)

    monitoring.register_event_duration_secs_listener(listener)
    return events


@pytest.fixture(scope="session")
def fns(env, traces):
    """jit(vmap(.)) of env.reset / env.step / env.hold_step, each compiled once per session."""

    def counted(name, f):
        def g(*args):
            traces[name] += 1
            return f(*args)
        return g

    return {
        "reset": jax.jit(jax.vmap(counted("reset", env.reset))),
        "step": jax.jit(jax.vmap(counted("step", env.step))),
        "hold": jax.jit(jax.vmap(counted("hold", env.hold_step))),
    }


def batch_reset(fns, seed=0, difficulties=DIFFICULTIES, track_ids=TRACK_IDS):
    keys = jax.random.split(jax.random.PRNGKey(seed), len(track_ids))
    return fns["reset"](keys, jnp.asarray(difficulties, jnp.float32),
                        jnp.asarray(track_ids, jnp.int32))


def actions(value, n=B):
    return jnp.full((n, 12), value, jnp.float32)


def with_time(state, t_s):
    """The state with its episode clock set to t_s (float32, not weak-typed: no recompile)."""
    info = dict(state.info)
    info["time_s"] = jnp.full(info["time_s"].shape, t_s, jnp.float32)
    return state.replace(info=info)


def index(state, i):
    return jax.tree.map(lambda x: x[i], state)


@pytest.fixture(scope="session")
def batch0(fns):
    """Reset states of tracks 0..3 at difficulties 1, 0.5, 1, 0."""
    return jax.device_get(batch_reset(fns))


@pytest.fixture(scope="session")
def hold_traj(fns, batch0):
    """51 states: the reset state and 50 scripted-standing (hold_step) control steps (1 s)."""
    out, s = [batch0], batch0
    for _ in range(50):
        s = fns["hold"](s)
        out.append(s)
    return jax.device_get(out)


@pytest.fixture(scope="session")
def fall_traj(fns, batch0):
    """101 states: the reset state with its clock past the pause, then 100 steps (2 s) of zero torque."""
    s = with_time(batch0, 1.0)
    out = [s]
    for _ in range(100):
        s = fns["step"](s, actions(0.0))
        out.append(s)
    return jax.device_get(out)

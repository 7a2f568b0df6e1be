"""The observation layout, named: state | heightmap | phase clock | one-hot, as slices resolved once
on the host.

`layout(env)` (an env, or an env config) gives the `ObsLayout` of its observation: the robot state
(51 columns, `STATE_SLICES`), the heightmap (rows x cols, flattened row-major), the gait phase clock
(2 columns with `phase_obs`) and the detector one-hot (3 columns with `detector_one_hot`), in that
order. Behaviour policies read the leading `policy` columns (state, heightmap, phase clock); switch
estimators the leading `estimator` columns (state, heightmap); the DQN selector the policy columns
and a one-hot. Every module that cuts an observation into parts reads it here.
"""

from __future__ import annotations

from typing import NamedTuple

from biped_switch.names import ARTIFACT_KINDS

STATE_SIZE = 51
PHASE_SIZE = 2  # sin, cos of the gait phase
ONE_HOT_SIZE = len(ARTIFACT_KINDS)  # the detected artifact kind (jumps, gaps, stairs)

STATE_SLICES = {
    "joint_pos": slice(0, 12),
    "joint_vel": slice(12, 24),
    "contact": slice(24, 33),
    "contact_prev": slice(33, 42),
    "com_lin_vel": slice(42, 45),
    "com_ang_vel": slice(45, 48),
    "pitch": slice(48, 49),
    "roll": slice(49, 50),
    "com_height": slice(50, 51),
}


class ObsLayout(NamedTuple):
    """The parts of an observation, by width; their column ranges are the slice properties."""

    grid: tuple  # heightmap (rows, cols)
    n_phase: int = 0  # phase-clock columns after the heightmap (PHASE_SIZE with phase_obs)
    n_one_hot: int = 0  # detector one-hot columns, last (ONE_HOT_SIZE with detector_one_hot)
    state_size: int = STATE_SIZE

    @property
    def hm_size(self) -> int:
        return int(self.grid[0]) * int(self.grid[1])

    @property
    def state(self) -> slice:
        return slice(0, self.state_size)

    @property
    def heightmap(self) -> slice:
        return slice(self.state_size, self.state_size + self.hm_size)

    @property
    def phase(self) -> slice:
        return slice(self.heightmap.stop, self.heightmap.stop + self.n_phase)

    @property
    def one_hot(self) -> slice:
        return slice(self.phase.stop, self.phase.stop + self.n_one_hot)

    @property
    def estimator(self) -> slice:
        """What a switch estimator reads: the robot state and the heightmap."""
        return slice(0, self.heightmap.stop)

    @property
    def policy(self) -> slice:
        """What a behaviour policy reads: state, heightmap and phase clock (never the one-hot)."""
        return slice(0, self.phase.stop)

    @property
    def policy_size(self) -> int:
        return self.policy.stop

    @property
    def size(self) -> int:
        return self.one_hot.stop

    def split(self, x):
        """(state, heightmap, the rest) of an input whose columns start state | heightmap."""
        return split_columns(x, self.state_size, self.hm_size)


def split_columns(x, state_size: int, hm_size: int):
    """(state, heightmap, the rest) of `x` (..., columns): the first `state_size` columns, the
    `hm_size` after them, and every column after those (phase clock, one-hot)."""
    hm_end = state_size + hm_size
    return x[..., :state_size], x[..., state_size:hm_end], x[..., hm_end:]


def layout(env) -> ObsLayout:
    """The `ObsLayout` of an env (its `obs_layout`) or of an env config (`shape`, `phase_obs`,
    `detector_one_hot`)."""
    lay = getattr(env, "obs_layout", None)
    if lay is not None:
        return lay
    sh = env.shape
    return ObsLayout((int(sh.grid_forward), int(sh.grid_lateral)),
                     PHASE_SIZE if env.phase_obs else 0,
                     ONE_HOT_SIZE if env.detector_one_hot else 0)

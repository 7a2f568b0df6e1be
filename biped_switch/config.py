"""Default configs, one per stage, as ml_collections ConfigDicts (MuJoCo Playground style).

Keys that fix array shapes (box capacity, grid, batch) are kept in `shape` sub-dicts, apart from
values that may be traced and vmapped (difficulty, reward weights, thresholds).

The seed ranges of the tracks each stage runs on are named here too, so that no stage trains,
sweeps or evaluates on another's tracks: track i of a stage has seed <stage>_TRACK_SEED + i.
"""

from __future__ import annotations
from ml_collections import config_dict

# Track seeds. Training (PPO, and the DQN selector) uses tracks TRAIN_TRACK_SEED + run seed + i,
# i in 0..n_tracks-1 (a run's `seed`, default 0, shifts them); the other stages start far above.
TRAIN_TRACK_SEED = 0
EVAL_TRACK_SEED = 10_000  # Table I (`evaluate single`) and the render CLI: never trained on
SWEEP_TRACK_SEED = 20_000  # switch-point sweeps (single-artifact tracks)
MULTI_TRACK_SEED = 30_000  # Table II (`evaluate multi`), Fig. 5 and the demo: mixed tracks
DETECTOR_TRACK_SEED = 40_000  # the learned terrain detector's data: training and validation tracks
# ... of which: kind k's training tracks from DETECTOR_TRACK_SEED + DETECTOR_KIND_STRIDE k, its
# validation tracks DETECTOR_VAL_OFFSET above them, the mixed validation tracks from
# DETECTOR_TRACK_SEED + DETECTOR_MIXED_OFFSET
DETECTOR_KIND_STRIDE = 1000
DETECTOR_VAL_OFFSET = 500
DETECTOR_MIXED_OFFSET = 9_000
TUNE_TRACK_SEED = 50_000  # mixed tracks for tuning switching thresholds (`evaluate multi --track-seed`)
STUDENT_TRACK_SEED = 80_000  # the distilled student's training tracks: mixed (setup: 60_000, 70_000)
# (reporting, tuning) mixed tracks of a line-up's Table II (lineups.LINEUPS): Table II-4 for stones
LINEUP_TRACK_SEEDS = {"paper": (MULTI_TRACK_SEED, TUNE_TRACK_SEED), "stones": (100_000, 110_000)}


def default_terrain_config(n_artifacts: int = 7) -> config_dict.ConfigDict:
    """Artifact sizes of the paper (Sec. IV), at difficulty 1; `n_artifacts` per track (paper: 7;
    the sweeps use 1, the demo 2)."""
    return config_dict.create(
        stair_rise_m=0.17,
        step_height_m=0.30,  # `jumps`: a block 0.3 m high ...
        step_length_m=0.16,  # ... and 0.16 m long
        gap_length_m=0.70,
        # `stones` (issue 57, docs/environment.md): stepping stones, a hole then a raised stone,
        # alternating; the hole's length and the stone's top scale with difficulty, as above
        stone_length_m=0.30,  # a stone's top, about a foot (0.24 m) plus a margin
        stone_height_m=0.15,  # its top above the ground (half the jump block's)
        stone_hole_m=0.45,  # the hole before each stone (under the gaps' 0.7 m)
        flat_min_m=0.36,  # flat segments (and stair runs) ~ U(0.36, 0.44) m
        flat_max_m=0.44,
        width_min_m=1.1,  # track width ~ U(1.1, 1.7) m, fixed per track
        width_max_m=1.7,
        segments_min=4,  # boxes (or holes) per artifact, 4..9
        segments_max=9,
        n_artifacts=int(n_artifacts),
        flat_before_m=0.9,  # at least this much flat before every artifact
        start_back_m=1.0,  # track starts this far behind the robot (x = 0)
        runup_m=1.0,  # flat ahead of the robot before the first artifact's lead-in
        goal_flat_m=2.0,  # flat after the last artifact
        finish_after_m=1.0,  # success line: this far past the last artifact's end
        slab_thickness_m=0.3,  # every box is a slab this thick under its top (>= step height)
    )


def default_model_config() -> config_dict.ConfigDict:
    return config_dict.create(
        xml_path="",  # empty: models/biped.xml of this package's checkout
        box_capacity=96,  # terrain box slots compiled into the model (a shape key)
        max_geom_pairs=32,  # MJX broad-phase cull; 32 missed no contact in tests (design.md)
        sim_dt_s=0.005, n_substeps=4,  # control period = 0.02 s (50 Hz)
        solver_iterations=4, ls_iterations=8,
    )


def default_env_config() -> config_dict.ConfigDict:
    return config_dict.create(
        kind="walk",  # terrain kind of the track bank
        backend="auto",  # physics: "mujoco" (C engine, native.py), "mjx", or "auto": mujoco on a
        # CPU, mjx on an accelerator
        action="torque",  # "torque": joint torques as fractions of the motor limits (the paper);
        # "pd": joint targets (pd_offset) + action * action_scale_rad, tracked by a PD law at every
        # physics substep, torques clipped to the motor limits
        pd_offset="gait",  # "pd": targets are offsets from the scripted gait's joint angles
        # ("gait", the standing pose during the pause) or from the standing pose ("stand")
        action_scale_rad=0.5,  # "pd": target offset [rad] at action 1
        pd_kp_per_gear=2.0,  # "pd": stiffness [Nm/rad] per Nm of motor limit (knee: 500 Nm/rad)
        pd_kd_ratio=0.025,  # "pd": damping [Nm s/rad] = pd_kd_ratio * stiffness. Explicit damping
        # is stable while c dt / I < 2: with the full joint guide on top (c = 0.1 gear) this keeps
        # the 60 Nm joints (I ~ 0.02 kg m^2 with armature) at the standing hold's 0.15 gear
        phase_obs=True,  # append the scripted gait's phase clock (sin, cos of 2 pi t / period)
        n_tracks=256,  # tracks in the bank; reset picks one at random
        seed=0,  # seed of the bank's first track (track i has seed + i)
        difficulty=1.0,  # traced: the curriculum changes it without recompiling
        guide_scale=0.0,  # traced: guided-curriculum guide forces (gait.py), 0 = none
        push_scale=0.0,  # traced: random pushes, fraction of curriculum max_push_N
        init="stand",  # "stand": keyframe + pause (RoA overlap), "random": random joints, no pause
        pause_s=0.5,
        random_joint_scale=0.5,  # "random" init: fraction of each joint's range around the keyframe
        episode_length_s=30.0,
        detect_range_m=0.9,  # oracle detector: next artifact once its start is this close
        detector_one_hot=False,  # append the detected kind (3) to the observation
        target_speed_mps=0.8,
        fall_height_m=0.55,  # pelvis CoM lower than this above the terrain beneath: fallen
        fall_tilt_rad=1.0,  # |pitch| or |roll| above this: fallen
        fall_z_m=-0.2,  # CoM below this height (flats are at z = 0): fallen into a gap or off the side
        max_qvel=200.0,  # [m/s, rad/s] a speed beyond any motion of this robot: the simulation
        # diverged, and the episode ends as a fall at its last finite state
        hold_kp_per_gear=3.0,  # standing PD hold of the pause: stiffness [Nm/rad] per Nm of motor
        # limit (knee: 750 Nm/rad)
        hold_kd_ratio=0.05,  # ... damping [Nm s/rad] = hold_kd_ratio * stiffness (knee: 37.5)
        reset_clearance_m=1e-3,  # a reset lifts or lowers the robot so its lowest sole is this
        # far above the ground beneath it
        reward=config_dict.create(
            progress=3.0,  # x velocity, capped at the target speed
            speed=1.0,  # exp(-(vx - target)^2 / speed_width) tracking bonus
            alive=1.0,
            upright=0.5,  # cos(pitch) * cos(roll)
            height=0.5,  # exp(-(h - h_stand)^2 / height_width)
            lateral=0.5,  # penalty on |y| drift and |yaw|
            torque=0.1,  # penalty on mean(a^2), a = torque as a fraction of its limit
            fall=10.0,  # one-off penalty on a fall
            speed_width=0.1,  # [(m/s)^2] of the speed bonus (not a weight)
            height_width=0.01,  # [m^2] of the height bonus (not a weight)
        ),
        shape=config_dict.create(
            grid_forward=60,  # heightmap rows, behind -> front
            grid_lateral=40,  # heightmap columns, right -> left
        ),
        heightmap=config_dict.create(
            cell_m=0.025,
            front_m=0.9,
            behind_m=0.6,
            side_m=0.5,
            depth_m=2.0,  # value 1 at this depth below the CoM
            max_boxes=12,  # boxes nearest the body that the lookup tests (see heightmap.py)
        ),
    )


def default_gait_config() -> config_dict.ConfigDict:
    """The scripted gait and the guide gains (see gait.py)."""
    return config_dict.create(
        period_s=0.8,
        hip_amp_rad=0.35,
        knee_amp_rad=0.6,
        kp_per_gear=2.0,  # joint guide stiffness [Nm/rad] per Nm of motor limit
        kd_ratio=0.05,  # damping [Nm s/rad] = kd_ratio * stiffness
        k_speed=150.0,  # [N per m/s]
        k_lateral=300.0,  # [N/m]
        d_lateral=60.0,  # [N s/m]
        k_height=1500.0,  # [N/m]; the pelvis block alone weighs 118 N
        d_height=150.0,  # [N s/m]
        k_tilt=400.0,  # [Nm/rad]
        d_tilt=40.0,  # [Nm s/rad]
        k_yaw=100.0,  # [Nm/rad]
        d_yaw=20.0,  # [Nm s/rad]
    )


def default_curriculum_config() -> config_dict.ConfigDict:
    """Guided curriculum (Tidd et al.): terrain up with guides, guides down, pushes up."""
    return config_dict.create(
        reward_milestone=0.65,  # advance when mean episode reward per step >= this fraction ...
        reward_per_step_max=5.4,  # ... of the best possible (3*0.8 + 1 + 1 + 0.5 + 0.5)
        min_progress=0.0,  # and mean progress_frac >= this (0 disables)
        max_fell=0.25,  # and at most this fraction of evaluation episodes fell (1 disables)
        regress_fell=0.6,  # one notch back when more than this fraction fell (1 disables) ...
        regress_patience=4,  # ... in this many evaluations in a row (1 = at once): a policy
        # needs a few chunks at a new level (curriculum.py)
        difficulty_step=0.1,
        guide_step=0.1,
        guide_min_step=0.025,  # the last notches shrink down to this (guide_notch 0.5: 0.1, 0.05,
        # 0.025, 0): jumps fell 12-27% at guides 0.1 and 100% at 0 (= guide_step disables)
        guide_notch=0.5,  # the fraction of the guide scale those last notches take, in (0, 1):
        # 0.5 halves; mixed trains with 0.25 (train --guide-notch; curriculum.py)
        push_step=0.1,
        push_plateau_steps=10_000_000,  # the push stage ends when its highest level has not risen
        # for this many env steps (0: only a milestone at push 1 ends it; curriculum.py)
        max_push_N=150.0,  # push force at push_scale 1
        push_duration_s=0.2,
        push_interval_s=2.0,  # mean time between pushes
        push_magnitude="uniform",  # each push's force: "uniform" U(0, 1) * push_scale * max_push_N,
        # as legged_gym and Playground draw theirs; "max" always push_scale * max_push_N (the
        # first runs' rule). Walk at 72M steps fell in 39% of 20 s episodes of max pushes at scale 1 (about 5%
        # per push, 9% at 0.5) and the push stages stalled for 10-38M steps a notch (README)
    )


def default_train_config(preset: str = "gpu") -> config_dict.ConfigDict:
    """A behaviour policy's training run (train.py): PPO (ppo.py), network and schedule; `preset`
    "cpu" sizes the batch for a 2-core machine. A run's config.json is this, saved (`runs.run_config`
    reads it back over today's defaults).

    `env` holds env-config overrides the policy is trained (and so must be evaluated) with: the
    action mode, the phase clock and the physics backend ("auto": mujoco on a CPU)."""
    cfg = config_dict.create(
        policy="walk",
        init="stand",
        seed=0,
        total_timesteps=100_000_000,
        chunk_timesteps=5_000_000,  # env steps between curriculum checks and checkpoints
        n_tracks=256,
        episode_length=1000,  # control steps (20 s)
        log_every=10,  # iterations between progress lines
        stop_when_done=True,  # stop when the curriculum finishes (one more milestone at full
        # pushes), before total_timesteps: `make train-all` runs the suite one policy at a time
        warm_start="",  # a checkpoint directory whose parameters start this run (e.g. walk's)
        # torque actions: the side-by-side on walk (README, Training) favoured them over pd
        env=config_dict.create(backend="auto", action="torque", pd_offset="gait", phase_obs=True),
        ppo=config_dict.create(
            num_envs=4096, unroll_length=20, num_minibatches=32, num_updates_per_batch=4,
            learning_rate=3e-4, entropy_cost=1e-3, value_cost=0.5, discounting=0.99,
            gae_lambda=0.95, clipping_epsilon=0.2, reward_scaling=0.1, max_grad_norm=1.0,
            init_action_std=0.5,
            max_action_std=0.0,  # a cap on each joint's std [fraction of the motor limit]; 0: none
        ),
        network=config_dict.create(policy_hidden=(256, 256), value_hidden=(256, 256),
                                   encoding="pool", pool=(2, 8), hm_hidden=(128, 64)),
        # the milestone's evaluation runs whole episodes, as the paper's "average episode reward":
        # 20 s meets three to four artifacts; a 5 s one met about one, and let
        # jumps and stairs anneal their guides while every training episode fell (curriculum.py)
        eval=config_dict.create(n_envs=256, horizon_steps=1000),
        curriculum=default_curriculum_config(),
        start=config_dict.create(stage=0, difficulty=0.0, guide_scale=1.0, push_scale=0.0),
    )
    if preset == "cpu":
        cfg.chunk_timesteps, cfg.total_timesteps, cfg.n_tracks = 1_000_000, 100_000_000, 32
        # 1 epoch x 16 minibatches: as good as 4 x 4 on 10M walk steps, 1.4x faster (docs/speed.md)
        cfg.ppo.update(num_envs=256, unroll_length=32, num_minibatches=16, num_updates_per_batch=1)
        cfg.eval.update(n_envs=64, horizon_steps=1000)
    elif preset != "gpu":
        raise ValueError(f"unknown preset {preset!r}; expected 'gpu' or 'cpu'")
    return cfg


def default_dqn_config(preset: str = "gpu") -> config_dict.ConfigDict:
    """The DQN selector baseline (dqn.py). `preset` "cpu" is the real training run for a 2-core
    machine: 64 envs (about 1,500 env steps/s here beside 4 PPO runs, updates included), the same
    networks, 4 replayed samples per transition (the GPU preset: 2), a 3 GB buffer."""
    cfg = config_dict.create(
        init="stand",
        seed=0,
        n_tracks=256,  # training tracks: mixed, seeds TRAIN_TRACK_SEED + seed + 0..n_tracks-1
        difficulty=1.0,
        num_envs=512,
        total_env_steps=20_000_000,
        chunk_env_steps=1_000_000,  # checkpoint period
        log_every=100,  # collection iterations per jitted call (one progress line)
        max_episode_s=60.0,  # time-out (bootstrapped), as evaluate multi's horizon
        reset_pool=0,  # episode starts drawn from this many reset states (0: one per bank track)
        replay_capacity=500_000,  # transitions (about 10 kB each)
        batch_size=512,
        learning_starts=200_000,  # transitions in the buffer before the first update
        updates_per_collect=2,  # gradient updates per iteration (num_envs transitions)
        learning_rate=3e-4,
        max_grad_norm=10.0,
        gamma=0.99,  # 50 Hz decisions: a 2 s horizon
        huber_delta=1.0,
        reward_scale=0.1,  # applied to env reward + bonus (Q-values of order 50)
        target_update_period=1000,  # gradient updates between target syncs
        tau=1.0,  # 1: hard copy; < 1: target <- tau online + (1 - tau) target
        epsilon=config_dict.create(start=1.0, end=0.05, decay_steps=5_000_000),  # env steps
        oracle_bonus=1.0,  # per step, for choosing the detected artifact's policy (walk if none)
        norm_std_floor=1e-2,  # the Q-input normaliser (dqn.py): std floor, ...
        norm_clip=10.0,  # ... the normalised input clipped to +-this, ...
        norm_rows=16_384,  # ... its statistics from this many rows, strided over the warm-up
        # transitions
        network=config_dict.create(hm_hidden=(128, 64), hidden=(256, 256)),  # as the policies
        eval_envs=64,  # greedy episodes after each chunk (fixed training tracks; 0: none)
    )
    if preset == "cpu":
        cfg.update(num_envs=64, total_env_steps=10_000_000, chunk_env_steps=256_000,
                   log_every=200, replay_capacity=300_000, batch_size=256, learning_starts=50_000,
                   updates_per_collect=1, eval_envs=16)  # a target sync every 64k env steps
        cfg.epsilon.decay_steps = 2_000_000
    elif preset != "gpu":
        raise ValueError(f"unknown preset {preset!r}; expected 'gpu' or 'cpu'")
    return cfg


def default_single_config() -> config_dict.ConfigDict:
    """Table I (`evaluate single`): each behaviour policy alone on tracks of its own kind."""
    return config_dict.create(
        horizon_speed_mps=0.6,  # the acceptance speed: the derived time limit lets a walker this
        horizon_margin=1.2,  # fast finish the farthest track with this margin on the walking time
    )


def default_sweep_config() -> config_dict.ConfigDict:
    """Switch-point sweeps (paper Sec. III-C): estimator data and lookup tables."""
    return config_dict.create(
        n_points=100_000,  # data points per target terrain kind (5 per switch sample)
        window=(-2, -1, 0, 1, 2),  # data points kept around the switch step t
        switch_max_m=0.9,  # switch at U(switch_min_m, switch_max_m) before the artifact (= detect
        switch_min_m=0.0,  # range); the paper's is U(0, 0.9) [m]; a raised floor puts the data
        # where the switching rules decide (0.3-0.9 m)
        lead_jitter_m=0.2,  # lead-in sweeps: earlier hand-overs at the context lookup's
        # distance minus U(0, this) [m], around where the learned rule switches
        approach_queries=2,  # per episode, observations recorded earlier on the approach, at
        # U(switch distance, switch_max_m) each: the states a "when" rule decides from
        steps_past=2,  # success: this many steps past the artifact's end, no fall (a step: a
        # landing of the other foot than the last step's, so 2 = both feet; labels.count_steps_past)
        horizon_s=20.0,  # a sample that has not succeeded or fallen by then is a failure
        lookup_bin_m=0.01,  # lookup table: success rate per 1 cm of switch distance (90 bins)
        batch=256,  # episodes per jitted rollout (split over local devices)
        difficulty=1.0,
    )


def default_switching_config() -> config_dict.ConfigDict:
    """When-to-switch rules (paper Sec. IV-B); all values may be traced."""
    return config_dict.create(
        estimator_threshold=0.85,  # switch once E_i(s) >= this
        estimator_persist_steps=1,  # ... on this many control steps in a row (1: the paper)
        force_switch_m=0.01,  # CoM-over-feet and estimator: force the switch this close
        feet_tol_m=0.10,  # CoM over feet: feet within this fore-aft distance of each other [m]
        support_margin_m=0.01,  # CoM over feet: CoM within this of the support polygon [m]
    )


def default_estimator_config() -> config_dict.ConfigDict:
    """Switch estimator: a small sigmoid classifier on (robot state, heightmap)."""
    return config_dict.create(
        hm_hidden=(64,),  # heightmap encoder
        hidden=(128, 64),  # after joining with the robot state
        epochs=1500,
        batch_size=1024,
        learning_rate=1e-3,
        val_frac=0.1,
        seed=0,
        std_floor=1e-2,  # input columns with a smaller std (constant heightmap cells) scale by this
        eval_chunk=4096,  # validation points per forward pass
    )


def default_when_config() -> config_dict.ConfigDict:
    """The learned "when" rule (switching/when.py): the success of switching at a distance d'
    <= the current one, from the state now; it switches when now is the best remaining moment."""
    return config_dict.create(
        trunk_hidden=(128, 64),  # on (active policy, distance, phase clock, state, profile)
        head_hidden=(64,),  # on (trunk, later distance, distance - later distance)
        ensemble=4,  # members (seeds) whose logits are averaged
        prior_bin_m=0.05,  # the prior table's bins of the switch distance [m]: the model is its
        # logit plus what the network learns from the state
        epochs=300,
        batch_size=512,
        learning_rate=1e-3,
        weight_decay=1e-3,  # AdamW
        patience=25,  # early stop: epochs without a better validation loss (BCE)
        val_track_mod=5,  # validation: sweep tracks whose id % val_track_mod == 0 (by track)
        std_floor=1e-2,
        seed=0,
        # the rule: a later distance d' on this grid [m], at least min_gap_m nearer, is a moment
        # still to come; switch when P(now) >= max P(d') + margin (margin chosen on tuning tracks)
        grid_m=(0.2, 0.9, 0.025),  # start, stop, step: the band the sweep data cover
        min_gap_m=0.02,
        band_tol=1.0,  # act only where the prior table is within this of its best (1: anywhere;
        # a host constant: chosen on tuning tracks)
        later_from="model",  # the later moments' P: the model given the state now ("model"), or
        # the prior table alone ("table"; chosen on tuning tracks, a key resolved on the host)
        margin=0.0,
        margin_choices=(-0.02, 0.0, 0.02, 0.05),
        persist_steps=1,  # ... on this many control steps in a row (temporal smoothing)
        ceiling_bin_m=0.05,  # the timing ceiling (`when --ceiling`): a sweep's best bin of this
        ceiling_band_m=(0.2, 0.9),  # width [m] within this band [m], of at least ...
        ceiling_min_n=50,  # ... this many switches; success per phase-clock sector (this many)
        ceiling_phase_bins=8,  # of the lead-in sweep's switches within one bin of the best
    )


def default_detector_config() -> config_dict.ConfigDict:
    """The learned terrain detector (switching/detector.py): a small MLP on the heightmap's forward
    profile that names the next artifact and its distance, in place of the oracle."""
    return config_dict.create(
        lateral_cols=(10, 30),  # heightmap columns averaged into the forward profile (+-0.25 m)
        feet_rows=(22, 26),  # rows under the body (x ~ -0.04 .. +0.06 m): the profile's zero
        rows_from=22,  # the network reads the profile's rows from here on (x >= -0.04 m: ahead)
        hidden=(64, 64),
        ahead_from_m=0.05,  # the distance: the first height change beyond this [m] ...
        min_change_m=0.03,  # ... by more than this [m] from the ground under the feet ...
        detect_range_m=0.9,  # ... and within the oracle's detection range [m]
        # the hand rule (the baseline): a drop this deep or deeper (no ground) is a gap, a rise this
        # high or higher a jumps block (0.30 m), a smaller rise a stair (0.17 m)
        hand_gap_drop_m=0.5,
        hand_jump_rise_m=0.25,
        epochs=400,
        batch_size=1024,
        learning_rate=1e-3,
        weight_decay=1e-4,
        patience=20,  # early stop: epochs without a better validation loss
        # the switching rollout reports a change of the detector's kind once it has held this
        # many control steps in a row (chosen on the validation tracks: `detector` prints each)
        debounce_steps=3,
        debounce_choices=(1, 2, 3, 4, 6),
        # ... and a kind never directly follows another, only after none (every artifact has a
        # flat before it): chosen on the validation tracks with the debounce
        debounce_via_none=True,
        via_none_choices=(False, True),
        # the filter chosen: the fewest wrong switches among those that name the mixed tracks'
        # artifacts at most this late [cm] on average
        choice_max_late_cm=10.0,
        seed=0,
        # data: each stand policy on its own terrain kind, walk on flat tracks (single kinds, as
        # the premise asks); validation on held-out seeds of the same and on mixed tracks
        n_envs=64,  # episodes per kind
        horizon_s=30.0,
        every=2,  # keep every n-th control step
        val_envs=32,
    )


# Setup policies per target (switching/setup.py): the sources each takes over from (the pairs
# whose context-sweep success is thin) and the distance [m] before the target artifact at which
# it hands over (from the context sweep's best bins into that target).
SETUP_TARGETS = {
    # jumps -> gaps best bin 0.405 m, stairs -> gaps 0.465 m
    "gaps": {"sources": ("jumps", "stairs"), "handover_m": 0.45},
    # jumps -> stairs and gaps -> stairs: the context sweep's best bins (lookup_stand_context)
    "stairs": {"sources": ("jumps", "gaps"), "handover_m": 0.45},
}


# The setup policies the switching controller uses (`lookup_context_setup`): those of the pairs
# whose overlap is thin. setup_stairs was trained and measured against no setup on held-out
# two-artifact tracks and did not help (jumps -> stairs 98.4% against 98.8%), so it is not one.
SETUP_SUITE = ("setup_gaps",)
# Pairs whose source policy is its own best setup (measured on the same held-out tracks: no setup,
# the source walking on to 0.45 m, 98.8% into stairs from jumps and from gaps): the controller
# keeps the source acting until the hand-over instead of switching at the lookup's distance.
SETUP_WALK_ON = {"stairs": {"sources": ("jumps", "gaps"), "handover_m": 0.45}}


def default_setup_config(target: str = "gaps") -> config_dict.ConfigDict:
    """A setup policy's training run (switching/setup.py): the train config of a
    behaviour policy (`default_train_config("cpu")`) with a `setup` section. The learner acts
    between the source policy's exit (target detected) and a fixed hand-over distance before
    the target artifact; source and target policies are the frozen `suite_init` suite."""
    if target not in SETUP_TARGETS:
        raise ValueError(f"no setup policy is defined for target {target!r}; expected one of "
                         f"{tuple(SETUP_TARGETS)} (config.SETUP_TARGETS)")
    cfg = default_train_config("cpu")
    cfg.policy = f"setup_{target}"
    cfg.warm_start = "walk_stand"  # a sound gait to start from (its normaliser too)
    cfg.total_timesteps = 200_000_000
    cfg.chunk_timesteps = 250_000
    cfg.n_tracks = 512  # two-artifact tracks [source, target]; one reset-pool start each
    cfg.episode_length = 400  # control steps (8 s) from the pool start: setup + target phases
    cfg.stop_when_done = False
    # the curriculum never moves: guides 0, no pushes, full difficulty throughout
    cfg.start.update(stage=2, difficulty=1.0, guide_scale=0.0, push_scale=0.0)
    cfg.curriculum.update(reward_milestone=10.0, regress_fell=1.0, push_plateau_steps=0)
    cfg.ppo.update(learning_rate=1e-4, discounting=0.995, init_action_std=0.3)
    cfg.eval.update(n_envs=128, horizon_steps=400)
    cfg.setup = config_dict.create(
        target=target,
        sources=SETUP_TARGETS[target]["sources"],  # mixed in one run, alternating over tracks
        suite_init="stand",  # the frozen source and target policies
        suite_runs="runs",  # ... found under this folder, then models/policies/ (a seeded
        # replay: its own folder, runs/replay_seed<S>)
        handover_m=SETUP_TARGETS[target]["handover_m"],  # hand over to the target policy this
        # far before its artifact [m]
        source_segments=(4, 5),  # segments of the source artifact (full tracks: 4..9): its exit
        target_segments=(2, 3),  # ... and of the target's (gaps: 1 or 2 holes); short tracks,
        # since only the setup phase trains the learner
        finish_after_m=0.5,  # success line this far past the target artifact's end
        setup_reward_scale=1.0,  # the walking reward (env reward terms) on setup steps
        success_bonus=200.0,  # once, when the target policy crosses (after the hand-over)
        fall_penalty=200.0,  # once, on a fall in the setup or target phase (source falls: 0)
        pool=True,  # episodes start from a pool of source-phase end states (one per track)
        pool_horizon=900,  # control steps the source phase may take when the pool is built
        train_track_seed=60_000,  # setup tracks: train seed + run seed + i, eval seed + i
        eval_track_seed=70_000,
    )
    return cfg


def default_distill_config(preset: str = "cpu") -> config_dict.ConfigDict:
    """The distilled student (learning/distillation.py): a train config (network and env as the
    behaviour policies', so it loads as a policy) with a `distill` section: DAgger on mixed
    tracks under Table II's conditions, labelled by the composed controller."""
    cfg = default_train_config("cpu")
    cfg.policy = "student"
    cfg.n_tracks = 512  # mixed tracks STUDENT_TRACK_SEED + seed + i
    cfg.distill = config_dict.create(
        teacher="lookup_context_setup",  # a Table II row (methods.py) with a switching rule
        teacher_runs="runs",  # its policies: this folder, then models/policies/
        total_env_steps=40_000_000, chunk_env_steps=500_000,  # the ceiling; checkpoint period
        num_envs=256, unroll_length=32,  # control steps per collection (8,192 env steps)
        horizon_s=60.0,  # episode time-out, as Table II's horizon
        # P(the teacher's action is executed): linear from mix_start to mix_end over the steps
        mix_start=1.0, mix_end=0.0, mix_decay_steps=4_000_000,
        action_noise_std=0.0,  # Gaussian noise on the student's executed action (0: none)
        buffer_size=1_048_576,  # aggregate rows (about 0.9 GB at 215 float32 columns)
        # Adam steps per collection, each on batch_size rows drawn uniformly from the buffer
        updates_per_iteration=8, batch_size=2048, learning_rate=3e-4, max_grad_norm=1.0,
        log_std=-1.6,  # the saved policy's action std [log] (about 0.2), for a PPO fine-tune
        log_every=10,  # iterations per progress line
        # `distill --memory-probe` (products/student_memory.py): histories of k inputs, Adam
        memory_probe=config_dict.create(ks=(1, 4), steps=12000, batch=2048, holdout=0.1,
                                          eval_every=3000))
    if preset != "cpu":
        raise ValueError(f"unknown preset {preset!r}; the distillation has a cpu preset only")
    return cfg

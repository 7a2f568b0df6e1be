"""Default configs, one per stage, as ml_collections ConfigDicts (MuJoCo Playground style).

Keys that fix array shapes (box capacity, grid, batch) are kept in `shape` sub-dicts, apart from
values that may be traced and vmapped (difficulty, reward weights, thresholds).
"""

from __future__ import annotations

from ml_collections import config_dict


def default_terrain_config() -> config_dict.ConfigDict:
    """Artifact sizes of the paper (Sec. IV), at difficulty 1."""
    return config_dict.create(
        stair_rise_m=0.17,
        step_height_m=0.30,  # `jumps`: a block 0.3 m high ...
        step_length_m=0.16,  # ... and 0.16 m long
        gap_length_m=0.70,
        flat_min_m=0.36,  # flat segments (and stair runs) ~ U(0.36, 0.44) m
        flat_max_m=0.44,
        width_min_m=1.1,  # track width ~ U(1.1, 1.7) m, fixed per track
        width_max_m=1.7,
        segments_min=4,  # boxes (or holes) per artifact, 4..9
        segments_max=9,
        n_artifacts=7,
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
        sim_dt_s=0.005,
        n_substeps=4,  # control period = 0.02 s (50 Hz)
        solver_iterations=4,
        ls_iterations=8,
    )


def default_env_config() -> config_dict.ConfigDict:
    return config_dict.create(
        kind="walk",  # terrain kind of the track bank
        n_tracks=256,  # tracks in the bank; reset picks one at random
        seed=0,  # seed of the bank's first track (track i has seed + i)
        difficulty=1.0,  # traced: the curriculum changes it without recompiling
        init="stand",  # "stand": keyframe + pause (RoA overlap), "random": random joints, no pause
        pause_s=0.5,
        random_joint_scale=0.5,  # "random" init: fraction of each joint's range around the keyframe
        episode_length_s=30.0,
        detect_range_m=0.9,  # oracle detector: next artifact once its start is this close
        detector_one_hot=False,  # append the detected kind (3) to the observation
        target_speed_mps=0.8,
        fall_height_m=0.55,  # pelvis CoM lower than this above the terrain beneath: fallen
        fall_tilt_rad=1.0,  # |pitch| or |roll| above this: fallen
        reward=config_dict.create(
            progress=3.0,  # x velocity, capped at the target speed
            speed=1.0,  # exp(-(vx - target)^2 / 0.1) tracking bonus
            alive=1.0,
            upright=0.5,  # cos(pitch) * cos(roll)
            height=0.5,  # exp(-(h - h_stand)^2 / 0.01)
            lateral=0.5,  # penalty on |y| drift and |yaw|
            torque=0.002,  # penalty on mean squared action * gear (Nm^2 scaled)
            fall=10.0,  # one-off penalty on a fall
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

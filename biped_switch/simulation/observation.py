"""The observation layout, named: state | heightmap | phase clock | one-hot, as slices resolved once on the host."""

from __future__ import annotations




STATE_SIZE = 51


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

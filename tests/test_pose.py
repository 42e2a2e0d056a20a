import numpy as np

from puppet.motion import Motion
from puppet.pose import (
    angles_from_matrices,
    head_pivot,
    posed_landmarks,
    rotation_matrices,
)


def test_angles_round_trip():
    angles = np.random.default_rng(0).uniform(-0.6, 0.6, (50, 3)).astype(np.float32)
    assert np.allclose(angles_from_matrices(rotation_matrices(angles)), angles, atol=1e-5)


def test_signs_match_the_documented_convention(demo):
    rest = demo.rig.landmarks
    nose = 30
    for axis, coordinate, direction in [(0, 1, +1), (1, 0, +1)]:  # pitch nods down, yaw turns to image right
        motion = Motion.still(1, 25)
        rotation = motion.rotation.copy()
        rotation[0, axis] = 0.2
        moved = posed_landmarks(rest, Motion(motion.offsets, rotation, motion.translation, 25))[0]
        assert (moved[nose, coordinate] - rest[nose, coordinate]) * direction > 0


def test_pivot_is_below_the_eyes_and_behind_the_face(demo):
    rest = demo.rig.landmarks
    pivot = head_pivot(rest)
    assert pivot[1] > rest[36:48, 1].mean() and pivot[2] < rest[:, 2].min()

"""Head pose: rotating a face's landmarks in 3-D about a neck pivot, and recovering the pose.

Points are image pixels, x right, y down, z toward the viewer; the projection is orthographic
(drop z). The rotation is R = Rz(roll) · Ry(yaw) · Rx(pitch), see `puppet.motion.Motion`.
"""
import numpy as np

from puppet.landmarks import eye_centres, face_axes, face_scale
from puppet.motion import Motion

# The pivot sits at the top of the neck: this many inter-ocular distances below the eye line
# and behind the eye plane.
PIVOT_DOWN = 1.6
PIVOT_BACK = 1.0


def head_pivot(rest: np.ndarray) -> np.ndarray:
    """(3,) float32 pixel position the head turns about, from (68, 3) rest landmarks."""
    scale = face_scale(rest)
    centre = eye_centres(rest[:, :2]).mean(0) + PIVOT_DOWN * scale * face_axes(rest)[1]
    return np.array([centre[0], centre[1], -PIVOT_BACK * scale], dtype=np.float32)


def rotation_matrices(angles: np.ndarray) -> np.ndarray:
    """(T, 3, 3) float32 rotation matrices from (T, 3) pitch, yaw, roll radians."""
    angles = np.asarray(angles, dtype=np.float64)
    cp, sp = np.cos(angles[:, 0]), np.sin(angles[:, 0])
    cy, sy = np.cos(angles[:, 1]), np.sin(angles[:, 1])
    cr, sr = np.cos(angles[:, 2]), np.sin(angles[:, 2])
    one, zero = np.ones_like(cp), np.zeros_like(cp)
    rx = np.stack([one, zero, zero, zero, cp, sp, zero, -sp, cp], -1).reshape(-1, 3, 3)
    ry = np.stack([cy, zero, sy, zero, one, zero, -sy, zero, cy], -1).reshape(-1, 3, 3)
    rz = np.stack([cr, -sr, zero, sr, cr, zero, zero, zero, one], -1).reshape(-1, 3, 3)
    return (rz @ ry @ rx).astype(np.float32)


def angles_from_matrices(matrices: np.ndarray) -> np.ndarray:
    """(T, 3) float32 pitch, yaw, roll radians: the inverse of `rotation_matrices` (|yaw| < 90°)."""
    m = np.asarray(matrices, dtype=np.float64)
    yaw = np.arcsin(np.clip(-m[:, 2, 0], -1.0, 1.0))
    pitch = np.arctan2(-m[:, 2, 1], m[:, 2, 2])
    roll = np.arctan2(m[:, 1, 0], m[:, 0, 0])
    return np.stack([pitch, yaw, roll], -1).astype(np.float32)


def move_points(points: np.ndarray, pivot: np.ndarray, motion: Motion, offsets: np.ndarray | None = None) -> np.ndarray:
    """(T, N, 3) float32: (N, 3) rest points rotated and shifted by each frame's head pose.

    offsets: optional (T, N, 3) displacements in the head frame, added before the rotation.
    """
    local = points[None] - pivot if offsets is None else points[None] + offsets - pivot
    rotated = np.einsum("tij,tnj->tni", rotation_matrices(motion.rotation), local)
    shift = np.concatenate([motion.translation, np.zeros((len(motion), 1), np.float32)], axis=1)
    return (rotated + pivot + shift[:, None]).astype(np.float32)


def posed_landmarks(rest: np.ndarray, motion: Motion) -> np.ndarray:
    """(T, 68, 3) float32 landmarks in the image's pixel frame: rest + offsets, then the head pose.

    This is what `--landmarks-out` writes and what a track file holds.
    """
    return move_points(rest, head_pivot(rest), motion, motion.offsets)

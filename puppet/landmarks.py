"""The 68-point iBUG landmark scheme, and reading, checking and measuring landmark sets.

Coordinates everywhere in puppet: image pixels, origin at the top-left corner of the
portrait, x right, y down, z toward the viewer (same pixel units).
"Right"/"left" in part names are the subject's own, as in iBUG: RIGHT_EYE is on the image's left.
"""
import json
from pathlib import Path

import numpy as np

from puppet.errors import PuppetError

N_LANDMARKS = 68

# Index ranges of each facial part (iBUG-68).
JAW = range(0, 17)
RIGHT_BROW = range(17, 22)
LEFT_BROW = range(22, 27)
NOSE_BRIDGE = range(27, 31)
NOSE_LOWER = range(31, 36)
RIGHT_EYE = range(36, 42)
LEFT_EYE = range(42, 48)
OUTER_LIP = range(48, 60)
INNER_LIP = range(60, 68)
NOSE = range(27, 36)
MOUTH = range(48, 68)

# The 8 facial parts of MakeItTalk's graph-Laplacian loss (Eq. 9).
FACIAL_PARTS = {
    "jaw": JAW,
    "right_brow": RIGHT_BROW,
    "left_brow": LEFT_BROW,
    "nose": NOSE,
    "right_eye": RIGHT_EYE,
    "left_eye": LEFT_EYE,
    "outer_lip": OUTER_LIP,
    "inner_lip": INNER_LIP,
}

NOSE_TIP = 30
MOUTH_CORNERS = (48, 54)
INNER_MOUTH_CORNERS = (60, 64)
# Upper/lower inner-lip points facing each other across the mouth opening.
INNER_LIP_PAIRS = ((61, 67), (62, 66), (63, 65))
# Upper/lower eyelid points facing each other (right eye, then left eye).
EYELID_PAIRS = ((37, 41), (38, 40), (43, 47), (44, 46))

# Depth of each landmark on an average face, in inter-ocular distances (eye centre to eye
# centre), toward the viewer, measured from the plane of the eye corners. A portrait is flat,
# so puppet borrows this depth to turn the head in 3-D.
CANONICAL_DEPTH = np.array(
    [-0.95, -0.90, -0.82, -0.72, -0.58, -0.40, -0.22, -0.06, 0.00,  # jaw, ear to chin
     -0.06, -0.22, -0.40, -0.58, -0.72, -0.82, -0.90, -0.95,
     0.02, 0.10, 0.14, 0.14, 0.12,  0.12, 0.14, 0.14, 0.10, 0.02,  # brows
     0.12, 0.22, 0.32, 0.42,  0.20, 0.24, 0.27, 0.24, 0.20,  # nose
     -0.02, 0.02, 0.02, 0.00, 0.02, 0.02,  0.00, 0.02, 0.02, -0.02, 0.02, 0.02,  # eyes
     0.10, 0.20, 0.26, 0.28, 0.26, 0.20, 0.10, 0.18, 0.23, 0.24, 0.23, 0.18,  # outer lip
     0.12, 0.22, 0.23, 0.22, 0.12, 0.21, 0.22, 0.21],  # inner lip
    dtype=np.float32,
)
assert CANONICAL_DEPTH.shape == (N_LANDMARKS,)


def eye_centres(points: np.ndarray) -> np.ndarray:
    """(2, D) centres of the subject's right eye (image left) and left eye, from (68, D) points."""
    return np.stack([points[RIGHT_EYE].mean(0), points[LEFT_EYE].mean(0)])


def face_scale(points: np.ndarray) -> float:
    """Inter-ocular distance in pixels: the unit every face-relative size in puppet is given in."""
    right, left = eye_centres(points[:, :2])
    return float(np.linalg.norm(left - right))


def face_axes(points: np.ndarray) -> np.ndarray:
    """(2, 2) rows: the face's own x axis (along the eye line) and y axis (down the face), image pixels."""
    right, left = eye_centres(points[:, :2])
    x = (left - right) / max(np.linalg.norm(left - right), 1e-6)
    return np.array([x, [-x[1], x[0]]], dtype=np.float32)


def from_face_units(offsets: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(T, 68, 3) float32 pixel offsets from offsets in this face's units: (T, 68, 3) in
    inter-ocular distances along the face's own axes (x along the eye line, y down the face,
    z toward the viewer), as the learned predictor gives them. points: (68, 2|3) the face, pixels."""
    scale = face_scale(points)
    x_axis, y_axis = face_axes(points)
    xy = offsets[..., :1] * x_axis + offsets[..., 1:2] * y_axis
    return (np.concatenate([xy, offsets[..., 2:3]], axis=-1) * scale).astype(np.float32)


def with_depth(points: np.ndarray) -> np.ndarray:
    """(68, 3) float32: (68, 2|3) pixel points with z from CANONICAL_DEPTH scaled to this face.

    A given z column is kept only if it varies (the shared cartoons' files carry a constant 1.0).
    """
    points = np.asarray(points, dtype=np.float32)
    if points.shape[1] == 3 and np.ptp(points[:, 2]) > 1e-3:
        return points.copy()
    z = CANONICAL_DEPTH * face_scale(points)
    return np.column_stack([points[:, :2], z]).astype(np.float32)


def load(path: str | Path) -> np.ndarray:
    """(68, 2|3) float32 landmarks, image pixels, from a `.json`, `.npy` or text file of 68 rows `x y [z]`.

    JSON may be a list of 68 `[x, y(, z)]` or an object with a "landmarks" list.
    """
    path = Path(path)
    if not path.is_file():
        raise PuppetError(f"landmark file not found: {path}")
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text())
            if isinstance(data, dict):
                data = data.get("landmarks")
            points = np.asarray(data, dtype=np.float32)
        elif path.suffix.lower() == ".npy":
            points = np.load(path, allow_pickle=False).astype(np.float32)
        else:
            points = np.loadtxt(path, dtype=np.float32, ndmin=2)
    except (ValueError, TypeError, OSError, UnicodeDecodeError) as error:
        raise PuppetError(f"cannot read landmarks from {path}: {str(error).splitlines()[0]}") from None
    return validate(points, source=str(path))


def validate(points: np.ndarray, source: str = "landmarks", image_size: tuple[int, int] | None = None) -> np.ndarray:
    """Check a landmark array; return it as (68, 2|3) float32 or raise PuppetError saying what is wrong.

    image_size: (width, height) in pixels; if given, every point must lie inside the image.
    """
    points = np.asarray(points, dtype=np.float32)
    if points.ndim != 2 or points.shape[0] != N_LANDMARKS or points.shape[1] not in (2, 3):
        raise PuppetError(f"{source}: expected 68 rows of 'x y [z]', got an array of shape {points.shape}")
    if not np.all(np.isfinite(points)):
        raise PuppetError(f"{source}: landmarks contain NaN or infinite values")
    if face_scale(points) < 2.0:
        raise PuppetError(f"{source}: the eyes are less than 2 pixels apart; these are not face landmarks")
    if image_size is not None:
        width, height = image_size
        x, y = points[:, 0], points[:, 1]
        outside = (x < -0.5) | (y < -0.5) | (x > width + 0.5) | (y > height + 0.5)
        if outside.any():
            raise PuppetError(
                f"{source}: {int(outside.sum())} landmarks lie outside the {width}x{height} image "
                f"(first: #{int(np.argmax(outside))}); are they for another image?"
            )
    return points


def clamp_to_image(points: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """(68, D) points moved inside the image: a detected or fitted face may reach past a tight crop."""
    points = np.array(points, dtype=np.float32)
    points[:, 0] = np.clip(points[:, 0], 0, image_size[0])
    points[:, 1] = np.clip(points[:, 1], 0, image_size[1])
    return points


def save_txt(path: str | Path, points: np.ndarray) -> None:
    """Write (68, 2|3) points as 68 rows `x y [z]`, the format `load` reads."""
    np.savetxt(path, np.asarray(points, dtype=np.float32), fmt="%.3f")

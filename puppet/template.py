"""A mean 68-point face placed on any portrait (cartoons included) from 5 points a user gives.

Sketch: the mean face is dlib's own predictor's mean shape (`make_mean_face`), stored in
assets/mean_face.txt in face units: eye centres at (-0.5, 0) and (0.5, 0), y down. `fit` maps
it onto the 5 control points with a least-squares affine map, then bends it with a thin-plate
spline (in face units, before the affine map) so that the 5 points are met exactly and
everything else follows smoothly. Each eye ring moves as one piece, so eyes keep their shape
and their centres land exactly on the given points. A fit that would fold the face is refused.

Regenerate the asset with `python -m puppet.template`.
"""
import functools
from importlib.resources import files

import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.spatial import Delaunay

from puppet import landmarks as lm
from puppet.errors import PuppetError

MEAN_FACE_FILE = "mean_face.txt"  # in the puppet.assets package (the repository's assets/)

CONTROL_POINTS = ("right_eye", "left_eye", "nose_tip", "right_mouth_corner", "left_mouth_corner")
POINTS_ORDER = (
    "the eye centre on the image's left (the subject's right eye), the eye centre on the image's "
    "right, the nose tip, the mouth corner on the image's left, the mouth corner on the image's right"
)
POINTS_HELP = f"5 points 'x,y' in image pixels, in this order: {POINTS_ORDER}"

MIN_EYE_DISTANCE = 2.0  # pixels, as in `landmarks.validate`
# The affine map's smaller stretch over its larger one: below this the points (nearly) lie on a
# line (the mean face's own control points give 1).
MIN_AFFINE_ASPECT = 0.2
# The bent face may be squeezed to this fraction of its area locally, no further (0: folded).
MIN_LOCAL_AREA = 0.1
# Spacing, in face units (inter-ocular distances), of the grid the fold check samples.
FOLD_GRID_STEP = 0.05
FOLD_STEP = 1e-3  # finite-difference step for the spline's Jacobian, face units


def make_mean_face() -> np.ndarray:
    """(68, 2) float64 mean face from dlib's predictor; eye centres at (-0.5, 0), (0.5, 0), y down."""
    from puppet.detect import (
        box_mean_shape,  # dlib is needed only to regenerate the asset
    )

    return _to_face_units(box_mean_shape())


def _to_face_units(points: np.ndarray) -> np.ndarray:
    """(68, 2) points moved, turned and scaled (no shear) so the eye centres are at (∓0.5, 0)."""
    z = points[:, 0] + 1j * points[:, 1]
    right, left = z[list(lm.RIGHT_EYE)].mean(), z[list(lm.LEFT_EYE)].mean()
    z = (z - (right + left) / 2) / (left - right)
    return np.column_stack([z.real, z.imag])


@functools.cache
def _load_mean_face() -> np.ndarray:
    text = (files("puppet.assets") / MEAN_FACE_FILE).read_text()
    face = np.loadtxt(text.splitlines(), dtype=np.float64, ndmin=2)
    face.setflags(write=False)
    return face


def __getattr__(name: str) -> np.ndarray:
    # MEAN_FACE, (68, 2) float64 face units, is read on first use, so that
    # `python -m puppet.template` can write its file when it is missing.
    if name == "MEAN_FACE":
        return _load_mean_face()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def control_points(face: np.ndarray) -> np.ndarray:
    """(5, 2) points of a (68, 2) face in `CONTROL_POINTS` order: eye centres, nose tip, mouth corners."""
    return np.vstack([lm.eye_centres(face[:, :2]), face[[lm.NOSE_TIP, *lm.MOUTH_CORNERS], :2]])


CENTRED_EYES = 0.22  # a face placed with no clues: eyes this share of the shorter side apart ...
CENTRED_EYE_LINE = 0.42  # ... on a line this far down the image


def centred(image_size: tuple[int, int]) -> np.ndarray:
    """(68, 2) float32 landmarks, image pixels: the mean face in the middle of an image, upright, for
    a portrait where no face was found (a starting point for the rig editor)."""
    width, height = image_size
    iod = CENTRED_EYES * min(width, height)
    return (_load_mean_face() * iod + (width / 2, CENTRED_EYE_LINE * height)).astype(np.float32)


def parse_points(texts: list[str]) -> np.ndarray:
    """(5, 2) float32 image pixels from 5 strings 'x,y' in `CONTROL_POINTS` order."""
    if len(texts) != len(CONTROL_POINTS):
        raise PuppetError(f"--points takes {len(CONTROL_POINTS)} points 'x,y' ({POINTS_ORDER}); got {len(texts)}")
    points = []
    for text in texts:
        try:
            x, y = (float(value) for value in text.split(","))
        except ValueError:
            raise PuppetError(f"--points: cannot read {text!r} as 'x,y' pixel coordinates, e.g. 120.5,88") from None
        if not np.isfinite([x, y]).all():
            raise PuppetError(f"--points: {text!r} is not a finite pixel position")
        points.append((x, y))
    return np.array(points, dtype=np.float32)


def _outside(points: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """(N,) bool: which of (N, 2) pixel points lie outside the image (same bounds as `landmarks.validate`)."""
    width, height = image_size
    x, y = points[:, 0], points[:, 1]
    return (x < -0.5) | (y < -0.5) | (x > width + 0.5) | (y > height + 0.5)


def _check(points: np.ndarray, image_size: tuple[int, int]) -> None:
    """Raise PuppetError unless (5, 2) pixel points can be a face's eyes, nose tip and mouth corners."""
    width, height = image_size
    outside = _outside(points, image_size)
    if outside.any():
        name = CONTROL_POINTS[int(np.argmax(outside))]
        raise PuppetError(f"--points: the {name} point lies outside the {width}x{height} image")
    right_eye, left_eye, nose, right_corner, left_corner = points
    across = left_eye - right_eye
    if np.linalg.norm(across) < MIN_EYE_DISTANCE:
        raise PuppetError("--points: the two eye points coincide; give the eye on the image's left first, then the other")
    if across[0] <= 0:
        raise PuppetError("--points: the eyes are swapped; give the eye on the image's left first")
    down = np.array([-across[1], across[0]])  # the eye line turned 90°: down the face
    below_eyes = (np.stack([nose, right_corner, left_corner]) - (right_eye + left_eye) / 2) @ down
    if np.any(below_eyes[1:] <= 0):
        raise PuppetError("--points: the mouth must be below the eyes; the order is " + POINTS_ORDER)
    if below_eyes[0] <= 0:
        raise PuppetError("--points: the nose tip must be below the eyes (on a face without a nose, pick a point between eyes and mouth)")
    if (left_corner - right_corner) @ across <= 0:
        raise PuppetError("--points: the mouth corners are swapped; give the corner on the image's left first")


def _affine(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(3, 2) least-squares affine map of (N, 2) source onto target: apply as [x, y, 1] @ map."""
    homogeneous = np.column_stack([source, np.ones(len(source))])
    return np.linalg.lstsq(homogeneous, target, rcond=None)[0]


def _apply(affine: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ affine[:2] + affine[2]


def _fold_check(bend: RBFInterpolator, face: np.ndarray) -> None:
    """Raise PuppetError if the spline `bend` squeezes or folds any part of the (68, 2) face."""
    hull = Delaunay(face)
    lo, hi = face.min(0), face.max(0)
    xs, ys = np.meshgrid(np.arange(lo[0], hi[0], FOLD_GRID_STEP), np.arange(lo[1], hi[1], FOLD_GRID_STEP))
    samples = np.column_stack([xs.ravel(), ys.ravel()])
    samples = np.vstack([face, samples[hull.find_simplex(samples) >= 0]])
    step = np.eye(2) * FOLD_STEP
    d_dx = (bend(samples + step[0]) - bend(samples - step[0])) / (2 * FOLD_STEP)
    d_dy = (bend(samples + step[1]) - bend(samples - step[1])) / (2 * FOLD_STEP)
    local_area = (1 + d_dx[:, 0]) * (1 + d_dy[:, 1]) - d_dx[:, 1] * d_dy[:, 0]
    if local_area.min() < MIN_LOCAL_AREA:
        raise PuppetError(
            "--points: a face cannot stretch that way (it would fold over itself); check the order: " + POINTS_ORDER
        )


def fit(points: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """(68, 2) float32 landmarks, image pixels, of the mean face bent onto 5 control points.

    points: (5, 2) image pixels in `CONTROL_POINTS` order. image_size: (width, height) pixels.
    The result's eye centres (ring means), nose tip and mouth corners equal the given points.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.shape != (len(CONTROL_POINTS), 2) or not np.isfinite(points).all():
        raise PuppetError(f"--points: expected 5 finite 'x,y' points, got an array of shape {points.shape}")
    _check(points, image_size)
    face = _load_mean_face()
    anchors = control_points(face)
    affine = _affine(anchors, points)
    stretches = np.linalg.svd(affine[:2], compute_uv=False)
    if np.linalg.det(affine[:2]) <= 0 or stretches[1] < MIN_AFFINE_ASPECT * stretches[0]:
        raise PuppetError("--points: the 5 points (nearly) lie on one line; the order is " + POINTS_ORDER)

    # The spline works in face units: where each control point must go, before the affine map.
    wanted = (points - affine[2]) @ np.linalg.inv(affine[:2])
    bend = RBFInterpolator(anchors, wanted - anchors, kernel="thin_plate_spline", degree=1)
    _fold_check(bend, face)
    offsets = bend(face)
    offsets[list(lm.RIGHT_EYE)] = bend(anchors[:1])  # eye rings move as a whole
    offsets[list(lm.LEFT_EYE)] = bend(anchors[1:2])
    result = _apply(affine, face + offsets)
    return result.astype(np.float32)


if __name__ == "__main__":
    path = files("puppet.assets") / MEAN_FACE_FILE
    np.savetxt(str(path), make_mean_face(), fmt="%.5f")
    print(f"wrote {path}")

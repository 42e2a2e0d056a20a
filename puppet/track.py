"""Motion-track files, and turning a track of posed landmarks back into a Motion.

A track file is an uncompressed `.npz` (no pickles) holding
    landmarks: (T, 68, 3) float32 absolute posed landmark positions, image pixels of the portrait
               (x right, y down, z toward the viewer), as `puppet.pose.posed_landmarks` gives them;
    fps:       scalar float64, frames per second.

`motion_from_track` splits each frame into a head pose and a face shape: a rigid 3-D fit (Kabsch,
rotation and translation, no scale) of the rest face's stable points (eye corners and nose, which
no expression moves) about the rig's neck pivot gives the rotation and shift; everything the fit
leaves over, rotated back into the head frame, is the frame's offsets. Posing the rest face with
that Motion gives the track back exactly, whatever the fit found.
"""
import zipfile
from pathlib import Path

import numpy as np

from puppet.errors import PuppetError
from puppet.landmarks import N_LANDMARKS
from puppet.motion import Motion
from puppet.pose import angles_from_matrices, head_pivot, rotation_matrices

# Points that move with the skull but not with expressions: eye corners, nose bridge, nose base.
STABLE_POINTS = (36, 39, 42, 45, 27, 28, 29, 30, 31, 32, 33, 34, 35)
FLAT_DEPTH = 1e-3  # pixels: a track whose z spans less than this is 2-D


def write(path: str | Path, landmarks: np.ndarray, fps: float) -> None:
    """Write (T, 68, 3) posed landmarks (image pixels) at `fps` to a track file at exactly `path`."""
    landmarks = _checked(np.asarray(landmarks, np.float32), fps, source=str(path))
    with open(path, "wb") as file:
        np.savez(file, landmarks=landmarks, fps=np.float64(fps))


def read(path: str | Path) -> tuple[np.ndarray, float]:
    """((T, 68, 3) float32 posed landmarks in image pixels, fps) from a track file; PuppetError if unusable."""
    path = Path(path)
    if not path.is_file():
        raise PuppetError(f"track file not found: {path}")
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise PuppetError(f"{path}: not a track file (expected an .npz with 'landmarks' and 'fps')")
        with data:
            missing = {"landmarks", "fps"} - set(data.files)
            if missing:
                raise PuppetError(f"{path}: not a track file, missing {sorted(missing)} (has {sorted(data.files)})")
            landmarks, fps = data["landmarks"], data["fps"]
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        reason = (str(error).splitlines() or [type(error).__name__])[0]
        raise PuppetError(f"cannot read track file {path}: {reason}") from None
    if np.ndim(fps) != 0 or not np.issubdtype(np.asarray(fps).dtype, np.number):
        raise PuppetError(f"{path}: 'fps' must be a single number, got shape {np.shape(fps)}")
    return _checked(landmarks, float(fps), source=str(path)), float(fps)


def _checked(landmarks: np.ndarray, fps: float, source: str) -> np.ndarray:
    """(T, 68, 3) float32 landmarks after checking shape, values and fps; PuppetError otherwise."""
    if landmarks.ndim != 3 or landmarks.shape[1:] != (N_LANDMARKS, 3) or len(landmarks) == 0:
        raise PuppetError(f"{source}: track landmarks must be (frames, 68, 3), got shape {landmarks.shape}")
    if not np.issubdtype(landmarks.dtype, np.number):
        raise PuppetError(f"{source}: track landmarks must be numbers, got {landmarks.dtype}")
    if not np.all(np.isfinite(landmarks)):
        raise PuppetError(f"{source}: track landmarks contain NaN or infinite values")
    if not np.isfinite(fps) or fps <= 0:
        raise PuppetError(f"{source}: fps must be a positive number, got {fps}")
    return landmarks.astype(np.float32)


def motion_from_track(landmarks: np.ndarray, rest: np.ndarray, fps: float) -> Motion:
    """The Motion that poses `rest` into each frame of a track.

    landmarks: (T, 68, 3) posed landmarks, image pixels. If z is the same everywhere (a 2-D track,
               e.g. from a 2-D detector), each point's z is taken from `rest` before fitting, so
               the head's turn out of the image plane is only estimated from the 2-D layout.
    rest:      (68, 3) float32 rest landmarks the rig poses, image pixels (with depth, see
               `puppet.landmarks.with_depth`).
    Returns a Motion with `pose.posed_landmarks(rest, motion)` equal to the track (3-D tracks; for
    2-D tracks x and y) to float32 precision.
    """
    target = np.array(landmarks, np.float64)
    rest64 = np.asarray(rest, np.float64)
    if np.ptp(target[..., 2]) < FLAT_DEPTH:
        target[..., 2] = rest64[:, 2]
    pivot = head_pivot(np.asarray(rest, np.float32)).astype(np.float64)

    source = rest64[list(STABLE_POINTS)] - pivot  # (S, 3) about the pivot
    moved = target[:, list(STABLE_POINTS)] - pivot  # (T, S, 3)
    source_mean, moved_mean = source.mean(0), moved.mean(1)
    covariance = np.einsum("si,tsj->tij", source - source_mean, moved - moved_mean[:, None])
    u, _, vt = np.linalg.svd(covariance)
    flip = np.sign(np.linalg.det(np.einsum("tji,tkj->tik", vt, u)))  # det(V Uᵀ): avoid reflections
    u[:, :, 2] *= flip[:, None]
    best = np.einsum("tji,tkj->tik", vt, u)  # R = V Uᵀ maps rest onto the frame

    rotation = angles_from_matrices(best)
    matrices = rotation_matrices(rotation).astype(np.float64)  # exactly what the rig will apply
    shift = moved_mean - np.einsum("tij,j->ti", matrices, source_mean)
    shift[:, 2] = 0.0  # a Motion shifts only in the image plane; depth goes into the offsets
    local = np.einsum("tji,tnj->tni", matrices, target - pivot - shift[:, None])  # Rᵀ(...)
    return Motion(
        offsets=(local + pivot - rest64).astype(np.float32),
        rotation=rotation,
        translation=shift[:, :2].astype(np.float32),
        fps=fps,
    )

"""Motion: what every motion source produces and the rig consumes.

A source (a track file, the loudness baseline, later the learned predictor) gives per-frame
landmark offsets in the head's own frame plus a head pose; the rig applies the pose.
"""
from dataclasses import dataclass

import numpy as np

from puppet.landmarks import N_LANDMARKS


@dataclass(frozen=True)
class Motion:
    """Per-frame facial motion of one puppet at a fixed frame rate.

    offsets:     (T, 68, 3) float32, pixels of the rest image: displacement of each landmark from
                 its rest position, in the head's own frame (before head rotation), x right, y down,
                 z toward the viewer.
    rotation:    (T, 3) float32, radians: head pitch (+ nods the chin down), yaw (+ turns the face
                 toward the image's right), roll (+ tilts clockwise on screen), about the rig's pivot.
    translation: (T, 2) float32, pixels: head shift in the image plane after rotation.
    fps:         frames per second.
    """

    offsets: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    fps: float

    def __post_init__(self):
        t = len(self.offsets)
        assert self.offsets.shape == (t, N_LANDMARKS, 3), self.offsets.shape
        assert self.rotation.shape == (t, 3) and self.translation.shape == (t, 2)

    def __len__(self) -> int:
        return len(self.offsets)

    @classmethod
    def still(cls, frames: int, fps: float) -> "Motion":
        """A puppet at rest for `frames` frames."""
        return cls(
            offsets=np.zeros((frames, N_LANDMARKS, 3), np.float32),
            rotation=np.zeros((frames, 3), np.float32),
            translation=np.zeros((frames, 2), np.float32),
            fps=fps,
        )

    def __getitem__(self, frames: slice) -> "Motion":
        """The frames in a slice, as a Motion."""
        return Motion(self.offsets[frames], self.rotation[frames], self.translation[frames], self.fps)

    def __add__(self, other: "Motion") -> "Motion":
        """Layer two motions of the same length and rate (offsets, angles and shifts add)."""
        if len(self) != len(other) or self.fps != other.fps:
            raise ValueError(f"cannot add motions of {len(self)}@{self.fps} and {len(other)}@{other.fps}")
        return Motion(
            offsets=self.offsets + other.offsets,
            rotation=self.rotation + other.rotation,
            translation=self.translation + other.translation,
            fps=self.fps,
        )


def interpolate_rows(sequence: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(P, ...) float32: a (T, ...) sequence linearly interpolated at (P,) fractional row positions
    (row t at position t); positions outside [0, T − 1] hold the first or last row."""
    positions = np.clip(positions, 0, len(sequence) - 1)
    low = np.floor(positions).astype(int)
    high = np.minimum(low + 1, len(sequence) - 1)
    weight = (positions - low).reshape(-1, *([1] * (sequence.ndim - 1)))
    return ((1 - weight) * sequence[low] + weight * sequence[high]).astype(np.float32)


def resample(sequence: np.ndarray, fps_in: float, fps_out: float, frames: int) -> np.ndarray:
    """(frames, ...) float32: a (T, ...) per-frame sequence at fps_in, linearly interpolated at the
    centres of `frames` frames at fps_out (frame i covers [i/fps, (i+1)/fps)); ends are held."""
    centres = (np.arange(frames) + 0.5) / fps_out  # seconds; input row t is centred at (t + 0.5) / fps_in
    return interpolate_rows(sequence, centres * fps_in - 0.5)

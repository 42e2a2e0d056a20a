"""Lip sync from the learned predictor: speech → the network's canonical motion → this face.

The network (puppet.predictor) hears the voice and its speaker embedding (puppet.speaker) and
gives landmark offsets in face units at MOTION_FPS plus a head rotation; here they are scaled and
turned onto the portrait's own face (q + Δq, as in MakeItTalk) and resampled to the video's rate.
Files use the offline model, which hears 300 ms ahead (the paper's content window); the live
window uses the streaming one, which hears 60 ms ahead.
"""
import functools

import numpy as np

from puppet import speaker
from puppet.features import MOTION_FPS, SAMPLE_RATE
from puppet.landmarks import from_face_units
from puppet.motion import Motion, resample
from puppet.predictor import MODEL_FILES, Predictor, default_model


@functools.cache
def shipped_predictor(kind: str) -> Predictor:
    """A trained model in assets/models, "offline" or "streaming", loaded once."""
    return Predictor(default_model(kind))


def has_model() -> bool:
    """Whether the trained models ship with this install."""
    return all(default_model(kind).is_file() for kind in MODEL_FILES)


def learned_motion(samples: np.ndarray, rest: np.ndarray, fps: float, frames: int, predictor: Predictor | None = None) -> Motion:
    """Motion of `frames` frames at `fps` for (N,) float32 16 kHz speech on a face with (68, 3)
    rest landmarks (pixels): mouth and expression offsets and head rotation, no translation."""
    predictor = predictor or shipped_predictor("offline")
    offsets, rotation = predictor.predict(samples, speaker.embed(samples), SAMPLE_RATE)
    return Motion(
        offsets=from_face_units(resample(offsets, MOTION_FPS, fps, frames), rest),
        rotation=resample(rotation, MOTION_FPS, fps, frames),
        translation=np.zeros((frames, 2), np.float32),
        fps=fps,
    )

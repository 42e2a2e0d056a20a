"""Looking alive: blinks, idle head sway and breathing, layered on any motion source.

Blinks: the gaps between them are drawn from a gamma distribution (mean from the blink rate,
spread from `blink_randomness`), and now and then a blink is doubled. Each blink is placed so that
one frame shows the eyes fully shut: the lids close along a half-cosine in the first third of the
blink and open along a slower one in the rest. Both eyes blink together.
Idle sway: each of pitch, yaw and roll is a sum of a few sines at incommensurate frequencies
with seeded phases, so it never visibly repeats; its size grows with a smoothed `activity`
(e.g. the loudness opening) so a talking head moves a little more than a listening one.
Breathing: a slow rise and fall of the head in the image (up the face) with a matching tiny lift
of the chin. Everything is deterministic for a seed.
"""
import math
from dataclasses import dataclass

import numpy as np

from puppet.articulation import blend, unit_offsets
from puppet.landmarks import face_axes, face_scale
from puppet.motion import Motion

MAX_ROTATION_DEGREES = 6.0  # no life motion turns the head further than this on any axis
BLINK_CLOSING_SHARE = 1.0 / 3.0  # share of a blink spent closing; the lids open twice as slowly
DOUBLE_BLINK_GAP = 1.6  # a double blink's second closure follows the first by this many blink durations
MIN_BLINK_GAP = 2.0  # no two blinks are closer than this many blink durations (peak to peak), doubles aside
# Idle sway: frequencies (Hz at speed 1) and their shares of the amplitude (summing to 1, so the
# sway never exceeds idle_degrees); slower components carry more, as in a real head's drift.
SWAY_HZ = (0.07, 0.13, 0.29, 0.53)
SWAY_SHARE = (0.4, 0.3, 0.2, 0.1)
SWAY_AXES = (0.7, 1.0, 0.5)  # pitch, yaw, roll relative sizes: heads turn more than they nod or tilt
ACTIVITY_SMOOTHING = 0.5  # seconds: how fast the sway's size follows activity
BREATH_TILT = 20.0  # degrees of chin lift per inter-ocular distance of rise (0.24° at the default amplitude)


@dataclass(frozen=True)
class LifeOptions:
    blink_rate: float = 15.0  # eye closures per minute, double blinks included
    blink_randomness: float = 0.5  # spread of the gaps between blinks (coefficient of variation; 0 = metronome)
    blink_duration: float = 0.15  # seconds from lids starting to close to fully open again
    double_blink: float = 0.1  # chance that a blink comes as a quick pair
    idle_degrees: float = 2.0  # largest idle head rotation when not talking (yaw; pitch 0.7x, roll 0.5x)
    idle_speed: float = 1.0  # multiplies the sway's frequencies (1: slowest swing about 14 s)
    activity_gain: float = 0.5  # the sway grows by this share at full activity
    breathing_period: float = 4.0  # seconds per breath
    breathing_amplitude: float = 0.012  # head rise per breath, in inter-ocular distances (1.2 px for eyes 100 px apart)
    seed: int = 0  # the same seed gives the same blinks and sway


def _blink_peaks(duration: float, options: LifeOptions, rng: np.random.Generator) -> list[float]:
    """Seconds at which the eyes are fully shut, in [0, duration)."""
    if options.blink_rate <= 0:
        return []
    mean_gap = 60.0 / options.blink_rate * (1.0 + options.double_blink)  # between blink episodes
    shape = 1.0 / max(options.blink_randomness, 1e-3) ** 2
    shortest = MIN_BLINK_GAP * options.blink_duration
    peaks = []
    time = rng.uniform(0.2, 1.0) * mean_gap
    while time < duration:
        peaks.append(time)
        if rng.random() < options.double_blink:
            peaks.append(time + DOUBLE_BLINK_GAP * options.blink_duration)
        time = peaks[-1] + max(rng.gamma(shape, mean_gap / shape), shortest)
    return [peak for peak in peaks if peak < duration]


def _blink_curve(frames: int, fps: float, peaks: list[float], blink_duration: float) -> np.ndarray:
    """(T,) float32 eye closure in [0, 1]; each peak is moved to the nearest frame, which reads exactly 1."""
    closing = BLINK_CLOSING_SHARE * blink_duration
    opening = blink_duration - closing
    t = np.arange(frames) / fps
    closure = np.zeros(frames, np.float32)
    for peak in peaks:
        peak = round(peak * fps) / fps
        before = np.clip((peak - t) / closing, 0.0, 1.0)
        after = np.clip((t - peak) / opening, 0.0, 1.0)
        shape = np.where(t <= peak, 0.5 + 0.5 * np.cos(np.pi * before), 0.5 + 0.5 * np.cos(np.pi * after))
        closure = np.maximum(closure, shape)
    return closure


def _sway(frames: int, fps: float, options: LifeOptions, rng: np.random.Generator) -> np.ndarray:
    """(T, 3) float64 idle pitch, yaw, roll in units of idle_degrees, each within [-axis size, +axis size]."""
    t = np.arange(frames)[:, None] / fps
    phases = rng.uniform(0.0, 2.0 * np.pi, (3, len(SWAY_HZ)))
    hz = np.asarray(SWAY_HZ) * options.idle_speed
    sway = [(np.sin(2.0 * np.pi * hz * t + phases[axis]) * SWAY_SHARE).sum(1) for axis in range(3)]
    return np.stack(sway, 1) * SWAY_AXES


def _smoothed_activity(activity: np.ndarray | None, frames: int, fps: float) -> np.ndarray:
    """(T,) activity in [0, 1], low-passed over ACTIVITY_SMOOTHING seconds (zeros when None)."""
    if activity is None:
        return np.zeros(frames)
    activity = np.clip(np.asarray(activity, np.float64).reshape(-1), 0.0, 1.0)
    if len(activity) != frames:
        raise ValueError(f"activity has {len(activity)} frames, the motion {frames}")
    keep = math.exp(-1.0 / max(fps * ACTIVITY_SMOOTHING, 1e-6))
    smooth = np.empty(frames)
    value = 0.0
    for i, level in enumerate(activity.tolist()):
        value = keep * value + (1.0 - keep) * level
        smooth[i] = value
    return smooth


def life_motion(frames: int, fps: float, rest: np.ndarray, options: LifeOptions = LifeOptions(),
                activity: np.ndarray | None = None) -> Motion:
    """Blinks, idle sway and breathing for `frames` frames.

    rest:     (68, 3) float32 rest landmarks, image pixels.
    activity: optional (T,) float32 in [0, 1], how animated the face is per frame (e.g. the jaw
              opening); the sway grows by up to `activity_gain` where it is high.
    Returns a Motion: offsets (T, 68, 3) float32 pixels in the head frame (blinks only), rotation
    (T, 3) radians within ±MAX_ROTATION_DEGREES, translation (T, 2) pixels (breathing, up the face).
    """
    rng = np.random.default_rng(options.seed)
    sway = _sway(frames, fps, options, rng)  # drawn first: blinks then depend only on the seed and duration
    closure = _blink_curve(frames, fps, _blink_peaks(frames / fps, options, rng), options.blink_duration)

    t = np.arange(frames) / fps
    breath = 0.5 - 0.5 * np.cos(2.0 * np.pi * t / options.breathing_period)  # 0 exhaled .. 1 inhaled
    rise = options.breathing_amplitude * breath  # inter-ocular distances
    livelier = 1.0 + options.activity_gain * _smoothed_activity(activity, frames, fps)
    degrees = options.idle_degrees * sway * livelier[:, None]
    degrees[:, 0] -= BREATH_TILT * rise
    rotation = np.radians(np.clip(degrees, -MAX_ROTATION_DEGREES, MAX_ROTATION_DEGREES))
    translation = -rise[:, None] * face_scale(rest) * face_axes(rest)[1]

    offsets = blend(unit_offsets(rest), {"blink_right": closure, "blink_left": closure})
    return Motion(offsets=offsets, rotation=rotation.astype(np.float32),
                  translation=translation.astype(np.float32), fps=fps)

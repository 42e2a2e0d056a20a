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


class Life:
    """Life motion for one face, evaluated at any increasing times: all at once for a video
    (`life_motion`) or frame by frame as a live window presents them.

    Blinks are drawn lazily as time advances, from the same random stream in the same order,
    so a live session and a rendered video with the same seed blink at the same moments.
    """

    def __init__(self, rest: np.ndarray, options: LifeOptions = LifeOptions()):
        """rest: (68, 3) float32 rest landmarks, image pixels."""
        self.options = options
        self.rng = np.random.default_rng(options.seed)
        self.phases = self.rng.uniform(0.0, 2.0 * np.pi, (3, len(SWAY_HZ)))  # drawn first: blinks then depend only on the seed
        self.units = unit_offsets(rest)
        self.scale, self.up = face_scale(rest), face_axes(rest)[1]
        self.peaks: list[float] = []  # seconds at which the eyes are fully shut, drawn up to `drawn_until`
        self.next_peak = self._first_peak()
        self.activity = 0.0  # smoothed activity at `last_time`
        self.last_time = None

    def _first_peak(self) -> float:
        if self.options.blink_rate <= 0:
            return math.inf
        return self.rng.uniform(0.2, 1.0) * self._mean_gap()

    def _mean_gap(self) -> float:
        """Seconds between blink episodes (a double blink counts once)."""
        return 60.0 / self.options.blink_rate * (1.0 + self.options.double_blink)

    def _draw_peaks(self, until: float) -> None:
        """Draw blink peaks up to `until` seconds; drop those too old to affect the present."""
        options = self.options
        shape = 1.0 / max(options.blink_randomness, 1e-3) ** 2
        while self.next_peak < until:
            self.peaks.append(self.next_peak)
            if self.rng.random() < options.double_blink:
                self.peaks.append(self.next_peak + DOUBLE_BLINK_GAP * options.blink_duration)
            gap = max(self.rng.gamma(shape, self._mean_gap() / shape), MIN_BLINK_GAP * options.blink_duration)
            self.next_peak = self.peaks[-1] + gap

    def closure(self, times: np.ndarray, fps: float | None = None) -> np.ndarray:
        """(T,) float32 eye closure in [0, 1] at increasing `times` (seconds). With `fps`, each
        blink's peak is moved to the nearest frame, which then reads exactly 1."""
        options = self.options
        self._draw_peaks(float(times[-1]) + options.blink_duration) if len(times) else None
        closing = BLINK_CLOSING_SHARE * options.blink_duration
        opening = options.blink_duration - closing
        closure = np.zeros(len(times), np.float32)
        for peak in self.peaks:
            if fps is not None:
                peak = round(peak * fps) / fps
            before = np.clip((peak - times) / closing, 0.0, 1.0)
            after = np.clip((times - peak) / opening, 0.0, 1.0)
            shape = np.where(times <= peak, 0.5 + 0.5 * np.cos(np.pi * before), 0.5 + 0.5 * np.cos(np.pi * after))
            closure = np.maximum(closure, shape)
        if len(times):  # blinks wholly in the past will never show again
            self.peaks = [peak for peak in self.peaks if peak + options.blink_duration >= times[-1] - 1.0]
        return closure

    def sway(self, times: np.ndarray) -> np.ndarray:
        """(T, 3) float64 idle pitch, yaw, roll in units of idle_degrees, each within ±its axis size."""
        hz = np.asarray(SWAY_HZ) * self.options.idle_speed
        t = np.asarray(times, np.float64)[:, None]
        sway = [(np.sin(2.0 * np.pi * hz * t + self.phases[axis]) * SWAY_SHARE).sum(1) for axis in range(3)]
        return np.stack(sway, 1) * SWAY_AXES

    def smooth_activity(self, times: np.ndarray, activity: np.ndarray | None) -> np.ndarray:
        """(T,) activity in [0, 1] low-passed over ACTIVITY_SMOOTHING seconds, carried across calls."""
        if activity is None:
            return np.zeros(len(times))
        activity = np.clip(np.asarray(activity, np.float64).reshape(-1), 0.0, 1.0)
        if len(activity) != len(times):
            raise ValueError(f"activity has {len(activity)} frames, the times {len(times)}")
        smooth = np.empty(len(times))
        for i, (time, level) in enumerate(zip(np.asarray(times, np.float64).tolist(), activity.tolist())):
            step = time - self.last_time if self.last_time is not None else (times[1] - times[0] if len(times) > 1 else 0.04)
            keep = math.exp(-max(step, 0.0) / ACTIVITY_SMOOTHING)
            self.activity = keep * self.activity + (1.0 - keep) * level
            self.last_time = time
            smooth[i] = self.activity
        return smooth

    def motion(self, times: np.ndarray, fps: float, activity: np.ndarray | None = None, snap_blinks: bool = True) -> Motion:
        """Life motion at increasing `times` (seconds from the start), reported as a Motion at `fps`.

        activity: optional (T,) float32 in [0, 1], how animated the face is (e.g. the jaw opening);
                  the sway grows by up to `activity_gain` where it is high.
        snap_blinks: put each blink's peak on a frame of `fps` (for videos, so one frame shows the
                  eyes fully shut); a live window presenting at irregular times leaves it off.
        Returns offsets (T, 68, 3) float32 pixels in the head frame (blinks only), rotation (T, 3)
        radians within ±MAX_ROTATION_DEGREES, translation (T, 2) pixels (breathing, up the face).
        """
        options = self.options
        times = np.asarray(times, np.float64)
        closure = self.closure(times, fps if snap_blinks else None)
        breath = 0.5 - 0.5 * np.cos(2.0 * np.pi * times / options.breathing_period)  # 0 exhaled .. 1 inhaled
        rise = options.breathing_amplitude * breath  # inter-ocular distances
        livelier = 1.0 + options.activity_gain * self.smooth_activity(times, activity)
        degrees = options.idle_degrees * self.sway(times) * livelier[:, None]
        degrees[:, 0] -= BREATH_TILT * rise
        rotation = np.radians(np.clip(degrees, -MAX_ROTATION_DEGREES, MAX_ROTATION_DEGREES))
        translation = -rise[:, None] * self.scale * self.up
        offsets = blend(self.units, {"blink_right": closure, "blink_left": closure})
        return Motion(offsets=offsets, rotation=rotation.astype(np.float32),
                      translation=translation.astype(np.float32), fps=fps)


def life_motion(frames: int, fps: float, rest: np.ndarray, options: LifeOptions = LifeOptions(),
                activity: np.ndarray | None = None) -> Motion:
    """Blinks, idle sway and breathing for a video of `frames` frames at `fps` (see `Life.motion`);
    rest: (68, 3) float32 rest landmarks, image pixels."""
    return Life(rest, options).motion(np.arange(frames) / fps, fps, activity)

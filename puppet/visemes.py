"""Mouth motion from aligned phones: viseme key poses blended by coarticulation.

Sketch (after Cohen & Massaro's coarticulation model): every phone has a key pose, a few weights
of the mouth's action units (`KEY_POSES`, e.g. "AA" opens the jaw, "UW" rounds the lips, "P"
presses them shut); the diphthongs glide from one key pose to another over their two halves.
Every phone also has a dominance over time: its class's strength at the phone's centre, held
over the class's `hold` share of the phone, then decaying exponentially (faster after the phone
than before it: mouths anticipate more than they linger) and tapering to exactly 0 at REACH
seconds past the held part.
Each unit's weight at time t is the dominance-weighted mean of all phones' targets for it; the
weights are then smoothed by a SMOOTHING-second Gaussian (the articulators' inertia) and
sampled at the frame centres.
Lip closures (p, b, m) and lip tucks (f, v) dominate strongly, so they win over their
neighbours even in fast speech; consonants made behind the lips (t, s, k, ...) hardly dominate
the lips' rounding and spreading, so "soon" rounds through the s. Silence targets the rest pose,
and because every dominance ends at REACH, a long silence is exactly at rest.
The blended weights drive the action units of `puppet.articulation` on the canonical face, and
the closure weight (saturating at CLOSURE_SATURATION: pressed lips cannot close further) finally
pulls the inner lips together (`articulation.close_lips`), so p, b, m shut the mouth however far
the neighbouring vowels have opened the jaw.
"""
from dataclasses import dataclass

import numpy as np

from puppet import landmarks, template
from puppet.alignment import SILENCE, Phone
from puppet.articulation import blend, close_lips, unit_offsets
from puppet.features import MOTION_FPS

# The action units a viseme moves; "lip_press" also sets how far `close_lips` shuts the mouth.
MOUTH_UNITS = ("jaw_open", "lip_wide", "lip_round", "upper_lip_raise", "lower_lip_tuck", "lip_press")
LIP_SHAPE_UNITS = ("lip_wide", "lip_round")  # what "lips free" consonants hardly dominate

# Key poses, as weights of MOUTH_UNITS (units not named are 0), and each phone's dominance class.
KEY_POSES: dict[str, tuple[dict[str, float], str]] = {
    SILENCE: ({}, "silence"),
    # vowels: jaw height, spreading, rounding
    "AA": ({"jaw_open": 0.75}, "vowel"),  # father
    "AE": ({"jaw_open": 0.6, "lip_wide": 0.35}, "vowel"),  # cat
    "AH": ({"jaw_open": 0.45}, "vowel"),  # but
    "AO": ({"jaw_open": 0.6, "lip_round": 0.4}, "vowel"),  # caught
    "EH": ({"jaw_open": 0.45, "lip_wide": 0.3}, "vowel"),  # bet
    "ER": ({"jaw_open": 0.25, "lip_round": 0.35, "upper_lip_raise": 0.2}, "vowel"),  # bird
    "IH": ({"jaw_open": 0.3, "lip_wide": 0.35}, "vowel"),  # bit
    "IY": ({"jaw_open": 0.15, "lip_wide": 0.6}, "vowel"),  # beet
    "UH": ({"jaw_open": 0.25, "lip_round": 0.6}, "vowel"),  # book
    "UW": ({"jaw_open": 0.12, "lip_round": 1.0}, "vowel"),  # boot
    # consonants
    "P": ({"jaw_open": 0.05, "lip_press": 1.0}, "bilabial"),
    "B": ({"jaw_open": 0.05, "lip_press": 1.0}, "bilabial"),
    "M": ({"jaw_open": 0.05, "lip_press": 1.0}, "bilabial"),
    "F": ({"jaw_open": 0.05, "lower_lip_tuck": 1.0, "upper_lip_raise": 0.3}, "labiodental"),
    "V": ({"jaw_open": 0.05, "lower_lip_tuck": 1.0, "upper_lip_raise": 0.3}, "labiodental"),
    "W": ({"jaw_open": 0.08, "lip_round": 1.0}, "rounded"),
    "SH": ({"jaw_open": 0.12, "lip_round": 0.5, "upper_lip_raise": 0.5}, "postalveolar"),
    "ZH": ({"jaw_open": 0.12, "lip_round": 0.5, "upper_lip_raise": 0.5}, "postalveolar"),
    "CH": ({"jaw_open": 0.12, "lip_round": 0.5, "upper_lip_raise": 0.5}, "postalveolar"),
    "JH": ({"jaw_open": 0.12, "lip_round": 0.5, "upper_lip_raise": 0.5}, "postalveolar"),
    "R": ({"jaw_open": 0.2, "lip_round": 0.45, "upper_lip_raise": 0.2}, "postalveolar"),
    "TH": ({"jaw_open": 0.2, "lip_wide": 0.1}, "dental"),  # tongue between the teeth
    "DH": ({"jaw_open": 0.2, "lip_wide": 0.1}, "dental"),
    "S": ({"jaw_open": 0.08, "lip_wide": 0.3}, "sibilant"),  # teeth nearly together
    "Z": ({"jaw_open": 0.08, "lip_wide": 0.3}, "sibilant"),
    "T": ({"jaw_open": 0.2}, "lingual"),
    "D": ({"jaw_open": 0.2}, "lingual"),
    "N": ({"jaw_open": 0.2}, "lingual"),
    "L": ({"jaw_open": 0.25}, "lingual"),
    "Y": ({"jaw_open": 0.15, "lip_wide": 0.4}, "lingual"),
    "K": ({"jaw_open": 0.3}, "velar"),
    "G": ({"jaw_open": 0.3}, "velar"),
    "NG": ({"jaw_open": 0.25}, "velar"),
    "HH": ({"jaw_open": 0.35}, "glottal"),  # takes the shape of the vowel it precedes
}
# Diphthongs glide from the first key pose (first half of the phone) to the second.
GLIDES = {"AW": ("AA", "UH"), "AY": ("AA", "IH"), "EY": ("EH", "IY"), "OW": ("AO", "UW"), "OY": ("AO", "IY")}


@dataclass(frozen=True)
class Dominance:
    """How strongly a class of phones holds the mouth to its key pose, and for how long."""

    strength: float  # dominance at the phone's centre (vowels: 1)
    anticipation: float  # 1/s: exponential decay rate before the phone (lower: felt earlier)
    carryover: float  # 1/s: decay rate after the phone
    hold: float  # share of the phone, around its centre, held at full strength
    lips_free: bool = False  # the lips' shape is free: LIPS_FREE of the strength over LIP_SHAPE_UNITS


DOMINANCE = {
    "silence": Dominance(strength=1.0, anticipation=25.0, carryover=25.0, hold=1.0),
    "vowel": Dominance(strength=1.0, anticipation=25.0, carryover=30.0, hold=0.5),
    "bilabial": Dominance(strength=25.0, anticipation=80.0, carryover=90.0, hold=0.5),
    "labiodental": Dominance(strength=15.0, anticipation=80.0, carryover=90.0, hold=0.5),
    "rounded": Dominance(strength=8.0, anticipation=40.0, carryover=60.0, hold=0.6),
    "postalveolar": Dominance(strength=4.0, anticipation=50.0, carryover=60.0, hold=0.5),
    "dental": Dominance(strength=2.0, anticipation=60.0, carryover=70.0, hold=0.5, lips_free=True),
    "sibilant": Dominance(strength=3.0, anticipation=60.0, carryover=70.0, hold=0.5, lips_free=True),
    "lingual": Dominance(strength=0.8, anticipation=60.0, carryover=70.0, hold=0.4, lips_free=True),
    "velar": Dominance(strength=0.5, anticipation=60.0, carryover=70.0, hold=0.4, lips_free=True),
    "glottal": Dominance(strength=0.1, anticipation=60.0, carryover=70.0, hold=0.3, lips_free=True),
}
LIPS_FREE = 0.05  # share of its strength a lips-free consonant has over the lips' shape
REACH = 0.3  # seconds past its held part at which a phone's dominance has tapered to exactly 0
BLEND_RATE = 1000.0  # Hz: weights are blended on this fine time grid, then smoothed and sampled
SMOOTHING = 0.02  # seconds: standard deviation of the Gaussian that stands for the articulators' inertia
CLOSURE_SATURATION = 0.75  # the lips are shut once the blended lip_press weight reaches this


@dataclass(frozen=True)
class VisemeOptions:
    """How the mouth articulates."""

    articulation: float = 1.0  # scales every key pose's weights (closures stay full): <1 mumbles, >1 over-articulates
    coarticulation: float = 1.0  # stretches every dominance's decay in time: >1 blends neighbouring phones more


def canonical_rest() -> np.ndarray:
    """(68, 3) float32 canonical face: the mean face, IOD units (eye centres at (∓0.5, 0)), y down,
    z toward the viewer. Mouth motion targets are offsets from it."""
    return landmarks.with_depth(template.MEAN_FACE).astype(np.float32)


def frame_times(n_frames: int, fps: float = MOTION_FPS) -> np.ndarray:
    """(T,) float64 seconds: the centre of each motion frame."""
    return (np.arange(n_frames) + 0.5) / fps


def _segments(phones: list[Phone]) -> list[tuple[str, float, float]]:
    """(key pose, start, end) per articulatory segment: phones, with diphthongs split in two halves."""
    segments = []
    for phone in phones:
        if phone.phone in GLIDES:
            middle = 0.5 * (phone.start + phone.end)
            first, second = GLIDES[phone.phone]
            segments += [(first, phone.start, middle), (second, middle, phone.end)]
        elif phone.phone in KEY_POSES:
            segments.append((phone.phone, phone.start, phone.end))
        else:
            raise ValueError(f"no key pose for phone {phone.phone!r}")
    return segments


def _dominance(kind: Dominance, offset: np.ndarray, held: float, coarticulation: float) -> np.ndarray:
    """Dominance of one segment at `offset` seconds from its centre (> 0 after it)."""
    distance = np.maximum(np.abs(offset) - held, 0.0)
    rate = np.where(offset < 0, kind.anticipation, kind.carryover) / coarticulation
    taper = np.clip(1.0 - distance / (REACH * coarticulation), 0.0, None) ** 2
    return kind.strength * np.exp(-rate * distance) * taper


def _blend_targets(segments, times: np.ndarray, options: VisemeOptions) -> dict[str, np.ndarray]:
    """{unit: (len(times),) float64}: the dominance-weighted mean of the segments' targets.

    Each segment is added only where its dominance is not 0, so the cost grows with the audio's
    length, not with its length times its number of phones.
    """
    numerator = {unit: np.zeros(len(times)) for unit in MOUTH_UNITS}
    denominator = {unit: np.zeros(len(times)) for unit in MOUTH_UNITS}
    for name, start, end in segments:
        pose, kind = KEY_POSES[name][0], DOMINANCE[KEY_POSES[name][1]]
        centre, held = 0.5 * (start + end), 0.5 * (end - start) * kind.hold
        extent = held + REACH * options.coarticulation
        window = slice(np.searchsorted(times, centre - extent), np.searchsorted(times, centre + extent))
        dominance = _dominance(kind, times[window] - centre, held, options.coarticulation)
        for unit in MOUTH_UNITS:
            share = LIPS_FREE if kind.lips_free and unit in LIP_SHAPE_UNITS else 1.0
            target = pose.get(unit, 0.0) * (1.0 if unit == "lip_press" else options.articulation)
            numerator[unit][window] += share * dominance * target
            denominator[unit][window] += share * dominance
    return {unit: np.where(denominator[unit] > 0, numerator[unit] / np.maximum(denominator[unit], 1e-12), 0.0)
            for unit in MOUTH_UNITS}


def unit_weights(phones: list[Phone], n_frames: int, fps: float = MOTION_FPS,
                 options: VisemeOptions = VisemeOptions()) -> dict[str, np.ndarray]:
    """{unit: (T,) float32 weight} for each of MOUTH_UNITS, sampled at frame centres.

    The dominance-weighted targets are blended on a BLEND_RATE grid, smoothed by a Gaussian of
    SMOOTHING seconds, sampled at the frames; lip_press saturates at CLOSURE_SATURATION.
    """
    segments = _segments(phones)
    if not segments or n_frames == 0:
        return {unit: np.zeros(n_frames, np.float32) for unit in MOUTH_UNITS}
    frames = frame_times(n_frames, fps)
    times = np.arange(frames[0] - 3 * SMOOTHING, frames[-1] + 3 * SMOOTHING, 1.0 / BLEND_RATE)
    blended = _blend_targets(segments, times, options)
    kernel = np.exp(-0.5 * (np.arange(-3 * SMOOTHING, 3 * SMOOTHING + 1e-9, 1.0 / BLEND_RATE) / SMOOTHING) ** 2)
    kernel /= kernel.sum()
    weights = {}
    for unit, weight in blended.items():
        smooth = np.convolve(np.pad(weight, len(kernel) // 2, mode="edge"), kernel, mode="valid")
        weights[unit] = np.interp(frames, times, smooth).astype(np.float32)
    weights["lip_press"] = np.minimum(weights["lip_press"] / CLOSURE_SATURATION, 1.0)
    return weights


def mouth_motion(phones: list[Phone], n_frames: int, fps: float = MOTION_FPS,
                 options: VisemeOptions = VisemeOptions()) -> np.ndarray:
    """(T, 68, 3) float32 mouth (and jaw) offsets from `canonical_rest()`, IOD units, head frame.

    phones: aligned phones covering the audio (see `puppet.alignment.align`); frame t shows the
            mouth at time (t + 0.5) / fps seconds.
    """
    rest = canonical_rest()
    weights = unit_weights(phones, n_frames, fps, options)
    offsets = blend(unit_offsets(rest), weights)
    return offsets + close_lips(rest + offsets, weights["lip_press"])

"""Head and brow motion from prosody: pitch accents and loud syllables nod or tilt the head and
raise the brows; pauses let the head drift to a new posture; each speaker has their own style.

Sketch: pitch (f0) comes from a YIN-style estimate every 10 ms (the cumulative-mean-normalised
difference of each 40 ms frame; the first dip under YIN_THRESHOLD between F0_MIN and F0_MAX Hz),
counted only inside aligned speech. Each vowel is a syllable; its prominence is the sum of its
z-scores over the utterance of peak pitch (semitones), loudness (dB) and duration. Syllables more
prominent than the style's threshold are accents. An accent adds a smooth bump (a raised cosine
ACCENT_SECONDS / speed long, peaking at the vowel's centre) to the head's rotation (a nod or a
tilt/turn, as the style prefers, with a size that grows with prominence) and to the brows (more
for pitch-led accents). Between phrases (silences of PAUSE_SECONDS or longer) the head eases
towards a new resting posture drawn from the style's seed, so it drifts slowly over pauses and
holds still-ish while speaking. The total is soft-limited (tanh) to ±MAX_DEGREES.
`style_for(speaker)` draws a `Style` from a hash of the speaker's name, so the same voice always
moves the same way and different voices differ.
"""
import hashlib
from dataclasses import dataclass

import numpy as np

from puppet.alignment import SILENCE, Phone
from puppet.features import HOP, MOTION_FPS, SAMPLE_RATE, WINDOW
from puppet.visemes import frame_times

MAX_DEGREES = 8.0  # no rotation from prosody exceeds this on any axis
F0_MIN, F0_MAX = 60.0, 400.0  # Hz: the pitch range searched
F0_WINDOW = 640  # samples: 40 ms, two periods of the lowest pitch
YIN_THRESHOLD = 0.2  # a period is accepted where the normalised difference dips under this
VOICING_MAX = 0.45  # frames whose best dip stays above this are unvoiced
PITCH_RATE = SAMPLE_RATE / HOP  # 100 pitch and energy frames per second
VOWELS = frozenset(["AA", "AE", "AH", "AO", "AW", "AY", "EH", "ER", "EY", "IH", "IY", "OW", "OY", "UH", "UW"])
PAUSE_SECONDS = 0.25  # a silence at least this long separates phrases
ACCENT_SECONDS = 0.5  # length of an accent's head bump at speed 1
BROW_SECONDS = 0.6  # length of an accent's brow bump at speed 1
DRIFT_SHARE = 0.6  # share of each pause's length the head takes to settle into its new posture
PROMINENCE_SCALE = 2.0  # prominence above the threshold that gives a full-size accent
MIN_ACCENT = 0.3  # size of an accent just over the threshold (full size: 1)
LENGTH_WEIGHT = 0.5  # weight of a vowel's duration z-score in its prominence (pitch and loudness: 1)
HEAD_LEAD = 0.05  # seconds (at speed 1) by which the head's bump leads the accented vowel's centre
OTHER_WAY = 3  # every third accent tilts and turns the other way from the speaker's habit
BROW_LOUD_SHARE = 0.4  # brow raise of an accent carried by loudness alone, relative to a pitch-led one
DRIFT_AXES = (0.6, 1.0, 0.5)  # pitch, yaw, roll sizes of the posture drift: heads turn more than they nod or tilt


@dataclass(frozen=True)
class Style:
    """How one speaker moves their head and brows while talking."""

    amplitude: float  # degrees of head rotation at a full-size accent
    nod: float  # share of accent motion that is a nod (pitch); the rest is tilt and turn
    turn: float  # of the rest, the share that is a turn (yaw); the remainder is a tilt (roll)
    side: float  # +1 or -1: which way this speaker tends to tilt and turn on accents
    speed: float  # tempo of the motion: bumps last ACCENT_SECONDS / speed
    brow: float  # brow-raise weight at a full-size, pitch-led accent
    threshold: float  # prominence (sum of z-scores) above which a syllable is an accent
    drift: float  # degrees of posture change from one phrase to the next
    seed: int  # draws the postures between phrases


def style_for(speaker: str) -> Style:
    """The head-motion style of a speaker, drawn deterministically from their name."""
    seed = int.from_bytes(hashlib.sha256(speaker.encode()).digest()[:8], "little")
    rng = np.random.default_rng(seed)
    return Style(
        amplitude=float(rng.uniform(1.5, 4.5)),
        nod=float(rng.uniform(0.2, 0.9)),
        turn=float(rng.uniform(0.2, 0.8)),
        side=float(rng.choice([-1.0, 1.0])),
        speed=float(rng.uniform(0.7, 1.4)),
        brow=float(rng.uniform(0.1, 0.7)),
        threshold=float(rng.uniform(0.5, 1.5)),
        drift=float(rng.uniform(0.5, 3.0)),
        seed=seed % 2**32,
    )


def pitch(samples: np.ndarray) -> np.ndarray:
    """(F,) float32 f0 in Hz every HOP samples (frame k centred at k·HOP), 0 where unvoiced.

    samples: (N,) float32 mono at SAMPLE_RATE (16 kHz).
    """
    samples = np.asarray(samples, np.float32)
    count = len(samples) // HOP + 1
    padded = np.pad(samples, (F0_WINDOW // 2, F0_WINDOW))
    frames = np.lib.stride_tricks.sliding_window_view(padded, F0_WINDOW)[::HOP][:count].astype(np.float64)
    frames = frames - frames.mean(1, keepdims=True)
    max_lag = int(SAMPLE_RATE / F0_MIN)
    spectrum = np.fft.rfft(frames, 2 * F0_WINDOW)
    autocorrelation = np.fft.irfft(np.abs(spectrum) ** 2)[:, :max_lag + 1]
    difference = np.maximum(2.0 * (autocorrelation[:, :1] - autocorrelation), 0.0)  # d(τ), τ = 0..max_lag
    lags = np.arange(max_lag + 1)
    cumulative = np.cumsum(difference, 1)
    normalised = np.ones_like(difference)
    normalised[:, 1:] = difference[:, 1:] * lags[1:] / np.maximum(cumulative[:, 1:], 1e-12)
    min_lag = int(SAMPLE_RATE / F0_MAX)
    search = normalised[:, min_lag:]
    # the bottom of the first dip under the threshold, else the deepest dip
    bottom = np.zeros_like(search, dtype=bool)
    bottom[:, 1:-1] = (search[:, 1:-1] <= search[:, :-2]) & (search[:, 1:-1] <= search[:, 2:])
    candidate = bottom & (search < YIN_THRESHOLD)
    lag = np.where(candidate.any(1), candidate.argmax(1), search.argmin(1))
    dip = search[np.arange(len(lag)), lag]
    f0 = SAMPLE_RATE / (lag + min_lag)
    silent = frames.std(1) < 1e-4
    return np.where((dip < VOICING_MAX) & ~silent, f0, 0.0).astype(np.float32)


def loudness(samples: np.ndarray) -> np.ndarray:
    """(F,) float32 dB (re full scale) RMS of WINDOW-sample (25 ms) frames every HOP samples, frame k
    centred at k·HOP."""
    samples = np.asarray(samples, np.float32)
    count = len(samples) // HOP + 1
    padded = np.pad(samples, WINDOW // 2 + 1)
    power = np.convolve(padded.astype(np.float64) ** 2, np.ones(WINDOW) / WINDOW, mode="valid")
    return (10.0 * np.log10(power[::HOP][:count] + 1e-10)).astype(np.float32)


def _zscore(values: np.ndarray) -> np.ndarray:
    return (values - values.mean()) / values.std() if len(values) > 1 and values.std() > 1e-6 else 0.0 * values


def accents(samples: np.ndarray, phones: list[Phone], style: Style) -> list[tuple[float, float, float]]:
    """(time s, strength 0..1, pitch share 0..1) of each accented vowel, from (N,) 16 kHz samples."""
    vowels = [p for p in phones if p.phone in VOWELS]
    if not vowels:
        return []
    f0, level = pitch(samples), loudness(samples)
    semitones = np.where(f0 > 0, 12.0 * np.log2(np.maximum(f0, 1.0) / 100.0), np.nan)
    voiced = semitones[np.isfinite(semitones)]
    floor = float(np.median(voiced)) if len(voiced) else 0.0
    peak_pitch, peak_level = [], []
    for vowel in vowels:
        span = slice(int(vowel.start * PITCH_RATE), max(int(vowel.end * PITCH_RATE), int(vowel.start * PITCH_RATE) + 1))
        heard = semitones[span][np.isfinite(semitones[span])]
        peak_pitch.append(heard.max() if len(heard) else floor)
        peak_level.append(level[span].max() if len(level[span]) else level.min())
    pitch_z, level_z = _zscore(np.array(peak_pitch)), _zscore(np.array(peak_level))
    length_z = _zscore(np.array([v.end - v.start for v in vowels]))
    prominence = pitch_z + level_z + LENGTH_WEIGHT * length_z
    found = []
    for vowel, total, pz, lz in zip(vowels, prominence, pitch_z, level_z):
        if total > style.threshold:
            strength = min(1.0, (total - style.threshold) / PROMINENCE_SCALE + MIN_ACCENT)
            share = float(np.clip(0.5 + 0.25 * (pz - lz), 0.0, 1.0))  # 1: pitch-led, 0: loudness-led
            found.append((0.5 * (vowel.start + vowel.end), strength, share))
    return found


def _bump(times: np.ndarray, centre: float, length: float) -> np.ndarray:
    """(T,) raised cosine: 1 at `centre`, 0 beyond ±length/2."""
    phase = np.clip((times - centre) / length * 2.0, -1.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * phase))


def _postures(phones: list[Phone], times: np.ndarray, style: Style, rng: np.random.Generator) -> np.ndarray:
    """(T, 3) degrees: a resting posture per phrase, eased into during the pause before it."""
    posture = np.zeros((len(times), 3))
    current = np.zeros(3)
    for phone in phones:
        if phone.phone == SILENCE and phone.end - phone.start >= PAUSE_SECONDS:
            target = rng.normal(0.0, style.drift, 3) * DRIFT_AXES
            ease_end = phone.start + DRIFT_SHARE * (phone.end - phone.start)
            share = np.clip((times - phone.start) / (ease_end - phone.start), 0.0, 1.0)
            share = 0.5 - 0.5 * np.cos(np.pi * share)
            posture += np.outer(share, target - current)
            current = target
    return posture


def head_motion(samples: np.ndarray, phones: list[Phone], n_frames: int, style: Style,
                fps: float = MOTION_FPS) -> tuple[np.ndarray, np.ndarray]:
    """Head rotation and brow raise for each motion frame (frame t at (t + 0.5) / fps seconds).

    samples: (N,) float32 mono speech at SAMPLE_RATE (16 kHz); phones: its alignment.
    Returns rotation (T, 3) float32 radians (pitch + nods down, yaw + turns to the image's right,
    roll + tilts clockwise), within ±MAX_DEGREES; brow (T,) float32 brow_raise weight in [0, 1].
    """
    times = frame_times(n_frames, fps)
    rng = np.random.default_rng([style.seed, len(samples)])
    degrees = _postures(phones, times, style, rng)
    brow = np.zeros(n_frames)
    for index, (centre, strength, pitch_share) in enumerate(accents(samples, phones, style)):
        head = _bump(times, centre - HEAD_LEAD / style.speed, ACCENT_SECONDS / style.speed) * strength * style.amplitude
        side = -style.side if index % OTHER_WAY == OTHER_WAY - 1 else style.side
        sideways = (1.0 - style.nod) * side
        degrees += np.outer(head, (style.nod, sideways * style.turn, sideways * (1.0 - style.turn)))
        brow += _bump(times, centre, BROW_SECONDS / style.speed) * strength * style.brow * (BROW_LOUD_SHARE + (1 - BROW_LOUD_SHARE) * pitch_share)
    degrees = MAX_DEGREES * np.tanh(degrees / MAX_DEGREES)
    return np.radians(degrees).astype(np.float32), np.clip(brow, 0.0, 1.0).astype(np.float32)

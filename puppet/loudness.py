"""The built-in speech-driven motion: the mouth follows how loud and how bright the voice is.

No training, no phonemes. Per video frame:
1. level: the RMS level in dB of a short Hann window centred on the frame (looking `lead` seconds
   ahead, because lips visibly move before the sound they make), relative to the clip's own speech
   level (a high percentile of all frame levels), so a quiet and a loud recording of the same
   speech move the mouth alike;
2. openness: a voice whose energy sits in the first-formant band of open vowels (600-1200 Hz)
   rather than in the low murmur of nasals and closed vowels (100-400 Hz), compared with the
   clip's typical balance, counts as a few dB louder; this is what tells "ah" from "m" at equal
   loudness;
3. opening: a noise gate with a soft knee maps that level to a jaw opening in [0, 1]; the gate
   sits `gate_db` below the speech level, or just above the recording's own background noise (a
   low percentile of frame levels) where that is louder, so breaths and hiss between words
   leave the mouth shut;
4. shape: the balance of high (1.5-4 kHz) against low (0.2-1.2 kHz) band energy, relative to the
   clip's typical balance, splits the opening into lip_wide ("ee", "s") or lip_round ("oo");
5. smoothing: a one-pole filter that follows rising targets fast (attack) and falling ones slower
   (release), so the mouth snaps open and settles shut; below CLOSED it is shut exactly;
6. emphasis: where the opening rises above its own slow average, the head nods a little (chin
   down) and the brows lift.
Silence (and a clip that is silent throughout) leaves every weight and angle at exactly 0.
"""
import math
from dataclasses import dataclass

import numpy as np

from puppet.articulation import blend, unit_offsets
from puppet.motion import Motion

ANALYSIS_SECONDS = 0.032  # shortest level window: 512 samples at 16 kHz; a frame's length if longer
LEVEL_FLOOR = 1e-10  # mean square of digital silence: -100 dBFS
MURMUR_BAND = (100.0, 400.0)  # Hz: voicing murmur, where nasals and closed vowels keep their energy
OPEN_BAND = (600.0, 1200.0)  # Hz: first formant of open vowels ("ah"), which rises as the jaw drops
LOW_BAND = (200.0, 1200.0)  # Hz: first formant and the voice's body ("oo" puts its energy here)
HIGH_BAND = (1500.0, 4000.0)  # Hz: second/third formants and fricatives ("ee", "s")
BANDS = {"murmur": MURMUR_BAND, "open": OPEN_BAND, "low": LOW_BAND, "high": HIGH_BAND}
CHUNK_FRAMES = 1000  # frames analysed at a time
SHAPE_SPREAD_DB = 6.0  # a band balance this far from the clip's typical one gives full wide/round
OPENNESS_LIMIT_DB = 12.0  # band balances further than this from the typical one count as this far
CLOSED = 0.01  # smoothed opening (or emphasis) below this is exactly 0 (a 0.002 IOD lip gap at max_jaw: invisible)
FULL_EMPHASIS = 0.5  # an opening this far above its slow average is full emphasis
MAX_NOD_DEGREES = 3.0  # speech-driven nods never exceed this, whatever the options say


@dataclass(frozen=True)
class LoudnessOptions:
    gate_db: float = -30.0  # frames quieter than this, in dB relative to the clip's speech level, keep the mouth shut
    noise_percentile: float = 5.0  # percentile of frame levels taken as the recording's background noise
    noise_margin_db: float = 6.0  # the gate is raised to at least this far above that noise ...
    gate_ceiling_db: float = -18.0  # ... but never above this, relative to the speech level (pause-free speech)
    knee_db: float = 6.0  # above the gate, the opening eases in over this many dB instead of starting with a step
    full_db: float = 0.0  # relative level (dB) at which the mouth reaches max_jaw
    openness: float = 0.4  # dB added to the level per dB that the open-vowel band gains on the murmur band
    sensitivity: float = 1.0  # multiplies the opening before clipping to [0, 1]; > 1 opens wider for the same sound
    max_jaw: float = 0.6  # jaw_open weight at full opening (0.6: inner lips part by 0.21 inter-ocular distances)
    speech_percentile: float = 95.0  # percentile of frame levels taken as the clip's speech level
    silence_dbfs: float = -65.0  # a clip whose speech level is below this absolute level is silence throughout
    attack: float = 0.025  # seconds for the mouth to go 63% of the way toward a wider target
    release: float = 0.07  # seconds to go 63% of the way toward a narrower one
    lead: float = 0.02  # seconds the mouth moves ahead of the sound
    lip_wide: float = 0.5  # lip_wide weight for a bright sound ("ee", "s") at full opening
    lip_round: float = 0.6  # lip_round weight for a dark sound ("oo") at full opening
    nod_degrees: float = 2.0  # head pitch (chin down) on a strongly emphasised syllable; capped at MAX_NOD_DEGREES
    brow_raise: float = 0.35  # brow_raise weight on a strongly emphasised syllable
    emphasis_attack: float = 0.08  # seconds for nods and brows to rise
    emphasis_release: float = 0.3  # seconds for them to settle
    emphasis_slow: float = 0.4  # seconds of the slow opening average that emphasis is measured against


def frame_count(n_samples: int, sample_rate: int, fps: float) -> int:
    """Video frames for `n_samples` of audio: ceil(duration * fps), frame i covering [i/fps, (i+1)/fps).

    The last frame may be partly past the end of the sound; an exact fit adds no extra frame
    (the product is rounded to 1e-9 frames first so 1 s at 25 fps is 25 frames, not 26).
    """
    return math.ceil(round(n_samples * fps / sample_rate, 9))


def _frame_features(samples: np.ndarray, sample_rate: int, fps: float, frames: int, lead: float) -> tuple[np.ndarray, dict]:
    """Per frame, from a Hann window centred `lead` s after the frame's middle (zeros outside the clip):
    (T,) level in dBFS and {band name: (T,) energy} for BANDS. Computed CHUNK_FRAMES at a time,
    so an hour of audio never holds more than a few megabytes of spectra."""
    width = max(round(ANALYSIS_SECONDS * sample_rate), round(sample_rate / fps))
    window = np.hanning(width).astype(np.float32)
    hz = np.fft.rfftfreq(width, 1.0 / sample_rate)
    masks = {name: (hz >= low) & (hz < high) for name, (low, high) in BANDS.items()}
    padded = np.concatenate([np.zeros(width, np.float32), samples, np.zeros(width, np.float32)])
    level = np.empty(frames, np.float64)
    bands = {name: np.empty(frames, np.float64) for name in BANDS}
    for start in range(0, frames, CHUNK_FRAMES):
        index = np.arange(start, min(start + CHUNK_FRAMES, frames))
        centres = np.round(((index + 0.5) / fps + lead) * sample_rate).astype(np.int64)
        starts = np.clip(centres - width // 2 + width, 0, len(padded) - width)
        windows = padded[starts[:, None] + np.arange(width)] * window
        level[index] = 10.0 * np.log10((windows**2).sum(1) / (window**2).sum() + LEVEL_FLOOR)
        power = np.abs(np.fft.rfft(windows, axis=1)) ** 2
        for name, mask in masks.items():
            bands[name][index] = power[:, mask].sum(1) + LEVEL_FLOOR
    return level, bands


def _follow(target: np.ndarray, fps: float, attack: float, release: float) -> np.ndarray:
    """(T,) float32: one-pole smoothing with time constant `attack` s upward, `release` s downward."""
    rise = 1.0 - math.exp(-1.0 / max(fps * attack, 1e-6))
    fall = 1.0 - math.exp(-1.0 / max(fps * release, 1e-6))
    out = np.empty(len(target), np.float32)
    value = 0.0
    for i, goal in enumerate(target.tolist()):
        value += (rise if goal > value else fall) * (goal - value)
        out[i] = value
    return out


def _gate(level: np.ndarray, speech_level: float, options: LoudnessOptions) -> float:
    """The noise gate in dB relative to the speech level, from (T,) frame levels in dBFS."""
    noise = float(np.percentile(level, options.noise_percentile)) - speech_level
    return max(options.gate_db, min(noise + options.noise_margin_db, options.gate_ceiling_db))


def _opening(level_db: np.ndarray, gate_db: float, options: LoudnessOptions) -> np.ndarray:
    """(T,) jaw opening in [0, 1] from (T,) levels in dB relative to the speech level: gate + soft knee."""
    above = level_db - gate_db
    knee = max(options.knee_db, 1e-6)
    eased = np.where(above < knee, np.clip(above, 0.0, knee) ** 2 / (2.0 * knee), above - knee / 2.0)
    full = max(options.full_db - gate_db - knee / 2.0, 1e-6)
    return np.clip(options.sensitivity * eased / full, 0.0, 1.0)


def _band_balance(upper: np.ndarray, lower: np.ndarray, voiced: np.ndarray) -> np.ndarray:
    """(T,) dB: energy of the upper band over the lower band, minus its median over voiced frames."""
    balance = 10.0 * np.log10(upper / lower)
    return balance - (np.median(balance[voiced]) if voiced.any() else 0.0)


def _mouth(bands: dict, relative: np.ndarray, gate_db: float, fps: float,
           options: LoudnessOptions) -> tuple[np.ndarray, np.ndarray]:
    """(T,) smoothed jaw opening in [0, 1] and (T,) brightness in [-1 round, 1 wide].

    bands: {name: (T,) band energies}; relative: (T,) frame levels in dB relative to the speech level.
    """
    voiced = relative > gate_db
    openness = np.clip(_band_balance(bands["open"], bands["murmur"], voiced), -OPENNESS_LIMIT_DB, OPENNESS_LIMIT_DB)
    target = _opening(relative + options.openness * openness, gate_db, options)
    opening = _follow(target, fps, options.attack, options.release)
    opening[opening < CLOSED] = 0.0
    brightness = np.clip(_band_balance(bands["high"], bands["low"], voiced) / SHAPE_SPREAD_DB, -1.0, 1.0)
    return opening, _follow(brightness, fps, options.attack, options.attack)


def _emphasis(opening: np.ndarray, fps: float, options: LoudnessOptions) -> np.ndarray:
    """(T,) in [0, 1]: how far the opening stands out from its own slow average, smoothed."""
    slow = _follow(opening, fps, options.emphasis_slow, options.emphasis_slow)
    standing_out = np.clip((opening - slow) / FULL_EMPHASIS, 0.0, 1.0)
    emphasis = _follow(standing_out, fps, options.emphasis_attack, options.emphasis_release)
    emphasis[emphasis < CLOSED] = 0.0
    return emphasis


def loudness_motion(samples: np.ndarray, sample_rate: int, rest: np.ndarray, fps: float,
                    options: LoudnessOptions = LoudnessOptions()) -> Motion:
    """Mouth, nod and brow motion that follows the loudness of speech.

    samples:     (N,) float32 mono audio in [-1, 1] (non-finite samples count as silence).
    sample_rate: samples per second (16000 in puppet).
    rest:        (68, 3) float32 rest landmarks, image pixels.
    Returns a Motion of `frame_count(N, sample_rate, fps)` frames: offsets (T, 68, 3) float32 pixels
    in the head frame from jaw_open, lip_wide, lip_round and brow_raise; rotation with pitch only
    (nods, at most MAX_NOD_DEGREES); zero translation. No blinks or idle motion (see puppet.life).
    """
    samples = np.nan_to_num(np.asarray(samples, np.float32).reshape(-1), nan=0.0, posinf=0.0, neginf=0.0)
    frames = frame_count(len(samples), sample_rate, fps)
    level, bands = _frame_features(samples, sample_rate, fps, frames, options.lead)
    speech_level = float(np.percentile(level, options.speech_percentile)) if frames else -np.inf
    if speech_level < options.silence_dbfs:
        return Motion.still(frames, fps)

    gate = _gate(level, speech_level, options)
    opening, brightness = _mouth(bands, level - speech_level, gate, fps, options)
    emphasis = _emphasis(opening, fps, options)
    weights = {
        "jaw_open": options.max_jaw * opening,
        "lip_wide": options.lip_wide * opening * np.clip(brightness, 0.0, 1.0),
        "lip_round": options.lip_round * opening * np.clip(-brightness, 0.0, 1.0),
        "brow_raise": options.brow_raise * emphasis,
    }
    rotation = np.zeros((frames, 3), np.float32)
    rotation[:, 0] = np.radians(np.clip(options.nod_degrees, -MAX_NOD_DEGREES, MAX_NOD_DEGREES)) * emphasis
    return Motion(
        offsets=blend(unit_offsets(rest), {name: w.astype(np.float32) for name, w in weights.items()}),
        rotation=rotation,
        translation=np.zeros((frames, 2), np.float32),
        fps=fps,
    )

"""Voice augmentation: turn one synthetic voice into many speakers heard through many rooms and microphones.

Every transform is a pure function on (N,) float32 mono audio at RATE (16 kHz), full scale 1.0.
They fall in two groups, and `apply` runs them in this order:

  voice (changes timing or the speaker; applied identically to the clean copy the aligner reads)
    1. pitch: resample by the pitch ratio, which scales the fundamental *and* the formants and
       shortens the clip by the same factor;
    2. formants: warp each STFT frame's spectral envelope (cepstrally smoothed log magnitude) by
       formant / pitch, leaving the harmonics where step 1 put them, so the formants end up scaled by
       `formant` (a vocal tract that much shorter) while the fundamental is scaled by `pitch`;
    3. tempo: WSOLA time-stretch (overlap-add of windows chosen by cross-correlation to continue the
       waveform) to exactly round(N / tempo) samples, which keeps pitch and formants.
  channel (length-preserving; only on the training copy)
    4. reverb: convolve with a synthetic room impulse response, exponentially decaying noise with the
       given RT60, mixed wet/dry;
    5. noise: white, pink or babble (the clip's own speech reversed and shifted several times) at an SNR;
    6. microphone: a smooth zero-phase EQ curve: high-pass, low-pass (a telephone band at the extreme),
       a spectral tilt and one peak or notch;
    7. level: scale so the peak sits at the given dBFS.

`draw(rng, pitch, formant)` picks the per-utterance settings for one speaker identity.
"""
from dataclasses import dataclass
from fractions import Fraction

import numpy as np
from scipy import signal

from puppet.audio import ANALYSIS_RATE

RATE = ANALYSIS_RATE  # Hz: everything here works on 16 kHz audio
NYQUIST = RATE / 2  # 8000 Hz

# Pitch: resampling ratios are rounded to a fraction with at most this denominator (error < 0.5 %).
RATIO_DENOMINATOR = 100

# Formant warp: STFT analysis of the spectral envelope.
ENVELOPE_FFT = 512  # samples: 32 ms frames, 257 bins of 31.25 Hz
ENVELOPE_HOP = ENVELOPE_FFT // 4  # 128 samples, 8 ms
ENVELOPE_LIFTER = 30  # cepstral coefficients kept: smooths away harmonics of voices below 16000/30 = 533 Hz

# Tempo: WSOLA.
WSOLA_FRAME = 512  # samples: 32 ms windows, longer than two periods of an 80 Hz voice
WSOLA_HOP = WSOLA_FRAME // 2  # 256 samples: Hann windows at half overlap sum to one
WSOLA_TOLERANCE = 160  # samples: each window may move +-10 ms to continue the waveform smoothly

# Reverb.
RT60_DECAY_DB = 60.0  # RT60 is the time the reverberant energy takes to fall by 60 dB
IR_MIN_TAIL_S = 0.05  # a very dry room still gets this much impulse response, seconds
IR_DAMPING_HZ = 4000.0  # the tail is low-passed here: walls absorb highs faster

# Noise.
NOISE_KINDS = ("white", "pink", "babble")
BABBLE_TALKERS = 4  # reversed, shifted copies of the utterance summed into babble

# Microphone EQ.
TELEPHONE_BAND = (300.0, 3400.0)  # Hz: the classic narrow band
EQ_ORDER = 4  # the high- and low-pass slopes are those of 4th-order Butterworth filters (24 dB/octave)

# Per-utterance ranges drawn by `draw`.
TEMPO_RANGE = (0.85, 1.2)  # speaking rate relative to the engine's
CLEAN_FRACTION = 0.15  # utterances without any added noise
SNR_RANGE_DB = (10.0, 40.0)
DRY_FRACTION = 0.2  # utterances without reverb
RT60_RANGE_S = (0.1, 0.6)
WET_RANGE = (0.1, 0.6)  # share of the reverberant signal in the mix
TELEPHONE_FRACTION = 0.1  # utterances heard through a telephone band
LOW_CUT_RANGE_HZ = (40.0, 250.0)
HIGH_CUT_RANGE_HZ = (4000.0, 8000.0)  # 8000: no low-pass at all
TILT_RANGE_DB = (-3.0, 3.0)  # dB per octave around 1 kHz
PEAK_RANGE_HZ = (300.0, 5000.0)
PEAK_GAIN_RANGE_DB = (-6.0, 6.0)
LEVEL_RANGE_DBFS = (-35.0, -3.0)  # peak level of the training copy
CLEAN_PEAK_DBFS = -3.0  # peak level of the aligner's copy


@dataclass(frozen=True)
class Settings:
    """One utterance's augmentation. The defaults change nothing but the level."""

    pitch: float = 1.0  # fundamental frequency ratio (speaker identity); 1.25 = a major third up
    formant: float = 1.0  # formant frequency ratio (speaker identity); >1 = shorter vocal tract
    tempo: float = 1.0  # speaking rate ratio; the clip lasts 1/tempo as long
    rt60: float = 0.0  # seconds for the room's reverb to decay by 60 dB; 0 = no reverb
    wet: float = 0.0  # 0..1 share of reverberant sound in the mix
    noise: str | None = None  # one of NOISE_KINDS, or None for no added noise
    snr_db: float = 40.0  # signal-to-noise ratio of the added noise over the whole clip, dB
    low_cut_hz: float = 0.0  # microphone high-pass corner; 0 = none
    high_cut_hz: float = NYQUIST  # microphone low-pass corner; NYQUIST = none
    tilt_db: float = 0.0  # microphone spectral tilt, dB per octave around 1 kHz
    peak_hz: float = 1000.0  # centre of the microphone's one resonance (or notch)
    peak_db: float = 0.0  # its gain, dB; 0 = flat
    level_dbfs: float = CLEAN_PEAK_DBFS  # peak level of the augmented copy


def draw(rng: np.random.Generator, pitch: float = 1.0, formant: float = 1.0) -> Settings:
    """Random per-utterance settings (tempo, room, noise, microphone, level) for the speaker (pitch, formant)."""
    telephone = rng.random() < TELEPHONE_FRACTION
    low_cut, high_cut = TELEPHONE_BAND if telephone else (rng.uniform(*LOW_CUT_RANGE_HZ), rng.uniform(*HIGH_CUT_RANGE_HZ))
    return Settings(
        pitch=pitch,
        formant=formant,
        tempo=float(rng.uniform(*TEMPO_RANGE)),
        rt60=0.0 if rng.random() < DRY_FRACTION else float(rng.uniform(*RT60_RANGE_S)),
        wet=float(rng.uniform(*WET_RANGE)),
        noise=None if rng.random() < CLEAN_FRACTION else str(rng.choice(NOISE_KINDS)),
        snr_db=float(rng.uniform(*SNR_RANGE_DB)),
        low_cut_hz=float(low_cut),
        high_cut_hz=float(high_cut),
        tilt_db=float(rng.uniform(*TILT_RANGE_DB)),
        peak_hz=float(np.exp(rng.uniform(*np.log(PEAK_RANGE_HZ)))),
        peak_db=float(rng.uniform(*PEAK_GAIN_RANGE_DB)),
        level_dbfs=float(rng.uniform(*LEVEL_RANGE_DBFS)),
    )


def apply(samples: np.ndarray, settings: Settings, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Augment (N,) float32 speech at RATE; returns (clean, augmented), both (round(N / tempo),) float32.

    `clean` has the speaker and timing changes only (peak at CLEAN_PEAK_DBFS), for the aligner;
    `augmented` is the same signal through the room, noise and microphone, at settings.level_dbfs.
    `rng` draws the impulse response and the noise.
    """
    voiced = reshape_voice(samples, settings)
    clean = set_level(voiced, CLEAN_PEAK_DBFS)
    heard = reverberate(voiced, settings.rt60, settings.wet, rng)
    if settings.noise is not None:
        heard = add_noise(heard, settings.snr_db, settings.noise, rng)
    heard = microphone(heard, settings)
    return clean, set_level(heard, settings.level_dbfs)


def reshape_voice(samples: np.ndarray, settings: Settings) -> np.ndarray:
    """(N,) → (round(N / tempo),) float32: pitch, formants and tempo of `settings` (steps 1-3)."""
    target = round(len(samples) / settings.tempo)
    shifted = resample(samples, settings.pitch)
    warped = shift_formants(shifted, settings.formant / settings.pitch)
    return stretch_to(warped, target)


def resample(samples: np.ndarray, ratio: float) -> np.ndarray:
    """(N,) → (about N / ratio,) float32 played back at the same rate: pitch and formants scaled by `ratio`."""
    fraction = Fraction(ratio).limit_denominator(RATIO_DENOMINATOR)
    if fraction == 1:
        return samples.astype(np.float32)
    return signal.resample_poly(samples, fraction.denominator, fraction.numerator).astype(np.float32)


def shift_pitch(samples: np.ndarray, ratio: float) -> np.ndarray:
    """(N,) → (N,) float32 with the fundamental and the formants scaled by `ratio`, duration kept."""
    return stretch_to(resample(samples, ratio), len(samples))


def shift_formants(samples: np.ndarray, ratio: float) -> np.ndarray:
    """(N,) → (N,) float32 with the spectral envelope scaled by `ratio` in frequency; harmonics stay put.

    Each frame's log magnitude is split into envelope (the first ENVELOPE_LIFTER cepstral
    coefficients) and fine structure; the envelope is read at f / ratio and the phase is kept.
    """
    if abs(ratio - 1.0) < 1e-6 or len(samples) < ENVELOPE_FFT:
        return samples.astype(np.float32)
    _, _, spectrum = signal.stft(samples, nperseg=ENVELOPE_FFT, noverlap=ENVELOPE_FFT - ENVELOPE_HOP)
    log_magnitude = np.log(np.abs(spectrum) + 1e-9)  # (bins, frames)
    cepstrum = np.fft.irfft(log_magnitude, axis=0)
    cepstrum[ENVELOPE_LIFTER : -ENVELOPE_LIFTER + 1] = 0.0
    envelope = np.fft.rfft(cepstrum, axis=0).real  # (bins, frames), smooth log magnitude
    bins = np.arange(envelope.shape[0])
    source = np.clip(bins / ratio, 0, bins[-1])  # where each output bin reads the envelope from
    lower = np.floor(source).astype(int)
    upper = np.minimum(lower + 1, bins[-1])
    frac = (source - lower)[:, None]
    moved = envelope[lower] * (1 - frac) + envelope[upper] * frac
    _, out = signal.istft(spectrum * np.exp(moved - envelope), nperseg=ENVELOPE_FFT, noverlap=ENVELOPE_FFT - ENVELOPE_HOP)
    return _fit(out, len(samples))


def stretch(samples: np.ndarray, tempo: float) -> np.ndarray:
    """(N,) → (round(N / tempo),) float32 spoken `tempo` times as fast; pitch and formants kept."""
    return stretch_to(samples, round(len(samples) / tempo))


def stretch_to(samples: np.ndarray, length: int) -> np.ndarray:
    """(N,) → (length,) float32 by WSOLA: output window k is centred on input time k * hop * N / length,
    moved by up to WSOLA_TOLERANCE to best continue the previously chosen window."""
    if length == len(samples):
        return samples.astype(np.float32)
    rate = len(samples) / length  # input samples consumed per output sample
    half = WSOLA_FRAME // 2
    pad = half + WSOLA_TOLERANCE + WSOLA_HOP
    padded = np.concatenate([np.zeros(pad), samples, np.zeros(pad + WSOLA_FRAME + int(WSOLA_HOP * rate) + 1)])
    window = signal.windows.hann(WSOLA_FRAME, sym=False)
    frames = int(np.ceil((length + half) / WSOLA_HOP)) + 1
    out = np.zeros(frames * WSOLA_HOP + WSOLA_FRAME)
    previous = None
    for k in range(frames):
        start = pad + round(k * WSOLA_HOP * rate) - half  # nominal window start in `padded`
        if previous is not None:
            follow = padded[previous + WSOLA_HOP : previous + WSOLA_HOP + WSOLA_FRAME]
            region = padded[start - WSOLA_TOLERANCE : start + WSOLA_TOLERANCE + WSOLA_FRAME]
            score = signal.correlate(region, follow, mode="valid")
            start += int(np.argmax(score)) - WSOLA_TOLERANCE
        out[k * WSOLA_HOP : k * WSOLA_HOP + WSOLA_FRAME] += window * padded[start : start + WSOLA_FRAME]
        previous = start
    return _fit(out[half:], length)


def room_impulse(rt60: float, rng: np.random.Generator) -> np.ndarray:
    """(M,) float32 impulse response of a synthetic room: a unit direct path, then Gaussian noise
    decaying by RT60_DECAY_DB over `rt60` seconds (low-passed at IR_DAMPING_HZ), M = RATE * max(rt60, 0.05)."""
    n = int(RATE * max(rt60, IR_MIN_TAIL_S))
    t = np.arange(n) / RATE
    decay = np.exp(-np.log(10 ** (RT60_DECAY_DB / 20)) * t / max(rt60, 1e-3))
    tail = signal.sosfilt(signal.butter(1, IR_DAMPING_HZ, fs=RATE, output="sos"), rng.standard_normal(n)) * decay
    tail[0] = 0.0
    tail /= np.sqrt(np.sum(tail**2)) + 1e-12  # unit energy, like the direct path
    tail[0] = 1.0
    return tail.astype(np.float32)


def reverberate(samples: np.ndarray, rt60: float, wet: float, rng: np.random.Generator) -> np.ndarray:
    """(N,) → (N,) float32: (1 - wet) * dry + wet * (dry convolved with `room_impulse(rt60)`), tail cut at N."""
    if rt60 <= 0 or wet <= 0:
        return samples.astype(np.float32)
    reverberant = signal.fftconvolve(samples, room_impulse(rt60, rng))[: len(samples)]
    return ((1 - wet) * samples + wet * reverberant).astype(np.float32)


def noise_like(samples: np.ndarray, kind: str, rng: np.random.Generator) -> np.ndarray:
    """(N,) float64 noise of `kind` (one of NOISE_KINDS), any scale."""
    n = len(samples)
    if kind == "white":
        return rng.standard_normal(n)
    if kind == "pink":  # 1/f power: shape white noise's spectrum by 1/sqrt(f)
        spectrum = np.fft.rfft(rng.standard_normal(n))
        f = np.fft.rfftfreq(n, 1 / RATE)
        return np.fft.irfft(spectrum / np.sqrt(np.maximum(f, 20.0)), n)
    if kind == "babble":  # speech-shaped, syllable-modulated, but no words: the clip reversed and shifted
        backwards = samples[::-1].astype(np.float64)
        return sum(np.roll(backwards, int(rng.integers(n))) for _ in range(BABBLE_TALKERS))
    raise ValueError(f"unknown noise kind {kind!r}; expected one of {NOISE_KINDS}")


def add_noise(samples: np.ndarray, snr_db: float, kind: str, rng: np.random.Generator) -> np.ndarray:
    """(N,) → (N,) float32 plus `kind` noise whose power over the clip is `snr_db` below the clip's."""
    noise = noise_like(samples, kind, rng)
    signal_power = np.mean(np.asarray(samples, np.float64) ** 2)
    noise *= np.sqrt(signal_power / (np.mean(noise**2) + 1e-20) / 10 ** (snr_db / 10))
    return (samples + noise).astype(np.float32)


def microphone(samples: np.ndarray, settings: Settings) -> np.ndarray:
    """(N,) → (N,) float32 through the microphone of `settings`: a zero-phase gain curve applied in one FFT."""
    n = len(samples)
    f = np.maximum(np.fft.rfftfreq(n, 1 / RATE), 1.0)
    gain = np.ones_like(f)
    if settings.low_cut_hz > 0:
        gain /= np.sqrt(1 + (settings.low_cut_hz / f) ** (2 * EQ_ORDER))
    if settings.high_cut_hz < NYQUIST:
        gain /= np.sqrt(1 + (f / settings.high_cut_hz) ** (2 * EQ_ORDER))
    octaves = np.log2(f / 1000.0)
    bell = np.exp(-0.5 * (np.log2(f / settings.peak_hz) / 0.5) ** 2)  # one octave wide at half gain
    gain *= 10 ** ((settings.tilt_db * np.clip(octaves, -3, 3) + settings.peak_db * bell) / 20)
    return np.fft.irfft(np.fft.rfft(samples) * gain, n).astype(np.float32)


def set_level(samples: np.ndarray, peak_dbfs: float) -> np.ndarray:
    """(N,) → (N,) float32 scaled so its peak sits at `peak_dbfs` (silence stays silence)."""
    peak = float(np.max(np.abs(samples))) if len(samples) else 0.0
    if peak == 0.0:
        return samples.astype(np.float32)
    return (samples * (10 ** (peak_dbfs / 20) / peak)).astype(np.float32)


def _fit(samples: np.ndarray, length: int) -> np.ndarray:
    """(M,) → (length,) float32, cut or zero-padded at the end."""
    out = np.zeros(length, np.float32)
    out[: min(length, len(samples))] = samples[:length]
    return out

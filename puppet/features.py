"""Audio features for the landmark predictor: one log-mel implementation (numpy, with scipy's FFT)
shared by training and run time, so the network hears at run time exactly what it learned from
(scipy's FFT runs 6× faster than numpy's here; the log-mels differ by under 1e-5).

The spec (also written into every exported model's metadata, see `SPEC`):
- input: mono float32 in [-1, 1] at SAMPLE_RATE (16 kHz); other rates are resampled by the decoder
- frames: Hann window of WINDOW samples (25 ms), hop HOP (10 ms), FFT size N_FFT, centred
  (the signal is padded by N_FFT/2 zeros on each side), so frame k is centred at k·HOP samples
- power spectrum |X|² → N_MELS triangular mel filters (Slaney mel scale, area-normalised,
  FMIN..FMAX Hz) → log10(max(mel, LOG_FLOOR))
- motion: the predictor emits one frame of landmark motion per FRAMES_PER_MOTION feature frames
  (MOTION_FPS = 50 motion frames per second); motion frame t covers feature frames
  [t·FRAMES_PER_MOTION, (t+1)·FRAMES_PER_MOTION).
"""
import functools

import numpy as np
import scipy.fft

SAMPLE_RATE = 16000
HOP = 160  # 10 ms
WINDOW = 400  # 25 ms
N_FFT = 512
N_MELS = 80
FMIN = 55.0
FMAX = 7600.0
LOG_FLOOR = 1e-5  # -5 in log10 units: silence
FEATURE_RATE = SAMPLE_RATE / HOP  # 100 feature frames per second
FRAMES_PER_MOTION = 2
MOTION_FPS = FEATURE_RATE / FRAMES_PER_MOTION  # 50 motion frames per second

SPEC = {
    "sample_rate": SAMPLE_RATE, "hop": HOP, "window": WINDOW, "n_fft": N_FFT, "n_mels": N_MELS,
    "fmin": FMIN, "fmax": FMAX, "log_floor": LOG_FLOOR, "mel_scale": "slaney", "log": "log10",
    "frames_per_motion": FRAMES_PER_MOTION, "motion_fps": MOTION_FPS,
}


def _hz_to_mel(hz: np.ndarray) -> np.ndarray:
    """Slaney's mel scale: linear below 1 kHz, logarithmic above."""
    hz = np.asarray(hz, dtype=np.float64)
    linear = hz / (200.0 / 3)
    log = 15.0 + np.log(np.maximum(hz, 1e-10) / 1000.0) / (np.log(6.4) / 27.0)
    return np.where(hz >= 1000.0, log, linear)


def _mel_to_hz(mel: np.ndarray) -> np.ndarray:
    mel = np.asarray(mel, dtype=np.float64)
    return np.where(mel >= 15.0, 1000.0 * np.exp((mel - 15.0) * (np.log(6.4) / 27.0)), mel * (200.0 / 3))


def mel_filterbank(sample_rate: int, n_fft: int, n_mels: int, fmin: float, fmax: float) -> np.ndarray:
    """(n_mels, n_fft // 2 + 1) float32 triangular filters on Slaney's mel scale, each with unit
    area in Hz (the same filters as librosa.filters.mel with its defaults)."""
    bins = np.linspace(0, sample_rate / 2, n_fft // 2 + 1)
    edges = _mel_to_hz(np.linspace(_hz_to_mel(fmin), _hz_to_mel(fmax), n_mels + 2))
    lower, centre, upper = edges[:-2, None], edges[1:-1, None], edges[2:, None]
    rising = (bins - lower) / (centre - lower)
    falling = (upper - bins) / (upper - centre)
    filters = np.maximum(0, np.minimum(rising, falling)) * (2.0 / (upper - lower))
    return filters.astype(np.float32)


@functools.cache
def mel_filters() -> np.ndarray:
    """(N_MELS, N_FFT // 2 + 1) float32: the predictor's filters."""
    return mel_filterbank(SAMPLE_RATE, N_FFT, N_MELS, FMIN, FMAX)


def frame_count(n_samples: int) -> int:
    """Feature frames for n_samples (centred framing): one per HOP, plus the frame at 0."""
    return n_samples // HOP + 1


def log_mel(samples: np.ndarray) -> np.ndarray:
    """(F, N_MELS) float32 log10 mel energies of (N,) float32 mono samples at SAMPLE_RATE.

    F = frame_count(N). Non-finite samples are treated as silence; values are clipped to [-1, 1].
    """
    samples = np.nan_to_num(np.asarray(samples, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    samples = np.clip(samples, -1.0, 1.0)
    padded = np.pad(samples, N_FFT // 2)
    count = frame_count(len(samples))
    needed = (count - 1) * HOP + N_FFT
    if len(padded) < needed:
        padded = np.pad(padded, (0, needed - len(padded)))
    frames = np.lib.stride_tricks.sliding_window_view(padded, N_FFT)[::HOP][:count]
    window = np.zeros(N_FFT, np.float32)
    offset = (N_FFT - WINDOW) // 2
    window[offset : offset + WINDOW] = np.hanning(WINDOW + 2)[1:-1]
    spectrum = np.abs(scipy.fft.rfft(frames * window, axis=1)) ** 2  # scipy's: 6× numpy's speed
    mel = spectrum.astype(np.float32) @ mel_filters().T
    return np.log10(np.maximum(mel, LOG_FLOOR)).astype(np.float32)


def motion_frame_count(n_samples: int) -> int:
    """Motion frames (at MOTION_FPS) for n_samples: every started group of FRAMES_PER_MOTION feature frames."""
    return -(-frame_count(n_samples) // FRAMES_PER_MOTION)

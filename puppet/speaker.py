"""Speaker embeddings: who is talking, as a 256-d unit vector, from Resemblyzer's VoiceEncoder
run through onnxruntime (exported by `puppet.voice_encoder`).

As in Resemblyzer: the voice is normalised to -30 dBFS (only raised), long silences are cut,
power mels (40 channels, 25 ms Hann window, 10 ms hop) are cut into 1.6 s partials at 1.3 per
second, each partial is embedded, and the mean is normalised (over the first MAX_VOICE_SECONDS of speech). One difference: silences are found
by an energy detector instead of WebRTC's VAD (not a dependency here), the same in training
and at run time.
"""
import functools
from importlib.resources import files

import numpy as np
import onnxruntime
from scipy.ndimage import binary_dilation

from puppet.features import mel_filterbank

SAMPLE_RATE = 16000
EMBEDDING_SIZE = 256
MEL_CHANNELS = 40
WINDOW = 400  # 25 ms
HOP = 160  # 10 ms
PARTIAL_FRAMES = 160  # 1.6 s of mels per partial
PARTIALS_PER_SECOND = 1.3
MIN_COVERAGE = 0.75  # a last partial this full (or more) is kept, zero-padded
TARGET_DBFS = -30.0
VAD_WINDOW = 480  # 30 ms
VAD_SMOOTHING = 8  # windows averaged
VAD_MAX_SILENCE = 6  # windows of silence kept between voiced ones
VAD_RANGE_DB = 40.0  # windows this far below the loudest are silence ...
VAD_ABOVE_FLOOR_DB = 12.0  # ... and so are those within this of the quietest tenth
MAX_VOICE_SECONDS = 12.0  # a voice is known from its first seconds of speech: longer clips are not embedded whole
MODEL_FILE = "voice_encoder.onnx"


def encoder_mels(samples: np.ndarray) -> np.ndarray:
    """(F, 40) float32 power mels as Resemblyzer computes them (librosa's melspectrogram:
    centred frames, zero padding, periodic Hann window); F = N // HOP + 1."""
    padded = np.pad(samples.astype(np.float32), WINDOW // 2)
    count = len(samples) // HOP + 1
    frames = np.lib.stride_tricks.sliding_window_view(padded, WINDOW)[::HOP][:count]
    window = (0.5 - 0.5 * np.cos(2 * np.pi * np.arange(WINDOW) / WINDOW)).astype(np.float32)
    power = np.abs(np.fft.rfft(frames * window, axis=1)) ** 2
    return (power.astype(np.float32) @ mel_filterbank(SAMPLE_RATE, WINDOW, MEL_CHANNELS, 0.0, SAMPLE_RATE / 2).T).astype(np.float32)


def prepare(samples: np.ndarray) -> np.ndarray:
    """(M,) float32: the voice raised to TARGET_DBFS and long silences removed (M ≤ N)."""
    samples = np.nan_to_num(np.clip(np.asarray(samples, np.float32), -1, 1))
    rms = float(np.sqrt(np.mean(samples.astype(np.float64) ** 2))) if len(samples) else 0.0
    if rms > 0:
        samples = samples * max(1.0, 10 ** (TARGET_DBFS / 20) / rms)
    count = len(samples) // VAD_WINDOW
    if count < 2:
        return samples
    windows = samples[: count * VAD_WINDOW].reshape(count, VAD_WINDOW)
    level = 10 * np.log10(np.mean(windows.astype(np.float64) ** 2, axis=1) + 1e-12)
    voiced = level > max(level.max() - VAD_RANGE_DB, np.percentile(level, 10) + VAD_ABOVE_FLOOR_DB)
    smoothed = np.convolve(voiced.astype(float), np.ones(VAD_SMOOTHING) / VAD_SMOOTHING, mode="same") >= 0.5
    keep = binary_dilation(smoothed, np.ones(VAD_MAX_SILENCE + 1, bool))
    if not keep.any():
        return samples
    return windows[keep].ravel()


def partial_slices(n_samples: int) -> list[slice]:
    """Mel-frame slices of the partials covering an utterance of n_samples (Resemblyzer's rule)."""
    n_frames = int(np.ceil((n_samples + 1) / HOP))
    step = int(round(SAMPLE_RATE / PARTIALS_PER_SECOND / HOP))
    starts = range(0, max(1, n_frames - PARTIAL_FRAMES + step + 1), step)
    slices = [slice(s, s + PARTIAL_FRAMES) for s in starts]
    coverage = (n_samples - slices[-1].start * HOP) / (PARTIAL_FRAMES * HOP)
    if coverage < MIN_COVERAGE and len(slices) > 1:
        slices = slices[:-1]
    return slices


class SpeakerEncoder:
    """Embeds voices with the ONNX voice encoder on one CPU thread."""

    def __init__(self, model_path=None):
        path = model_path or files("puppet.assets") / "models" / MODEL_FILE
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = 1
        self.session = onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])

    def embed(self, samples: np.ndarray) -> np.ndarray:
        """(256,) float32 unit vector for (N,) float32 mono 16 kHz speech."""
        voice = prepare(samples)[: int(MAX_VOICE_SECONDS * SAMPLE_RATE)]
        slices = partial_slices(len(voice))
        voice = np.pad(voice, (0, max(0, slices[-1].stop * HOP - len(voice))))
        mels = encoder_mels(voice)
        batch = np.stack([mels[s] for s in slices])
        (partials,) = self.session.run(None, {"mels": batch})
        mean = partials.mean(axis=0)
        return (mean / max(float(np.linalg.norm(mean)), 1e-12)).astype(np.float32)


@functools.cache
def _default() -> SpeakerEncoder:
    return SpeakerEncoder()


def embed(samples: np.ndarray) -> np.ndarray:
    """(256,) float32 unit-norm speaker embedding of (N,) float32 mono 16 kHz speech."""
    return _default().embed(samples)

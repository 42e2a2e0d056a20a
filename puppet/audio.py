"""Audio: read any speech recording, as mono samples for analysis or as a resampled stream to mux.

Decoding is PyAV (FFmpeg's libraries ship in its wheel, no system ffmpeg), so wav of any depth,
flac, mp3, ogg/vorbis, opus and m4a/aac all take the same path: demux the first audio stream,
decode, convert with `av.AudioResampler`. Conversion happens frame by frame, so streaming an hour
of audio to the encoder holds one frame at a time; `load` keeps only the 16 kHz mono result.
"""
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import av
import numpy as np

from puppet.errors import PuppetError, reason

ANALYSIS_RATE = 16000  # Hz: speech features are computed at 16 kHz (8 kHz of bandwidth covers speech)
SILENCE_DBFS = -80.0  # a recording whose peak stays below this has nothing to lip-sync to
SILENCE_PEAK = 10 ** (SILENCE_DBFS / 20)  # 1e-4 of full scale


@dataclass(frozen=True)
class AudioInfo:
    """What a file holds, read without decoding all of it."""

    duration: float  # seconds, as the file declares it (decoded length may differ by a codec frame)
    sample_rate: int  # Hz, as stored in the file
    channels: int  # as stored in the file; `load` averages them to mono


def probe(path) -> AudioInfo:
    """Describe the first audio stream of `path`; PuppetError if it cannot be read or holds no sound."""
    container, stream = _open(path)
    with container:
        frames = _decode(container, stream, path)
        first = next((f for f in frames if f.samples), None)
        if first is None:
            raise PuppetError(f"{path} contains no audio samples")
        if stream.duration is not None:
            duration = float(stream.duration * stream.time_base)
        elif container.duration is not None:
            duration = container.duration / av.time_base
        else:  # a raw stream without an index: count what decodes
            duration = (first.samples + sum(f.samples for f in frames)) / stream.rate
        return AudioInfo(duration=duration, sample_rate=stream.rate, channels=stream.channels)


def load(path, sample_rate: int = ANALYSIS_RATE) -> np.ndarray:
    """Decode `path` to (N,) float32 mono in [-1, 1] at `sample_rate` Hz (channels are averaged).

    Raises PuppetError for a missing, unreadable or empty file and for decoding errors mid-file.
    """
    # Filled in place (sized from the declared duration, grown if that was short), so an hour of
    # audio costs its own size in memory and not a list of frames besides.
    samples = np.empty(int(probe(path).duration * sample_rate * 1.01) + sample_rate, np.float32)
    count = 0
    for frame in iter_resampled(path, sample_rate):
        planes = frame.to_ndarray()
        chunk = planes[0] if len(planes) == 1 else planes.mean(axis=0)
        if count + len(chunk) > len(samples):
            samples = np.resize(samples, max(2 * len(samples), count + len(chunk)))
        samples[count : count + len(chunk)] = chunk
        count += len(chunk)
    samples = samples[:count]
    if not samples.size:
        raise PuppetError(f"{path} contains no audio samples")
    # Float files may hold values past full scale (or NaN); analysis expects [-1, 1].
    np.nan_to_num(samples, copy=False)
    return np.clip(samples, -1.0, 1.0, out=samples)


def check_audible(samples: np.ndarray, source) -> None:
    """Raise PuppetError if `samples` ((N,) float, full scale 1.0) peak below SILENCE_DBFS."""
    peak = float(np.abs(samples).max()) if samples.size else 0.0
    if peak < SILENCE_PEAK:
        level = f"{20 * np.log10(peak):.0f} dBFS" if peak > 0 else "digital silence"
        raise PuppetError(
            f"{source} is silent (peak {level}, below {SILENCE_DBFS:.0f} dBFS); "
            "give a recording with speech in it"
        )


def iter_resampled(path, sample_rate: int, layout: str | None = None) -> Iterator[av.AudioFrame]:
    """Stream the first audio track of `path` as planar float32 ("fltp") frames.

    sample_rate: Hz of the frames yielded.
    layout:      channel layout of the frames ("mono", "stereo"); None keeps the file's own.
    Frame sizes vary; count samples to place the frames in time.
    The file is opened now, so a missing or unreadable file raises PuppetError here; decoding
    errors raise PuppetError while iterating. Closing the generator closes the file.
    """
    container, stream = _open(path)
    return _resample(container, stream, path, sample_rate, layout)


def _open(path) -> tuple[av.container.InputContainer, av.audio.AudioStream]:
    path = Path(path)
    if not path.exists():
        raise PuppetError(f"audio file not found: {path}")
    if not path.is_file():
        raise PuppetError(f"not an audio file: {path} is a folder or device")
    try:
        container = av.open(str(path))
    except (av.FFmpegError, OSError) as e:
        raise PuppetError(f"cannot read {path} as audio: {reason(e)}") from None
    if not container.streams.audio:
        container.close()
        raise PuppetError(f"{path} has no audio stream (is it an image or a silent video?)")
    return container, container.streams.audio[0]


def _decode(container, stream, path) -> Iterator[av.AudioFrame]:
    """Frames of `stream` as decoded; corrupt data becomes PuppetError."""
    try:
        yield from container.decode(stream)
    except (av.FFmpegError, OSError) as e:
        raise PuppetError(f"cannot decode {path}: {reason(e)}") from None


def _resample(container, stream, path, sample_rate, layout) -> Iterator[av.AudioFrame]:
    with container:
        resampler, source_format = None, None
        for frame in _decode(container, stream, path):
            # A resampler is fixed to its input format; some files change rate or layout mid-stream.
            frame_format = (frame.format.name, frame.layout.name, frame.sample_rate)
            if frame_format != source_format:
                if resampler is not None:
                    yield from resampler.resample(None)
                resampler = av.AudioResampler(format="fltp", layout=layout, rate=sample_rate)
                source_format = frame_format
            yield from resampler.resample(frame)
        if resampler is not None:
            yield from resampler.resample(None)

"""Live audio for `puppet live`: a microphone, or a file played back in sync, as 16 kHz mono.

Real time the uLipSync way. PortAudio's callback thread only copies its block into a locked ring
buffer at the device's own rate, stamped with the time its last sample was captured. The frame loop
calls `read()` once a frame: it takes everything new out of the ring and converts it to 16 kHz with
a streaming resampler that keeps its filter state from read to read, so chunk edges leave no seams.

Timing. `Chunk.end_time` is the perf_counter time at which the newest sample read so far was
captured (or, for a file, reaches the speakers). The resampler holds back the newest ~1 ms of input
(its filter's reach, 16 samples at 16 kHz) until more arrives; end_time ignores that, so it runs at
most 1 ms ahead of the samples returned, a twentieth of a motion frame.

Robustness. A microphone that fails to open, stops calling back, or reports its stream inactive
is closed and reopened every RETRY_SECONDS from a watchdog thread; meanwhile `status` says so and
`read()` returns empty chunks. `read()` never blocks on the device and never raises.
"""
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import av
import numpy as np
from scipy.signal import resample_poly

from puppet import audio, features
from puppet.errors import PuppetError, reason

CAPTURE_RATE = features.SAMPLE_RATE  # 16000 Hz: what read() returns, what the predictor hears
BLOCK_SECONDS = 0.005  # audio callback block: 5 ms (240 samples at 48 kHz), for low latency
RING_SECONDS = 2.0  # ring capacity: how long the frame loop may stall before audio is dropped
MAX_REPORTED_LATENCY = 1.0  # s: a PortAudio stream latency beyond this is a host API's nonsense
NO_PORTAUDIO = "no audio input: the PortAudio library is missing (Debian/Ubuntu: sudo apt install libportaudio2)"
LIST_HINT = "run `puppet live --list-devices` to see them"


@dataclass(frozen=True)
class Chunk:
    """The audio that arrived since the previous read."""

    samples: np.ndarray  # (n,) float32 mono at CAPTURE_RATE, in [-1, 1]; n may be 0
    end_time: float  # perf_counter s when the newest sample read so far was captured; nan before any
    dropped: int  # samples (at the device rate) lost to ring overflow since the previous read


class RingBuffer:
    """Fixed capacity float32 ring. The audio callback thread only calls write(); the frame loop calls read()."""

    def __init__(self, capacity: int):
        self.buffer = np.zeros(capacity, np.float32)
        self.capacity = capacity
        self.written = 0  # samples written since creation
        self.taken = 0  # samples read or dropped since creation
        self.end_time = math.nan  # perf_counter s of the newest sample written
        self.lock = threading.Lock()

    def write(self, samples: np.ndarray, end_time: float) -> None:
        """samples: (n,) float32; end_time: perf_counter s when the last of them was captured."""
        n = len(samples)
        if n == 0:
            return
        kept = samples[-self.capacity :]  # a block longer than the ring would overwrite its own start
        with self.lock:
            start = (self.written + n - len(kept)) % self.capacity
            first = min(len(kept), self.capacity - start)
            self.buffer[start : start + first] = kept[:first]
            self.buffer[: len(kept) - first] = kept[first:]
            self.written += n
            self.end_time = end_time

    def read(self) -> tuple[np.ndarray, float, int]:
        """Everything written since the last read, oldest first, as a new (n,) float32 array (the oldest
        dropped if more than `capacity` arrived); the end_time of the newest sample; how many were dropped."""
        with self.lock:
            count = self.written - self.taken
            dropped = max(0, count - self.capacity)
            count -= dropped
            start = (self.written - count) % self.capacity
            first = min(count, self.capacity - start)
            samples = np.concatenate([self.buffer[start : start + first], self.buffer[: count - first]])
            self.taken = self.written
            return samples, self.end_time, dropped


class _Pipe:
    """A ring at the device rate and the streaming resampler that empties it at CAPTURE_RATE."""

    def __init__(self, rate: int, seconds: float = RING_SECONDS, end_time: float = math.nan):
        self.rate = rate
        self.ring = RingBuffer(round(seconds * rate))
        self.resampler = None if rate == CAPTURE_RATE else av.AudioResampler(format="flt", layout="mono", rate=CAPTURE_RATE)
        self.fed = 0  # samples given to the resampler: the pts of the next frame, in 1/rate s
        self.end_time = end_time  # of the newest sample read

    def read(self, last: bool = False) -> Chunk:
        """What the ring holds, at CAPTURE_RATE; `last`: the source has ended, flush the resampler."""
        samples, end_time, dropped = self.ring.read()
        if len(samples):
            self.end_time = end_time
        if self.resampler is not None and (len(samples) or last):
            samples = self._resample(samples, last)
        return Chunk(np.clip(samples, -1.0, 1.0, out=samples), self.end_time, dropped)

    def _resample(self, samples: np.ndarray, last: bool) -> np.ndarray:
        frames = []
        if len(samples):
            frame = av.AudioFrame.from_ndarray(samples[None, :], format="flt", layout="mono")
            frame.sample_rate, frame.pts = self.rate, self.fed
            self.fed += len(samples)
            frames += self.resampler.resample(frame)
        if last:
            frames += self.resampler.resample(None)
        return np.concatenate([f.to_ndarray()[0] for f in frames]) if frames else np.zeros(0, np.float32)


class AudioSource(Protocol):
    """Where `puppet live` hears its voice: `Microphone` or `FilePlayer`. A context manager (start/close)."""

    name: str  # for messages: the device's or the file's name
    status: str | None  # None when fine, else a short message for the window overlay
    finished: bool  # a file source has played to its end and read() has returned all of it

    def start(self) -> None: ...

    def read(self) -> Chunk:
        """Non-blocking: everything new since the last read, 16 kHz mono."""

    def close(self) -> None:
        """Stop delivering audio; idempotent."""

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.close()


def load_sounddevice():
    """The sounddevice module (imported on first use); PuppetError if the PortAudio library is missing."""
    try:
        import sounddevice
    except OSError:  # sounddevice raises OSError at import when it cannot load libportaudio
        raise PuppetError(NO_PORTAUDIO) from None
    return sounddevice


def list_devices(backend=None) -> str:
    """A table of the audio input devices (index, name, channels, default rate), the default marked
    with `*`; a one-line message when there are none. backend: the sounddevice module or a stand-in."""
    backend = backend if backend is not None else load_sounddevice()
    inputs = _inputs(backend)
    if not inputs:
        return "no audio input devices found: plug in a microphone, or drive the puppet from a recording with --audio FILE"
    default = backend.default.device[0]
    width = max(len(info["name"]) for _, info in inputs)
    lines = ["audio input devices (* = default):"]
    for index, info in inputs:
        mark = "*" if index == default else " "
        lines.append(f"{mark} {index:>3}  {info['name']:<{width}}  {info['max_input_channels']} ch  "
                     f"{info['default_samplerate']:.0f} Hz")
    return "\n".join(lines)


def _inputs(backend) -> list[tuple[int, dict]]:
    """(index, info) of every device with input channels; none when PortAudio cannot list them."""
    try:
        devices = backend.query_devices()
    except backend.PortAudioError:
        return []
    return [(index, info) for index, info in enumerate(devices) if info["max_input_channels"] > 0]


def _find_input(backend, device: int | str | None) -> tuple[int, dict]:
    """The input device `device` names: an index (int or digits), a case-insensitive part of its name
    (an exact name wins, else the first match), or None for the system default. PuppetError if none."""
    inputs = _inputs(backend)
    if not inputs:
        raise PuppetError("no audio input devices found: plug in a microphone, or drive the puppet from a recording with --audio FILE")
    if device is None:
        default = backend.default.device[0]
        return next(((i, info) for i, info in inputs if i == default), inputs[0])
    if isinstance(device, str) and device.strip().isdigit():
        device = int(device)
    if isinstance(device, int):
        found = [(i, info) for i, info in inputs if i == device]
        if not found:
            raise PuppetError(f"audio device {device} does not exist or is not an input: {LIST_HINT}")
        return found[0]
    wanted = device.strip().lower()
    found = [(i, info) for i, info in inputs if wanted in info["name"].lower()]
    if not found:
        raise PuppetError(f"no audio input device matching '{device}': {LIST_HINT}")
    return next(((i, info) for i, info in found if info["name"].lower() == wanted), found[0])


class Microphone(AudioSource):
    """A PortAudio input device, reopened by itself when it is lost (unplugged, taken, stalled)."""

    RETRY_SECONDS = 2.0  # between attempts to reopen a lost device
    STALL_SECONDS = 0.5  # a running stream without a callback for this long is lost
    START_SECONDS = 3.0  # a new stream may take this long to deliver its first block (PulseAudio's ALSA plugin can take 2 s)

    def __init__(self, device: int | str | None = None, backend=None, ring_seconds: float = RING_SECONDS):
        """device: index or part of the name of an input device (see `list_devices`), None for the
        default. backend: the sounddevice module (default) or a stand-in with the same API.
        PuppetError now if PortAudio is missing or no such input device exists."""
        self.backend = backend if backend is not None else load_sounddevice()
        self.device = device
        self.ring_seconds = ring_seconds
        self.name = _find_input(self.backend, device)[1]["name"]
        self.status: str | None = None
        self.finished = False
        self._pipe: _Pipe | None = None  # replaced at each (re)open; read() takes whichever is current
        self._stream = None  # open stream, touched by start, the watchdog and close only
        self._opened_at = 0.0
        self._retry_at = 0.0
        self._stop = threading.Event()
        self._watchdog: threading.Thread | None = None

    def start(self) -> None:
        """Open the device (on failure `status` says why and the watchdog keeps trying)."""
        self._open()
        self._watchdog = threading.Thread(target=self._watch, name="puppet-microphone", daemon=True)
        self._watchdog.start()

    def read(self) -> Chunk:
        pipe = self._pipe
        return pipe.read() if pipe is not None else Chunk(np.zeros(0, np.float32), math.nan, 0)

    def close(self) -> None:
        self._stop.set()
        if self._watchdog is not None:
            self._watchdog.join()
            self._watchdog = None
        self._close_stream()

    def _open(self) -> None:
        stream = None
        try:
            index, info = _find_input(self.backend, self.device)
            rate = int(info["default_samplerate"])
            pipe = _Pipe(rate, self.ring_seconds, self._pipe.end_time if self._pipe is not None else math.nan)
            ring = pipe.ring

            def callback(indata, frames, time_info, status):
                ring.write(indata[:, 0], time.perf_counter())

            # latency="low": the host's small buffers (PulseAudio otherwise delivers in 20 ms bursts, 10 ms later on average)
            stream = self.backend.InputStream(samplerate=rate, blocksize=round(rate * BLOCK_SECONDS), device=index,
                                              channels=1, dtype="float32", callback=callback, latency="low")
            stream.start()
        except PuppetError:
            self._lose("not connected")
        except self.backend.PortAudioError as error:
            if stream is not None:
                _close_quietly(self.backend, stream)
            self._lose(reason(error))
        else:
            self._pipe, self._stream, self._opened_at = pipe, stream, time.perf_counter()
            self.name, self.status = info["name"], None

    def _watch(self) -> None:
        while not self._stop.wait(min(self.STALL_SECONDS, self.RETRY_SECONDS) / 5):
            now = time.perf_counter()
            if self._stream is None:
                if now >= self._retry_at:
                    self._refresh()
                    self._open()
                continue
            ring = self._pipe.ring
            heard, patience = (ring.end_time, self.STALL_SECONDS) if ring.written else (self._opened_at, self.START_SECONDS)
            if not self._stream.active:
                self._lose("the stream stopped")
            elif now - heard > patience:
                self._lose(f"no audio for {now - heard:.1f} s")

    def _lose(self, why: str) -> None:
        self._close_stream()
        self.status = f"microphone lost ({why}) — retrying"
        self._retry_at = time.perf_counter() + self.RETRY_SECONDS

    def _close_stream(self) -> None:
        if self._stream is not None:
            _close_quietly(self.backend, self._stream)
            self._stream = None

    def _refresh(self) -> None:
        """PortAudio lists devices once per initialisation: start it afresh so that a replugged device
        shows up (sounddevice's maintainers' advice, spatialaudio/python-sounddevice#125). That would
        stop other streams; puppet has none open while its microphone is lost."""
        for step in (self.backend._terminate, self.backend._initialize):
            try:
                step()
            except self.backend.PortAudioError:
                pass  # not initialised, or no audio system yet: the next retry tries again


class FilePlayer(AudioSource):
    """An audio file fed through the same ring and resampler as a microphone, in real time: played
    through the speakers when there are any (the ring gets each block as it goes to them), otherwise
    paced by a clock thread."""

    def __init__(self, path, playback: bool = True, backend=None, loop: bool = False):
        """path: any audio file puppet.audio reads (PuppetError now if unreadable or silent).
        playback: play it aloud (falls back to silent pacing without PortAudio or an output device).
        backend: the sounddevice module (default) or a stand-in. loop: start over at the end, forever."""
        self.samples = audio.load(path)  # (N,) float32 at CAPTURE_RATE
        audio.check_audible(self.samples, path)
        self.name = Path(path).name
        self.loop = loop
        self.backend = _playback_backend(backend) if playback else None
        self.output: str | None = None  # the speakers' name once start() found some
        self.status: str | None = None
        self.finished = False
        self._delivered = False  # the writer has put the clip's last sample into the ring
        self._pipe: _Pipe | None = None
        self._stream = None
        self._stop = threading.Event()
        self._pacer: threading.Thread | None = None

    def start(self) -> None:
        self._stream = self._open_speakers() if self.backend is not None else None
        if self._stream is None:
            self._pipe = _Pipe(CAPTURE_RATE)
            self._pacer = threading.Thread(target=self._pace, args=(_Clip(self.samples, self.loop), self._pipe.ring),
                                           name="puppet-file-audio", daemon=True)
            self._pacer.start()

    def read(self) -> Chunk:
        pipe = self._pipe
        if pipe is None:
            return Chunk(np.zeros(0, np.float32), math.nan, 0)
        last = self._delivered and not self.finished  # checked before the ring is read: its last block is in this read
        chunk = pipe.read(last)
        if last:
            self.finished = True
        return chunk

    def close(self) -> None:
        self._stop.set()
        if self._pacer is not None:
            self._pacer.join()
            self._pacer = None
        if self._stream is not None:
            _close_quietly(self.backend, self._stream)
            self._stream = None

    def _open_speakers(self):
        """An OutputStream playing the clip (at 16 kHz, else at the device's own rate), or None."""
        try:
            info = self.backend.query_devices(kind="output")
        except (self.backend.PortAudioError, ValueError):  # no default output device
            return None
        for rate in dict.fromkeys([CAPTURE_RATE, int(info["default_samplerate"])]):
            try:
                stream = self._play(rate)
            except self.backend.PortAudioError:
                continue
            self.output = info["name"]
            return stream
        return None

    def _play(self, rate: int):
        samples = self.samples if rate == CAPTURE_RATE else _resample_once(self.samples, rate)
        clip, pipe = _Clip(samples, self.loop), _Pipe(rate)
        ring = pipe.ring

        def callback(outdata, frames, time_info, status):
            block = clip.take(frames)
            outdata[: len(block), 0] = block
            outdata[len(block) :] = 0.0
            if len(block):
                # The block reaches the speakers after the stream's output latency, its last sample later still.
                ahead = _latency(time_info.outputBufferDacTime - time_info.currentTime)
                ring.write(block, time.perf_counter() + ahead + (len(block) - 1) / rate)
            self._delivered = clip.done

        stream = self.backend.OutputStream(samplerate=rate, blocksize=round(rate * BLOCK_SECONDS),
                                           channels=1, dtype="float32", callback=callback)
        try:
            stream.start()
        except self.backend.PortAudioError:
            _close_quietly(self.backend, stream)
            raise
        self._pipe = pipe
        return stream

    def _pace(self, clip: "_Clip", ring: RingBuffer) -> None:
        """Write BLOCK_SECONDS blocks at the pace of playback, on an absolute schedule (no drift)."""
        block = round(CAPTURE_RATE * BLOCK_SECONDS)
        start, sent = time.perf_counter(), 0
        while not clip.done:
            samples = clip.take(block)
            sent += len(samples)
            due = start + sent / CAPTURE_RATE  # when the last of them would have been played
            if self._stop.wait(max(0.0, due - time.perf_counter())):
                return
            ring.write(samples, due)
            self._delivered = clip.done


class _Clip:
    """A clip handed out block by block; a looping one starts over at its end and is never done."""

    def __init__(self, samples: np.ndarray, loop: bool):
        self.samples = samples
        self.loop = loop
        self.position = 0

    @property
    def done(self) -> bool:
        return not self.loop and self.position >= len(self.samples)

    def take(self, n: int) -> np.ndarray:
        """The next (≤ n,) samples: fewer only at the end of a clip that does not loop."""
        if self.loop:
            block = self.samples.take(np.arange(self.position, self.position + n), mode="wrap")
            self.position = (self.position + n) % len(self.samples)
            return block
        block = self.samples[self.position : self.position + n]
        self.position += len(block)
        return block


def _playback_backend(backend):
    """The backend to play through: the given one, else sounddevice, else None without PortAudio."""
    if backend is not None:
        return backend
    try:
        return load_sounddevice()
    except PuppetError:
        return None


def _resample_once(samples: np.ndarray, rate: int) -> np.ndarray:
    """(N,) float32 at CAPTURE_RATE → float32 at `rate` (polyphase), for speakers that refuse 16 kHz."""
    divisor = math.gcd(rate, CAPTURE_RATE)
    return resample_poly(samples, rate // divisor, CAPTURE_RATE // divisor).astype(np.float32)


def _latency(seconds: float) -> float:
    """A latency from PortAudio timestamps, or 0 where the host API reports none or nonsense."""
    return seconds if 0.0 <= seconds < MAX_REPORTED_LATENCY else 0.0


def _close_quietly(backend, stream) -> None:
    """Close a stream whose device may already be gone."""
    try:
        stream.close()
    except backend.PortAudioError:
        pass

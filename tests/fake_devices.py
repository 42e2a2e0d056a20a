"""Fakes behind the real device interfaces, for machines without sound cards or virtual cameras.

`FakeSoundDevice` stands in for the `sounddevice` module (the part puppet.capture uses): its streams
call back from a daemon thread at real-time pace, and `unplug()`/`replug()` take the devices away
and bring them back. `FakeCameraBackend` is a pyvirtualcam backend that keeps what it was sent.
"""
import collections
import threading
import time
from types import SimpleNamespace
from typing import ClassVar

import numpy as np


class PortAudioError(Exception):
    """sounddevice.PortAudioError's stand-in."""


class DeviceList(tuple):
    """sounddevice.DeviceList's stand-in: a tuple of device dicts that prints as a table."""

    def __repr__(self):
        return "\n".join(f"{d['index']:>3} {d['name']} ({d['max_input_channels']} in, {d['max_output_channels']} out)"
                         for d in self)


class FakeSoundDevice:
    """A module-like stand-in for `sounddevice`.

    inputs, outputs: (name, default sample rate) of each device; inputs get indices 0, 1, ... and
    outputs follow. Inputs have 2 channels, outputs 2; a stream opens only at its device's default rate.
    signal: what inputs hear, a callable (n, rate) → (n,) float32 called once a block, or an (N,)
    array at the device rate played over and over; default: quiet white noise.
    """

    PortAudioError = PortAudioError
    OUTPUT_LATENCY = 0.02  # s: output streams report their first sample reaches the DAC this long after the callback

    def __init__(self, inputs=(("Fake USB Mic", 48000.0),), outputs=(), signal=None):
        ends = [(name, rate, 2, 0) for name, rate in inputs] + [(name, rate, 0, 2) for name, rate in outputs]
        self.devices = [{"name": name, "index": index, "hostapi": 0, "max_input_channels": ins,
                         "max_output_channels": outs, "default_samplerate": float(rate)}
                        for index, (name, rate, ins, outs) in enumerate(ends)]
        self.default = SimpleNamespace(device=[0 if inputs else -1, len(inputs) if outputs else -1])
        noise = np.random.default_rng(0)
        self.signal = signal if signal is not None else (lambda n, rate: noise.uniform(-0.1, 0.1, n).astype(np.float32))
        self.plugged = True
        self.silent_unplug = False  # unplugged streams keep reporting active (a stall) instead of stopping
        self.streams: list[_FakeStream] = []  # every stream opened, oldest first
        self.initialisations = 0  # _initialize calls: PortAudio restarted to rescan devices

    def InputStream(self, **kwargs):
        return _FakeStream(self, "input", **kwargs)

    def OutputStream(self, **kwargs):
        return _FakeStream(self, "output", **kwargs)

    def query_devices(self, device=None, kind=None):
        """As sounddevice: every device (DeviceList), or one device's dict (the default of `kind` if no
        device is given); PortAudioError for a device that does not exist, ValueError for the wrong kind."""
        if kind not in (None, "input", "output"):
            raise ValueError(f"Invalid kind: {kind!r}")
        if device is None and kind is None:
            return DeviceList(dict(d) for d in self.devices)
        if device is None:
            device = self.default.device[0 if kind == "input" else 1]
        if isinstance(device, str):
            found = [d["index"] for d in self.devices if device.lower() in d["name"].lower()
                     and (kind is None or d[f"max_{kind}_channels"] > 0)]
            if not found:
                raise ValueError(f"No {kind or 'input/output'} device matching {device!r}")
            device = found[0]
        if not 0 <= device < len(self.devices):
            raise PortAudioError(f"Error querying device {device}")
        info = dict(self.devices[device])
        if kind is not None and info[f"max_{kind}_channels"] < 1:
            raise ValueError(f"Not an {kind} device: {info['name']!r}")
        return info

    def unplug(self, silently: bool = False) -> None:
        """Take every device away: callbacks stop, streams turn inactive (unless `silently`: they stall
        while still reporting active), and opening a stream raises PortAudioError until `replug`."""
        self.silent_unplug = silently
        self.plugged = False

    def replug(self) -> None:
        self.plugged = True

    def _terminate(self) -> None:
        pass

    def _initialize(self) -> None:
        self.initialisations += 1

    def _block(self, n: int, rate: float, position: int) -> np.ndarray:
        if callable(self.signal):
            return np.asarray(self.signal(n, rate), np.float32)
        return self.signal.take(np.arange(position, position + n), mode="wrap").astype(np.float32)


class _FakeStream:
    """An InputStream or OutputStream: a daemon thread calls `callback` every block, on an absolute clock."""

    def __init__(self, sound, kind, *, samplerate, blocksize, callback, device=None, channels=1, dtype="float32", **_):
        name = "InputStream" if kind == "input" else "OutputStream"
        if not sound.plugged:
            raise PortAudioError(f"Error opening {name}: Device unavailable [PaErrorCode -9985]")
        info = sound.query_devices(device, kind)
        if samplerate != info["default_samplerate"]:
            raise PortAudioError(f"Error opening {name}: Invalid sample rate [PaErrorCode -9997]")
        if not 1 <= channels <= info[f"max_{kind}_channels"] or dtype != "float32":
            raise PortAudioError(f"Error opening {name}: Invalid number of channels [PaErrorCode -9998]")
        self.sound, self.kind, self.device = sound, kind, info["index"]
        self.samplerate, self.blocksize, self.channels, self.callback = samplerate, blocksize, channels, callback
        self.active = False
        self.closed = False
        self.blocks = 0  # callbacks made
        self.played = collections.deque(maxlen=12000)  # output: the (blocksize,) blocks the speakers got (last minute)
        self._stop = threading.Event()
        self._thread = None
        sound.streams.append(self)

    def start(self) -> None:
        self.active = True
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
        self.active = False

    def close(self) -> None:
        self.stop()
        self.closed = True

    def _run(self) -> None:
        period = self.blocksize / self.samplerate
        start = time.perf_counter()
        while not self._stop.wait(max(0.0, start + (self.blocks + 1) * period - time.perf_counter())):
            if not self.sound.plugged:
                self.active = self.sound.silent_unplug
                return
            now = time.perf_counter()
            if self.kind == "input":
                block = self.sound._block(self.blocksize, self.samplerate, self.blocks * self.blocksize)
                data = np.repeat(block[:, None], self.channels, axis=1)
                timing = SimpleNamespace(inputBufferAdcTime=now - period, currentTime=now, outputBufferDacTime=0.0)
            else:
                data = np.zeros((self.blocksize, self.channels), np.float32)
                timing = SimpleNamespace(inputBufferAdcTime=0.0, currentTime=now, outputBufferDacTime=now + self.sound.OUTPUT_LATENCY)
            try:
                self.callback(data, self.blocksize, timing, 0)  # 0: no CallbackFlags set
            except Exception:
                self.active = False
                raise
            if self.kind == "output":
                self.played.append(data[:, 0].copy())
            self.blocks += 1


class FakeCameraBackend:
    """A pyvirtualcam backend that keeps the number of frames sent and the last one."""

    instances: ClassVar[list["FakeCameraBackend"]] = []  # every camera opened since register_fake_camera

    def __init__(self, *, width, height, fps, fourcc, device, **kw):
        self.width, self.height, self.fps, self.fourcc = width, height, fps, fourcc
        self.name = device if device is not None else "Fake Camera"
        self.frames = 0  # frames sent
        self.last_frame = None  # (height, width, 3) uint8 copy of the last frame sent
        self.closed = False
        FakeCameraBackend.instances.append(self)

    def send(self, frame: np.ndarray) -> None:
        self.frames += 1
        self.last_frame = frame.reshape(self.height, self.width, 3).copy()

    def close(self) -> None:
        self.closed = True

    def device(self) -> str:
        return self.name

    def native_fourcc(self) -> int:
        return self.fourcc


def register_fake_camera() -> type[FakeCameraBackend]:
    """Register FakeCameraBackend with pyvirtualcam as backend "fake" (forgetting earlier instances)."""
    import pyvirtualcam

    FakeCameraBackend.instances.clear()
    pyvirtualcam.register_backend("fake", FakeCameraBackend)
    return FakeCameraBackend

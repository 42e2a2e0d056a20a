"""Live audio: the ring buffer, a microphone and a played file through fake PortAudio devices, in real time."""
import importlib.abc
import math
import sys
import time
import wave

import numpy as np
import pytest
from fake_devices import FakeSoundDevice

from puppet import capture
from puppet.capture import CAPTURE_RATE, FilePlayer, Microphone, RingBuffer
from puppet.errors import PuppetError

TONE_HZ = 440.0


def tone(seconds: float, rate: int, amplitude: float = 0.5) -> np.ndarray:
    t = np.arange(round(seconds * rate)) / rate
    return (amplitude * np.sin(2 * np.pi * TONE_HZ * t)).astype(np.float32)


def write_wav(path, samples: np.ndarray, rate: int = CAPTURE_RATE):
    with wave.open(str(path), "wb") as file:
        file.setnchannels(1)
        file.setsampwidth(2)
        file.setframerate(rate)
        file.writeframes((samples * 32767).astype("<i2").tobytes())
    return path


def collect(source, seconds: float, until=lambda: False):
    """Read `source` every 10 ms for `seconds` (or until `until()`): samples, last chunk, read times."""
    chunks, start = [], time.perf_counter()
    while time.perf_counter() - start < seconds and not until():
        time.sleep(0.01)
        chunks.append(source.read())
    return np.concatenate([c.samples for c in chunks]), chunks


def wait_for(condition, seconds: float = 3.0, poll=lambda: None) -> bool:
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        poll()
        if condition():
            return True
        time.sleep(0.01)
    return False


def dominant_hz(samples: np.ndarray, rate: int) -> float:
    spectrum = np.abs(np.fft.rfft(samples * np.hanning(len(samples))))
    return float(np.argmax(spectrum) * rate / len(samples))


def test_ring_returns_what_was_written_in_order_across_the_wrap():
    ring, rng = RingBuffer(64), np.random.default_rng(1)
    signal = rng.standard_normal(5000).astype(np.float32)
    got, position = [], 0
    while position < len(signal):
        for _ in range(rng.integers(1, 4)):
            block = signal[position : position + rng.integers(0, 20)]
            position += len(block)
            ring.write(block, position)
        samples, end_time, dropped = ring.read()
        assert dropped == 0 and end_time == position
        got.append(samples)
    np.testing.assert_array_equal(np.concatenate(got), signal)


def test_ring_drops_the_oldest_on_overflow_and_counts_them():
    ring = RingBuffer(8)
    samples, end_time, dropped = ring.read()
    assert len(samples) == 0 and math.isnan(end_time) and dropped == 0

    ring.write(np.arange(5, dtype=np.float32), 1.0)
    ring.write(np.arange(5, 10, dtype=np.float32), 2.0)
    ring.write(np.arange(10, 15, dtype=np.float32), 3.0)
    samples, end_time, dropped = ring.read()
    np.testing.assert_array_equal(samples, np.arange(7, 15))
    assert end_time == 3.0 and dropped == 7

    ring.write(np.arange(100, 120, dtype=np.float32), 4.0)  # one block longer than the ring
    samples, end_time, dropped = ring.read()
    np.testing.assert_array_equal(samples, np.arange(112, 120))
    assert dropped == 12

    samples, end_time, dropped = ring.read()  # nothing new: empty, the newest sample's time
    assert len(samples) == 0 and end_time == 4.0 and dropped == 0


def test_microphone_delivers_16k_mono_in_real_time():
    fake = FakeSoundDevice(inputs=[("Fake USB Mic", 48000.0)], signal=tone(1.0, 48000))
    with Microphone(backend=fake) as mic:
        started = time.perf_counter()
        samples, chunks = collect(mic, 0.3)
        elapsed = time.perf_counter() - started
        stream = fake.streams[-1]

    assert (stream.samplerate, stream.blocksize, stream.channels) == (48000, 240, 1)
    assert samples.dtype == np.float32 and mic.status is None and not mic.finished
    # All that was captured, less the last block in flight and the resampler's 1 ms: within 20 ms.
    assert abs(len(samples) - elapsed * CAPTURE_RATE) < 0.02 * CAPTURE_RATE
    assert 0 <= chunks[-1].end_time <= time.perf_counter() and chunks[-1].end_time > started + elapsed - 0.03
    assert abs(dominant_hz(samples, CAPTURE_RATE) - TONE_HZ) < 5
    assert np.abs(samples).max() == pytest.approx(0.5, abs=0.02)


def test_microphone_chosen_by_index_or_name():
    fake = FakeSoundDevice(inputs=[("Built-in Microphone", 44100.0), ("HD Webcam C920", 16000.0)],
                           outputs=[("Speakers", 48000.0)])
    assert Microphone(backend=fake).name == "Built-in Microphone"  # the default
    assert Microphone(1, backend=fake).name == "HD Webcam C920"
    assert Microphone("1", backend=fake).name == "HD Webcam C920"  # as typed after --device
    assert Microphone("webcam", backend=fake).name == "HD Webcam C920"

    for wrong in ["headset", 2, 7]:  # no such name; an output; no such index
        with pytest.raises(PuppetError, match="--list-devices"):
            Microphone(wrong, backend=fake)
    with pytest.raises(PuppetError, match="no audio input devices"):
        Microphone(backend=FakeSoundDevice(inputs=[]))


def test_microphone_at_16k_is_passed_through_unresampled():
    signal = np.random.default_rng(3).uniform(-0.5, 0.5, 16000).astype(np.float32)
    fake = FakeSoundDevice(inputs=[("Mic", 16000.0)], signal=signal)
    with Microphone(backend=fake) as mic:
        samples, _ = collect(mic, 0.1)
    np.testing.assert_array_equal(samples, signal[: len(samples)])


class _NoPortAudio(importlib.abc.MetaPathFinder):
    """Makes `import sounddevice` fail as it does when libportaudio is not installed."""

    def find_spec(self, name, path=None, target=None):
        if name == "sounddevice":
            raise OSError("PortAudio library not found")


def test_missing_portaudio(monkeypatch, tmp_path):
    monkeypatch.delitem(sys.modules, "sounddevice", raising=False)
    monkeypatch.setattr(sys, "meta_path", [_NoPortAudio(), *sys.meta_path])
    with pytest.raises(PuppetError, match="libportaudio2"):
        Microphone()
    with pytest.raises(PuppetError, match="libportaudio2"):
        capture.list_devices()
    player = FilePlayer(write_wav(tmp_path / "a.wav", tone(0.05, CAPTURE_RATE)))  # plays silently instead
    assert player.backend is None


@pytest.mark.parametrize("silently", [False, True], ids=["stream-stops", "stream-stalls"])
def test_microphone_lost_and_found_again(monkeypatch, silently):
    monkeypatch.setattr(Microphone, "STALL_SECONDS", 0.1)
    monkeypatch.setattr(Microphone, "RETRY_SECONDS", 0.1)
    fake = FakeSoundDevice()
    heard = []
    with Microphone(backend=fake) as mic:
        assert wait_for(lambda: len(heard) and len(heard[-1]), poll=lambda: heard.append(mic.read().samples))
        fake.unplug(silently=silently)
        assert wait_for(lambda: mic.status is not None, poll=mic.read)
        assert mic.status.startswith("microphone lost")
        time.sleep(0.25)  # a couple of failed retries
        mic.read()
        assert len(mic.read().samples) == 0 and fake.initialisations >= 1

        fake.replug()
        assert wait_for(lambda: mic.status is None, poll=mic.read)
        heard.clear()
        assert wait_for(lambda: sum(map(len, heard)) > 0.05 * CAPTURE_RATE, poll=lambda: heard.append(mic.read().samples))
        assert not math.isnan(mic.read().end_time)
    assert all(stream.closed for stream in fake.streams)


def test_microphone_that_cannot_open_says_so_and_retries(monkeypatch):
    monkeypatch.setattr(Microphone, "RETRY_SECONDS", 0.05)
    fake = FakeSoundDevice()
    mic = Microphone(backend=fake)
    fake.unplug()
    with mic:
        assert "Device unavailable" in mic.status and len(mic.read().samples) == 0
        fake.replug()
        assert wait_for(lambda: mic.status is None)


def test_file_played_silently_in_real_time(tmp_path):
    clip = tone(0.25, CAPTURE_RATE)
    path = write_wav(tmp_path / "speech.wav", clip)
    with FilePlayer(path, playback=False) as player:
        started = time.perf_counter()
        samples, chunks = collect(player, 2.0, until=lambda: player.finished)
        elapsed = time.perf_counter() - started

    assert player.output is None and player.status is None and player.name == "speech.wav"
    assert 0.24 <= elapsed <= 0.32
    np.testing.assert_allclose(samples, clip, atol=1e-4)  # all of it, exactly once (16-bit wav)
    assert chunks[-1].end_time == pytest.approx(started + 0.25, abs=0.015)


def test_file_loops(tmp_path):
    path = write_wav(tmp_path / "short.wav", tone(0.1, CAPTURE_RATE))
    with FilePlayer(path, playback=False, loop=True) as player:
        samples, _ = collect(player, 0.3)
        assert not player.finished
    assert len(samples) > 0.25 * CAPTURE_RATE


@pytest.mark.parametrize("speaker_rate", [16000, 44100])
def test_file_played_through_speakers(tmp_path, speaker_rate):
    clip = tone(0.2, CAPTURE_RATE)
    fake = FakeSoundDevice(inputs=[], outputs=[("Fake Speakers", float(speaker_rate))])
    with FilePlayer(write_wav(tmp_path / "speech.wav", clip), backend=fake) as player:
        samples, chunks = collect(player, 2.0, until=lambda: player.finished)
        newest = chunks[-1].end_time - time.perf_counter()
        played = np.concatenate(fake.streams[-1].played)

    assert player.output == "Fake Speakers" and fake.streams[-1].samplerate == speaker_rate
    assert abs(dominant_hz(played, speaker_rate) - TONE_HZ) < 5
    assert np.abs(played).max() == pytest.approx(0.5, abs=0.02)
    # What the ring heard is what was played, back at 16 kHz and stamped with when it is heard.
    assert abs(len(samples) - len(clip)) <= 2
    assert abs(dominant_hz(samples, CAPTURE_RATE) - TONE_HZ) < 5
    assert -0.03 < newest < FakeSoundDevice.OUTPUT_LATENCY + 0.01


def test_bad_files(tmp_path):
    (tmp_path / "corrupt.wav").write_bytes(b"RIFF\x00\x00\x00\x00WAVEjunk" * 10)
    with pytest.raises(PuppetError, match="corrupt.wav"):
        FilePlayer(tmp_path / "corrupt.wav")
    with pytest.raises(PuppetError, match="silent"):
        FilePlayer(write_wav(tmp_path / "silence.wav", np.zeros(1600, np.float32)))


def test_list_devices():
    fake = FakeSoundDevice(inputs=[("Built-in Microphone", 44100.0), ("HD Webcam C920", 16000.0)],
                           outputs=[("Speakers", 48000.0)])
    lines = capture.list_devices(fake).splitlines()
    assert len(lines) == 3  # a heading, two inputs; no speakers
    assert lines[1].startswith("*") and "Built-in Microphone" in lines[1] and "44100 Hz" in lines[1]
    assert "HD Webcam C920" in lines[2] and not lines[2].startswith("*") and " 1  " in lines[2]

    text = capture.list_devices(FakeSoundDevice(inputs=[], outputs=[("Speakers", 48000.0)]))
    assert text.startswith("no audio input devices found") and "\n" not in text

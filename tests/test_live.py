import json
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import x_env

from puppet import audio, features, live, settings
from puppet.capture import Chunk
from puppet.landmarks import face_scale
from puppet.lipsync import shipped_predictor
from puppet.live import Controls, LipSync, LiveOptions, LivePuppet, Stats, VoiceGate
from puppet.settings import LiveSettings
from puppet.window import Event, Offscreen

RATE = features.SAMPLE_RATE
BLOCK = 80  # 5 ms, as the microphone delivers it


def tone(seconds, level=0.1, hz=220.0):
    t = np.arange(int(seconds * RATE)) / RATE
    return (level * np.sin(2 * np.pi * hz * t)).astype(np.float32)


def blocks(samples, start=100.0):
    """(chunk, capture time of its last sample) as a microphone would hand them over."""
    for begin in range(0, len(samples), BLOCK):
        piece = samples[begin : begin + BLOCK]
        yield Chunk(piece, start + (begin + len(piece) - 1) / RATE, 0), start + (begin + len(piece)) / RATE


def lip_gap(positions, rest):
    """Inner-lip opening (62 to 66) in inter-ocular distances."""
    return float(np.linalg.norm(positions[66] - positions[62]) / face_scale(rest))


@pytest.fixture(scope="module")
def speech():
    from puppet.bundle import demo_files

    return audio.load(demo_files()[2])


def test_the_gate_passes_voice_holds_over_pauses_and_silences_noise_and_mute():
    gate = VoiceGate(LiveSettings(gate_db=-40.0))
    loud = gate(tone(0.2, 0.1), True)
    assert np.abs(loud[-800:]).max() > 0.09
    hold = gate(tone(0.1, 0.001), True)  # -60 dB right after speech: still open (word endings)
    assert np.abs(hold[-400:]).max() > 0.0009
    later = gate(tone(0.5, 0.001), True)  # after the hold the gate closes
    assert np.abs(later[-800:]).max() < 1e-5
    muted = gate(tone(0.3, 0.1), False)
    assert np.abs(muted[-800:]).max() < 1e-5


def test_sensitivity_is_a_gain_in_decibels():
    plain = VoiceGate(LiveSettings(gate_db=-90.0))(tone(0.3), True)
    louder = VoiceGate(LiveSettings(gate_db=-90.0, sensitivity_db=6.0))(tone(0.3), True)
    assert np.abs(louder[-1000:]).max() / np.abs(plain[-1000:]).max() == pytest.approx(10 ** (6 / 20), rel=1e-3)


def test_speech_frames_are_stamped_with_the_moment_they_depict(speech, demo):
    lips = LipSync(shipped_predictor("streaming"), demo.rig.landmarks)
    for chunk, now in blocks(speech[: 2 * RATE]):
        lips.hear(chunk.samples, chunk.end_time)
        delay = lips.delay(now)
    step = features.FRAMES_PER_MOTION * features.HOP
    first = lips.emitted - len(lips.times)
    expected = 100.0 + (step * np.arange(first, lips.emitted) + step // 2) / RATE
    np.testing.assert_allclose(list(lips.times), expected, atol=1e-9)
    lookahead = live.lookahead_seconds(shipped_predictor("streaming"))
    assert lookahead == pytest.approx(0.0725)
    assert lookahead <= delay <= lookahead + 0.03  # frames come every 20 ms, audio every 5


def test_the_mouth_moves_with_speech_and_rests_in_silence(speech, demo):
    puppet = LivePuppet(demo, LiveSettings(blink_rate=0.0), shipped_predictor("streaming"))
    rest = demo.rig.landmarks
    clip = np.concatenate([speech[: 3 * RATE], np.zeros(RATE, np.float32)])
    gaps = []
    for chunk, now in blocks(clip, start=puppet.start):
        puppet.hear(chunk, True)
        gaps.append(lip_gap(puppet.pose(now)[0], rest))
    gaps = np.asarray(gaps)
    talking, silent = gaps[RATE // BLOCK // 2 : 3 * RATE // BLOCK], gaps[-RATE // BLOCK // 2 :]
    rest_gap = lip_gap(rest, rest)
    assert talking.max() > rest_gap + 0.15
    assert np.abs(silent - rest_gap).max() < 0.03
    puppet.close()


def fan(seconds, level_db, seed=0):
    """Brown noise (a fan, a room) at level_db dBFS."""
    from scipy.signal import lfilter

    noise = lfilter([1.0], [1.0, -0.95], np.random.default_rng(seed).normal(size=int(seconds * RATE)))
    return (noise / np.sqrt(np.mean(noise**2)) * 10 ** (level_db / 20)).astype(np.float32)


def test_the_gate_rises_above_the_rooms_noise_and_still_passes_the_voice():
    gate = VoiceGate(LiveSettings(gate_db=-50.0))
    assert gate.threshold_db == -50.0  # nothing heard yet: the user's gate
    noise = np.concatenate([gate(piece, True) for piece in np.split(fan(3.0, -40.0), 60)])  # 50 ms pieces
    assert gate.threshold_db == pytest.approx(gate.floor_db + live.NOISE_MARGIN_DB) and -45 < gate.floor_db < -40
    assert np.abs(noise[-RATE:]).max() < 1e-5  # the fan alone no longer opens the gate
    voice = gate(tone(0.5, 0.1) + fan(0.5, -40.0, seed=1), True)  # a voice 23 dB over the fan
    assert np.abs(voice[-800:]).max() > 0.09
    quiet = VoiceGate(LiveSettings(gate_db=-50.0))
    quiet(fan(3.0, -80.0), True)
    assert quiet.threshold_db == -50.0  # a quiet room keeps the user's gate


def test_the_mouth_rests_while_a_fan_runs_and_moves_when_spoken_over(speech, demo):
    puppet = LivePuppet(demo, LiveSettings(blink_rate=0.0), shipped_predictor("streaming"))
    rest = demo.rig.landmarks
    clip = fan(6.0, -40.0)
    clip[3 * RATE :] += speech[: 3 * RATE] * (10 ** (-15 / 20) / np.sqrt(np.mean(speech[: 3 * RATE] ** 2)))  # speech at -15 dBFS
    gaps = []
    for chunk, now in blocks(clip, start=puppet.start):
        puppet.hear(chunk, True)
        gaps.append(lip_gap(puppet.pose(now)[0], rest))
    gaps, per_second = np.asarray(gaps) - lip_gap(rest, rest), RATE // BLOCK
    assert np.abs(gaps[int(1.5 * per_second) : 3 * per_second]).mean() < 0.02  # the fan alone, once the floor is known (was 0.06)
    assert gaps[int(3.5 * per_second) :].max() > 0.15  # talking over it
    puppet.close()


def test_muted_voice_leaves_the_mouth_at_rest(speech, demo):
    puppet = LivePuppet(demo, LiveSettings(blink_rate=0.0), shipped_predictor("streaming"))
    rest = demo.rig.landmarks
    gaps = []
    for chunk, now in blocks(speech[: 2 * RATE], start=puppet.start):
        puppet.hear(chunk, False)
        gaps.append(lip_gap(puppet.pose(now)[0], rest))
    assert np.abs(np.asarray(gaps) - lip_gap(rest, rest)).max() < 0.03
    puppet.close()


def test_a_hotkey_changes_the_expression(demo):
    controls = Controls(LiveSettings())
    puppet = LivePuppet(demo, controls.settings, shipped_predictor("streaming"))
    before = puppet.pose(puppet.start + 0.5)[0]
    assert controls.handle(Event("key", "2"))
    assert controls.settings.expression == "happy"
    puppet.apply(controls.settings)
    after = puppet.pose(puppet.start + 1.5)[0]
    corners = [48, 54]
    assert (before[corners, 1] - after[corners, 1]).mean() > 0.03 * face_scale(demo.rig.landmarks)  # corners rose
    puppet.close()


def test_controls_mute_push_to_talk_and_steps():
    controls = Controls(LiveSettings())
    assert controls.talking
    controls.handle(Event("key", "m"))
    assert not controls.talking
    controls.handle(Event("key", "m"))
    assert controls.handle(Event("key", "t")) and not controls.talking
    controls.handle(Event("key", "space"))
    assert controls.talking
    controls.handle(Event("release", "space"))
    assert not controls.talking
    controls.handle(Event("key", "="))
    controls.handle(Event("key", "]"))
    assert controls.settings.sensitivity_db == live.SENSITIVITY_STEP and controls.settings.gate_db == -50 + live.GATE_STEP
    controls.handle(Event("key", "h"))
    assert any("push-to-talk" in line for line in controls.lines(None, Stats(60.0), VoiceGate(controls.settings)))
    controls.handle(Event("key", "escape"))
    assert controls.quit


def test_stats_count_fps_latency_and_dropped_frames():
    stats = Stats(30.0)
    times = list(np.arange(60) / 30.0)
    del times[30:32]  # two frames missed
    for t in times:
        stats.add(t, 0.08 + 0.01 * (t > 0.9), 0.004)
    summary = stats.summary()
    assert summary["dropped_frames"] == 2
    assert summary["fps"] == pytest.approx(57 / (59 / 30), rel=1e-3)
    assert summary["latency_ms_p50"] == pytest.approx(90, abs=0.1) and summary["latency_ms_p95"] == pytest.approx(90, abs=0.1)
    assert summary["obs_audio_delay_ms"] in (80, 90)


def test_the_loop_renders_at_the_target_rate_with_bounded_latency(gl, demo, demo_speech, tmp_path):
    from fake_devices import register_fake_camera

    from puppet.camera import VirtualCamera
    from puppet.capture import FilePlayer

    backend = register_fake_camera()
    camera = VirtualCamera((128, 160), 15.0, (0, 177, 64), backend="fake")
    display = Offscreen(gl, (160, 200))
    source = FilePlayer(demo_speech, playback=False)
    path = tmp_path / "live.json"
    display.events.append(Event("key", "3"))  # angry: saved with the puppet
    stats = live.run(demo, source, display, LiveOptions(size=(128, 160), fps=30.0, duration=2.5), LiveSettings(), camera, path)
    camera.close()
    summary = stats.summary()
    assert 26 <= summary["fps"] <= 31
    assert summary["dropped_frames"] <= 3
    lookahead_ms = 1000 * live.lookahead_seconds(shipped_predictor("streaming"))
    assert lookahead_ms < summary["latency_ms_p50"] <= summary["latency_ms_p95"] < 140
    assert settings.load(path).expression == "angry"
    sent = backend.instances[-1]
    assert 30 <= sent.frames <= 40 and sent.last_frame.shape == (160, 128, 3)  # 2.5 s at the camera's 15 fps
    assert tuple(sent.last_frame[0, 0]) == (0, 177, 64)  # the key colour where the portrait is transparent
    assert np.abs(display.canvas.read()[..., 3].astype(int)).max() == 255  # the puppet was drawn


def run_cli(*args, env=None):
    return subprocess.run([sys.executable, "-m", "puppet", *args], capture_output=True, text=True, env=env, timeout=120, check=False)


def test_live_in_a_window_writes_sane_stats(xvfb, demo_speech, tmp_path):
    env = x_env(xvfb)
    stats = tmp_path / "stats.json"
    result = run_cli("live", "--demo", "--audio", str(demo_speech), "--no-playback", "--duration", "3", "--fps", "30",
                     "--size", "320", "--stats", str(stats), "--show-stats", env=env)
    assert result.returncode == 0, result.stderr
    summary = json.loads(stats.read_text())
    for key in ("fps", "latency_ms_p50", "latency_ms_p95", "dropped_frames"):
        assert math.isfinite(summary[key]), key
    assert 25 <= summary["fps"] <= 31 and summary["dropped_frames"] <= 5
    assert 60 < summary["latency_ms_p50"] <= summary["latency_ms_p95"] < 150
    again = run_cli("live", "--demo", "--audio", str(demo_speech), "--duration", "1", "--stats", str(stats), env=env)
    assert again.returncode == 2 and "--force" in again.stderr and len(again.stderr.strip().splitlines()) == 1


def test_live_refuses_bad_input_with_one_line(tmp_path):
    for args in (["live"], ["live", "--demo", "--audio", str(tmp_path / "missing.wav"), "--no-window"],
                 ["live", "--demo", "--loop"], ["live", str(tmp_path / "nope.png")]):
        result = run_cli(*args)
        assert result.returncode == 2, (args, result.stderr)
        assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr


def test_no_virtual_camera_says_what_to_install(demo_speech):
    result = run_cli("live", "--demo", "--audio", str(demo_speech), "--no-window", "--virtual-camera", "--duration", "1")
    assert result.returncode == 2
    assert "v4l2loopback" in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_list_devices_runs_without_any_device():
    result = run_cli("live", "--list-devices")
    assert result.returncode in (0, 2) and "Traceback" not in result.stderr


class ShrinkingOffscreen(Offscreen):
    """An offscreen display that is 'minimized' (size 0) for a while, then restored larger."""

    def __init__(self, ctx, clock):
        super().__init__(ctx, (120, 150))
        self.clock = clock
        self.seen = set()

    @property
    def size(self):
        elapsed = time.perf_counter() - self.clock
        size = (120, 150) if elapsed < 0.4 else (0, 0) if elapsed < 0.8 else (100, 120)
        self.seen.add(size)
        return size

    @size.setter
    def size(self, value):
        pass


def test_the_loop_survives_a_lost_microphone_and_a_minimized_window(gl, demo, monkeypatch):
    import threading

    from fake_devices import FakeSoundDevice

    from puppet.capture import Microphone

    monkeypatch.setattr(Microphone, "STALL_SECONDS", 0.1)
    monkeypatch.setattr(Microphone, "RETRY_SECONDS", 0.1)
    fake = FakeSoundDevice(signal=tone(1.0, 0.2))
    mic = Microphone(backend=fake)
    statuses = []
    threading.Timer(0.3, fake.unplug).start()
    threading.Timer(0.8, fake.replug).start()
    display = ShrinkingOffscreen(gl, time.perf_counter())
    original = Controls.lines

    def spy(self, status, stats, level):
        statuses.append(status)
        return original(self, status, stats, level)

    monkeypatch.setattr(Controls, "lines", spy)
    stats = live.run(demo, mic, display, LiveOptions(size=(100, 120), fps=30.0, duration=1.6), LiveSettings())
    assert any(s and s.startswith("microphone lost") for s in statuses)
    assert statuses[-1] is None  # found again
    assert {(0, 0), (100, 120)} <= display.seen
    assert stats.frames > 20 and stats.summary()["latency_ms_p95"] < 400


WINDOW_SCRIPT = """
import sys
from pathlib import Path

import glfw
import numpy as np

from puppet import bundle, live, settings
from puppet.capture import FilePlayer
from puppet.live import LiveOptions
from puppet.renderer import Background, PuppetRenderer
from puppet.settings import LiveSettings
from puppet.window import Event, Window

image, landmarks, speech = bundle.demo_files()
demo = bundle.load(image, landmarks)
window = Window("test", (200, 240))
renderer = PuppetRenderer(window.ctx, demo.image, demo.rig)
glfw.set_window_size(window.handle, 160, 180)
glfw.poll_events()
assert window.size == (160, 180), window.size
window.begin(Background((0, 0, 0, 1)))
renderer.draw(demo.rig.vertices[:, :2], window.size)
pixels = np.frombuffer(window.ctx.screen.read(viewport=(0, 0, 160, 180), components=3), np.uint8)
assert pixels.max() > 200, "nothing drawn at the new size"
window.present()
window.events += [Event("key", "4"), Event("key", "f")]
path = Path(sys.argv[1])
stats = live.run(demo, FilePlayer(speech, playback=False), window, LiveOptions(size=(160, 180), fps=30.0, duration=1.0), LiveSettings(), None, path)
window.close()
assert stats.frames > 20, stats.frames
saved = settings.load(path)
assert saved.expression == "surprised" and saved.show_stats, saved
print("ok")
"""


def test_a_real_window_takes_hotkeys_and_resizes(xvfb, tmp_path):
    # Its own process: a GLX window cannot share a process with the tests' EGL context.
    env = x_env(xvfb)
    result = subprocess.run([sys.executable, "-c", WINDOW_SCRIPT, str(tmp_path / "live.json")],
                            capture_output=True, text=True, env=env, timeout=120, check=False)
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr


def test_without_a_display_says_to_use_no_window(demo_speech):
    env = {key: value for key, value in os.environ.items() if key not in ("DISPLAY", "WAYLAND_DISPLAY")}
    result = run_cli("live", "--demo", "--audio", str(demo_speech), "--duration", "1", env=env)
    assert result.returncode == 2 and "--no-window" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_the_voice_is_learned_from_speech_not_from_silence(speech, demo):
    puppet = LivePuppet(demo, LiveSettings(), shipped_predictor("streaming"))
    for chunk, _ in blocks(np.zeros(4 * RATE, np.float32), start=puppet.start):
        puppet.hear(chunk, True)
    assert puppet.voice.seconds == 0
    for chunk, _ in blocks(speech[: 7 * RATE], start=puppet.start + 4):
        puppet.hear(chunk, True)
    assert live.VOICE_SECONDS[0] < puppet.voice.seconds <= 7.0
    if puppet.voice.job is not None:
        puppet.voice.job.result(timeout=30)
    puppet.hear(Chunk(np.zeros(BLOCK, np.float32), puppet.start + 12, 0), True)
    assert not np.allclose(puppet.lips.stream.speaker, live.neutral_voice())  # the stream now knows this voice
    puppet.close()

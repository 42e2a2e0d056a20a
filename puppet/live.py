"""Live: a microphone (or a file played in sync) → streaming lip sync → the puppet at display rate.

One frame of the loop (`run`), top to bottom:
    input events → new audio from the source → voice gate (sensitivity, noise gate, mute,
    push-to-talk) → the streaming predictor → speech frames, each stamped with the capture time
    of the moment of voice it depicts → the moment to show, `now − delay` → speech interpolated
    there, plus life (blinks, sway, breathing) and the expression → rig → render (virtual camera,
    then window) → present → stats.

Timing. A speech frame depicts the voice at its centre, but the network must hear LOOKAHEAD
seconds past it (72.5 ms with the shipped model) before it can emit it, and frames come 20 ms
apart. The loop shows the moment `now − delay`, with `delay` the median age of the newest speech
frame over the last two seconds (never below LOOKAHEAD + 10 ms): the picture then trails the voice
by a constant amount, the number to type into OBS's audio delay, and a moment up to
MAX_EXTRAPOLATION past the newest frame is extrapolated from the last two. A frame's latency is
the time it is presented minus the capture time of the voice it shows, which is the capture time
of the newest audio sample that shaped it plus the lookahead.
"""
import functools
import json
import math
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from puppet import audio, features
from puppet import settings as saved
from puppet.bundle import Puppet, demo_files
from puppet.capture import AudioSource, Chunk
from puppet.expression import EXPRESSIONS, ExpressionBlend
from puppet.landmarks import face_scale, from_face_units
from puppet.life import Life, LifeOptions
from puppet.motion import Motion
from puppet.predictor import Predictor
from puppet.renderer import Background, Canvas, PuppetRenderer
from puppet.settings import LiveSettings
from puppet.speaker import MAX_VOICE_SECONDS, embed
from puppet.window import Event, TextOverlay

MAX_EXTRAPOLATION = 0.02  # seconds past the newest speech frame the loop may extrapolate
DELAY_WINDOW = 2.0  # seconds of newest-frame ages the delay is the median of
QUIET_AFTER = 0.15  # with no speech frame this long past the newest, the mouth eases to rest over as long again
VOICE_SECONDS = (3.0, MAX_VOICE_SECONDS)  # seconds of heard voice after which the speaker embedding is (re)computed
ENVELOPE_SECONDS = 0.01  # time constant of the gate's level detector
GATE_HOLD = 0.25  # seconds the gate stays open after the voice drops below it (word endings, short pauses)
GATE_FADE = 0.005  # time constant of the gate opening and closing (no clicks)
# The room's noise (a fan, a hum, traffic) lifts the gate: it opens only NOISE_MARGIN_DB above the
# noise floor, the NOISE_PERCENTILE of the levels of the last NOISE_WINDOW seconds in NOISE_BLOCK blocks
# (between words and phrases the level falls to it), once NOISE_MIN_SECONDS have been heard.
NOISE_BLOCK = 0.05
NOISE_WINDOW = 8.0
NOISE_PERCENTILE = 10
NOISE_MARGIN_DB = 6.0
NOISE_MIN_SECONDS = 1.0
JAW_ACTIVITY = 0.25  # inter-ocular distances of lower-lip drop that count as fully active (livelier sway)
SENSITIVITY_STEP = 3.0  # dB per key press
GATE_STEP = 5.0
BLINK_STEP = 5.0  # blinks per minute per key press
NOTICE_SECONDS = 2.0  # how long a changed setting shows in the window

KEYS = (
    ("H", "show or hide these keys"),
    ("1-5", "expression: " + ", ".join(EXPRESSIONS)),
    ("M", "mute / unmute the microphone"),
    ("T", "push-to-talk on / off (then hold Space to talk)"),
    ("+ / -", f"sensitivity up / down ({SENSITIVITY_STEP:g} dB)"),
    ("] / [", f"noise gate up / down ({GATE_STEP:g} dB; it also rises above the room's noise)"),
    (". / ,", "more / fewer blinks"),
    ("F", "fps and latency readout"),
    ("Esc, Q", "quit"),
)


@dataclass(frozen=True)
class LiveOptions:
    size: tuple[int, int] = (640, 720)  # window and virtual camera (width, height) in pixels
    fps: float | None = None  # frames per second; None: the display's refresh rate
    background: Background = field(default_factory=Background)  # transparent where the window allows, else `key`
    key: tuple[float, float, float] = (0.0, 177 / 255, 64 / 255)  # RGB 0-1 shown instead of transparency (chroma green)
    samples: int = 0  # MSAA samples
    duration: float | None = None  # stop after this many seconds; None: at the end of a file, or never for a microphone
    seed: int = 0  # blinks and idle sway


def lookahead_seconds(predictor: Predictor) -> float:
    """From the moment a speech frame depicts (its centre) to the newest audio sample the network
    needs before it can emit that frame: 72.5 ms with the shipped model."""
    step = features.FRAMES_PER_MOTION * features.HOP
    return (step * predictor.lookahead + features.WINDOW // 2) / features.SAMPLE_RATE


@functools.cache
def neutral_voice() -> np.ndarray:
    """(256,) float32: the speaker embedding used until the live voice has been heard (the demo's)."""
    return embed(audio.load(demo_files()[2]))


class VoiceGate:
    """Sensitivity, noise gate, mute and push-to-talk on a 16 kHz stream, state carried across chunks.

    The level is a one-pole power envelope (ENVELOPE_SECONDS); the gate opens while it is above
    `threshold_db` (after the sensitivity gain) and stays open GATE_HOLD seconds after; its gain fades
    over GATE_FADE so nothing clicks. A closed gate hands the predictor silence, so the mouth rests.
    The threshold is the user's `gate_db`, raised to NOISE_MARGIN_DB above the room's noise floor
    where that is louder: the network opens the mouth on steady noise as it does on speech.
    """

    def __init__(self, settings: LiveSettings):
        self.settings = settings
        self.envelope = 1.0 - math.exp(-1.0 / (ENVELOPE_SECONDS * features.SAMPLE_RATE))
        self.fade = 1.0 - math.exp(-1.0 / (GATE_FADE * features.SAMPLE_RATE))
        self.power_state = np.zeros(1)
        self.gain_state = np.zeros(1)
        self.samples_seen = 0
        self.last_open = -10**12  # sample index at which the level was last above the gate
        self.level_db = -120.0  # level of the latest chunk after the gain (for the readout)
        self.block = int(NOISE_BLOCK * features.SAMPLE_RATE)
        self.block_levels: deque[float] = deque(maxlen=round(NOISE_WINDOW / NOISE_BLOCK))  # dB
        self.pending = np.zeros(0)  # envelope power of a block not yet complete
        self.floor_db = -120.0  # the room's noise floor, after the gain

    @property
    def threshold_db(self) -> float:
        """The level (dBFS, after the gain) above which the gate opens."""
        return max(self.settings.gate_db, self.floor_db + NOISE_MARGIN_DB)

    def __call__(self, samples: np.ndarray, allowed: bool) -> np.ndarray:
        """(n,) float32 16 kHz → (n,) float32: gained, gated; all silence when not `allowed` (muted)."""
        if len(samples) == 0:
            return samples
        gained = samples.astype(np.float64) * 10 ** (self.settings.sensitivity_db / 20)
        power, self.power_state = lfilter([self.envelope], [1.0, self.envelope - 1.0], gained**2, zi=self.power_state)
        self.level_db = 10 * math.log10(max(float(power[-1]), 1e-12))
        index = self.samples_seen + np.arange(len(samples))
        above = np.where(power > 10 ** (self.threshold_db / 10), index, -(10**12))
        self._track_floor(power)
        last_open = np.maximum.accumulate(np.maximum(above, self.last_open))
        self.last_open = int(last_open[-1])
        self.samples_seen += len(samples)
        target = ((index - last_open) <= GATE_HOLD * features.SAMPLE_RATE) & allowed
        gain, self.gain_state = lfilter([self.fade], [1.0, self.fade - 1.0], target.astype(np.float64), zi=self.gain_state)
        return np.clip(gained * gain, -1.0, 1.0).astype(np.float32)

    def _track_floor(self, power: np.ndarray) -> None:
        """Add the envelope power of new samples to the noise-floor blocks and update floor_db."""
        power = np.concatenate([self.pending, power])
        whole = len(power) // self.block * self.block
        self.pending = power[whole:]
        if whole == 0:
            return
        self.block_levels.extend(10 * np.log10(power[:whole].reshape(-1, self.block).mean(axis=1) + 1e-12))
        if len(self.block_levels) * NOISE_BLOCK >= NOISE_MIN_SECONDS:
            self.floor_db = float(np.percentile(self.block_levels, NOISE_PERCENTILE))


class LipSync:
    """The streaming predictor with clock times: speech frames stamped with the capture time of
    the moment they depict, interpolated at any time the window asks for."""

    def __init__(self, predictor: Predictor, rest: np.ndarray):
        """rest: (68, 3) float32 rest landmarks, image pixels."""
        self.predictor = predictor
        self.rest = rest
        self.stream = predictor.stream(neutral_voice())
        self.lookahead = lookahead_seconds(predictor)
        self.samples = 0  # samples pushed
        self.emitted = 0  # speech frames emitted
        self.times: deque[float] = deque(maxlen=8)  # capture time of the moment each recent frame depicts
        self.offsets: deque[np.ndarray] = deque(maxlen=8)  # (68, 3) face units
        self.rotation: deque[np.ndarray] = deque(maxlen=8)  # (3,) radians
        self.ages: deque[tuple[float, float]] = deque()  # (clock time, age of the newest frame then)
        self.newest_sample = math.nan  # capture time of the newest sample pushed

    def hear(self, samples: np.ndarray, end_time: float) -> None:
        """Push (n,) float32 16 kHz samples whose last one was captured at `end_time` (perf_counter)."""
        if len(samples) == 0:
            return
        offsets, rotation = self.stream.push(samples)
        self.samples += len(samples)
        self.newest_sample = end_time
        step = features.FRAMES_PER_MOTION * features.HOP
        for frame_offsets, frame_rotation in zip(offsets, rotation):
            centre = step * self.emitted + step // 2  # sample index of the moment this frame depicts
            self.times.append(end_time - (self.samples - 1 - centre) / features.SAMPLE_RATE)
            self.offsets.append(frame_offsets)
            self.rotation.append(frame_rotation)
            self.emitted += 1

    def delay(self, now: float) -> float:
        """Seconds the shown moment trails the clock: the median age of the newest frame lately."""
        if self.times:
            self.ages.append((now, now - self.times[-1]))
        while self.ages and self.ages[0][0] < now - DELAY_WINDOW:
            self.ages.popleft()
        floor = self.lookahead + 0.5 / features.MOTION_FPS
        return max(floor, float(np.median([age for _, age in self.ages]))) if self.ages else floor

    def at(self, moment: float) -> tuple[np.ndarray, np.ndarray]:
        """Offsets (68, 3) float32 pixels (head frame) and rotation (3,) radians of the voice at
        `moment` (perf_counter time of capture); at rest before any speech and after it stops."""
        if not self.times:
            return np.zeros((len(self.rest), 3), np.float32), np.zeros(3, np.float32)
        times = np.asarray(self.times)
        offsets, rotation = np.asarray(self.offsets), np.asarray(self.rotation)
        if moment <= times[0] or len(times) == 1:
            o, r = offsets[0 if moment <= times[0] else -1], rotation[0 if moment <= times[0] else -1]
        else:
            k = min(int(np.searchsorted(times, moment)), len(times) - 1)  # times[k-1] < moment <= times[k], or past the end
            share = (min(moment, times[-1] + MAX_EXTRAPOLATION) - times[k - 1]) / (times[k] - times[k - 1])
            o = offsets[k - 1] + share * (offsets[k] - offsets[k - 1])
            r = rotation[k - 1] + share * (rotation[k] - rotation[k - 1])
        quiet = min(max((moment - times[-1] - QUIET_AFTER) / QUIET_AFTER, 0.0), 1.0)  # no audio lately: ease to rest
        pixels = from_face_units(o[None] * (1.0 - quiet), self.rest)[0]
        return pixels, (r * (1.0 - quiet)).astype(np.float32)


class VoiceLearner:
    """Learns who is speaking: the gated voice is collected and, after each of VOICE_SECONDS, embedded
    on a worker thread; the stream's speaker embedding is swapped when the result is in."""

    def __init__(self, stream):
        self.stream = stream
        self.heard: list[np.ndarray] = []
        self.seconds = 0.0
        self.pending = list(VOICE_SECONDS)
        self.worker = ThreadPoolExecutor(max_workers=1)
        self.job = None

    def hear(self, voice: np.ndarray) -> None:
        """voice: (n,) float32 16 kHz samples heard above the noise gate."""
        if self.job is not None and self.job.done():
            self.stream.speaker = self.job.result()
            self.job = None
        if not self.pending or len(voice) == 0:
            return
        self.heard.append(voice)
        self.seconds += len(voice) / features.SAMPLE_RATE
        if self.seconds >= self.pending[0] and self.job is None:
            self.pending.pop(0)
            self.job = self.worker.submit(embed, np.concatenate(self.heard))
            if not self.pending:
                self.heard = []

    def close(self) -> None:
        self.worker.shutdown(wait=False, cancel_futures=True)


class LivePuppet:
    """Everything that moves the puppet live: voice → lip sync, life and expression → mesh positions."""

    def __init__(self, puppet: Puppet, settings: LiveSettings, predictor: Predictor, seed: int = 0):
        self.puppet = puppet
        self.rest = puppet.rig.landmarks
        self.iod = face_scale(self.rest)
        self.seed = seed
        self.gate = VoiceGate(settings)
        self.lips = LipSync(predictor, self.rest)
        self.voice = VoiceLearner(self.lips.stream)
        self.expression = ExpressionBlend(self.rest, settings.expression)
        self.start = time.perf_counter()
        self.life: Life | None = None
        self.voice_until = -math.inf  # capture time until which the gate let the voice through
        self.apply(settings)

    def apply(self, settings: LiveSettings) -> None:
        """Take new settings (from a hotkey or the command line)."""
        self.settings = settings
        self.gate.settings = settings
        self.expression.choose(settings.expression)
        life = LifeOptions(blink_rate=settings.blink_rate, blink_randomness=settings.blink_randomness,
                           idle_degrees=settings.idle_degrees, seed=self.seed)
        previous, self.life = self.life, Life(self.rest, life)
        if previous is not None:  # keep the sway's smoothing; blinks are rescheduled from now on
            self.life.activity, self.life.last_time = previous.activity, previous.last_time

    def hear(self, chunk: Chunk, talking: bool) -> None:
        """New audio from the source; `talking` is False while muted or push-to-talk is released."""
        voice = self.gate(chunk.samples, talking)
        if talking and self.gate.level_db > self.gate.threshold_db:  # only speech teaches who is speaking
            self.voice.hear(voice)
        self.lips.hear(voice, chunk.end_time)
        if len(voice):  # until when (capture time) the gate lets the voice through
            heard_last = chunk.end_time - (self.gate.samples_seen - 1 - self.gate.last_open) / features.SAMPLE_RATE
            self.voice_until = heard_last + GATE_HOLD if talking else min(self.voice_until, chunk.end_time)

    def pose(self, now: float) -> tuple[np.ndarray, float]:
        """(N, 2) float32 mesh positions (image pixels) to present at about `now` (perf_counter),
        and the capture time of the moment of voice they show."""
        moment = now - self.lips.delay(now)
        offsets, rotation = self.lips.at(moment)
        offsets = offsets * (1.0 - min(max((moment - self.voice_until) / QUIET_AFTER, 0.0), 1.0))  # gate shut: the mouth rests
        activity = min(abs(float(offsets[57, 1])) / (JAW_ACTIVITY * self.iod), 1.0)
        life = self.life.motion(np.array([now - self.start]), features.MOTION_FPS, np.array([activity]), snap_blinks=False)
        motion = Motion(
            offsets=(offsets + self.expression.offsets(now))[None] + life.offsets,
            rotation=rotation[None] + life.rotation,
            translation=life.translation,
            fps=features.MOTION_FPS,
        )
        return self.puppet.rig.animate(motion)[0], moment

    def close(self) -> None:
        self.voice.close()


class Stats:
    """What the loop measures, in constant memory however long it runs: frame count, missed display
    slots, and histograms (0.1 ms bins) of latency and per-frame work; the last two seconds are
    kept whole for the window's readout."""

    BIN = 1e-4  # seconds per histogram bin
    BINS = 20000  # up to 2 s; longer values land in the last bin

    def __init__(self, target_fps: float):
        self.target_fps = target_fps
        self.frames = 0
        self.first = self.last = math.nan  # perf_counter of the first and latest presented frame
        self.dropped = 0  # display slots missed
        self.latency = np.zeros(self.BINS, np.int64)  # seconds from the voice's capture to presentation
        self.work = np.zeros(self.BINS, np.int64)  # seconds from the start of a frame's work to presentation
        self.recent: deque[tuple[float, float]] = deque()  # (presented, latency) over the last 2 s
        self.audio_dropped = 0  # samples the ring buffer lost (the loop fell behind the audio)

    def add(self, presented: float, latency: float, work: float) -> None:
        if self.frames:
            gap = (presented - self.last) * self.target_fps
            self.dropped += max(round(gap) - 1, 0) if gap > 1.5 else 0
        else:
            self.first = presented
        self.frames += 1
        self.last = presented
        self.latency[min(max(int(latency / self.BIN), 0), self.BINS - 1)] += 1
        self.work[min(max(int(work / self.BIN), 0), self.BINS - 1)] += 1
        self.recent.append((presented, latency))
        while self.recent[0][0] < presented - 2.0:
            self.recent.popleft()

    @classmethod
    def _percentile(cls, histogram: np.ndarray, share: float) -> float:
        """Milliseconds below which `share` of the values fall (bin centres)."""
        cumulative = np.cumsum(histogram)
        if cumulative[-1] == 0:
            return 0.0
        return (int(np.searchsorted(cumulative, share * cumulative[-1])) + 0.5) * cls.BIN * 1000

    def summary(self) -> dict:
        """The `--stats` JSON object."""
        span = self.last - self.first if self.frames > 1 else 0.0
        p50 = self._percentile(self.latency, 0.5)
        return {
            "fps": round((self.frames - 1) / span, 2) if span > 0 else 0.0,
            "target_fps": round(self.target_fps, 2),
            "latency_ms_p50": round(p50, 1),
            "latency_ms_p95": round(self._percentile(self.latency, 0.95), 1),
            "dropped_frames": self.dropped,
            "frames": self.frames,
            "seconds": round(span, 2),
            "frame_work_ms_p50": round(self._percentile(self.work, 0.5), 2),
            "frame_work_ms_p95": round(self._percentile(self.work, 0.95), 2),
            "audio_dropped_samples": self.audio_dropped,
            "obs_audio_delay_ms": int(round(p50 / 10) * 10),
        }

    def readout(self) -> str:
        """One line for the window: fps and latency over the last two seconds."""
        if len(self.recent) < 2:
            return "measuring..."
        fps = (len(self.recent) - 1) / (self.recent[-1][0] - self.recent[0][0])
        latency = np.array([value for _, value in self.recent]) * 1000
        median = float(np.median(latency))
        return f"{fps:.0f} fps   latency {median:.0f} ms (p95 {np.percentile(latency, 95):.0f})   OBS audio delay {round(median / 10) * 10:.0f} ms"


class Controls:
    """Hotkeys → settings, mute and push-to-talk; remembers what to tell the user."""

    def __init__(self, settings: LiveSettings):
        self.settings = settings
        self.muted = False
        self.space_held = False
        self.show_help = False
        self.quit = False
        self.notice = ("press H for keys", time.perf_counter())

    @property
    def talking(self) -> bool:
        return not self.muted and (self.space_held or not self.settings.push_to_talk)

    def handle(self, event: Event) -> bool:
        """Apply one input event; True when the saved settings changed."""
        if event.key == "space":
            self.space_held = event.kind == "key"
            return False
        if event.kind != "key":
            return False
        s, key = self.settings, event.key
        names = list(EXPRESSIONS)
        changes = {
            "+": {"sensitivity_db": s.sensitivity_db + SENSITIVITY_STEP},
            "=": {"sensitivity_db": s.sensitivity_db + SENSITIVITY_STEP},
            "-": {"sensitivity_db": s.sensitivity_db - SENSITIVITY_STEP},
            "]": {"gate_db": s.gate_db + GATE_STEP},
            "[": {"gate_db": s.gate_db - GATE_STEP},
            ".": {"blink_rate": s.blink_rate + BLINK_STEP},
            ",": {"blink_rate": s.blink_rate - BLINK_STEP},
            "t": {"push_to_talk": not s.push_to_talk},
            "f": {"show_stats": not s.show_stats},
        }
        if key.isdigit() and 1 <= int(key) <= len(names):
            changes[key] = {"expression": names[int(key) - 1]}
        if key in ("escape", "q"):
            self.quit = True
        elif key in ("h", "f1"):
            self.show_help = not self.show_help
        elif key == "m":
            self.muted = not self.muted
            self.tell("muted" if self.muted else "microphone on")
        elif key in changes:
            self.settings = replace(s, **changes[key]).clamped()
            self.tell(describe(key, self.settings))
            return True
        return False

    def tell(self, text: str) -> None:
        self.notice = (text, time.perf_counter())

    def lines(self, status: str | None, stats: Stats, gate: VoiceGate) -> list[str]:
        """The overlay's text this frame."""
        lines = [f"{key:8s} {action}" for key, action in KEYS] if self.show_help else []
        if self.settings.show_stats:
            lines.append(stats.readout())
            noise = f" (room noise {gate.floor_db:.0f} dB)" if gate.threshold_db > self.settings.gate_db else ""
            lines.append(f"voice {gate.level_db:5.0f} dB   gate {gate.threshold_db:.0f} dB{noise}   sensitivity {self.settings.sensitivity_db:+.0f} dB")
        if status:
            lines.append(status)
        if self.muted:
            lines.append("MUTED (M)")
        elif self.settings.push_to_talk and not self.space_held:
            lines.append("push-to-talk: hold Space")
        text, since = self.notice
        if time.perf_counter() - since < NOTICE_SECONDS:
            lines.append(text)
        return lines


def describe(key: str, settings: LiveSettings) -> str:
    """A short message for a changed setting."""
    if key in "+=-":
        return f"sensitivity {settings.sensitivity_db:+.0f} dB"
    if key in "[]":
        return f"noise gate {settings.gate_db:.0f} dB"
    if key in ".,":
        return f"{settings.blink_rate:.0f} blinks a minute"
    if key == "t":
        return "push-to-talk on: hold Space to talk" if settings.push_to_talk else "push-to-talk off"
    if key == "f":
        return "readout on" if settings.show_stats else "readout off"
    return f"expression: {settings.expression}"


def run(puppet: Puppet, source: AudioSource, display, options: LiveOptions, settings: LiveSettings,
        camera=None, settings_path: Path | None = None, predictor: Predictor | None = None) -> Stats:
    """The live loop: until the window closes, Esc/Q, `options.duration`, or the end of a file source.

    display: a `puppet.window.Window` or `Offscreen`; camera: an optional `puppet.camera.VirtualCamera`
    fed (options.size) frames over the key colour. Returns what it measured.
    """
    from puppet.lipsync import shipped_predictor

    live = LivePuppet(puppet, settings, predictor or shipped_predictor("streaming"), options.seed)
    controls = Controls(settings)
    renderer = PuppetRenderer(display.ctx, puppet.image, puppet.rig)
    overlay = TextOverlay(display.ctx)
    camera_canvas = Canvas(display.ctx, options.size, options.samples) if camera is not None else None
    key = Background((*options.key, 1.0))
    window_background = options.background if (display.transparent or options.background.opaque) else key
    fps = options.fps or display.refresh_rate()
    period = 1.0 / fps
    stats = Stats(fps)
    source.start()
    start = deadline = camera_due = time.perf_counter()
    ended_at = None
    try:
        while not (display.closing or controls.quit):
            now = time.perf_counter()
            if options.duration is not None and now - start >= options.duration:
                break
            if source.finished:
                ended_at = ended_at or now
                if options.duration is None and now - ended_at > 2 * QUIET_AFTER:
                    break
            for event in display.poll():
                if controls.handle(event):
                    live.apply(controls.settings)
                    if settings_path is not None:
                        saved.save(settings_path, controls.settings)
            chunk = source.read()
            stats.audio_dropped += chunk.dropped
            live.hear(chunk, controls.talking)
            positions, moment = live.pose(now)
            if camera is not None and now >= camera_due:  # the camera's own rate, often below the display's
                camera_due = max(camera_due + 1.0 / camera.fps, now)
                camera_canvas.begin(key)
                renderer.draw(positions, options.size)
                camera.send(camera_canvas.read())
            size = display.size
            if min(size) > 0:  # minimized: nothing to draw
                display.begin(window_background)
                renderer.draw(positions, size)
                overlay.draw(controls.lines(source.status, stats, live.gate), size)
            presented = display.present()
            if min(size) > 0 and not math.isnan(moment):
                stats.add(presented, presented - moment, presented - now)
            deadline = max(deadline + period, presented)  # late: start the next frame now, never a burst to catch up
            pause = deadline - time.perf_counter()
            if pause > 0:
                time.sleep(pause)
    except KeyboardInterrupt:  # Ctrl-C in the terminal ends the session like Esc: stats are still written
        pass
    finally:
        source.close()
        live.close()
    return stats


def write_stats(path: Path, stats: Stats, extra: dict) -> dict:
    """Write the `--stats` JSON object (atomically) and return it."""
    summary = stats.summary() | extra
    partial = path.with_name(f".{path.name}.partial")
    partial.write_text(json.dumps(summary, indent=1))
    partial.replace(path)
    return summary

"""`puppet bench`: how fast this machine renders and exports, beside a bare-GL floor.

Render figures are frames per second of draw + MSAA resolve + readback of the demo puppet in
motion; the floor is one textured quad through the very same canvas in the same context, so
the ratio shows what the mesh and shaders cost over the unavoidable minimum. Export is a
whole `render` of a 30 s clip (decode, motion, render, H.264 + AAC encode) as a multiple of
real time. Live is the `puppet live` loop, offscreen at 512×512 and 60 fps, fed the demo clip on
repeat as a microphone would feed it: frame rate, latency from the voice's capture to the frame
presented, dropped frames. `--soak MINUTES` runs only the live loop, for long, and samples memory.
"""
import json
import os
import platform
import tempfile
import threading
import time
import wave
from pathlib import Path

import moderngl
import numpy as np

from puppet import audio, bundle, video
from puppet.renderer import (
    Background,
    Canvas,
    PuppetRenderer,
    fit,
    headless_context,
    premultiply,
    shader_source,
)

SIZES = {"512": (512, 512), "1080": (1920, 1080)}
EXPORT_SIZE = (512, 512)
EXPORT_RUNS = 2  # the export figure is the faster of this many whole renders
RECOGNISE_RUNS = 2  # recognise_realtime_x: the faster of this many runs on the demo clip
LIVE_SIZE = (512, 512)  # the demo's live window
LIVE_FPS = 60.0  # a common display rate
SOAK_SAMPLE = 10.0  # seconds between memory samples in a soak


class FloorQuad:
    """One textured quad: the least any frame of the portrait at that size can cost."""

    def __init__(self, ctx: moderngl.Context, image: np.ndarray):
        self.ctx = ctx
        self.program = ctx.program(vertex_shader=shader_source("quad.vert"), fragment_shader=shader_source("quad.frag"))
        self.texture = ctx.texture((image.shape[1], image.shape[0]), 4, premultiply(image).tobytes())
        corners = ctx.buffer(np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32).tobytes())
        self.quad = ctx.vertex_array(self.program, [(corners, "2f", "in_corner")])

    def draw(self, target_size: tuple[int, int]) -> None:
        """Cover the same rectangle the puppet's portrait is fitted to."""
        scale, shift = fit((self.texture.width, self.texture.height), target_size)
        width, height = round(self.texture.width * scale[0]), round(self.texture.height * scale[1])
        self.ctx.viewport = (round(shift[0]), round(shift[1]), width, height)
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_func = moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA
        self.texture.use(0)
        self.quad.render(moderngl.TRIANGLE_STRIP)
        self.ctx.viewport = (0, 0, *target_size)


def _rates(steps: dict, seconds: float, rounds: int = 5) -> dict:
    """Calls per second of each step: the best of `rounds` interleaved runs of seconds/rounds
    each, so a slow moment on a shared machine hurts every step alike and leaves the best run."""
    best = dict.fromkeys(steps, 0.0)
    for step in steps.values():
        step(), step()  # warm up: shader compilation, first upload
    for _ in range(rounds):
        for name, step in steps.items():
            count, start = 0, time.perf_counter()
            while time.perf_counter() - start < seconds / rounds:
                step()
                count += 1
            best[name] = max(best[name], count / (time.perf_counter() - start))
    return best


def measure_render(puppet: bundle.Puppet, seconds: float) -> dict:
    """render_fps_* and floor_fps_* for each size in SIZES."""
    _, _, speech = bundle.demo_files()
    motion = video.make_motion(puppet, speech, video.VideoOptions(motion=video.default_motion()))
    positions = puppet.rig.animate(motion)
    figures = {}
    ctx = headless_context()
    renderer = PuppetRenderer(ctx, puppet.image, puppet.rig)
    floor = FloorQuad(ctx, puppet.image)
    background = Background((1.0, 1.0, 1.0, 1.0))
    for name, size in SIZES.items():
        canvas = Canvas(ctx, size, video.VideoOptions().samples)
        frame = iter(range(10**9))

        def puppet_frame():
            canvas.begin(background)
            renderer.draw(positions[next(frame) % len(positions)], size)
            canvas.read()

        def floor_frame():
            canvas.begin(background)
            floor.draw(size)
            canvas.read()

        rates = _rates({"render": puppet_frame, "floor": floor_frame}, seconds)
        figures[f"render_fps_{name}"] = round(rates["render"], 1)
        figures[f"floor_fps_{name}"] = round(rates["floor"], 1)
        figures[f"render_vs_floor_{name}"] = round(figures[f"render_fps_{name}"] / figures[f"floor_fps_{name}"], 3)
    ctx.release()
    return figures


def measure_export(puppet: bundle.Puppet, clip_seconds: float) -> dict:
    """export_realtime_x_512: the best of EXPORT_RUNS whole renders of a clip_seconds clip at 512×512, 25 fps."""
    _, _, speech = bundle.demo_files()
    samples = audio.load(speech)
    repeats = int(np.ceil(clip_seconds * audio.ANALYSIS_RATE / len(samples)))
    clip = np.tile(samples, repeats)[: int(clip_seconds * audio.ANALYSIS_RATE)]
    with tempfile.TemporaryDirectory() as folder:
        wav = Path(folder) / "clip.wav"
        with wave.open(str(wav), "wb") as out:
            out.setnchannels(1)
            out.setsampwidth(2)
            out.setframerate(audio.ANALYSIS_RATE)
            out.writeframes((np.clip(clip, -1, 1) * 32767).astype("<i2").tobytes())
        options = video.VideoOptions(size=EXPORT_SIZE, motion=video.default_motion())
        elapsed = float("inf")
        for _ in range(EXPORT_RUNS):
            start = time.perf_counter()
            video.render(puppet, wav, Path(folder) / "clip.mp4", options, force=True, progress=False)
            elapsed = min(elapsed, time.perf_counter() - start)
    return {"export_seconds_512": round(elapsed, 2), "export_realtime_x_512": round(clip_seconds / elapsed, 2)}


def measure_predictor(seconds: float) -> dict:
    """predictor_ms_per_frame (the streaming model in 20 ms chunks, one thread), predict_realtime_x
(what files use on the whole clip: the offline and streaming models averaged, a thread each) and
recognise_realtime_x (the same with --recognise: the words recognised, aligned and articulated)."""
    from puppet import lipsync, speaker
    from puppet.predictor import Predictor, default_model

    if not lipsync.has_model():
        return {}
    _, _, speech = bundle.demo_files()
    samples = audio.load(speech)
    embedding = speaker.embed(samples)
    predictor, offline = Predictor(default_model("streaming"), threads=1), lipsync.file_predictor()
    chunk = audio.ANALYSIS_RATE // 50  # 20 ms, one motion frame

    def stream_clip():
        stream, frames = predictor.stream(embedding), 0
        for start in range(0, len(samples), chunk):
            frames += len(stream.push(samples[start : start + chunk])[0])
        return frames

    def offline_clip():
        offline.predict(samples, embedding)

    def recognised_clip():
        start = time.perf_counter()
        lipsync.speech_offsets(samples, offline, embedding, recognise=True)
        return time.perf_counter() - start

    frames = stream_clip()
    stream_rate = _rates({"stream": stream_clip}, seconds, rounds=3)["stream"]
    offline_rate = _rates({"offline": offline_clip}, seconds, rounds=3)["offline"]
    clip_seconds = len(samples) / audio.ANALYSIS_RATE
    return {
        "predictor_ms_per_frame": round(1000 / (stream_rate * frames), 3),
        "predict_realtime_x": round(offline_rate * clip_seconds, 1),
        "recognise_realtime_x": round(clip_seconds / min(recognised_clip() for _ in range(RECOGNISE_RUNS)), 1),
    }


def measure_live(seconds: float, size: tuple[int, int] = LIVE_SIZE, fps: float = LIVE_FPS) -> dict:
    """The live loop, offscreen, driven by the demo clip on repeat as if from a microphone:
    live_fps, live_latency_ms_p50/p95 (voice capture → frame presented), live_dropped_frames."""
    from puppet import capture, lipsync, live
    from puppet.settings import LiveSettings
    from puppet.window import Offscreen

    if not lipsync.has_model():
        return {}
    image, landmarks, speech = bundle.demo_files()
    puppet = bundle.load(image, landmarks)
    display = Offscreen(headless_context(), size, owns_context=True)
    try:
        source = capture.FilePlayer(speech, playback=False, loop=True)
        stats = live.run(puppet, source, display, live.LiveOptions(size=size, fps=fps, duration=seconds), LiveSettings())
    finally:
        display.close()
    summary = stats.summary()
    return {
        "live_fps": summary["fps"],
        "live_latency_ms_p50": summary["latency_ms_p50"],
        "live_latency_ms_p95": summary["latency_ms_p95"],
        "live_dropped_frames": summary["dropped_frames"],
        "live_frame_work_ms_p95": summary["frame_work_ms_p95"],
    }


def soak(minutes: float) -> dict:
    """The live loop for `minutes` (as `measure_live`), with the process's resident memory sampled
    every SOAK_SAMPLE seconds: it should stay flat."""
    samples: list[float] = []
    done = threading.Event()

    def sample():
        while not done.wait(SOAK_SAMPLE):
            samples.append(_rss_mb())

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    figures = measure_live(minutes * 60)
    done.set()
    sampler.join()
    per_minute = max(1, round(60 / SOAK_SAMPLE))
    by_minute = [round(max(samples[i : i + per_minute]), 1) for i in range(0, len(samples), per_minute)]
    return figures | {
        "soak_minutes": minutes,
        "rss_mb_first_minute": by_minute[0] if by_minute else None,
        "rss_mb_last_minute": by_minute[-1] if by_minute else None,
        "rss_mb_max": max(by_minute) if by_minute else None,
        "rss_mb_by_minute": by_minute,
    }


def _rss_mb() -> float:
    """This process's resident memory in MB (Linux /proc; elsewhere the peak from getrusage)."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 1e6
    except (OSError, ValueError, IndexError):
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


def main(as_json: bool, seconds: float, clip_seconds: float, soak_minutes: float | None = None) -> int:
    if soak_minutes is not None:
        figures = soak(soak_minutes)
        print(json.dumps(figures) if as_json else "\n".join(f"{key:<28}{value:>10}" for key, value in figures.items()))
        return 0
    image, landmarks, _ = bundle.demo_files()
    puppet = bundle.load(image, landmarks)
    ctx = headless_context()
    renderer_name = ctx.info["GL_RENDERER"]
    ctx.release()
    figures = {"machine": f"{platform.machine()}, {_cpu_count()} CPU cores, {renderer_name}"}
    figures.update(measure_render(puppet, seconds))
    figures.update(measure_export(puppet, clip_seconds))
    figures.update(measure_predictor(seconds))
    figures.update(measure_live(2 * seconds))
    if as_json:
        print(json.dumps(figures))
        return 0
    print(f"machine: {figures['machine']}")
    print(f"{'measure':<28}{'value':>10}")
    for key, value in figures.items():
        if key != "machine":
            print(f"{key:<28}{value:>10}")
    return 0


def _cpu_count() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()

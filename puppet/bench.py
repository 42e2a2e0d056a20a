"""`puppet bench`: how fast this machine renders and exports, beside a bare-GL floor.

Render figures are frames per second of draw + MSAA resolve + readback of the demo puppet in
motion; the floor is one textured quad through the very same canvas in the same context, so
the ratio shows what the mesh and shaders cost over the unavoidable minimum. Export is a
whole `render` of a 30 s clip (decode, motion, render, H.264 + AAC encode) as a multiple of
real time.
"""
import json
import os
import platform
import tempfile
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
    headless_context,
    premultiply,
    shader_source,
)

SIZES = {"512": (512, 512), "1080": (1920, 1080)}
EXPORT_SIZE = (512, 512)


class FloorQuad:
    """One textured quad covering the target: the least any frame of that size can cost."""

    def __init__(self, ctx: moderngl.Context, image: np.ndarray):
        self.ctx = ctx
        self.program = ctx.program(vertex_shader=shader_source("quad.vert"), fragment_shader=shader_source("quad.frag"))
        self.texture = ctx.texture((image.shape[1], image.shape[0]), 4, premultiply(image).tobytes())
        corners = ctx.buffer(np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32).tobytes())
        self.quad = ctx.vertex_array(self.program, [(corners, "2f", "in_corner")])

    def draw(self) -> None:
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_func = moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA
        self.texture.use(0)
        self.quad.render(moderngl.TRIANGLE_STRIP)


def _rate(step, seconds: float) -> float:
    """Calls of `step` per second over about `seconds` (after two warm-up calls)."""
    step(), step()
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        step()
        count += 1
    return count / (time.perf_counter() - start)


def measure_render(puppet: bundle.Puppet, seconds: float) -> dict:
    """render_fps_* and floor_fps_* for each size in SIZES."""
    _, _, speech = bundle.demo_files()
    motion = video.make_motion(puppet, speech, video.VideoOptions())
    positions = puppet.rig.animate(motion)
    figures = {}
    ctx = headless_context()
    renderer = PuppetRenderer(ctx, puppet.image, puppet.rig)
    floor = FloorQuad(ctx, puppet.image)
    background = Background((1.0, 1.0, 1.0, 1.0))
    for name, size in SIZES.items():
        canvas = Canvas(ctx, size)
        frame = iter(range(10**9))

        def puppet_frame():
            canvas.begin(background)
            renderer.draw(positions[next(frame) % len(positions)], size)
            canvas.read()

        def floor_frame():
            canvas.begin(background)
            floor.draw()
            canvas.read()

        figures[f"render_fps_{name}"] = round(_rate(puppet_frame, seconds), 1)
        figures[f"floor_fps_{name}"] = round(_rate(floor_frame, seconds), 1)
        figures[f"render_vs_floor_{name}"] = round(figures[f"render_fps_{name}"] / figures[f"floor_fps_{name}"], 3)
    ctx.release()
    return figures


def measure_export(puppet: bundle.Puppet, clip_seconds: float) -> dict:
    """export_realtime_x_512: a whole render of a clip_seconds clip at 512×512, 25 fps."""
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
        options = video.VideoOptions(size=EXPORT_SIZE)
        start = time.perf_counter()
        video.render(puppet, wav, Path(folder) / "clip.mp4", options, progress=False)
        elapsed = time.perf_counter() - start
    return {"export_seconds_512": round(elapsed, 2), "export_realtime_x_512": round(clip_seconds / elapsed, 2)}


def main(as_json: bool, seconds: float, clip_seconds: float) -> int:
    image, landmarks, _ = bundle.demo_files()
    puppet = bundle.load(image, landmarks)
    ctx = headless_context()
    renderer_name = ctx.info["GL_RENDERER"]
    ctx.release()
    figures = {"machine": f"{platform.machine()}, {_cpu_count()} CPU cores, {renderer_name}"}
    figures.update(measure_render(puppet, seconds))
    figures.update(measure_export(puppet, clip_seconds))
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

"""GPU drawing of a rigged portrait: one renderer for the window, headless export, and tests.

Each class owns its GL resources and is handed a moderngl context. `PuppetRenderer` draws the
mesh into whatever framebuffer is bound; `Canvas` is the offscreen framebuffer (multisampled,
resolved, read back) used headless. The portrait texture is premultiplied once at upload, so
linear filtering and blending (ONE, ONE_MINUS_SRC_ALPHA) keep transparent edges clean.
"""
from dataclasses import dataclass
from importlib.resources import files

import moderngl
import numpy as np

from puppet.errors import PuppetError
from puppet.rig import Rig

MIPMAP_BELOW_SCALE = 0.75  # portrait pixels per output pixel below which mipmaps are sampled


def shader_source(name: str) -> str:
    """The text of a GLSL file from the installed `shaders/` folder."""
    return (files("puppet.shaders") / name).read_text()


def headless_context() -> moderngl.Context:
    """A standalone OpenGL 3.3+ context through EGL: needs no display (Mesa llvmpipe on a CPU)."""
    try:
        return moderngl.create_standalone_context(require=330, backend="egl")
    except Exception as error:  # moderngl raises plain Exception when no EGL/GL driver loads
        raise PuppetError(f"cannot create an OpenGL context through EGL ({error}); install Mesa's EGL (libegl1, libgl1-mesa-dri)") from None


def fit(image_size: tuple[int, int], target_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Scale (2,) and shift (2,) placing the portrait centred in the target, aspect kept."""
    scale = min(target_size[0] / image_size[0], target_size[1] / image_size[1])
    shift = (np.array(target_size) - scale * np.array(image_size)) / 2
    return np.array([scale, scale], np.float32), shift.astype(np.float32)


def premultiply(image: np.ndarray) -> np.ndarray:
    """(H, W, 4) uint8 RGBA with colour multiplied by alpha."""
    alpha = image[..., 3:4].astype(np.uint16)
    rgb = (image[..., :3].astype(np.uint16) * alpha + 127) // 255
    return np.concatenate([rgb.astype(np.uint8), image[..., 3:4]], axis=-1)


class PuppetRenderer:
    """Draws one rigged portrait; only the per-vertex displacement changes between frames."""

    def __init__(self, ctx: moderngl.Context, image: np.ndarray, rig: Rig):
        """image: (H, W, 4) uint8 RGBA, straight alpha, rows top to bottom; rig: its mesh."""
        height, width = image.shape[:2]
        if (width, height) != tuple(rig.image_size):
            raise PuppetError(f"the rig is for a {rig.image_size[0]}x{rig.image_size[1]} image, not {width}x{height}")
        self.ctx = ctx
        self.rig = rig
        vertex_shader = shader_source("puppet.vert")
        self.skin_program = ctx.program(vertex_shader=vertex_shader, fragment_shader=shader_source("skin.frag"))
        self.mouth_program = ctx.program(vertex_shader=vertex_shader, fragment_shader=shader_source("mouth.frag"))
        self.texture = ctx.texture((width, height), 4, np.ascontiguousarray(premultiply(image)).tobytes())
        self.texture.build_mipmaps()
        self.texture.repeat_x = self.texture.repeat_y = False
        self.rest = rig.vertices[:, :2].astype(np.float32)
        self.rest_buffer = ctx.buffer(self.rest.tobytes())
        self.offset_buffer = ctx.buffer(reserve=self.rest.nbytes, dynamic=True)
        self.mouth_buffer = ctx.buffer(rig.mouth_coords.tobytes())
        self.paint_mouth = rig.mouth_style.interior == "cavity"
        self.index_buffers = []
        skin = np.delete(rig.triangles, rig.mouth, axis=0) if self.paint_mouth else rig.triangles
        self.skin = self._vertex_array(self.skin_program, skin)
        self.mouth = self._vertex_array(self.mouth_program, rig.triangles[rig.mouth])
        style = rig.mouth_style
        for program in (self.skin_program, self.mouth_program):
            program["u_image_size"].value = (float(width), float(height))
            program["u_texture"].value = 0
        self.mouth_program["u_cavity"].value = tuple(style.cavity)
        self.mouth_program["u_teeth"].value = tuple(style.teeth)
        self.mouth_program["u_tongue"].value = tuple(style.tongue)
        self.target_size = None

    def release(self) -> None:
        """Free this puppet's GL objects (the context lives on)."""
        for resource in (self.skin, self.mouth, *self.index_buffers, self.rest_buffer, self.offset_buffer,
                         self.mouth_buffer, self.texture, self.skin_program, self.mouth_program):
            resource.release()

    def _vertex_array(self, program: moderngl.Program, triangles: np.ndarray) -> moderngl.VertexArray:
        index = self.ctx.buffer(np.ascontiguousarray(triangles, dtype=np.int32).tobytes())
        self.index_buffers.append(index)
        buffers = [(self.rest_buffer, "2f", "in_rest"), (self.offset_buffer, "2f", "in_offset")]
        if "in_mouth" in program:
            buffers.append((self.mouth_buffer, "3f", "in_mouth"))
        return self.ctx.vertex_array(program, buffers, index_buffer=index, index_element_size=4)

    def _frame(self, target_size: tuple[int, int]) -> None:
        """Set up drawing into a target of a new size (done once per size, not per frame)."""
        self.target_size = target_size
        scale, shift = fit(self.rig.image_size, target_size)
        # Trilinear mipmapping only where the portrait is shrunk: it costs a lot on a CPU rasteriser.
        minify = moderngl.LINEAR_MIPMAP_LINEAR if scale[0] < MIPMAP_BELOW_SCALE else moderngl.LINEAR
        self.texture.filter = (minify, moderngl.LINEAR)
        for program in (self.skin_program, self.mouth_program):
            program["u_target_size"].value = (float(target_size[0]), float(target_size[1]))
            program["u_scale"].value = tuple(scale)
            program["u_shift"].value = tuple(shift)

    def draw(self, positions: np.ndarray, target_size: tuple[int, int]) -> None:
        """Draw into the bound framebuffer of `target_size` (width, height) pixels.

        positions: (N, 2) float32 vertex positions this frame, portrait pixels (`Rig.animate`).
        The portrait is fitted into the target, centred, aspect kept.
        """
        self.offset_buffer.write(np.ascontiguousarray(positions - self.rest, dtype=np.float32).tobytes())
        if target_size != self.target_size:
            self._frame(target_size)
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_func = moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA
        self.texture.use(0)
        self.skin.render(moderngl.TRIANGLES)
        if self.paint_mouth:
            self.mouth.render(moderngl.TRIANGLES)


@dataclass(frozen=True)
class Background:
    """What shows where the portrait is transparent: RGBA in 0–1; alpha 0 keeps it transparent."""

    rgba: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    @property
    def opaque(self) -> bool:
        return self.rgba[3] >= 1.0


class Canvas:
    """An offscreen framebuffer: draw with MSAA, resolve, read back as straight-alpha RGBA."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int], samples: int = 4):
        """size: (width, height) pixels; samples: MSAA samples (0 or 1 = none)."""
        self.ctx = ctx
        self.size = size
        samples = min(samples, ctx.max_samples) if samples > 1 else 0
        self.resolved = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, 4)])
        self.multisampled = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, 4, samples=samples)]) if samples else None

    def begin(self, background: Background) -> None:
        """Bind the drawing framebuffer and clear it to the (premultiplied) background."""
        target = self.multisampled or self.resolved
        target.use()
        r, g, b, a = background.rgba
        target.clear(r * a, g * a, b * a, a)

    def read(self) -> np.ndarray:
        """(H, W, 4) uint8 RGBA, straight alpha, rows top to bottom: the frame just drawn."""
        if self.multisampled is not None:
            self.ctx.copy_framebuffer(self.resolved, self.multisampled)
        width, height = self.size
        data = np.frombuffer(self.resolved.read(components=4, alignment=1), np.uint8)
        frame = data.reshape(height, width, 4)[::-1]  # GL rows run bottom-up: the one flip
        return unpremultiply(frame)


def unpremultiply(frame: np.ndarray) -> np.ndarray:
    """(H, W, 4) uint8 straight-alpha RGBA from premultiplied; opaque frames pass through."""
    alpha = frame[..., 3]
    if alpha.min() == 255:
        return np.ascontiguousarray(frame)
    out = frame.astype(np.uint16)
    a = np.maximum(alpha, 1).astype(np.uint16)[..., None]
    out[..., :3] = np.minimum((out[..., :3] * 255 + a // 2) // a, 255)
    return out.astype(np.uint8)

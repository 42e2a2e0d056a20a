"""Where live frames go: a desktop window (glfw) or an offscreen canvas, behind one interface.

Both are handed to the live loop and the rig editor as a `Display`: `ctx` to build renderers on,
`size` of the drawing target in pixels, `begin` to bind and clear it, `present` to show the frame
(returning the time it was shown), `poll` for the user's input since the last frame. The puppet is
drawn by the same `PuppetRenderer` as headless export; `TextOverlay` writes the readouts and help.
"""
import time
from dataclasses import dataclass

import cv2
import glfw
import moderngl
import numpy as np

from puppet.errors import PuppetError
from puppet.renderer import Background, Canvas, shader_source

DEFAULT_REFRESH = 60.0  # frames per second when the display does not say
# glfw key codes that have no printable name, by the name events carry.
SPECIAL_KEYS = {
    glfw.KEY_ESCAPE: "escape", glfw.KEY_SPACE: "space", glfw.KEY_ENTER: "enter", glfw.KEY_TAB: "tab",
    glfw.KEY_BACKSPACE: "backspace", glfw.KEY_DELETE: "delete", glfw.KEY_F1: "f1",
    glfw.KEY_KP_ADD: "+", glfw.KEY_KP_SUBTRACT: "-", glfw.KEY_UP: "up", glfw.KEY_DOWN: "down",
    glfw.KEY_LEFT: "left", glfw.KEY_RIGHT: "right",
}


@dataclass(frozen=True)
class Event:
    """One input event. kind: "key" (pressed or repeated), "release", "press"/"drag"/"up" (mouse
    button 1, at x, y in target pixels), "move" (the mouse, no button held). key: lower-case key
    name ("h", "1", "space", "escape"); ctrl/shift: modifiers held."""

    kind: str
    key: str = ""
    x: float = 0.0
    y: float = 0.0
    ctrl: bool = False
    shift: bool = False


class Window:
    """A glfw window with a moderngl context; the default framebuffer is the drawing target."""

    def __init__(self, title: str, size: tuple[int, int], transparent: bool = False):
        """size: (width, height) in screen units; transparent: ask for a see-through background
        (`self.transparent` says whether the platform granted it)."""
        glfw.ERROR_REPORTING = "ignore"  # failures are reported below, as one line
        if not glfw.init():
            raise PuppetError(f"cannot open a window ({_glfw_error()}): run it on a desktop, or use --no-window")
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        glfw.window_hint(glfw.TRANSPARENT_FRAMEBUFFER, transparent)
        self.handle = glfw.create_window(size[0], size[1], title, None, None)
        if not self.handle:
            glfw.terminate()
            raise PuppetError(f"cannot open a window with OpenGL 3.3 on this display ({_glfw_error()}): update the graphics driver, or use --no-window")
        glfw.make_context_current(self.handle)
        glfw.swap_interval(1)
        self.ctx = moderngl.create_context()
        self.transparent = transparent and bool(glfw.get_window_attrib(self.handle, glfw.TRANSPARENT_FRAMEBUFFER))
        self.events: list[Event] = []
        self._dragging = False
        glfw.set_key_callback(self.handle, self._on_key)
        glfw.set_mouse_button_callback(self.handle, self._on_button)
        glfw.set_cursor_pos_callback(self.handle, self._on_cursor)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the framebuffer in pixels; (0, 0) while minimized."""
        return tuple(glfw.get_framebuffer_size(self.handle))

    @property
    def closing(self) -> bool:
        return bool(glfw.window_should_close(self.handle))

    def refresh_rate(self) -> float:
        """The primary monitor's refresh rate in Hz (DEFAULT_REFRESH when it does not say)."""
        monitor = glfw.get_primary_monitor()
        mode = glfw.get_video_mode(monitor) if monitor else None
        return float(mode.refresh_rate) if mode and mode.refresh_rate > 0 else DEFAULT_REFRESH

    def begin(self, background: Background) -> None:
        """Bind the window's framebuffer and clear it to the (premultiplied) background."""
        width, height = self.size
        self.ctx.screen.viewport = (0, 0, width, height)  # follows resizes
        self.ctx.screen.use()
        r, g, b, a = background.rgba
        self.ctx.screen.clear(r * a, g * a, b * a, a)

    def present(self) -> float:
        """Show the frame just drawn; the perf_counter time it was handed to the display."""
        glfw.swap_buffers(self.handle)
        return time.perf_counter()

    def poll(self) -> list[Event]:
        """The input events since the last call."""
        glfw.poll_events()
        events, self.events = self.events, []
        return events

    def close(self) -> None:
        if self.handle is not None:
            self.ctx.release()
            glfw.destroy_window(self.handle)
            glfw.terminate()
            self.handle = None

    def _to_pixels(self, x: float, y: float) -> tuple[float, float]:
        """Cursor position (screen units) → framebuffer pixels (differs on high-DPI screens)."""
        window = glfw.get_window_size(self.handle)
        frame = self.size
        return x * frame[0] / max(window[0], 1), y * frame[1] / max(window[1], 1)

    def _on_key(self, handle, key, scancode, action, mods):
        name = SPECIAL_KEYS.get(key) or (glfw.get_key_name(key, scancode) or "").lower()
        if not name:
            return
        kind = "release" if action == glfw.RELEASE else "key"
        self.events.append(Event(kind, name, ctrl=bool(mods & glfw.MOD_CONTROL), shift=bool(mods & glfw.MOD_SHIFT)))

    def _on_button(self, handle, button, action, mods):
        if button != glfw.MOUSE_BUTTON_LEFT:
            return
        x, y = self._to_pixels(*glfw.get_cursor_pos(handle))
        self._dragging = action == glfw.PRESS
        kind = "press" if action == glfw.PRESS else "up"
        self.events.append(Event(kind, x=x, y=y, ctrl=bool(mods & glfw.MOD_CONTROL), shift=bool(mods & glfw.MOD_SHIFT)))

    def _on_cursor(self, handle, x, y):
        x, y = self._to_pixels(x, y)
        self.events.append(Event("drag" if self._dragging else "move", x=x, y=y))


def _glfw_error() -> str:
    """glfw's description of its last error."""
    _, description = glfw.get_error()
    return description.decode(errors="replace") if description else "no display found"


class Offscreen:
    """The same interface without a screen: frames are drawn into a `Canvas` (for a virtual
    camera on a machine with no desktop, and for tests, which put their input into `events`)."""

    transparent = True
    closing = False

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int], samples: int = 0, owns_context: bool = False):
        """owns_context: release `ctx` on close (it was made for this display)."""
        self.ctx = ctx
        self.owns_context = owns_context
        self.size = size
        self.canvas = Canvas(ctx, size, samples)
        self.events: list[Event] = []

    def refresh_rate(self) -> float:
        return DEFAULT_REFRESH

    def begin(self, background: Background) -> None:
        self.canvas.begin(background)

    def present(self) -> float:
        self.ctx.finish()
        return time.perf_counter()

    def poll(self) -> list[Event]:
        events, self.events = self.events, []
        return events

    def close(self) -> None:
        if self.owns_context:
            self.ctx.release()
            self.owns_context = False


class Picture:
    """A premultiplied RGBA image drawn as one quad over a rectangle of the bound target (the
    readouts and help text of the live window, the landmark marks of the rig editor)."""

    def __init__(self, ctx: moderngl.Context):
        self.ctx = ctx
        self.program = ctx.program(vertex_shader=shader_source("overlay.vert"), fragment_shader=shader_source("quad.frag"))
        self.corners = ctx.buffer(np.array([0, 0, 1, 0, 0, 1, 1, 1], np.float32).tobytes())
        self.quad = ctx.vertex_array(self.program, [(self.corners, "2f", "in_corner")])
        self.texture = None

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the image shown, pixels."""
        return self.texture.size

    def upload(self, image: np.ndarray) -> None:
        """image: (H, W, 4) uint8 RGBA, premultiplied, rows top to bottom."""
        height, width = image.shape[:2]
        if self.texture is None or self.texture.size != (width, height):
            if self.texture is not None:
                self.texture.release()
            self.texture = self.ctx.texture((width, height), 4)
        self.texture.write(np.ascontiguousarray(image))

    def draw(self, rect: tuple[float, float, float, float]) -> None:
        """rect: x, y, width, height as fractions of the target, from its top-left corner."""
        self.program["u_rect"].value = rect
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_func = moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA
        self.texture.use(0)
        self.quad.render(moderngl.TRIANGLE_STRIP)

    def release(self) -> None:
        for resource in (self.texture, self.quad, self.corners, self.program):
            if resource is not None:
                resource.release()


class TextOverlay:
    """Lines of text in the top-left corner of the bound target, on a dark translucent plate,
    rasterised by OpenCV only when they change."""

    SCALE = 0.5  # OpenCV font scale at 100 % (grows with the target's height)

    def __init__(self, ctx: moderngl.Context):
        self.picture = Picture(ctx)
        self.shown: tuple[list[str], float] | None = None  # the lines and font scale the picture holds

    def release(self) -> None:
        self.picture.release()

    def draw(self, lines: list[str], target_size: tuple[int, int]) -> None:
        """Draw `lines` over whatever is in the bound framebuffer of target_size (width, height)."""
        if not lines or min(target_size) <= 0:
            return
        scale = self.SCALE * max(1.0, target_size[1] / 720)
        if self.shown != (lines, scale):
            self.picture.upload(_text_plate(lines, scale))
            self.shown = (list(lines), scale)
        width, height = self.picture.size
        self.picture.draw((8.0 / target_size[0], 8.0 / target_size[1], width / target_size[0], height / target_size[1]))


def _text_plate(lines: list[str], scale: float) -> np.ndarray:
    """(H, W, 4) uint8 premultiplied RGBA: white lines on a translucent black plate."""
    font, thickness = cv2.FONT_HERSHEY_SIMPLEX, 1
    line_height = int(32 * scale) + 4
    width = max(cv2.getTextSize(line, font, scale, thickness)[0][0] for line in lines) + 16
    plate = np.zeros((line_height * len(lines) + 10, width, 4), np.uint8)
    plate[...] = (0, 0, 0, 160)
    for i, line in enumerate(lines):
        cv2.putText(plate, line, (8, line_height * (i + 1)), font, scale, (255, 255, 255, 255), thickness, cv2.LINE_AA)
    alpha = plate[..., 3:4].astype(np.uint16)
    plate[..., :3] = (plate[..., :3].astype(np.uint16) * alpha // 255).astype(np.uint8)
    return plate

"""The rig editor (`puppet rig IMAGE --edit`): drag a portrait's 68 landmarks into place, preview
the puppet moving, save the bundle.

One frame of the loop (`edit`): input events → `Editor.handle` → `Editor.draw` → present, at
EDIT_FPS while the user is busy or the preview plays, IDLE_FPS otherwise.
The editing view is the portrait at rest: a mesh at rest shows the image exactly whatever its
landmarks, so dragging a point needs no new rig; only the landmark marks are redrawn. The preview
and the save rebuild the rig from the edited points (`rig.build`, ~10 ms); a rig that cannot be
built is reported in the overlay and nothing is previewed or saved. The preview loops
PREVIEW_SECONDS of scripted motion (talking, "oo", "ee", a blink, a head turn, plus breathing and
sway) drawn by the same `PuppetRenderer` as the exported videos.

Coordinates: landmarks are image pixels (origin top-left, y down); events and marks are target
(window) pixels, mapped to and from the image with `renderer.fit`, like the portrait itself.
"""
import time
from dataclasses import replace
from pathlib import Path

import cv2
import moderngl
import numpy as np

from puppet import bundle
from puppet import landmarks as lm
from puppet.articulation import blend, unit_offsets
from puppet.bundle import Puppet
from puppet.errors import PuppetError
from puppet.life import LifeOptions, life_motion
from puppet.motion import Motion
from puppet.renderer import Background, PuppetRenderer, fit
from puppet.rig import Rig, build
from puppet.window import Event, Picture, TextOverlay

EDIT_FPS = 60.0  # frames per second while dragging, previewing or just after any input
IDLE_FPS = 10.0  # frames per second otherwise (the window still repaints)
IDLE_AFTER = 1.0  # seconds without input after which the loop slows to IDLE_FPS
PICK_RADIUS = 12.0  # window pixels: a press this close to a point grabs it
WINDOW_MAX = (1600, 1000)  # the window opens at most this (width, height), screen units
WINDOW_MIN_HEIGHT = 600  # smaller portraits are enlarged to this height (within WINDOW_MAX)
BACKGROUND = Background((0.3, 0.3, 0.3, 1.0))  # behind the portrait: shows transparent parts
NOTICE_SECONDS = 4.0  # how long a message ("saved -> ...") stays in the overlay

# The preview: PREVIEW_SECONDS at the export's default frame rate, looped.
PREVIEW_FPS = 25.0  # as `puppet.video.DEFAULT_FPS`
PREVIEW_SECONDS = 4.0  # 100 frames
TALK = (0.0, 1.2)  # (start, length) seconds: the jaw opens and closes twice
OO = (1.2, 0.8)  # lips rounded, jaw a little open
EE = (2.0, 0.8)  # lips wide, jaw a little open
BLINK = (2.8, 0.25)  # both eyes
TURN = (3.0, 1.0)  # the head turns toward the image's right, then left, and back
TALK_JAW = 0.8  # jaw_open weight at the top of each syllable
VOWEL_JAW = 0.25  # jaw_open weight under "oo" and "ee"
TURN_DEGREES = 5.0  # largest yaw of the head turn; pitch follows at TURN_PITCH of it
TURN_PITCH = 0.3

# The marks. Colours are RGB; each part's outline is drawn in its colour, its points as dots.
OUTLINES = (  # (indices, closed, colour)
    (lm.JAW, False, (255, 214, 0)),
    (lm.RIGHT_BROW, False, (255, 140, 0)),
    (lm.LEFT_BROW, False, (255, 140, 0)),
    (lm.NOSE_BRIDGE, False, (0, 220, 255)),
    (lm.NOSE_LOWER, False, (0, 220, 255)),
    (lm.RIGHT_EYE, True, (90, 255, 120)),
    (lm.LEFT_EYE, True, (90, 255, 120)),
    (lm.OUTER_LIP, True, (255, 70, 70)),
    (lm.INNER_LIP, True, (255, 90, 255)),
)
POINT_COLOURS = np.array([next(colour for indices, _, colour in OUTLINES if i in indices) for i in range(lm.N_LANDMARKS)], np.uint8)
DOT_RADIUS = 4.0  # window pixels, at most: in a small view dots shrink to DOT_SHARE of the face's
DOT_SHARE = 0.04  # inter-ocular distance (down to MIN_DOT_RADIUS) so that neighbours stay apart
MIN_DOT_RADIUS = 1.5
SELECTED_RADIUS = 7.0  # the selected point, with a white ring
LINE_THICKNESS = 1
SUBPIXEL_BITS = 4  # OpenCV draws at 1/16 pixel

# Names shown for the point under the mouse; "right"/"left" are the subject's own (iBUG).
PART_NAMES = {i: name.replace("_", " ") for name, part in lm.FACIAL_PARTS.items() for i in part}
# What Shift+drag (or part mode) moves together: the whole mouth, not one of its lip rings.
GROUPS = (lm.JAW, lm.RIGHT_BROW, lm.LEFT_BROW, lm.NOSE, lm.RIGHT_EYE, lm.LEFT_EYE, lm.MOUTH)
# Rings that must not cross themselves (the inner lip may: a crossed closed mouth is repaired by the rig).
SIMPLE_RINGS = (("right eye", lm.RIGHT_EYE), ("left eye", lm.LEFT_EYE), ("outer lip", lm.OUTER_LIP))

HELP_LINE = "drag points   Space preview   S save   Ctrl+Z undo   R reset   H keys   Esc quit"
KEYS = (
    ("drag", "move a point; Shift+drag moves its whole part (eye, brow, nose, mouth, jaw)"),
    ("P", "part mode on / off: every drag moves a whole part"),
    ("Space", "preview the animation / back to editing"),
    ("S", "save the bundle"),
    ("Ctrl+Z", "undo"),
    ("R", "reset to the starting points"),
    ("H", "show or hide these keys"),
    ("Esc, Q", "quit"),
)


def preview_motion(rest: np.ndarray, fps: float = PREVIEW_FPS) -> Motion:
    """PREVIEW_SECONDS of motion showing what a rig does: the jaw opens and closes twice, "oo",
    "ee", a blink and a small head turn, over life's breathing and sway (no random blinks).

    rest: (68, 3) float32 rest landmarks, image pixels. Starts and ends at rest, so it loops.
    """
    frames = round(PREVIEW_SECONDS * fps)
    t = np.arange(frames) / fps

    def bump(span: tuple[float, float], count: int = 1) -> np.ndarray:
        """(T,) 0 → 1 → 0 `count` times, smoothly, over span (start, length) seconds."""
        x = np.clip((t - span[0]) / span[1], 0.0, 1.0)
        return (np.sin(np.pi * count * x) ** 2).astype(np.float32)

    blink = bump(BLINK)
    weights = {
        "jaw_open": TALK_JAW * bump(TALK, 2) + VOWEL_JAW * (bump(OO) + bump(EE)),
        "lip_round": bump(OO),
        "lip_wide": bump(EE),
        "blink_right": blink,
        "blink_left": blink,
    }
    inside = (t >= TURN[0]) & (t < TURN[0] + TURN[1])
    yaw = np.radians(TURN_DEGREES) * np.sin(2.0 * np.pi * (t - TURN[0]) / TURN[1]) * inside
    rotation = np.stack([TURN_PITCH * np.abs(yaw), yaw, np.zeros(frames)], axis=1).astype(np.float32)
    scripted = Motion(blend(unit_offsets(rest), weights), rotation, np.zeros((frames, 2), np.float32), fps)
    return scripted + life_motion(frames, fps, rest, LifeOptions(blink_rate=0.0))


def window_size(image_size: tuple[int, int]) -> tuple[int, int]:
    """(width, height) of an editor window for a portrait of image_size: the portrait's aspect,
    within WINDOW_MAX, small portraits enlarged to WINDOW_MIN_HEIGHT."""
    width, height = image_size
    scale = min(WINDOW_MAX[0] / width, WINDOW_MAX[1] / height, max(1.0, WINDOW_MIN_HEIGHT / height))
    return max(1, round(width * scale)), max(1, round(height * scale))


def crossed_ring(points: np.ndarray) -> str | None:
    """What is wrong when an eye or the outer lip of (68, 2) points crosses itself, else None."""
    for name, ring in SIMPLE_RINGS:
        ring = list(ring)
        edges = list(zip(ring, ring[1:] + ring[:1]))
        for k, (a, b) in enumerate(edges):
            for c, d in edges[k + 2 :]:
                if len({a, b, c, d}) == 4 and _segments_cross(points[a], points[b], points[c], points[d]):
                    return f"the {name} outline crosses itself (points {ring[0]}-{ring[-1]}): drag them back in order"
    return None


def _segments_cross(p, q, r, s) -> bool:
    def side(o, a, b):
        return np.sign((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))

    return side(p, q, r) * side(p, q, s) < 0 and side(r, s, p) * side(r, s, q) < 0


class Marks:
    """The landmarks over the portrait: part outlines and dots, rasterised by OpenCV into one
    target-sized premultiplied RGBA texture when they change, drawn as one quad."""

    def __init__(self, ctx: moderngl.Context):
        self.picture = Picture(ctx)
        self.drawn = None  # what the picture shows

    def draw(self, points: np.ndarray, selected: int | None, target_size: tuple[int, int]) -> None:
        """Draw into the bound framebuffer of target_size (width, height).

        points: (68, 2) float32 target pixels, origin top-left, y down; selected: highlighted point.
        """
        state = (points.tobytes(), selected, tuple(target_size))
        if state != self.drawn:
            self.picture.upload(self._rasterise(points, selected, target_size))
            self.drawn = state
        self.picture.draw((0.0, 0.0, 1.0, 1.0))

    def _rasterise(self, points: np.ndarray, selected: int | None, target_size: tuple[int, int]) -> np.ndarray:
        """(H, W, 4) uint8 premultiplied RGBA marks the size of the target."""
        width, height = target_size
        plate = np.zeros((height, width, 4), np.uint8)  # drawn on transparent black: AA edges come out premultiplied
        one = 1 << SUBPIXEL_BITS
        xy = np.round(points * one).astype(np.int32)
        for indices, closed, colour in OUTLINES:
            cv2.polylines(plate, [xy[list(indices)]], closed, (*colour, 255), LINE_THICKNESS, cv2.LINE_AA, SUBPIXEL_BITS)
        dot = float(np.clip(DOT_SHARE * lm.face_scale(points), MIN_DOT_RADIUS, DOT_RADIUS))
        for i, (x, y) in enumerate(xy.tolist()):
            radius = SELECTED_RADIUS if i == selected else dot
            cv2.circle(plate, (x, y), round((radius + 1.5) * one), (0, 0, 0, 255), -1, cv2.LINE_AA, SUBPIXEL_BITS)
            cv2.circle(plate, (x, y), round(radius * one), (*POINT_COLOURS[i].tolist(), 255), -1, cv2.LINE_AA, SUBPIXEL_BITS)
            if i == selected:
                cv2.circle(plate, (x, y), round((radius + 3) * one), (255, 255, 255, 255), 2, cv2.LINE_AA, SUBPIXEL_BITS)
        return plate

    def release(self) -> None:
        self.picture.release()


class Editor:
    """The editor's state and what the user does to it; drawing goes to any `puppet.window` Display.

    points: (68, 2) float32 edited landmarks, image pixels. `handle` maps event positions with
    `target_size`, the size of the target they were given in (set by `draw` and by the loop).
    """

    def __init__(self, puppet: Puppet, ctx: moderngl.Context, output: Path):
        """Saving writes `output` (overwriting it: whether that is allowed is `edit`'s question)."""
        self.puppet = puppet
        self.output = Path(output)
        self.ctx = ctx
        self.image_size = tuple(puppet.rig.image_size)
        rest = puppet.rig.landmarks
        self.start = rest[:, :2].astype(np.float32).copy()
        # Depth given with the landmarks is kept; depth the rig derived is derived again for the new points.
        derived = np.allclose(rest[:, 2], lm.with_depth(rest[:, :2])[:, 2], atol=1e-3)
        self.depth = None if derived else rest[:, 2:3].copy()
        self.points = self.start.copy()
        self.saved_points = self.start.copy()  # the points as last saved (or as given): quitting loses nothing
        self.history: list[np.ndarray] = []  # undo stack of earlier points
        self.target_size = (1, 1)
        self.selected: int | None = None  # the point being dragged
        self.hovered: int | None = None  # the point under the mouse (or last grabbed)
        self.grab: tuple[list[int], np.ndarray, np.ndarray] | None = None  # dragged indices, their points and the mouse at the press
        self.part_mode = False
        self.show_help = False
        self.confirm_quit = False
        self.quit = False
        self.saved: Path | None = None
        self.problem: str | None = None  # why the points cannot be rigged now
        self.notice = ("", -np.inf)  # (text, perf_counter time it was given)
        self.preview_since: float | None = None  # None: editing; else when the preview loop began (None until drawn)
        self.previewing = False
        self.preview_positions: np.ndarray | None = None  # (T, N, 2) float32 image pixels
        self.preview_renderer: PuppetRenderer | None = None
        self.built: tuple[bytes, Rig] | None = None  # the last rig built, for the points it was built from
        self.renderer = PuppetRenderer(ctx, puppet.image, puppet.rig)
        self.rest_positions = puppet.rig.vertices[:, :2].astype(np.float32)
        self.marks = Marks(ctx)
        self.overlay = TextOverlay(ctx)
        self.rebuild()

    @property
    def dirty(self) -> bool:
        """Whether the points differ from what was last saved (or given)."""
        return not np.array_equal(self.points, self.saved_points)

    # Mapping between image pixels and target pixels.

    def to_target(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) image pixels → target pixels."""
        scale, shift = fit(self.image_size, self.target_size)
        return points * scale + shift

    def to_image(self, x: float, y: float) -> np.ndarray:
        """(2,) float32 image pixels under target pixel (x, y), clamped to the image."""
        scale, shift = fit(self.image_size, self.target_size)
        point = (np.array([x, y], np.float32) - shift) / scale
        return np.clip(point, 0.0, np.array(self.image_size, np.float32)).astype(np.float32)

    def pick(self, x: float, y: float) -> int | None:
        """The point within PICK_RADIUS target pixels of (x, y), nearest first; None if none."""
        distance = np.linalg.norm(self.to_target(self.points) - (x, y), axis=1)
        nearest = int(np.argmin(distance))
        return nearest if distance[nearest] <= PICK_RADIUS else None

    # Input.

    def handle(self, event: Event) -> None:
        """Apply one input event (see `puppet.window.Event`; "move" is the mouse moving unpressed)."""
        if event.kind == "press":
            self._press(event)
        elif event.kind == "drag":
            self._drag(event)
        elif event.kind == "up":
            self._release()
        elif event.kind == "move":
            self.hovered = self.pick(event.x, event.y)
        elif event.kind == "key":
            self._key(event)

    def _press(self, event: Event) -> None:
        self.confirm_quit = False
        self.stop_preview()
        index = self.pick(event.x, event.y)
        self.selected = self.hovered = index
        if index is None:
            return
        indices = [index]
        if event.shift or self.part_mode:
            indices = list(next(group for group in GROUPS if index in group))
        self.history.append(self.points.copy())
        self.grab = (indices, self.points[indices].copy(), self.to_image(event.x, event.y))

    def _drag(self, event: Event) -> None:
        if self.grab is None:
            return
        indices, start, mouse = self.grab
        if len(indices) == 1:
            self.points[indices[0]] = self.to_image(event.x, event.y)
            return
        # A part keeps its shape: the shift is limited so that every point stays in the image.
        shift = self.to_image(event.x, event.y) - mouse
        shift = np.clip(shift, -start.min(0), np.array(self.image_size) - start.max(0))
        self.points[indices] = start + shift

    def _release(self) -> None:
        if self.grab is None:
            return
        if np.array_equal(self.points, self.history[-1]):
            self.history.pop()  # a click without a move changes nothing
        else:
            self.rebuild()
        self.grab, self.selected = None, None

    def _key(self, event: Event) -> None:
        key = event.key
        if key not in ("escape", "q"):
            self.confirm_quit = False
        if key in ("escape", "q"):
            if self.dirty and not self.confirm_quit:
                self.confirm_quit = True
                self.tell("unsaved changes: S saves, Esc again quits")
            else:
                self.quit = True
        elif key == "z" and event.ctrl:
            self.undo()
        elif key == "space":
            self.stop_preview() if self.previewing else self.start_preview()
        elif key == "s":
            self.save()
        elif key == "r":
            self.reset()
        elif key == "p":
            self.part_mode = not self.part_mode
            self.tell("part mode: drags move whole parts" if self.part_mode else "part mode off: drags move single points")
        elif key in ("h", "f1"):
            self.show_help = not self.show_help

    def tell(self, text: str) -> None:
        self.notice = (text, time.perf_counter())

    # Actions.

    def undo(self) -> None:
        if self.grab is not None or not self.history:
            return
        self.stop_preview()
        self.points = self.history.pop()
        self.rebuild()

    def reset(self) -> None:
        if self.grab is not None or np.array_equal(self.points, self.start):
            return
        self.stop_preview()
        self.history.append(self.points.copy())
        self.points = self.start.copy()
        self.rebuild()
        self.tell("back to the starting points (Ctrl+Z undoes)")

    def landmarks(self) -> np.ndarray:
        """(68, 2|3) float32 the edited landmarks, with depth when the puppet came with its own."""
        return self.points.copy() if self.depth is None else np.hstack([self.points, self.depth])

    def rebuild(self) -> Rig | None:
        """The rig of the edited points (built once per set of points), or None, with `problem` saying why."""
        key = self.points.tobytes()
        if self.built is not None and self.built[0] == key:
            self.problem = None
            return self.built[1]
        try:
            crossed = crossed_ring(self.points)
            if crossed:
                raise PuppetError(crossed)
            points = lm.validate(self.landmarks(), source="the edited points", image_size=self.image_size)
            made = build(points, self.image_size)
        except PuppetError as error:
            self.problem = str(error)
            return None
        style = replace(self.puppet.rig.mouth_style, interior=made.mouth_style.interior)  # keep the puppet's colours
        made = replace(made, mouth_style=style)
        self.problem = None
        self.built = (key, made)
        return made

    def save(self) -> Path | None:
        """Write the bundle; the folder, or None (and a message) when the points cannot be rigged."""
        made = self.rebuild()
        if made is None:
            self.tell(f"not saved: {self.problem}")
            return None
        try:
            bundle.save(Puppet(self.puppet.image, made, self.puppet.name), self.output, force=True)
        except (PuppetError, OSError) as error:
            self.tell(f"not saved: {error}")
            return None
        self.saved = self.output
        self.saved_points = self.points.copy()
        self.tell(f"saved -> {self.output}")
        return self.output

    def start_preview(self) -> None:
        made = self.rebuild()
        if made is None:
            self.tell(f"no preview: {self.problem}")
            return
        if self.preview_renderer is None or self.preview_renderer.rig is not made:
            if self.preview_renderer is not None:
                self.preview_renderer.release()
            self.preview_renderer = PuppetRenderer(self.ctx, self.puppet.image, made)
            self.preview_positions = made.animate(preview_motion(made.landmarks))
        self.previewing, self.preview_since = True, None

    def stop_preview(self) -> None:
        self.previewing = False

    # Drawing.

    def draw(self, display, now: float | None = None) -> None:
        """Draw the frame for perf_counter time `now` (default: the clock) into `display`
        (begin and draw; the caller presents)."""
        now = time.perf_counter() if now is None else now
        self.target_size = size = tuple(display.size)
        if min(size) <= 0:  # minimized
            return
        display.begin(BACKGROUND)
        if self.previewing:
            if self.preview_since is None:
                self.preview_since = now
            frame = int((now - self.preview_since) * PREVIEW_FPS) % len(self.preview_positions)
            self.preview_renderer.draw(self.preview_positions[frame], size)
        else:
            self.renderer.draw(self.rest_positions, size)
            self.marks.draw(self.to_target(self.points).astype(np.float32), self.selected, size)
        self.overlay.draw(self.lines(now), size)

    def lines(self, now: float) -> list[str]:
        """The overlay's text this frame."""
        lines = [f"{key:8s} {action}" for key, action in KEYS] if self.show_help else [HELP_LINE]
        if self.previewing:
            lines.append("preview (Space: back to editing)")
        elif self.hovered is not None:
            x, y = self.points[self.hovered]
            lines.append(f"point {self.hovered}: {PART_NAMES[self.hovered]}  ({x:.0f}, {y:.0f})")
        if self.part_mode:
            lines.append("part mode")
        if self.problem:
            lines.append(f"cannot rig: {self.problem}")
        text, since = self.notice
        if now - since < NOTICE_SECONDS or (self.confirm_quit and text):
            lines.append(text)
        return [piece for line in lines for piece in _wrap(line, self.target_size)]

    def close(self) -> None:
        """Free the GL resources."""
        for renderer in (self.renderer, self.preview_renderer):
            if renderer is not None:
                renderer.release()
        self.marks.release()
        self.overlay.release()


def _wrap(line: str, target_size: tuple[int, int]) -> list[str]:
    """`line` broken at spaces into pieces that `TextOverlay` draws within the target's width."""
    scale = TextOverlay.SCALE * max(1.0, target_size[1] / 720)  # as TextOverlay sizes its text

    def fits(text: str) -> bool:
        return cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] + 32 <= target_size[0]  # plate margins

    pieces, current = [], ""
    for word in line.split(" "):
        longer = f"{current} {word}" if current else word
        if current and not fits(longer):
            pieces.append(current)
            longer = word
        current = longer
    return pieces + [current]



def edit(puppet: Puppet, output: Path, force: bool = False, display=None) -> Path | None:
    """Open the editor on `puppet` (its rig's landmarks are the starting points).

    S writes the bundle folder `output` (`bundle.save`); an `output` that exists without `force`
    is refused before the window opens. display: a `puppet.window` Display; None opens a Window
    (closed again on return). Returns the saved folder, or None when the user quit without saving.
    """
    output = Path(output)
    if output.exists() and not force:
        raise PuppetError(f"{output} exists; use --force to overwrite")
    if not output.parent.is_dir():
        raise PuppetError(f"output folder does not exist: {output.parent}")
    own = display is None
    if own:
        from puppet.window import Window

        display = Window(f"puppet rig — {puppet.name}", window_size(puppet.rig.image_size))
    try:
        editor = Editor(puppet, display.ctx, output)
        try:
            _loop(editor, display)
        finally:
            editor.close()
    finally:
        if own:
            display.close()
    return editor.saved


def _loop(editor: Editor, display) -> None:
    """poll → handle → draw → present until the user quits or the window closes. Input is polled
    at EDIT_FPS always; frames are drawn at EDIT_FPS while busy, IDLE_FPS when nothing changes."""
    period = 1.0 / EDIT_FPS
    deadline = time.perf_counter()
    last_input = last_drawn = -np.inf
    while not (display.closing or editor.quit):
        now = time.perf_counter()
        size = tuple(display.size)
        resized, editor.target_size = size != editor.target_size, size
        events = display.poll()
        for event in events:
            editor.handle(event)
        if editor.quit:
            break
        if events:
            last_input = now
        busy = editor.previewing or editor.grab is not None or now - last_input < IDLE_AFTER
        if busy or resized or now - last_drawn >= 1.0 / IDLE_FPS:
            editor.draw(display, now)
            display.present()
            last_drawn = now
        deadline = max(deadline + period, now)  # after a stall, pace from now on
        pause = deadline - time.perf_counter()
        if pause > 0:
            time.sleep(pause)

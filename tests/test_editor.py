import json
import subprocess
import sys
import textwrap
import time

import cv2
import numpy as np
import pytest
from conftest import x_env

from puppet import bundle, cli
from puppet.editor import Editor, edit, preview_motion, window_size
from puppet.errors import PuppetError
from puppet.renderer import Canvas, fit
from puppet.window import Event, Offscreen, TextOverlay

SIZE = (600, 480)  # wider than the 512x512 demo: the portrait sits centred, scaled by 480/512
LOWER_LIP = 57


class Scripted(Offscreen):
    """An offscreen display that hands out one scripted event per frame and counts the frames
    begun; it reports closing when the script has run out (so a broken editor cannot hang)."""

    def __init__(self, ctx, size, script):
        super().__init__(ctx, size)
        self.script = list(script)
        self.frames = 0

    @property
    def closing(self):
        return not self.script

    def poll(self):
        return [self.script.pop(0)] if self.script else []

    def begin(self, background):
        self.frames += 1
        super().begin(background)


@pytest.fixture
def editor(gl, demo, tmp_path):
    editor = Editor(demo, gl, tmp_path / "edited.puppet")
    yield editor
    editor.close()


def to_window(point, size, image_size=(512, 512)):
    """(2,) window pixels showing image pixel `point` of the portrait fitted into a window of `size`."""
    scale, shift = fit(image_size, size)
    return np.asarray(point, np.float32) * scale + shift


def drag(points, index, to_image, size=SIZE):
    """Mouse events dragging point `index` of (68, 2) `points` to image pixel `to_image`, in window pixels."""
    start, end = to_window(points[index, :2], size), to_window(to_image, size)
    path = [start + (end - start) * k / 4 for k in range(1, 5)]
    return [Event("press", x=start[0], y=start[1])] + [Event("drag", x=x, y=y) for x, y in path] + [Event("up", x=end[0], y=end[1])]


def test_dragging_a_point_moves_it_to_the_mouse_and_undo_restores_it(gl, editor):
    display = Offscreen(gl, SIZE)
    editor.draw(display)
    before = editor.points.copy()
    target = before[LOWER_LIP] + (7.0, 25.0)
    for event in drag(editor.points, LOWER_LIP, target):
        editor.handle(event)
    assert np.abs(editor.points[LOWER_LIP] - target).max() < 1.0
    assert np.array_equal(np.delete(editor.points, LOWER_LIP, 0), np.delete(before, LOWER_LIP, 0))
    assert editor.dirty and editor.problem is None
    editor.handle(Event("key", "z", ctrl=True))
    assert np.array_equal(editor.points, before) and not editor.dirty


def test_a_point_cannot_leave_the_image(gl, editor):
    editor.draw(Offscreen(gl, SIZE))
    for event in drag(editor.points, 8, (250.0, 700.0)):  # the chin, far below the 512 px portrait
        editor.handle(event)
    assert editor.points[8, 1] == 512.0


def test_shift_drag_moves_the_whole_mouth(gl, editor):
    editor.draw(Offscreen(gl, SIZE))
    before = editor.points.copy()
    events = drag(editor.points, LOWER_LIP, before[LOWER_LIP] + (0.0, 10.0))
    events[0] = Event("press", x=events[0].x, y=events[0].y, shift=True)
    for event in events:
        editor.handle(event)
    moved = editor.points - before
    assert np.abs(moved[48:68] - (0.0, 10.0)).max() < 1.0
    assert not moved[:48].any()


def test_hovering_names_the_point(gl, editor):
    editor.draw(Offscreen(gl, SIZE))
    x, y = editor.to_target(editor.points[LOWER_LIP]) + 5.0
    editor.handle(Event("move", x=x, y=y))
    assert any("point 57: outer lip" in line for line in editor.lines(time.perf_counter()))


def test_saving_writes_a_bundle_that_renders(gl, demo, demo_speech, tmp_path):
    output = tmp_path / "edited.puppet"
    target = demo.rig.landmarks[LOWER_LIP, :2] + (0.0, 20.0)
    script = drag(demo.rig.landmarks, LOWER_LIP, target) + [Event("key", "s"), Event("key", "escape")]
    display = Scripted(gl, SIZE, script)
    assert edit(demo, output, display=display) == output
    assert display.frames >= 5  # the loop drew between the events
    landmarks = np.array(json.loads((output / bundle.RIG_FILE).read_text())["vertices"])[:68, :2]
    assert np.abs(landmarks[LOWER_LIP] - target).max() < 1.0
    assert np.allclose(np.delete(landmarks, LOWER_LIP, 0), np.delete(demo.rig.landmarks[:, :2], LOWER_LIP, 0), atol=1e-3)
    video = tmp_path / "out.mp4"
    assert cli.main(["render", str(output), str(demo_speech), "-o", str(video), "--motion", "loudness", "-q"]) == 0
    assert video.stat().st_size > 0


def test_quitting_without_saving_returns_none_and_writes_nothing(gl, demo, tmp_path):
    output = tmp_path / "never.puppet"
    script = drag(demo.rig.landmarks, LOWER_LIP, demo.rig.landmarks[LOWER_LIP, :2] + (0.0, 20.0)) + [Event("key", "escape")]
    display = Scripted(gl, SIZE, script + [Event("key", "escape")])
    assert edit(demo, output, display=display) is None
    assert not display.script  # the first Esc only warned: the second was needed
    assert list(tmp_path.iterdir()) == []


def test_first_escape_with_unsaved_changes_only_warns(gl, editor):
    editor.draw(Offscreen(gl, SIZE))
    for event in drag(editor.points, LOWER_LIP, editor.points[LOWER_LIP] + (0.0, 10.0)):
        editor.handle(event)
    editor.handle(Event("key", "escape"))
    assert not editor.quit
    assert "unsaved changes: S saves, Esc again quits" in editor.lines(time.perf_counter())
    editor.handle(Event("key", "s"))
    editor.handle(Event("key", "escape"))
    assert editor.quit and editor.saved == editor.output


def test_preview_moves_the_puppet(gl, editor):
    display = Offscreen(gl, SIZE)
    editor.handle(Event("key", "space"))
    assert editor.previewing
    editor.draw(display, now=0.0)
    rest = display.canvas.read().astype(int)
    differences = []
    for now in (0.3, 1.6, 2.4, 2.92, 3.25):  # talking, "oo", "ee", the blink, the head turn
        editor.draw(display, now=now)
        differences.append(np.abs(display.canvas.read().astype(int) - rest).max(axis=2))
    mouth = (slice(285, 345), slice(250, 350))  # around the mouth: image (256, 331) * 480/512 + (60, 0)
    assert (differences[0][mouth] > 60).sum() > 200  # the jaw is open
    assert all((difference > 60).sum() > 100 for difference in differences)
    editor.handle(Event("key", "space"))
    assert not editor.previewing


def test_preview_motion_loops_from_rest(demo):
    motion = preview_motion(demo.rig.landmarks)
    assert len(motion) == 100
    jaw = motion.offsets[:, LOWER_LIP, 1]
    assert abs(jaw[0]) < 0.5 and abs(jaw[-1]) < 0.5 and jaw.max() > 10.0
    assert np.degrees(np.abs(motion.rotation[:, 1]).max()) > 4.0


def test_an_unriggable_edit_is_refused_not_saved(gl, editor, tmp_path):
    editor.draw(Offscreen(gl, SIZE))
    for event in drag(editor.points, 36, editor.points[39] + (15.0, 0.0)):  # an eye corner dragged across the eye
        editor.handle(event)
    assert "right eye outline crosses itself" in editor.problem
    editor.handle(Event("key", "s"))
    editor.handle(Event("key", "space"))
    assert not editor.previewing and editor.saved is None
    assert not (tmp_path / "edited.puppet").exists()
    assert any(line.startswith("cannot rig:") for line in editor.lines(time.perf_counter()))
    editor.handle(Event("key", "z", ctrl=True))
    assert editor.problem is None
    editor.handle(Event("key", "space"))
    assert editor.previewing


def test_an_inner_lip_corner_across_the_mouth_is_refused(gl, editor):
    editor.draw(Offscreen(gl, SIZE))
    for event in drag(editor.points, 60, editor.points[64] + (5.0, 0.0)):
        editor.handle(event)
    assert "folded mesh" in editor.problem
    assert editor.save() is None


def test_existing_output_is_refused_before_anything_is_drawn(gl, demo, tmp_path):
    output = tmp_path / "taken.puppet"
    output.mkdir()
    display = Scripted(gl, SIZE, [Event("key", "s"), Event("key", "escape")])
    with pytest.raises(PuppetError, match="exists"):
        edit(demo, output, display=display)
    assert display.frames == 0 and len(display.script) == 2
    assert edit(demo, output, force=True, display=display) == output
    assert (output / bundle.RIG_FILE).is_file()


def test_a_resized_window_keeps_the_mapping(gl, editor):
    display = Offscreen(gl, SIZE)
    editor.draw(display)
    display.size = (300, 700)  # narrow and tall: the portrait is 300 px wide, centred vertically
    display.canvas = Canvas(gl, display.size, 0)
    editor.draw(display)
    x, y = np.round(to_window(editor.points[LOWER_LIP], display.size)).astype(int)
    assert (x, y) == (150, 394)  # (256, 331) * 300/512 + (0, 200)
    assert tuple(display.canvas.read()[y, x, :3]) == (255, 70, 70)  # the lower lip's dot is drawn there
    target = editor.points[LOWER_LIP] + (-12.0, 30.0)
    for event in drag(editor.points, LOWER_LIP, target, display.size):
        editor.handle(event)
    assert np.abs(editor.points[LOWER_LIP] - target).max() < 1.0


def test_the_overlay_text_fits_a_narrow_window(gl, editor):
    editor.draw(Offscreen(gl, (300, 700)))
    editor.handle(Event("key", "h"))
    editor.problem = "the right eye outline crosses itself (points 36-41): drag them back in order"
    lines = editor.lines(time.perf_counter())
    assert len(lines) > 10
    assert all(cv2.getTextSize(line, cv2.FONT_HERSHEY_SIMPLEX, TextOverlay.SCALE, 1)[0][0] + 32 <= 300 for line in lines)


def test_reset_returns_to_the_starting_points(gl, editor):
    editor.draw(Offscreen(gl, SIZE))
    for index in (LOWER_LIP, 30):
        for event in drag(editor.points, index, editor.points[index] + (5.0, 5.0)):
            editor.handle(event)
    editor.handle(Event("key", "r"))
    assert np.array_equal(editor.points, editor.start) and not editor.dirty
    editor.handle(Event("key", "z", ctrl=True))
    assert editor.dirty


def test_window_size_follows_the_portrait():
    assert window_size((512, 512)) == (600, 600)
    assert window_size((3000, 2000)) == (1500, 1000)
    assert window_size((800, 900)) == (800, 900)


# The window test runs in its own interpreter: this one has the EGL test context current, and
# GLX refuses to make a window's context current beside it (BadAccess).
WINDOW_SCRIPT = textwrap.dedent("""
    import sys
    import numpy as np
    from puppet import bundle
    from puppet.editor import edit, window_size
    from puppet.renderer import fit
    from puppet.window import Event, Window

    puppet = bundle.load(*bundle.demo_files()[:2])
    window = Window("puppet rig test", window_size(puppet.rig.image_size))
    scale, shift = fit(puppet.rig.image_size, window.size)
    start = puppet.rig.landmarks[57, :2] * scale + shift
    end = (puppet.rig.landmarks[57, :2] + (0, 20)) * scale + shift
    window.events += [Event("press", x=start[0], y=start[1]), Event("drag", x=end[0], y=end[1]),
                      Event("up", x=end[0], y=end[1]), Event("key", "s"), Event("key", "escape")]
    print(edit(puppet, sys.argv[1], display=window))
    window.close()
""")


def test_a_real_window_edits_and_saves(xvfb, demo, tmp_path):
    output = tmp_path / "window.puppet"
    env = x_env(xvfb)
    result = subprocess.run([sys.executable, "-c", WINDOW_SCRIPT, str(output)], capture_output=True, text=True,
                            timeout=60, check=False, env=env)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == str(output)
    moved = bundle.load(output).rig.landmarks[LOWER_LIP, :2]
    assert np.abs(moved - (demo.rig.landmarks[LOWER_LIP, :2] + (0.0, 20.0))).max() < 1.0

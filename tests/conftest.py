"""Shared fixtures: one headless GL context, the demo puppet, and the optional shared media."""
from pathlib import Path

import numpy as np
import pytest

from puppet import bundle
from puppet.landmarks import with_depth
from puppet.renderer import headless_context

# Third-party test media beside the repo (absent on a user's fresh clone: tests using it skip).
SHARED_MEDIA = Path(__file__).resolve().parents[2] / "shared" / "media"


@pytest.fixture(scope="session")
def gl():
    ctx = headless_context()
    yield ctx
    ctx.release()


@pytest.fixture(scope="session")
def demo():
    image, landmarks, _ = bundle.demo_files()
    return bundle.load(image, landmarks)


@pytest.fixture(scope="session")
def demo_speech():
    return bundle.demo_files()[2]


def shared(*parts: str) -> Path:
    """A path under ../shared/media, skipping the test when it is absent."""
    path = SHARED_MEDIA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"{path} is not available")
    return path


def drawn_face(centre=(256.0, 256.0), iod=100.0, tilt_degrees=0.0, mouth_gap=0.02):
    """(68, 3) float32 rest landmarks of a drawn frontal face, image pixels; eyes `iod` px apart."""
    arc = np.linspace(np.pi, 0.0, 17)
    jaw = np.column_stack([np.cos(arc), 1.45 * np.sin(arc)])
    brow = np.column_stack([np.linspace(-0.85, -0.2, 5), -0.3 - 0.08 * np.sin(np.linspace(0.3, 2.8, 5))])
    nose = [(0, 0.05), (0, 0.25), (0, 0.45), (0, 0.62), (-0.2, 0.7), (-0.1, 0.74), (0, 0.76), (0.1, 0.74), (0.2, 0.7)]
    eye = np.array([(-0.65, 0), (-0.55, -0.06), (-0.45, -0.06), (-0.35, 0), (-0.45, 0.05), (-0.55, 0.05)])
    h = mouth_gap / 2
    lips = [(-0.4, 1.0), (-0.25, 0.92), (-0.1, 0.88), (0, 0.9), (0.1, 0.88), (0.25, 0.92), (0.4, 1.0),
            (0.25, 1.1), (0.1, 1.14), (0, 1.15), (-0.1, 1.14), (-0.25, 1.1),
            (-0.32, 1.0), (-0.1, 1 - h), (0, 1 - h), (0.1, 1 - h), (0.32, 1.0), (0.1, 1 + h), (0, 1 + h), (-0.1, 1 + h)]
    unit = np.concatenate([jaw, brow, brow[::-1] * (-1, 1), nose, eye, eye[[3, 2, 1, 0, 5, 4]] * (-1, 1), lips])
    c, s = np.cos(np.radians(tilt_degrees)), np.sin(np.radians(tilt_degrees))
    return with_depth(unit @ np.array([[c, s], [-s, c]]) * iod + np.asarray(centre))


@pytest.fixture(scope="session")
def xvfb():
    """A virtual X display for window tests, its number chosen by Xvfb (-displayfd): the DISPLAY
    name to give a subprocess (skips when Xvfb is not installed). Windows open in subprocesses:
    GLX will not make a window current beside the tests' EGL context (BadAccess)."""
    import os
    import shutil
    import subprocess

    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (apt install xvfb)")
    read, write = os.pipe()
    server = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                              pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write)
    try:
        with os.fdopen(read) as pipe:
            number = pipe.readline().strip()
        if not number:
            pytest.skip("Xvfb did not start")
        yield f":{number}"
    finally:
        server.terminate()
        server.wait(timeout=10)


def x_env(display: str) -> dict:
    """This process's environment pointed at an X display only (no Wayland), for a window subprocess."""
    import os

    return {key: value for key, value in os.environ.items() if key != "WAYLAND_DISPLAY"} | {"DISPLAY": display}

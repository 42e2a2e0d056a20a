from pathlib import Path

import cv2
import numpy as np
import pytest

from puppet import detect as detect_module
from puppet import landmarks as lm
from puppet.detect import composite_over_white, detect
from puppet.errors import PuppetError
from puppet.image import load_image

# Third-party portraits beside the repo (absent on a user's fresh clone: those tests skip).
PORTRAITS = sorted((Path(__file__).resolve().parents[2] / "shared" / "media" / "portraits").glob("*.*"))
needs_portraits = pytest.mark.skipif(not PORTRAITS, reason="../shared/media/portraits is not here")
MIN_EYE_DISTANCE = 30  # pixels: the smallest faces among the portraits are about 60


def _assert_plausible(points: np.ndarray, image: np.ndarray) -> None:
    height, width = image.shape[:2]
    lm.validate(points, image_size=(width, height))
    assert lm.face_scale(points) > MIN_EYE_DISTANCE
    right_eye, left_eye = lm.eye_centres(points)
    assert right_eye[0] < left_eye[0]  # the subject's right eye is on the image's left
    eyes_y = (right_eye[1] + left_eye[1]) / 2
    mouth_y = points[list(lm.MOUTH_CORNERS), 1].mean()
    assert eyes_y < points[lm.NOSE_TIP, 1] < mouth_y < points[8, 1]  # eyes, nose, mouth, chin


def test_no_face_raises_with_the_rigging_hint():
    rng = np.random.default_rng(0)
    image = np.dstack([cv2.GaussianBlur(rng.integers(0, 256, (240, 320, 3), dtype=np.uint8), (9, 9), 0),
                       np.full((240, 320), 255, np.uint8)])
    with pytest.raises(PuppetError) as error:
        detect(image, "noise.png")
    message = str(error.value)
    assert "no face found in noise.png" in message
    assert "--landmarks FILE" in message and "puppet rig noise.png --edit" in message and "--points" in message


def test_wrong_image_layout_is_refused():
    with pytest.raises(PuppetError, match="RGBA"):
        detect(np.zeros((64, 64, 3), np.uint8), "rgb.png")


def test_transparent_pixels_become_white():
    image = np.array([[[10, 20, 30, 0], [10, 20, 30, 255], [0, 0, 0, 128]]], dtype=np.uint8)
    np.testing.assert_array_equal(composite_over_white(image), [[[255, 255, 255], [10, 20, 30], [127, 127, 127]]])


@needs_portraits
@pytest.mark.parametrize("path", PORTRAITS, ids=lambda path: path.name)
def test_portraits_are_detected(path):
    image = load_image(path)
    _assert_plausible(detect(image, path.name), image)


@needs_portraits
def test_landmarks_follow_the_image_when_it_is_scaled():
    # 256 px is searched upsampled, 2560 px on a shrunken copy: both map back to the same face.
    image = load_image(next(path for path in PORTRAITS if path.name == "makeittalk_monalisa2.jpg"))
    small = detect(image, "small")
    large = detect(cv2.resize(image, None, fx=10, fy=10, interpolation=cv2.INTER_CUBIC), "large")
    error = np.linalg.norm((large + 0.5) / 10 - 0.5 - small, axis=1).mean()
    assert error < 0.03 * lm.face_scale(small)


@needs_portraits
def test_cnn_fallback_finds_the_same_face(monkeypatch):
    image = load_image(next(path for path in PORTRAITS if path.name == "sadtalker_people_0.png"))
    by_hog = detect(image, "hog")
    monkeypatch.setattr(detect_module, "_hog_box", lambda rgb: None)
    by_cnn = detect(image, "cnn")
    _assert_plausible(by_cnn, image)
    assert np.linalg.norm(by_cnn - by_hog, axis=1).mean() < 0.05 * lm.face_scale(by_hog)

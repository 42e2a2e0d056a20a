import numpy as np
import pytest

from puppet import landmarks as lm
from puppet.errors import PuppetError
from puppet.template import (
    CONTROL_POINTS,
    MEAN_FACE,
    control_points,
    fit,
    make_mean_face,
    parse_points,
)

SIZE = (400, 400)
# Plausible control points for a face in a 400x400 image, in CONTROL_POINTS order.
POINTS = np.array([[150, 160], [250, 165], [198, 225], [160, 270], [240, 272]], dtype=np.float32)


def test_mean_face_is_normalised_and_face_shaped():
    assert MEAN_FACE.shape == (lm.N_LANDMARKS, 2)
    np.testing.assert_allclose(lm.eye_centres(MEAN_FACE), [[-0.5, 0.0], [0.5, 0.0]], atol=1e-4)
    nose, chin = MEAN_FACE[lm.NOSE_TIP], MEAN_FACE[8]
    mouth = MEAN_FACE[list(lm.MOUTH_CORNERS)]
    assert 0 < nose[1] < mouth[:, 1].min() and mouth[:, 1].max() < chin[1]
    assert mouth[0, 0] < nose[0] < mouth[1, 0]
    assert np.all(np.diff(MEAN_FACE[list(lm.JAW)[:9], 0]) > 0)  # the jaw runs left to right to the chin


def test_regenerated_mean_face_matches_the_committed_file():
    np.testing.assert_allclose(make_mean_face(), MEAN_FACE, atol=0.01)


def test_fit_meets_the_control_points_exactly():
    face = fit(POINTS, SIZE)
    assert face.shape == (lm.N_LANDMARKS, 2) and face.dtype == np.float32
    assert np.abs(control_points(face) - POINTS).max() < 0.01
    lm.validate(face, image_size=SIZE)


@pytest.mark.parametrize("scale, degrees, shift", [(100, 0, (200, 150)), (57.5, 20, (80, 60)), (200, -35, (250, 300))])
def test_fit_to_a_moved_mean_face_gives_that_face(scale, degrees, shift):
    angle = np.radians(degrees)
    turn = np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]])
    face = MEAN_FACE @ turn * scale + shift
    np.testing.assert_allclose(fit(control_points(face), (600, 800)), face, atol=0.01)


def test_fit_to_a_squashed_face_keeps_every_part_in_place():
    # Wide-set eyes, a nose low over a small mouth: a cartoon's proportions.
    points = np.array([[110, 150], [290, 150], [200, 250], [175, 285], [225, 285]], dtype=np.float32)
    face = fit(points, SIZE)
    chin = lm.JAW[len(lm.JAW) // 2]
    assert np.all(np.diff(face[list(lm.JAW)[: chin + 1], 0]) > 0)
    assert np.all(np.diff(face[list(lm.JAW)[chin:], 0]) > 0)
    for ring in (lm.RIGHT_EYE, lm.LEFT_EYE, lm.OUTER_LIP, lm.INNER_LIP):
        assert np.sign(_signed_area(face[list(ring)])) == np.sign(_signed_area(MEAN_FACE[list(ring)]))
    right_eye, left_eye = face[list(lm.RIGHT_EYE)], face[list(lm.LEFT_EYE)]
    assert right_eye[:, 0].max() < face[lm.NOSE_TIP, 0] < left_eye[:, 0].min()
    assert face[list(lm.MOUTH)][:, 1].min() > face[lm.NOSE_TIP, 1]


def _signed_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _moved(index: int, to: tuple[float, float]) -> np.ndarray:
    points = POINTS.copy()
    points[index] = to
    return points


@pytest.mark.parametrize(
    "points, message",
    [
        (_moved(4, (410, 272)), "outside the 400x400 image"),
        (POINTS[[1, 0, 2, 3, 4]], "eyes are swapped"),
        (_moved(1, (150.5, 160.5)), "coincide"),
        (_moved(3, (160, 100)), "mouth must be below the eyes"),
        (_moved(2, (198, 120)), "nose tip must be below the eyes"),
        (POINTS[[0, 1, 2, 4, 3]], "mouth corners are swapped"),
        (np.array([[100, 100], [300, 100], [200, 101], [150, 102], [250, 102]], dtype=np.float32), "one line"),
        (_moved(2, (200, 330)), "fold"),  # nose tip below the mouth
        (_moved(2, (120, 200)), "fold"),  # nose tip beside the face
    ],
)
def test_fit_refuses_nonsense(points, message):
    with pytest.raises(PuppetError, match=message):
        fit(points, SIZE)


def test_parse_points_reads_five_pixel_positions():
    points = parse_points(["150,160", "250.5,165", "198,225", " 160 , 270", "240,272.25"])
    assert points.shape == (len(CONTROL_POINTS), 2) and points.dtype == np.float32
    np.testing.assert_allclose(points[[1, 3, 4]], [[250.5, 165], [160, 270], [240, 272.25]])


@pytest.mark.parametrize(
    "texts, message",
    [
        (["1,2"] * 4, "takes 5 points"),
        (["1,2"] * 6, "takes 5 points"),
        (["1,2"] * 4 + ["3;4"], "cannot read '3;4'"),
        (["1,2"] * 4 + ["a,b"], "cannot read 'a,b'"),
        (["1,2"] * 4 + ["1,2,3"], "cannot read '1,2,3'"),
        (["1,2"] * 4 + ["nan,4"], "not a finite"),
    ],
)
def test_parse_points_errors(texts, message):
    with pytest.raises(PuppetError, match=message):
        parse_points(texts)


def test_a_face_cut_off_by_the_frame_still_fits():
    points = np.array([[20, 20], [60, 20], [40, 45], [25, 60], [55, 60]], dtype=np.float32)  # chin below the edge
    face = fit(points, SIZE)
    assert face[8, 1] > 60  # the chin continues the face; bundle.load clamps it into the image


def test_a_centred_face_sits_upright_in_the_middle_and_rigs():
    from puppet.landmarks import eye_centres
    from puppet.rig import build
    from puppet.template import CENTRED_EYES, centred

    face = centred((400, 300))
    eyes = eye_centres(face)
    assert abs(np.linalg.norm(eyes[1] - eyes[0]) - CENTRED_EYES * 300) < 0.5
    assert abs(eyes[:, 1] - eyes[:, 1].mean()).max() < 0.5 and abs(eyes[:, 0].mean() - 200) < 0.5
    assert face.min() >= 0 and face[:, 0].max() <= 400 and face[:, 1].max() <= 300
    build(face, (400, 300))

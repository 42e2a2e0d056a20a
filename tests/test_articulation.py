from pathlib import Path

import numpy as np
import pytest
from conftest import drawn_face

from puppet.articulation import JAW_OPEN_GAP, UNITS, blend, close_lips, unit_offsets
from puppet.landmarks import (
    EYELID_PAIRS,
    INNER_LIP_PAIRS,
    JAW,
    LEFT_BROW,
    LEFT_EYE,
    MOUTH,
    NOSE,
    RIGHT_BROW,
    RIGHT_EYE,
    load,
    with_depth,
)

# Hand-placed landmarks of real cartoon portraits, beside the repository when available.
CARTOONS = sorted((Path(__file__).resolve().parents[2] / "shared" / "media" / "cartoons").glob("*_landmarks.txt"))



REST = drawn_face()
OWN_PARTS = {  # the points each unit may move
    "jaw_open": set(JAW) | set(MOUTH),
    "lip_wide": set(MOUTH),
    "lip_round": set(MOUTH),
    "lip_press": set(MOUTH),
    "smile": set(MOUTH) | set(JAW),
    "blink_right": {37, 38, 40, 41},
    "blink_left": {43, 44, 46, 47},
    "brow_raise": set(RIGHT_BROW) | set(LEFT_BROW),
    "brow_frown": set(RIGHT_BROW) | set(LEFT_BROW),
    "upper_lip_raise": set(MOUTH),
    "lower_lip_tuck": set(MOUTH),
}


def inner_gap(points):
    """Mean inner-lip opening (pixels) of (..., 68, 3) points on an upright face."""
    return np.mean([points[..., lower, 1] - points[..., upper, 1] for upper, lower in INNER_LIP_PAIRS], axis=0)


def test_every_unit_is_present_and_moves_only_its_own_part():
    units = unit_offsets(REST)
    assert set(units) == set(UNITS)
    for name, offsets in units.items():
        assert offsets.shape == (68, 3) and offsets.dtype == np.float32
        moved = set(np.flatnonzero(np.abs(offsets).max(1) > 1e-6))
        assert moved, name
        assert moved <= OWN_PARTS[name], (name, sorted(moved - OWN_PARTS[name]))


def test_jaw_open_parts_the_lips_by_a_third_of_the_eye_distance_and_leaves_eyes_brows_and_nose():
    units = unit_offsets(REST)
    opened = REST + units["jaw_open"]
    assert inner_gap(opened) - inner_gap(REST) == pytest.approx(JAW_OPEN_GAP * 100.0, abs=0.5)
    assert opened[57, 1] > REST[57, 1] + 25 and opened[8, 1] > REST[8, 1] + 20  # lower lip and chin drop
    for part in (RIGHT_EYE, LEFT_EYE, RIGHT_BROW, LEFT_BROW, NOSE):
        assert np.all(units["jaw_open"][list(part)] == 0)


@pytest.mark.parametrize("name, pairs", [("blink_right", EYELID_PAIRS[:2]), ("blink_left", EYELID_PAIRS[2:])])
def test_a_full_blink_closes_the_lids_exactly_and_a_half_blink_half_way(name, pairs):
    offsets = unit_offsets(drawn_face(tilt_degrees=17.0))[name]
    rest = drawn_face(tilt_degrees=17.0)
    for upper, lower in pairs:
        shut = rest + offsets
        assert np.linalg.norm(shut[upper] - shut[lower]) < 1e-4
        assert shut[lower, 1] < rest[lower, 1]  # the lower lid rises a little
        half = rest + 0.5 * offsets
        opening = np.linalg.norm(rest[upper] - rest[lower])
        assert np.linalg.norm(half[upper] - half[lower]) == pytest.approx(opening / 2, rel=1e-4)


def test_units_scale_with_the_face():
    small, huge = unit_offsets(drawn_face(iod=20.0)), unit_offsets(drawn_face((900.0, 700.0), iod=400.0))
    for name in UNITS:
        np.testing.assert_allclose(huge[name], 20.0 * small[name], atol=1e-3, err_msg=name)


def test_units_turn_with_a_tilted_face():
    angle = np.radians(25.0)
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    upright, tilted = unit_offsets(REST), unit_offsets(drawn_face(tilt_degrees=25.0))
    for name in UNITS:
        np.testing.assert_allclose(tilted[name][:, :2], upright[name][:, :2] @ turn.T, atol=1e-3, err_msg=name)
        np.testing.assert_allclose(tilted[name][:, 2], upright[name][:, 2], atol=1e-3, err_msg=name)


def test_lip_shapes_do_what_their_names_say():
    units = unit_offsets(REST)
    width = lambda points: points[54, 0] - points[48, 0]
    assert width(REST + units["lip_wide"]) > width(REST) + 10
    rounded = REST + units["lip_round"]
    assert width(rounded) < width(REST) - 15 and rounded[51, 2] > REST[51, 2] + 5  # narrower, pushed forward
    smiling = REST + units["smile"]
    assert smiling[48, 1] < REST[48, 1] - 5 and smiling[54, 1] < REST[54, 1] - 5 and width(smiling) > width(REST)
    assert np.all((REST + units["brow_raise"])[17:27, 1] < REST[17:27, 1] - 5)
    frowning = REST + units["brow_frown"]
    assert frowning[22, 0] - frowning[21, 0] < REST[22, 0] - REST[21, 0] - 5


def test_lip_press_closes_an_open_mouth():
    rest = drawn_face(mouth_gap=0.2)
    pressed = rest + unit_offsets(rest)["lip_press"]
    assert inner_gap(rest) > 19 and abs(inner_gap(pressed)) < 1e-3
    assert pressed[57, 1] - pressed[51, 1] < rest[57, 1] - rest[51, 1] - 20  # lips thinner as well as closed


def test_upper_lip_raise_bares_the_teeth_and_lower_lip_tuck_rolls_the_lower_lip_up_and_in():
    units = unit_offsets(REST)
    raised = REST + units["upper_lip_raise"]
    assert raised[51, 1] < REST[51, 1] - 5 and raised[62, 1] < REST[62, 1] - 4
    assert np.all(units["upper_lip_raise"][list(range(55, 60)) + [65, 66, 67]] == 0)  # lower lip stays
    tucked = REST + units["lower_lip_tuck"]
    assert tucked[57, 1] < REST[57, 1] - 8 and tucked[66, 1] < REST[66, 1] - 6  # up ...
    assert tucked[57, 2] < REST[57, 2] - 4 and tucked[66, 2] < REST[66, 2] - 6  # ... and back
    assert np.all(units["lower_lip_tuck"][[50, 51, 52, 61, 62, 63]] == 0)  # upper lip stays


def test_close_lips_shuts_any_mouth_shape_and_keeps_the_lips_thick():
    units = unit_offsets(REST)
    shapes = np.stack([REST, REST + units["jaw_open"], REST + 0.6 * units["jaw_open"] + units["lip_round"]])
    closed = shapes + close_lips(shapes, np.ones(3, np.float32))
    assert np.all(np.abs(inner_gap(closed)) < 1e-3)
    np.testing.assert_allclose(closed[:, 57] - closed[:, 66], shapes[:, 57] - shapes[:, 66], atol=1e-4)
    half = shapes + close_lips(shapes, np.full(3, 0.5, np.float32))
    np.testing.assert_allclose(inner_gap(half), inner_gap(shapes) / 2, atol=1e-3)
    assert np.all(close_lips(shapes, np.zeros(3, np.float32)) == 0)


def test_blend_is_the_weighted_sum_per_frame():
    units = unit_offsets(REST)
    jaw = np.array([0.0, 0.5, 1.0], np.float32)
    blink = np.array([1.0, 0.0, 0.25], np.float32)
    offsets = blend(units, {"jaw_open": jaw, "blink_left": blink})
    assert offsets.shape == (3, 68, 3) and offsets.dtype == np.float32
    for t in range(3):
        np.testing.assert_allclose(offsets[t], jaw[t] * units["jaw_open"] + blink[t] * units["blink_left"], atol=1e-5)
    with pytest.raises(KeyError):
        blend(units, {"wink": jaw})


@pytest.mark.skipif(not CARTOONS, reason="../shared/media/cartoons is not here")
@pytest.mark.parametrize("path", CARTOONS, ids=lambda path: path.stem)
def test_hand_placed_cartoon_faces_blink_and_press_shut(path):
    rest = with_depth(load(path))
    units = unit_offsets(rest)
    assert all(np.all(np.isfinite(offsets)) for offsets in units.values())
    shut = rest + units["blink_right"] + units["blink_left"]
    pressed = rest + units["lip_press"]
    for upper, lower in EYELID_PAIRS:
        assert np.linalg.norm(shut[upper] - shut[lower]) < 1e-3
    for upper, lower in INNER_LIP_PAIRS:
        assert np.linalg.norm(pressed[upper] - pressed[lower]) < 1e-3

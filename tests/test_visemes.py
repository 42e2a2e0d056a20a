import numpy as np
import pytest

from puppet.alignment import PHONES, SILENCE, Phone
from puppet.landmarks import INNER_LIP_PAIRS, MOUTH, MOUTH_CORNERS
from puppet.visemes import (
    GLIDES,
    KEY_POSES,
    VisemeOptions,
    canonical_rest,
    mouth_motion,
)

FPS = 50.0
REST = canonical_rest()


def utterance(*spec: tuple[str, float], rate: float = 1.0) -> list[Phone]:
    """Phones from (name, seconds) pairs, back to back from 0; rate < 1 speaks faster."""
    phones, time = [], 0.0
    for name, seconds in spec:
        phones.append(Phone(name, time, time + seconds * rate))
        time += seconds * rate
    return phones


def shapes(phones: list[Phone], articulation: float = 1.0) -> np.ndarray:
    """(T, 68, 3) canonical landmarks, IOD units."""
    options = VisemeOptions(articulation=articulation)
    return REST + mouth_motion(phones, int(np.ceil(phones[-1].end * FPS)), FPS, options)


def centre_frame(phone: Phone) -> int:
    return int((phone.start + phone.end) / 2 * FPS)


def inner_gap(points: np.ndarray) -> np.ndarray:
    return np.mean([points[..., lower, 1] - points[..., upper, 1] for upper, lower in INNER_LIP_PAIRS], axis=0)


def mouth_width(points: np.ndarray) -> np.ndarray:
    return points[..., MOUTH_CORNERS[1], 0] - points[..., MOUTH_CORNERS[0], 0]


SENTENCE = utterance(("SIL", 0.4), ("B", 0.07), ("AA", 0.14), ("M", 0.08), ("IY", 0.1), ("F", 0.1), ("UW", 0.15),
                     ("W", 0.08), ("AO", 0.12), ("P", 0.07), ("AH", 0.08), ("V", 0.09), ("IH", 0.1), ("T", 0.08),
                     ("SIL", 0.6))


def test_every_phone_has_a_key_pose():
    assert set(PHONES) | {SILENCE} == set(KEY_POSES) | set(GLIDES)
    assert set(GLIDES.values()) and all(a in KEY_POSES and b in KEY_POSES for a, b in GLIDES.values())


def test_the_mouth_rests_exactly_in_silence_and_in_long_pauses():
    silent = shapes(utterance(("SIL", 1.0)))
    assert silent.shape == (50, 68, 3) and silent.dtype == np.float32
    np.testing.assert_array_equal(silent, np.broadcast_to(REST, silent.shape))
    points = shapes(SENTENCE)
    np.testing.assert_array_equal(points[:2], np.broadcast_to(REST, (2, 68, 3)))  # before speech
    np.testing.assert_array_equal(points[-3:], np.broadcast_to(REST, (3, 68, 3)))  # and well after it


@pytest.mark.parametrize("rate", [1.0, 0.6, 0.4], ids=["normal", "fast", "very-fast"])
def test_lips_shut_at_the_centre_of_every_p_b_m(rate):
    phones = utterance(*[(p.phone, p.end - p.start) for p in SENTENCE], rate=rate)
    points = shapes(phones)
    for phone in phones:
        if phone.phone in ("P", "B", "M"):
            assert abs(inner_gap(points[centre_frame(phone)])) < 0.02, (phone, rate)


def test_ah_opens_the_jaw_more_than_ee():
    points = shapes(SENTENCE)
    aa, iy = (centre_frame(next(p for p in SENTENCE if p.phone == name)) for name in ("AA", "IY"))
    assert inner_gap(points[aa]) > inner_gap(points[iy]) + 0.1
    assert inner_gap(points[aa]) > inner_gap(REST) + 0.15


@pytest.mark.parametrize("name", ["UW", "W"])
def test_oo_and_w_round_the_lips(name):
    points = shapes(SENTENCE)
    frame = points[centre_frame(next(p for p in SENTENCE if p.phone == name))]
    assert mouth_width(frame) < mouth_width(REST) - 0.15
    assert frame[51, 2] > REST[51, 2] + 0.05  # pushed toward the viewer


@pytest.mark.parametrize("name", ["F", "V"])
def test_f_and_v_tuck_the_lower_lip_up(name):
    points = shapes(SENTENCE)
    frame = points[centre_frame(next(p for p in SENTENCE if p.phone == name))]
    assert frame[57, 1] < REST[57, 1] - 0.05 and frame[66, 1] < REST[66, 1] - 0.04
    assert frame[57, 2] < REST[57, 2] - 0.03  # rolled back under the teeth


def test_motion_is_smooth_and_only_moves_the_mouth_and_jaw():
    offsets = shapes(SENTENCE) - REST
    steps = np.linalg.norm(np.diff(offsets, axis=0), axis=2)
    assert steps.max() < 0.15  # IOD per frame at 50 fps
    others = np.setdiff1d(np.arange(68), list(MOUTH) + list(range(17)))
    assert np.all(offsets[:, others] == 0)


def test_diphthongs_glide_from_one_shape_to_another():
    phones = utterance(("SIL", 0.3), ("AY", 0.3), ("SIL", 0.3))
    points = shapes(phones)
    early, late = int(0.37 * FPS), int(0.53 * FPS)
    assert inner_gap(points[early]) > inner_gap(points[late]) + 0.05  # "ah" → "ih"


def test_options_scale_the_articulation():
    weak = shapes(SENTENCE, articulation=0.5)
    strong = shapes(SENTENCE)
    aa = centre_frame(next(p for p in SENTENCE if p.phone == "AA"))
    assert inner_gap(weak[aa]) < inner_gap(strong[aa]) - 0.05

import numpy as np
import pytest
from conftest import shared

from puppet import landmarks as lm
from puppet import rig as rigging
from puppet.errors import PuppetError
from puppet.motion import Motion

CARTOONS = ["bluehead.jpg", "cartoonM.png", "cuphead.png", "danbooru1.jpg", "draw.png", "girl.png"]


def areas(rig, positions):
    return rigging._signed_areas(positions, rig.triangles)


def test_demo_rig_has_tagged_mouth_and_eyes_and_no_fold(demo):
    rig = demo.rig
    assert len(rig.mouth) == len(rigging.MOUTH_STRIP) and len(rig.eyes) == 8
    assert set(rig.triangles[rig.mouth].ravel()) == set(lm.INNER_LIP)
    assert set(rig.triangles[rig.eyes].ravel()) == set(lm.RIGHT_EYE) | set(lm.LEFT_EYE)
    rest = areas(rig, rig.vertices[None, :, :2])[0]
    assert (np.delete(rest, np.r_[rig.mouth, rig.eyes]) > 0).all()
    assert not rig._folded(rig.vertices[None, :, :2])[0]


def test_mesh_covers_the_whole_image_exactly(demo):
    rig = demo.rig
    width, height = rig.image_size
    assert areas(rig, rig.vertices[None, :, :2])[0].sum() == pytest.approx(width * height, rel=1e-4)


def test_head_turn_moves_outline_but_not_border(demo):
    rig = demo.rig
    motion = Motion.still(1, 25)
    motion = Motion(motion.offsets, np.array([[0.0, 0.15, 0.05]], np.float32), motion.translation, 25)
    moved = rig.animate(motion)[0] - rig.vertices[:, :2]
    outline = slice(lm.N_LANDMARKS, lm.N_LANDMARKS + rig.n_outline)
    border = slice(lm.N_LANDMARKS + rig.n_outline, None)
    assert np.abs(moved[outline]).max() > 3
    assert np.abs(moved[border]).max() == 0


def test_fold_guard_scales_back_an_impossible_turn(demo):
    rig = demo.rig
    still = Motion.still(1, 25)
    wild = Motion(still.offsets, np.array([[0.0, 1.4, 1.2]], np.float32), np.array([[900.0, 0.0]], np.float32), 25)
    positions = rig.animate(wild)
    assert not rig._folded(positions)[0]
    assert np.abs(positions - rig.vertices[None, :, :2]).max() > 1  # scaled back, not frozen


def test_lips_asked_to_cross_meet_instead(demo):
    rig = demo.rig
    motion = Motion.still(1, 25)
    offsets = motion.offsets.copy()
    offsets[0, [61, 62, 63], 1] += 0.3 * lm.face_scale(rig.landmarks)  # upper lip pushed below the lower
    positions = rig.animate(Motion(offsets, motion.rotation, motion.translation, 25))[0]
    for upper, lower in lm.INNER_LIP_PAIRS:
        assert positions[lower, 1] >= positions[upper, 1] - 1e-3


def test_a_mouth_drawn_open_shuts_where_the_canonical_mouth_shuts(demo):
    """Most cartoons are drawn mid-smile: offsets that close the canonical face's rest gap (0.10 IOD)
    shut their lips too; offsets that open the mouth are not stretched; a mouth drawn shut is left alone."""
    assert rigging.canonical_lip_gap() == pytest.approx(0.10, abs=0.005)
    points = demo.rig.landmarks.copy()
    scale = lm.face_scale(points)
    points[list(range(55, 60)) + [65, 66, 67] + list(range(5, 12)), 1] += 0.3 * scale  # jaw and lower lip drawn 0.3 IOD lower
    rig = rigging.build(points, demo.rig.image_size)
    still = Motion.still(3, 25)
    offsets = still.offsets.copy()
    offsets[0, [65, 66, 67], 1] -= rigging.canonical_lip_gap() * scale  # the canonical lips shut
    offsets[1, [65, 66, 67], 1] -= 0.5 * rigging.canonical_lip_gap() * scale  # half-way
    offsets[2, list(range(55, 60)) + [65, 66, 67] + list(range(5, 12)), 1] += 0.2 * scale  # jaw opened wider
    positions = rig.animate(Motion(offsets, still.rotation, still.translation, 25))
    gap = rigging._lip_gap(positions, lm.face_axes(points)[1]) / scale
    drawn = float(rigging._lip_gap(points, lm.face_axes(points)[1])) / scale
    assert gap[0] == pytest.approx(0.0, abs=0.01) and gap[1] == pytest.approx(drawn / 2, abs=0.01)
    assert gap[2] == pytest.approx(drawn + 0.2, abs=0.01)
    assert not rig._folded(positions).any()
    shut = demo.rig.animate(Motion(offsets, still.rotation, still.translation, 25))  # drawn with lips together
    assert np.allclose(shut[2, [65, 66, 67]] - demo.rig.landmarks[[65, 66, 67], :2], offsets[2, [65, 66, 67], :2], atol=1e-4)


def test_lips_drawn_as_lines_open_round_and_shut_without_folding(demo):
    """A cartoon mouth drawn as an open outline (outer lip points on the inner ones) follows a
    canonical "ah, m, oo" as drawn lips should: no frame needs the fold guard, the lips shut on m."""
    from puppet.alignment import Phone
    from puppet.visemes import mouth_motion

    points = demo.rig.landmarks.copy()
    scale = lm.face_scale(points)
    points[list(range(55, 60)) + [65, 66, 67] + list(range(5, 12)), 1] += 0.25 * scale  # drawn open
    for lip, (outer, inner) in rigging.LIPS.items():  # lips drawn as lines: outer points almost on the inner curve
        points[outer, 1] += 0.9 * (rigging._across(points, lip) @ points[inner, 1] - points[outer, 1])
    assert np.abs(rigging._lip_thickness(points, "upper")).max() < 0.02
    rig = rigging.build(points, demo.rig.image_size)
    phones = [Phone("SIL", 0.0, 0.2), Phone("AA", 0.2, 0.4), Phone("M", 0.4, 0.55), Phone("UW", 0.55, 0.8), Phone("SIL", 0.8, 1.0)]
    offsets = lm.from_face_units(mouth_motion(phones, 50), points)
    still = Motion.still(len(offsets), 50)
    assert not rig._folded(rig._place(still, rig.fitted(offsets), 1.0, 1.0)).any()
    gap = rigging._lip_gap(rig.animate(Motion(offsets, still.rotation, still.translation, 50)), lm.face_axes(points)[1]) / scale
    drawn = float(rigging._lip_gap(points, lm.face_axes(points)[1])) / scale
    assert gap[int(0.475 * 50)] < 0.15 * drawn and gap[int(0.3 * 50)] > drawn + 0.1


def test_crossed_lips_in_a_landmark_file_are_mended(demo):
    points = demo.rig.landmarks.copy()
    points[[61, 62, 63], 1] += 3  # upper inner lip drawn below the lower one
    rig = rigging.build(points, demo.rig.image_size)
    assert not rig._folded(rig.vertices[None, :, :2])[0]


def test_scrambled_landmarks_are_refused(demo):
    points = demo.rig.landmarks[np.random.default_rng(1).permutation(68)]
    with pytest.raises(PuppetError):
        rigging.build(points, demo.rig.image_size)


@pytest.mark.parametrize("name", CARTOONS)
def test_every_shared_cartoon_rigs_cleanly(name):
    from puppet.image import load_image

    image = load_image(shared("cartoons", name))
    points = lm.load(shared("cartoons", name.rsplit(".", 1)[0] + "_landmarks.txt"))
    rig = rigging.build(points, (image.shape[1], image.shape[0]))
    assert not rig._folded(rig.vertices[None, :, :2])[0]
    jaw_open = Motion.still(1, 25).offsets.copy()
    jaw_open[0, list(range(55, 60)) + [65, 66, 67] + list(range(5, 12)), 1] += 0.3 * lm.face_scale(points)
    opened = rig.animate(Motion(jaw_open, np.zeros((1, 3), np.float32), np.zeros((1, 2), np.float32), 25))
    assert not rig._folded(opened)[0]
    mouth = areas(rig, opened)[0][rig.mouth].sum()
    assert mouth > areas(rig, rig.vertices[None, :, :2])[0][rig.mouth].sum()


@pytest.mark.parametrize("name", CARTOONS)
def test_every_shared_cartoon_opens_on_ah_and_closes_on_m(name):
    """Drawn open or shut, thick-lipped or line-lipped: a canonical "ah, m, ah" opens the mouth
    past its drawn gap and at least halves the gap of one drawn open."""
    from puppet.alignment import Phone
    from puppet.image import load_image
    from puppet.visemes import mouth_motion

    image = load_image(shared("cartoons", name))
    points = lm.load(shared("cartoons", name.rsplit(".", 1)[0] + "_landmarks.txt"))
    rig = rigging.build(points, (image.shape[1], image.shape[0]))
    phones = [Phone("SIL", 0.0, 0.3), Phone("AA", 0.3, 0.5), Phone("M", 0.5, 0.65), Phone("AA", 0.65, 0.85), Phone("SIL", 0.85, 1.2)]
    offsets = lm.from_face_units(mouth_motion(phones, 60), rig.landmarks)
    still = Motion.still(len(offsets), 50)
    down, scale = lm.face_axes(rig.landmarks)[1], lm.face_scale(rig.landmarks)
    gap = rigging._lip_gap(rig.animate(Motion(offsets, still.rotation, still.translation, 50)), down) / scale
    drawn = float(rigging._lip_gap(rig.landmarks, down)) / scale
    assert gap[int(0.4 * 50)] > drawn + 0.1
    assert gap[int(0.575 * 50)] < max(0.5 * drawn, 0.03)

import numpy as np
import pytest
from conftest import drawn_face

from puppet.landmarks import EYELID_PAIRS, face_scale
from puppet.life import MAX_ROTATION_DEGREES, LifeOptions, life_motion

FPS = 25.0
MINUTE = int(60 * FPS)




REST = drawn_face(tilt_degrees=8.0)


def lid_gaps(motion):
    """(T, 4) distance in pixels between each upper and lower eyelid point pair."""
    points = REST + motion.offsets
    return np.stack([np.linalg.norm(points[:, upper] - points[:, lower], axis=1) for upper, lower in EYELID_PAIRS], 1)


def closures(motion):
    """Number of times the eyes go fully shut."""
    shut = lid_gaps(motion).max(1) < 1e-3
    return int(np.sum(shut[1:] & ~shut[:-1]) + shut[0])


def test_the_same_seed_gives_the_same_motion_and_another_seed_another():
    first, again = life_motion(MINUTE, FPS, REST), life_motion(MINUTE, FPS, REST)
    other = life_motion(MINUTE, FPS, REST, LifeOptions(seed=1))
    for name in ("offsets", "rotation", "translation"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
    assert not np.array_equal(first.rotation, other.rotation)
    assert not np.array_equal(first.offsets, other.offsets)


def test_a_longer_clip_starts_the_same_way():
    short, long = life_motion(MINUTE // 2, FPS, REST), life_motion(MINUTE, FPS, REST)
    np.testing.assert_array_equal(short.offsets, long.offsets[: MINUTE // 2])
    np.testing.assert_allclose(short.rotation, long.rotation[: MINUTE // 2])


@pytest.mark.parametrize("rate", [6.0, 15.0, 30.0])
def test_blinks_per_minute_are_near_the_rate(rate):
    counts = [closures(life_motion(MINUTE, FPS, REST, LifeOptions(blink_rate=rate, seed=seed))) for seed in range(8)]
    assert abs(np.mean(counts) - rate) < 0.25 * rate
    assert min(counts) > 0.4 * rate and max(counts) < 1.7 * rate


def test_no_blinks_at_rate_zero():
    motion = life_motion(MINUTE, FPS, REST, LifeOptions(blink_rate=0.0))
    assert np.all(motion.offsets == 0)


def test_both_eyes_shut_fully_and_together_at_every_blink_and_are_open_between():
    motion = life_motion(MINUTE, FPS, REST)
    gaps = lid_gaps(motion)
    rest_gaps = lid_gaps(life_motion(1, FPS, REST, LifeOptions(blink_rate=0.0)))[0]
    shut = gaps.min(1) < 1e-3
    assert shut.sum() >= 5
    assert np.all(gaps[shut] < 1e-3)  # when one lid pair is shut, all four are
    assert np.median(gaps / rest_gaps, axis=0).min() > 0.99  # open most of the time
    moved = np.flatnonzero(np.abs(motion.offsets).max((0, 2)) > 0)
    assert set(moved) == {37, 38, 40, 41, 43, 44, 46, 47}


def test_blinks_close_faster_than_they_open():
    fps = 100.0  # fine enough to time a 0.15 s blink
    motion = life_motion(int(20 * fps), fps, REST, LifeOptions(blink_rate=10.0, double_blink=0.0))
    closure = 1.0 - lid_gaps(motion).mean(1) / lid_gaps(motion)[0].mean()
    peak = int(np.argmax(closure))
    moving = closure > 0.05
    closing_frames = np.sum(np.cumprod(moving[:peak][::-1]))
    opening_frames = np.sum(np.cumprod(moving[peak + 1:]))
    assert 2 <= closing_frames < opening_frames <= 15


WILD = LifeOptions(idle_degrees=30.0, idle_speed=5.0, breathing_amplitude=0.5)


@pytest.mark.parametrize("options", [LifeOptions(), WILD])
def test_head_rotation_stays_bounded_even_when_talking(options):
    motion = life_motion(4 * MINUTE, FPS, REST, options, activity=np.ones(4 * MINUTE, np.float32))
    assert np.degrees(np.abs(motion.rotation)).max() <= MAX_ROTATION_DEGREES + 1e-4
    assert np.all(np.isfinite(motion.rotation)) and np.all(np.isfinite(motion.translation))


def test_the_head_sways_gently_and_more_while_talking():
    idle = life_motion(2 * MINUTE, FPS, REST)
    talking = life_motion(2 * MINUTE, FPS, REST, activity=np.ones(2 * MINUTE, np.float32))
    degrees = np.degrees(idle.rotation)
    assert 0.5 < np.abs(degrees).max() < 3.5
    assert np.abs(np.diff(degrees, axis=0)).max() < 0.2  # smooth: well under a degree per frame
    assert np.degrees(talking.rotation).std() > 1.2 * degrees.std()


def test_breathing_lifts_the_head_slowly_up_the_face():
    options = LifeOptions(idle_degrees=0.0, blink_rate=0.0)
    motion = life_motion(int(8 * FPS), FPS, REST, options)
    up = -REST[8, :2] + REST[27, :2]  # chin toward the nose bridge
    rise = motion.translation @ (up / np.linalg.norm(up))
    assert rise.max() == pytest.approx(options.breathing_amplitude * face_scale(REST), rel=0.01)
    assert rise.min() > -1e-3 and np.argmax(rise) == pytest.approx(2.0 * FPS, abs=1)  # peaks mid-breath
    assert np.abs(np.degrees(motion.rotation)).max() < 0.5


def test_activity_must_match_the_frame_count():
    with pytest.raises(ValueError):
        life_motion(10, FPS, REST, activity=np.zeros(9, np.float32))
    assert len(life_motion(0, FPS, REST)) == 0

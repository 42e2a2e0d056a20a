import numpy as np
import pytest

from puppet.motion import Motion, interpolate_rows, resample


def ramp(frames):
    """(frames, 68, 3) offsets whose every value is the frame index: easy to read after interpolation."""
    return np.broadcast_to(np.arange(frames, dtype=np.float32)[:, None, None], (frames, 68, 3)).copy()


def test_interpolate_rows_is_linear_between_rows_and_holds_the_ends():
    rows = interpolate_rows(ramp(5), np.array([-1.0, 0.0, 0.25, 2.5, 4.0, 7.0]))
    assert rows.dtype == np.float32 and rows.shape == (6, 68, 3)
    np.testing.assert_allclose(rows[:, 0, 0], [0.0, 0.0, 0.25, 2.5, 4.0, 4.0])


def test_resample_reads_each_output_frame_at_its_centre():
    # 50 fps → 25 fps: output frame i is centred at (i + 0.5) / 25 s, between input frames 2i and 2i + 1.
    halved = resample(ramp(10), 50, 25, 5)
    np.testing.assert_allclose(halved[:, 3, 1], [0.5, 2.5, 4.5, 6.5, 8.5])
    # Same rate: unchanged; more frames than the input covers: the last frame is held.
    np.testing.assert_array_equal(resample(ramp(4), 30, 30, 4), ramp(4))
    np.testing.assert_allclose(resample(ramp(4), 25, 50, 10)[-3:, 0, 0], [3.0, 3.0, 3.0])
    rotation = np.stack([np.linspace(0, 1, 8)] * 3, axis=1)
    assert resample(rotation, 50, 30, 5).shape == (5, 3)


def test_motions_add_slice_and_check_their_shapes():
    still = Motion.still(6, 25.0)
    moving = Motion(ramp(6), np.ones((6, 3), np.float32), np.zeros((6, 2), np.float32), 25.0)
    both = still + moving
    np.testing.assert_array_equal(both.offsets, moving.offsets)
    assert len(both[2:5]) == 3 and both[2:5].offsets[0, 0, 0] == 2.0
    with pytest.raises(ValueError):
        still + Motion.still(6, 30.0)
    with pytest.raises(AssertionError):
        Motion(ramp(6), np.zeros((5, 3), np.float32), np.zeros((6, 2), np.float32), 25.0)

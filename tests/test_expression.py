import numpy as np
import pytest
from conftest import drawn_face

from puppet.errors import PuppetError
from puppet.expression import EXPRESSIONS, ExpressionBlend, expression_offsets
from puppet.landmarks import face_scale

REST = drawn_face(tilt_degrees=5.0)
IOD = face_scale(REST)


def brow_height(offsets):
    """How far the brows rose (IOD), on average, up the face (the face here is nearly upright)."""
    return float(-offsets[17:27, 1].mean() / IOD)


def corner_height(offsets):
    return float(-offsets[[48, 54], 1].mean() / IOD)


def eye_opening(offsets):
    """Change of the upper-to-lower lid distance, IOD (negative: narrower)."""
    points = REST + offsets
    return float((np.linalg.norm(points[41] - points[37]) - np.linalg.norm(REST[41] - REST[37])) / IOD)


def test_neutral_moves_nothing_and_every_other_expression_moves_the_face():
    assert np.all(expression_offsets(REST, "neutral") == 0)
    for name in set(EXPRESSIONS) - {"neutral"}:
        assert np.abs(expression_offsets(REST, name)).max() > 0.03 * IOD, name


def test_each_expression_reads_as_itself():
    happy, angry, surprised, sad = (expression_offsets(REST, n) for n in ("happy", "angry", "surprised", "sad"))
    assert corner_height(happy) > 0.05 and eye_opening(happy) < 0
    assert brow_height(angry) < -0.03 and corner_height(angry) < 0
    assert brow_height(surprised) > 0.05 and eye_opening(surprised) > 0.01
    assert corner_height(sad) < -0.05
    inner, outer = -sad[21, 1], -sad[17, 1]
    assert inner > outer  # sad brows rise at their inner ends


def test_unknown_expression_is_a_clear_error():
    with pytest.raises(PuppetError, match="happy"):
        expression_offsets(REST, "smug")


def test_blend_eases_from_one_expression_to_the_next():
    blend = ExpressionBlend(REST, "neutral")
    assert np.all(blend.offsets(0.0) == 0)
    blend.choose("happy")
    target = expression_offsets(REST, "happy")
    early = blend.offsets(0.05)
    assert 0.1 < np.abs(early).max() / np.abs(target).max() < 0.5
    np.testing.assert_allclose(blend.offsets(2.0), target, atol=1e-3)

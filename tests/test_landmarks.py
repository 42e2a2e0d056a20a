import json

import numpy as np
import pytest

from puppet import landmarks as lm
from puppet.errors import PuppetError


def test_parts_cover_the_68_points_once():
    covered = sorted(i for part in lm.FACIAL_PARTS.values() for i in part)
    assert covered == list(range(lm.N_LANDMARKS))


@pytest.mark.parametrize("suffix", [".txt", ".json", ".npy"])
def test_load_each_format(tmp_path, demo, suffix):
    points = demo.rig.landmarks[:, :2]
    path = tmp_path / f"face{suffix}"
    if suffix == ".txt":
        lm.save_txt(path, points)
    elif suffix == ".json":
        path.write_text(json.dumps({"landmarks": points.tolist()}))
    else:
        np.save(path, points)
    assert np.allclose(lm.load(path), points, atol=1e-3)


def test_text_file_with_constant_z_gets_canonical_depth(tmp_path, demo):
    points = np.column_stack([demo.rig.landmarks[:, :2], np.ones(68)])
    path = tmp_path / "face.txt"
    lm.save_txt(path, points)
    depth = lm.with_depth(lm.load(path))[:, 2]
    assert depth[lm.NOSE_TIP] > 0 > depth[0]


@pytest.mark.parametrize(
    "text, message",
    [("1 2\n3 4\n", "68 rows"), ("not numbers at all", "cannot read"), ("\n".join(["nan 1"] * 68), "NaN")],
)
def test_malformed_files_are_refused(tmp_path, text, message):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(PuppetError, match=message):
        lm.load(path)


def test_points_outside_the_image_are_refused(demo):
    points = demo.rig.landmarks[:, :2] + [5000, 0]
    with pytest.raises(PuppetError, match="outside"):
        lm.validate(points, image_size=demo.rig.image_size)


def test_face_axes_follow_a_tilted_face(demo):
    points = demo.rig.landmarks[:, :2]
    angle = np.radians(30)
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    x_axis, _ = lm.face_axes(points @ turn.T)
    assert np.allclose(x_axis, turn @ lm.face_axes(points)[0], atol=1e-5)
    assert lm.face_scale(points @ turn.T) == pytest.approx(lm.face_scale(points), rel=1e-5)

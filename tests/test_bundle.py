import json

import numpy as np
import pytest

from puppet import bundle
from puppet.errors import PuppetError


def test_save_and_load_round_trip(tmp_path, demo):
    folder = bundle.save(demo, tmp_path / "pip.puppet")
    assert sorted(p.name for p in folder.iterdir()) == ["image.png", "preview.png", "rig.json"]
    assert json.loads((folder / "rig.json").read_text())["version"] == bundle.RIG_VERSION
    again = bundle.load(folder)
    assert np.array_equal(again.image, demo.image)
    assert np.allclose(again.rig.vertices, demo.rig.vertices, atol=1e-3)
    assert np.array_equal(again.rig.triangles, demo.rig.triangles)
    assert again.rig.mouth_style == demo.rig.mouth_style


def test_existing_bundle_needs_force(tmp_path, demo):
    folder = bundle.save(demo, tmp_path / "pip.puppet")
    stamp = (folder / "rig.json").stat().st_mtime_ns
    with pytest.raises(PuppetError, match="--force"):
        bundle.save(demo, folder)
    assert (folder / "rig.json").stat().st_mtime_ns == stamp
    bundle.save(demo, folder, force=True)
    assert not list(tmp_path.glob(".*partial*"))


def test_mouth_colours_are_settable_in_the_bundle(tmp_path, demo):
    folder = bundle.save(demo, tmp_path / "pip.puppet")
    data = json.loads((folder / "rig.json").read_text())
    data["mouth_style"]["teeth"] = [1.0, 1.0, 0.0]
    (folder / "rig.json").write_text(json.dumps(data))
    assert bundle.load(folder).rig.mouth_style.teeth == (1.0, 1.0, 0.0)


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda d: "{not json", "not valid JSON"),
        (lambda d: json.dumps({**d, "format": "other"}), "not a puppet rig"),
        (lambda d: json.dumps({**d, "version": 99}), "upgrade"),
        (lambda d: json.dumps({**d, "triangles": [[0, 1, 100000]]}), "damaged"),
    ],
)
def test_damaged_bundles_are_refused(tmp_path, demo, damage, message):
    folder = bundle.save(demo, tmp_path / "pip.puppet")
    data = json.loads((folder / "rig.json").read_text())
    (folder / "rig.json").write_text(damage(data))
    with pytest.raises(PuppetError, match=message):
        bundle.load(folder)


def test_a_plain_folder_is_not_a_bundle(tmp_path):
    with pytest.raises(PuppetError, match="puppet rig"):
        bundle.load(tmp_path)

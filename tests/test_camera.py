"""The virtual camera: frames keyed over the key colour reach pyvirtualcam; no camera is one clear error."""
import sys

import numpy as np
import pytest
from fake_devices import register_fake_camera

from puppet import camera
from puppet.camera import KeyComposite, VirtualCamera
from puppet.errors import PuppetError

GREEN = (0, 255, 0)


def reference(frame: np.ndarray, key) -> np.ndarray:
    """RGBA over `key` in floating point, rounded."""
    alpha = frame[..., 3:].astype(np.float64) / 255
    return np.rint(frame[..., :3] * alpha + np.asarray(key) * (1 - alpha)).astype(np.uint8)


def test_opaque_transparent_and_half_transparent_pixels():
    frame = np.array([[[200, 100, 50, 255], [200, 100, 50, 0], [200, 100, 50, 128], [10, 20, 30, 64]]], np.uint8)
    out = KeyComposite((4, 1), GREEN)(frame)
    np.testing.assert_array_equal(out[0, 0], [200, 100, 50])  # opaque: the puppet
    np.testing.assert_array_equal(out[0, 1], GREEN)  # transparent: the key
    np.testing.assert_array_equal(out[0, 2], [100, 177, 25])  # half: halfway, (200·128 + 0·127) / 255 = 100.4
    np.testing.assert_array_equal(out[0, 3], reference(frame, GREEN)[0, 3])


@pytest.mark.parametrize("key", [GREEN, (255, 0, 255), (17, 200, 99)])
def test_every_colour_and_alpha_composites_exactly(key):
    frame = np.zeros((256, 256, 4), np.uint8)
    frame[..., :3] = np.arange(256)[None, :, None]  # every value ...
    frame[..., 3] = np.arange(256)[:, None]  # ... at every alpha
    np.testing.assert_array_equal(KeyComposite((256, 256), key)(frame), reference(frame, key))


def test_frames_reach_the_camera():
    backend = register_fake_camera()
    frame = np.random.default_rng(0).integers(0, 256, (48, 64, 4), dtype=np.uint8)
    with VirtualCamera((64, 48), 30.0, GREEN, backend="fake") as cam:
        for _ in range(3):
            cam.send(frame)
        fake = backend.instances[-1]
        assert cam.name == "Fake Camera" and (fake.width, fake.height, fake.fps) == (64, 48, 30.0)
        with pytest.raises(ValueError, match="RGBA"):
            cam.send(frame[:, :32])
    assert fake.frames == 3 and fake.closed
    np.testing.assert_array_equal(fake.last_frame, reference(frame, GREEN))
    cam.close()  # again: nothing happens


@pytest.mark.parametrize("platform, advice", [("linux", "modprobe v4l2loopback"), ("win32", "OBS Studio"),
                                              ("darwin", "OBS Studio")])
def test_no_virtual_camera_says_what_to_install(monkeypatch, platform, advice):
    class Absent:
        def __init__(self, **kw):
            raise RuntimeError("No virtual camera found. See the documentation.")

    import pyvirtualcam

    monkeypatch.setitem(pyvirtualcam.camera.BACKENDS, "absent", Absent)
    monkeypatch.setattr(sys, "platform", platform)
    with pytest.raises(PuppetError, match=advice) as error:
        VirtualCamera((64, 48), 30.0, GREEN, backend="absent")
    assert "No virtual camera found" in str(error.value) and "\n" not in str(error.value)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="v4l2loopback is Linux's virtual camera")
def test_no_v4l2loopback_device():
    try:
        VirtualCamera((64, 48), 30.0, GREEN, backend="v4l2loopback").close()
    except PuppetError as error:
        message = str(error)
    else:
        pytest.skip("this machine has a v4l2loopback device")
    assert "v4l2loopback" in message and "sudo apt install v4l2loopback-dkms" in message and "\n" not in message


def test_unknown_backend_and_missing_pyvirtualcam(monkeypatch):
    with pytest.raises(PuppetError, match="no virtual camera backend 'nope'"):
        VirtualCamera((64, 48), 30.0, GREEN, backend="nope")
    monkeypatch.setitem(sys.modules, "pyvirtualcam", None)
    with pytest.raises(PuppetError, match="pip install pyvirtualcam"):
        camera.VirtualCamera((64, 48), 30.0, GREEN)

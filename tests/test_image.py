import cv2
import numpy as np
import pytest

from puppet.errors import PuppetError
from puppet.image import MAX_SIDE, load_image


def test_png_with_alpha_keeps_it(tmp_path):
    bgra = np.zeros((40, 50, 4), np.uint8)
    bgra[..., 0] = 200  # blue
    bgra[10:20, 10:20, 3] = 255
    cv2.imwrite(str(tmp_path / "a.png"), bgra)
    rgba = load_image(tmp_path / "a.png")
    assert rgba.shape == (40, 50, 4)
    assert rgba[15, 15].tolist() == [0, 0, 200, 255] and rgba[0, 0, 3] == 0


@pytest.mark.parametrize("channels", [1, 3])
def test_gray_and_colour_jpeg_become_opaque_rgba(tmp_path, channels):
    image = np.full((40, 40, channels), 120, np.uint8).squeeze()
    cv2.imwrite(str(tmp_path / "a.jpg"), image)
    rgba = load_image(tmp_path / "a.jpg")
    assert rgba.shape == (40, 40, 4) and (rgba[..., 3] == 255).all()


def test_sixteen_bit_png(tmp_path):
    cv2.imwrite(str(tmp_path / "a.png"), np.full((40, 40, 3), 65535, np.uint16))
    assert load_image(tmp_path / "a.png")[0, 0].tolist() == [255, 255, 255, 255]


def test_bad_images(tmp_path):
    (tmp_path / "text.png").write_text("hello")
    good = cv2.imencode(".png", np.zeros((64, 64, 3), np.uint8))[1].tobytes()
    (tmp_path / "cut.png").write_bytes(good[: len(good) // 2])
    cv2.imwrite(str(tmp_path / "tiny.png"), np.zeros((8, 8, 3), np.uint8))
    for name, message in [("missing.png", "not found"), ("text.png", "cannot read"), ("cut.png", "cannot read"), ("tiny.png", "at least")]:
        with pytest.raises(PuppetError, match=message):
            load_image(tmp_path / name)


def test_huge_image_is_refused(tmp_path):
    cv2.imwrite(str(tmp_path / "huge.png"), np.zeros((10, MAX_SIDE + 1), np.uint8))
    with pytest.raises(PuppetError, match="scale it down"):
        load_image(tmp_path / "huge.png")

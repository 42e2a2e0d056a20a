"""Reading portraits: any image OpenCV decodes, as 8-bit RGBA with straight alpha."""
from pathlib import Path

import cv2
import numpy as np

from puppet.errors import PuppetError

MAX_SIDE = 4096  # larger portraits are refused: GPU texture limits and memory (4096² RGBA = 64 MiB)
MIN_SIDE = 32  # smaller images cannot carry a face worth animating


def load_image(path: str | Path) -> np.ndarray:
    """(H, W, 4) uint8 RGBA, straight alpha, rows top to bottom, from a PNG/JPEG/WebP/... file."""
    path = Path(path)
    if not path.is_file():
        raise PuppetError(f"image not found: {path}")
    data = np.fromfile(path, dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if image is None:
        raise PuppetError(f"cannot read {path} as an image (corrupt, or not a picture format OpenCV knows)")
    height, width = image.shape[:2]
    if max(width, height) > MAX_SIDE:
        raise PuppetError(f"{path} is {width}x{height}; the largest portrait puppet takes is {MAX_SIDE} px on a side: scale it down first")
    if min(width, height) < MIN_SIDE:
        raise PuppetError(f"{path} is only {width}x{height}; give a portrait at least {MIN_SIDE} px on a side")
    return to_rgba(image)


def to_rgba(image: np.ndarray) -> np.ndarray:
    """(H, W, 4) uint8 RGBA from OpenCV's gray, BGR or BGRA, 8- or 16-bit."""
    if image.dtype == np.uint16:
        image = (image // 257).astype(np.uint8)
    elif image.dtype != np.uint8:
        image = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2RGBA)
    if image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGBA)
    return cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA)


def save_png(path: str | Path, image: np.ndarray) -> None:
    """Write (H, W, 3|4) uint8 RGB(A) as PNG."""
    code = cv2.COLOR_RGBA2BGRA if image.shape[2] == 4 else cv2.COLOR_RGB2BGR
    if not cv2.imwrite(str(path), cv2.cvtColor(image, code)):
        raise PuppetError(f"cannot write {path}")

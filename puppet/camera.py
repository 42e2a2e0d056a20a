"""The virtual camera: the puppet as a webcam that OBS, Zoom or Meet can pick.

pyvirtualcam drives the system's virtual camera (v4l2loopback on Linux, OBS Studio's on Windows and
macOS). Virtual cameras carry no alpha, so each RGBA frame is laid over a key colour that the
streaming software keys out again. Per channel, with k the key and α the alpha (0..255),

    out = round((rgb·α + k·(255 − α)) / 255) = k + round((rgb − k)·α / 255) − round((k − rgb)·α / 255)

(one of the two rounded terms is zero), computed with OpenCV's saturating 8-bit operations into
buffers allocated once: exact, and about 2 ms for 1280x720.
"""
import sys

import cv2
import numpy as np

from puppet.errors import PuppetError

V4L2LOOPBACK = ('install v4l2loopback: sudo apt install v4l2loopback-dkms && '
                'sudo modprobe v4l2loopback devices=1 exclusive_caps=1 card_label="puppet"')
OBS = "install OBS Studio 26 or newer and start its Virtual Camera once"
INSTALL = {"linux": V4L2LOOPBACK, "win32": OBS, "darwin": OBS}  # by sys.platform: what provides a virtual camera


class KeyComposite:
    """RGBA over a key colour, for outputs without alpha: (H, W, 4) uint8 straight alpha → (H, W, 3) uint8."""

    def __init__(self, size: tuple[int, int], key: tuple[int, int, int]):
        """size: (width, height) in pixels; key: (r, g, b) 0..255, what fully transparent pixels become."""
        width, height = size
        self.shape = (height, width, 4)
        self.key = np.empty((height, width, 3), np.uint8)
        self.key[:] = key
        self.rgb, self.alpha, self.up, self.down, self.out = (np.empty_like(self.key) for _ in range(5))
        self.plane = np.empty((height, width), np.uint8)

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        """frame: (H, W, 4) uint8 RGBA, straight alpha. Returns (H, W, 3) uint8 RGB, a buffer that the
        next call overwrites."""
        if frame.shape != self.shape or frame.dtype != np.uint8:
            raise ValueError(f"expected a {self.shape} uint8 RGBA frame, got {frame.shape} {frame.dtype}")
        frame = np.ascontiguousarray(frame)
        cv2.cvtColor(frame, cv2.COLOR_RGBA2RGB, dst=self.rgb)
        cv2.extractChannel(frame, 3, dst=self.plane)
        cv2.cvtColor(self.plane, cv2.COLOR_GRAY2RGB, dst=self.alpha)
        cv2.subtract(self.rgb, self.key, dst=self.up)  # saturating: max(rgb − k, 0)
        cv2.subtract(self.key, self.rgb, dst=self.down)  # max(k − rgb, 0)
        cv2.multiply(self.up, self.alpha, dst=self.up, scale=1 / 255)  # rounds to nearest (no ties occur)
        cv2.multiply(self.down, self.alpha, dst=self.down, scale=1 / 255)
        cv2.add(self.key, self.up, dst=self.out)
        return cv2.subtract(self.out, self.down, dst=self.out)


class VirtualCamera:
    """The system's virtual camera fed RGBA frames over a key colour; a context manager."""

    def __init__(self, size: tuple[int, int], fps: float, key: tuple[int, int, int],
                 device: str | None = None, backend: str | None = None):
        """size: (width, height) of the frames sent; fps: the rate they come at (a hint to the camera);
        key: (r, g, b) 0..255 under transparent pixels; device: e.g. "/dev/video2", None for the
        first free one; backend: a pyvirtualcam backend name, None to try each. PuppetError if the
        system has no virtual camera."""
        try:
            import pyvirtualcam
        except ImportError:
            raise PuppetError("--virtual-camera needs pyvirtualcam: pip install pyvirtualcam") from None
        if backend is not None and backend not in pyvirtualcam.camera.BACKENDS:
            known = ", ".join(pyvirtualcam.camera.BACKENDS) or "none"
            raise PuppetError(f"no virtual camera backend '{backend}' (this system has: {known})")
        width, height = size
        try:
            self.camera = pyvirtualcam.Camera(width, height, fps, fmt=pyvirtualcam.PixelFormat.RGB,
                                              device=device, backend=backend)
        except RuntimeError as error:
            raise PuppetError(f"no virtual camera ({_brief(error)}): {_install_hint()}") from None
        used, name = self.camera.backend, self.camera.device
        self.name = name if used.lower() in name.lower() else f"{used} {name}"
        self.fps = fps
        self.composite = KeyComposite(size, key)

    def send(self, frame: np.ndarray) -> None:
        """frame: (H, W, 4) uint8 RGBA, straight alpha, rows top to bottom (as Canvas.read returns)."""
        self.camera.send(self.composite(frame))

    def close(self) -> None:
        if self.camera is not None:
            self.camera.close()
            self.camera = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _brief(error: RuntimeError) -> str:
    """pyvirtualcam's reasons (one line per backend tried), first sentences only, on one line."""
    reasons = [line.split(". ")[0].strip() for line in str(error).splitlines() if line.strip()]
    return "; ".join(reasons) or "pyvirtualcam has no backend for this system"


def _install_hint() -> str:
    platform = "linux" if sys.platform.startswith("linux") else sys.platform
    return INSTALL.get(platform, "pyvirtualcam supports Linux (v4l2loopback), Windows and macOS (OBS Studio)")

"""Automatic 68-point landmarks for photos and paintings, with dlib.

Sketch: composite the RGBA portrait over white; find faces with dlib's HOG detector on a copy
scaled to a useful size (small images upsampled, very large ones shrunk); if HOG finds none, try
dlib's CNN (MMOD) detector on a small copy, and re-centre its box the way the landmark predictor
expects. The predictor then runs on a crop of the largest face scaled to a fixed box size, so
that dlib's integer landmark coordinates carry sub-pixel precision in the original image.

Coordinates: image pixels, pixel centres at integer positions, origin top-left, x right, y down.
"""
import functools
import importlib.util
from pathlib import Path

import cv2
import dlib
import numpy as np

from puppet.errors import NoFaceError, PuppetError
from puppet.landmarks import N_LANDMARKS

# HOG sees faces of about 80 px and up; it runs on a copy whose long side is at least
# HOG_MIN_SIDE (upsampling by 2 at most HOG_MAX_UPSAMPLE times) and at most HOG_MAX_SIDE.
HOG_MIN_SIDE = 1000
HOG_MAX_SIDE = 2000
HOG_MAX_UPSAMPLE = 2  # a 256 px image is searched at 1024 px
# HOG detections scoring below this (photos and paintings score 1 to 3) must be confirmed by the
# CNN: weak ones are mostly drawings, where the predictor's landmarks land off the face.
HOG_MIN_SCORE = 0.5
# The CNN detector runs on a copy with this long side: about 1.5 s on 2 CPU cores.
CNN_SIDE = 512
# The predictor runs on a crop scaled so the face box is this wide: dlib rounds landmarks to
# whole pixels, i.e. to 1/1600 of the box (0.1 px for a 160 px face).
FIT_BOX_SIDE = 800
# The crop keeps this fraction of the box width around the box on every side.
FIT_MARGIN = 0.5
# The predictor's mean shape is read in a box this wide on a uniform grey image (see
# `box_mean_shape`), with this margin around it: the trees probe pixels up to about a tenth of
# the box outside it, and dlib reads pixels outside the image as black.
MEAN_SHAPE_BOX = 4000
MEAN_SHAPE_MARGIN = MEAN_SHAPE_BOX // 4  # 1000 px: a 6000 px square image
GREY = 128


def _model_file(name: str) -> str:
    """Path of a dlib model shipped in the `face-recognition-models` package.

    Found without importing that package: its __init__ needs pkg_resources, which recent
    setuptools no longer has.
    """
    spec = importlib.util.find_spec("face_recognition_models")
    if spec is None or not spec.submodule_search_locations:
        raise PuppetError("face detection needs the face-recognition-models package: pip install face-recognition-models")
    path = Path(spec.submodule_search_locations[0]) / "models" / name
    if not path.is_file():
        raise PuppetError(f"face-recognition-models is installed without {name}; reinstall it")
    return str(path)


@functools.cache
def _hog_detector() -> dlib.fhog_object_detector:
    return dlib.get_frontal_face_detector()


@functools.cache
def _cnn_detector() -> dlib.cnn_face_detection_model_v1:
    return dlib.cnn_face_detection_model_v1(_model_file("mmod_human_face_detector.dat"))


@functools.cache
def _shape_predictor() -> dlib.shape_predictor:
    return dlib.shape_predictor(_model_file("shape_predictor_68_face_landmarks.dat"))


@functools.cache
def box_mean_shape() -> np.ndarray:
    """(68, 2) float64: the predictor's own mean shape, in units of its box (box corners at 0 and 1).

    On a uniform grey image every pixel comparison in the regression trees is equal, so the
    predictor returns (essentially) the mean shape it starts from, placed in the given box.
    """
    side = MEAN_SHAPE_BOX + 2 * MEAN_SHAPE_MARGIN
    image = np.full((side, side), GREY, dtype=np.uint8)
    first, last = MEAN_SHAPE_MARGIN, MEAN_SHAPE_MARGIN + MEAN_SHAPE_BOX - 1
    shape = _shape_predictor()(image, dlib.rectangle(first, first, last, last))
    mean = (_parts(shape) - first) / (last - first)
    mean.setflags(write=False)
    return mean


def _parts(shape: dlib.full_object_detection) -> np.ndarray:
    return np.array([(shape.part(i).x, shape.part(i).y) for i in range(N_LANDMARKS)], dtype=np.float64)


def _resize(image: np.ndarray, scale: float) -> np.ndarray:
    interpolation = cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC
    return cv2.resize(image, None, fx=scale, fy=scale, interpolation=interpolation)


def _scale_box(box: dlib.rectangle, scale: float) -> np.ndarray:
    """(4,) float64 left, top, right, bottom of a box found on a copy scaled by `scale`, original pixels."""
    corners = np.array([box.left(), box.top(), box.right(), box.bottom()], dtype=np.float64)
    return (corners + 0.5) / scale - 0.5


def _largest(boxes: list[np.ndarray]) -> np.ndarray | None:
    return max(boxes, key=lambda b: (b[2] - b[0]) * (b[3] - b[1]), default=None)


def _hog_box(rgb: np.ndarray) -> np.ndarray | None:
    """(4,) float64 box of the largest face HOG finds with confidence, original pixels, or None."""
    side = max(rgb.shape[:2])
    scale = min(1.0, HOG_MAX_SIDE / side)
    upsample = int(np.clip(np.ceil(np.log2(HOG_MIN_SIDE / side)), 0, HOG_MAX_UPSAMPLE))
    boxes, scores, _ = _hog_detector().run(_resize(rgb, scale) if scale < 1 else rgb, upsample)
    return _largest([_scale_box(box, scale) for box, score in zip(boxes, scores) if score >= HOG_MIN_SCORE])


def _cnn_box(rgb: np.ndarray) -> np.ndarray | None:
    """(4,) float64 box of the largest face the CNN finds, original pixels, or None."""
    scale = CNN_SIDE / max(rgb.shape[:2])
    found = _cnn_detector()(_resize(rgb, scale), 0)
    return _largest([_scale_box(face.rect, scale) for face in found])


def _fit(rgb: np.ndarray, box: np.ndarray) -> np.ndarray:
    """(68, 2) float64 landmarks, original pixels, from the predictor on a scaled crop around `box`.

    box: (4,) left, top, right, bottom in original pixels; right and bottom are inclusive.
    """
    width = box[2] - box[0]
    scale = FIT_BOX_SIDE / width
    margin = FIT_MARGIN * width
    x0 = int(np.clip(np.floor(box[0] - margin), 0, rgb.shape[1] - 1))
    y0 = int(np.clip(np.floor(box[1] - margin), 0, rgb.shape[0] - 1))
    x1 = int(np.clip(np.ceil(box[2] + margin), x0 + 1, rgb.shape[1]))
    y1 = int(np.clip(np.ceil(box[3] + margin), y0 + 1, rgb.shape[0]))
    crop = _resize(rgb[y0:y1, x0:x1], scale)
    left, top, right, bottom = np.round((box - [x0, y0, x0, y0] + 0.5) * scale - 0.5).astype(int)
    shape = _shape_predictor()(np.ascontiguousarray(crop), dlib.rectangle(left, top, right, bottom))
    return (_parts(shape) + 0.5) / scale - 0.5 + [x0, y0]


def _box_for(points: np.ndarray) -> np.ndarray:
    """(4,) float64 box the predictor would expect for (68, 2) `points`: least-squares fit of its mean shape."""
    mean = box_mean_shape()
    centred = mean - mean.mean(0)
    size = float(np.sum(centred * (points - points.mean(0))) / np.sum(centred**2))
    origin = points.mean(0) - size * mean.mean(0)
    return np.array([origin[0], origin[1], origin[0] + size, origin[1] + size])


def composite_over_white(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an (H, W, 4) uint8 straight-alpha RGBA image laid over white."""
    alpha = image[..., 3:].astype(np.uint16)
    # colour * alpha + white * (1 - alpha), in 1/255 units: at most 255 * 255, fits in uint16.
    rgb = (image[..., :3] * alpha + 255 * (255 - alpha) + 127) // 255
    return rgb.astype(np.uint8)


def detect(image: np.ndarray, source: str) -> np.ndarray:
    """(68, 2) float32 landmarks of the largest face, image pixels, origin top-left, y down.

    image: (H, W, 4) uint8 RGBA, straight alpha. source: the image's name, for error messages.
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 4 or image.dtype != np.uint8 or 0 in image.shape:
        raise PuppetError(f"{source}: expected an (H, W, 4) uint8 RGBA image, got {image.dtype} {image.shape}")
    rgb = composite_over_white(image)
    box = _hog_box(rgb)
    if box is not None:
        return _fit(rgb, box).astype(np.float32)
    box = _cnn_box(rgb)
    if box is None:
        raise NoFaceError(
            f"no face found in {source}; give its 68 landmarks with --landmarks FILE, "
            f"or rig it by hand: puppet rig {source} --edit (or --points ...)"
        )
    # The CNN's boxes sit differently on the face than the HOG boxes the predictor was trained
    # on: fit once, then fit again in the box the predictor expects for those landmarks.
    return _fit(rgb, _box_for(_fit(rgb, box))).astype(np.float32)


def track(frames) -> np.ndarray:
    """(T, 68, 2) float32 landmarks of the main face through a video, image pixels.

    frames: iterable of (H, W, 3) uint8 RGB frames. The face is detected in the first frame (and
    again whenever it is lost); later frames fit the predictor in the box its previous landmarks
    imply, which is steadier and ten times faster than detecting every frame.
    Frames where no face can be found repeat the last landmarks (NaN before the first face).
    """
    result, previous = [], None
    for rgb in frames:
        rgb = np.ascontiguousarray(rgb)
        if previous is None:
            box = _hog_box(rgb)
            box = box if box is not None else _cnn_box(rgb)
            previous = None if box is None else _fit(rgb, _box_for(_fit(rgb, box)))
        else:
            previous = _fit(rgb, _box_for(previous))
        result.append(np.full((N_LANDMARKS, 2), np.nan) if previous is None else previous)
    return np.asarray(result, dtype=np.float32).reshape(-1, N_LANDMARKS, 2)

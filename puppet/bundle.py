"""Puppets: a portrait with its rig, from an image (landmarks from a file, detection or a
template fit) or from a saved puppet bundle.

A bundle is a folder: `image.png` (the portrait), `rig.json` (format name and version, the
landmarks, the mesh, the mouth style) and `preview.png` (the mesh drawn over the portrait,
for people). Every command takes a bundle wherever it takes an image.
"""
import json
import shutil
from dataclasses import asdict, dataclass
from importlib.resources import files
from pathlib import Path

import cv2
import numpy as np

from puppet import landmarks as lm
from puppet.errors import PuppetError
from puppet.image import load_image, save_png
from puppet.rig import MouthStyle, Rig, build

RIG_FORMAT = "puppet-rig"
RIG_VERSION = 1
RIG_FILE = "rig.json"
IMAGE_FILE = "image.png"
PREVIEW_FILE = "preview.png"


@dataclass(frozen=True)
class Puppet:
    """image: (H, W, 4) uint8 RGBA, straight alpha; rig: its mesh; name: for messages and files."""

    image: np.ndarray
    rig: Rig
    name: str


def demo_files() -> tuple[Path, Path, Path]:
    """Paths of the bundled character image, its landmark file and its speech clip."""
    demo = files("puppet.assets") / "demo"
    return Path(str(demo / "character.png")), Path(str(demo / "character_landmarks.txt")), Path(str(demo / "speech.wav"))


def load(path: str | Path, landmarks: str | Path | None = None, points: np.ndarray | None = None) -> Puppet:
    """A puppet from a bundle folder, or from an image rigged on the spot.

    For an image, landmarks come from the `landmarks` file if given, else from a template fit
    to `points` ((5, 2) pixels, see `puppet.template.CONTROL_POINTS`) if given, else from face
    detection.
    """
    path = Path(path)
    if path.is_dir():
        if landmarks is not None or points is not None:
            raise PuppetError(f"{path} is a rigged puppet already; --landmarks and --points are for images")
        return load_bundle(path)
    image = load_image(path)
    size = (image.shape[1], image.shape[0])
    if landmarks is not None:
        points68 = lm.validate(lm.load(landmarks), source=str(landmarks), image_size=size)
    elif points is not None:
        from puppet.template import fit

        points68 = lm.clamp_to_image(fit(points, size), size)
    else:
        from puppet.detect import detect

        points68 = lm.clamp_to_image(detect(image, str(path)), size)
    return Puppet(image, build(points68, size), path.stem)


def load_centred(path: str | Path) -> Puppet:
    """A puppet from an image with the mean face placed in its middle (`template.centred`): the rig
    editor's starting point when no face is found."""
    from puppet.template import centred

    image = load_image(path)
    size = (image.shape[1], image.shape[0])
    return Puppet(image, build(lm.clamp_to_image(centred(size), size), size), Path(path).stem)


def load_bundle(folder: Path) -> Puppet:
    """A puppet from a bundle folder written by `save`."""
    rig_path = folder / RIG_FILE
    if not rig_path.is_file():
        raise PuppetError(f"{folder} is a folder but not a puppet bundle (no {RIG_FILE}); make one with: puppet rig IMAGE -o {folder}")
    try:
        data = json.loads(rig_path.read_text())
    except (ValueError, UnicodeDecodeError) as error:
        raise PuppetError(f"{rig_path} is not valid JSON: {error}") from None
    if not isinstance(data, dict) or data.get("format") != RIG_FORMAT:
        raise PuppetError(f"{rig_path} is not a puppet rig file")
    if data.get("version", 0) > RIG_VERSION:
        raise PuppetError(f"{rig_path} has rig format version {data['version']}; this puppet reads up to {RIG_VERSION}: upgrade puppet")
    image = load_image(folder / data.get("image", IMAGE_FILE))
    try:
        rig = _rig_from_json(data)
    except (KeyError, TypeError, ValueError) as error:
        raise PuppetError(f"{rig_path} is damaged ({type(error).__name__}: {error})") from None
    if tuple(rig.image_size) != (image.shape[1], image.shape[0]):
        raise PuppetError(f"{rig_path} is for a {rig.image_size[0]}x{rig.image_size[1]} image but {IMAGE_FILE} is {image.shape[1]}x{image.shape[0]}")
    return Puppet(image, rig, folder.name.removesuffix(".puppet"))


def save(puppet: Puppet, folder: str | Path, force: bool = False) -> Path:
    """Write a bundle folder (atomically: a partial folder is renamed into place)."""
    folder = Path(folder)
    if not folder.parent.is_dir():
        raise PuppetError(f"output folder does not exist: {folder.parent}")
    if folder.exists() and not force:
        raise PuppetError(f"{folder} exists; use --force to overwrite")
    partial = folder.parent / f".{folder.name}.partial"
    shutil.rmtree(partial, ignore_errors=True)
    try:
        partial.mkdir()
        save_png(partial / IMAGE_FILE, puppet.image)
        (partial / RIG_FILE).write_text(json.dumps(_rig_to_json(puppet.rig), indent=1))
        save_png(partial / PREVIEW_FILE, preview(puppet))
        if folder.exists():
            shutil.rmtree(folder) if folder.is_dir() else folder.unlink()
        partial.rename(folder)
    finally:
        shutil.rmtree(partial, ignore_errors=True)
    return folder


def preview(puppet: Puppet) -> np.ndarray:
    """(H, W, 3) uint8 RGB: the portrait over grey with the mesh (mouth red, eyes blue) and the
    68 landmarks drawn on it."""
    image = puppet.image.astype(np.float32)
    alpha = image[..., 3:4] / 255
    canvas = (image[..., :3] * alpha + 128 * (1 - alpha)).astype(np.uint8)
    rig = puppet.rig
    thickness = max(1, round(max(rig.image_size) / 600))
    xy = np.round(rig.vertices[:, :2]).astype(np.int32)
    colours = np.full((len(rig.triangles), 3), (80, 220, 80))
    colours[rig.mouth] = (240, 60, 60)
    colours[rig.eyes] = (60, 120, 255)
    for triangle, colour in zip(rig.triangles, colours):
        cv2.polylines(canvas, [xy[triangle]], True, tuple(int(c) for c in colour), thickness, cv2.LINE_AA)
    for x, y in xy[: lm.N_LANDMARKS]:
        cv2.circle(canvas, (int(x), int(y)), 2 * thickness, (255, 230, 0), -1, cv2.LINE_AA)
    return canvas


def _rig_to_json(rig: Rig) -> dict:
    return {
        "format": RIG_FORMAT,
        "version": RIG_VERSION,
        "image": IMAGE_FILE,
        "image_size": list(rig.image_size),
        "n_outline": rig.n_outline,
        "vertices": np.round(rig.vertices, 3).tolist(),
        "triangles": rig.triangles.tolist(),
        "mouth_triangles": rig.mouth.tolist(),
        "eye_triangles": rig.eyes.tolist(),
        "mouth_style": asdict(rig.mouth_style),
    }


def _rig_from_json(data: dict) -> Rig:
    vertices = np.asarray(data["vertices"], dtype=np.float32)
    triangles = np.asarray(data["triangles"], dtype=np.int32)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < lm.N_LANDMARKS:
        raise ValueError(f"vertices have shape {vertices.shape}")
    if triangles.ndim != 2 or triangles.shape[1] != 3 or triangles.min() < 0 or triangles.max() >= len(vertices):
        raise ValueError("triangles index missing vertices")
    if not np.isfinite(vertices).all():
        raise ValueError("vertices are not finite")
    style = data.get("mouth_style", {})
    style = MouthStyle(**{k: tuple(v) if isinstance(v, list) else v for k, v in style.items()})
    return Rig(
        vertices=vertices,
        triangles=triangles,
        mouth=np.asarray(data["mouth_triangles"], dtype=np.int32),
        eyes=np.asarray(data["eye_triangles"], dtype=np.int32),
        n_outline=int(data["n_outline"]),
        image_size=tuple(int(v) for v in data["image_size"]),
        mouth_style=style,
    )

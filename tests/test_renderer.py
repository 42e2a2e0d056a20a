import numpy as np

from puppet import landmarks as lm
from puppet.motion import Motion
from puppet.renderer import (
    Background,
    Canvas,
    PuppetRenderer,
    fit,
    premultiply,
    unpremultiply,
)

WHITE = Background((1.0, 1.0, 1.0, 1.0))


def draw(gl, puppet, positions, background=Background(), samples=4):
    renderer = PuppetRenderer(gl, puppet.image, puppet.rig)
    canvas = Canvas(gl, puppet.rig.image_size, samples)
    canvas.begin(background)
    renderer.draw(positions, canvas.size)
    return canvas.read()


def face_box(rig, margin=0.0):
    points = rig.landmarks[:, :2]
    low, high = points.min(0) - margin, points.max(0) + margin
    return slice(int(low[1]), int(high[1])), slice(int(low[0]), int(high[0]))


def psnr(a, b):
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return 10 * np.log10(255**2 / max(mse, 1e-12))


def mouth_opened(rig, amount=0.35):
    offsets = Motion.still(1, 25).offsets.copy()
    lower = list(range(55, 60)) + [65, 66, 67] + list(range(5, 12))
    offsets[0, lower, 1] += amount * lm.face_scale(rig.landmarks)
    return rig.animate(Motion(offsets, np.zeros((1, 3), np.float32), np.zeros((1, 2), np.float32), 25))[0]


def test_rest_pose_reproduces_the_portrait(gl, demo):
    frame = draw(gl, demo, demo.rig.vertices[:, :2])
    rows, cols = face_box(demo.rig)
    assert psnr(frame[rows, cols], demo.image[rows, cols]) >= 40


def test_alpha_survives(gl, demo):
    frame = draw(gl, demo, demo.rig.vertices[:, :2])
    assert frame[0, 0, 3] == 0 and demo.image[0, 0, 3] == 0  # transparent corner stays transparent
    assert np.abs(frame[..., 3].astype(int) - demo.image[..., 3]).max() <= 1
    soft = (demo.image[..., 3] > 64) & (demo.image[..., 3] < 192)  # anti-aliased silhouette edge
    assert soft.any()
    assert np.abs(frame[soft][:, :3].astype(int) - demo.image[soft][:, :3]).mean() < 3


def test_opening_the_mouth_changes_only_the_lower_face(gl, demo):
    rig = demo.rig
    rest = draw(gl, demo, rig.vertices[:, :2], WHITE)
    opened = draw(gl, demo, mouth_opened(rig), WHITE)
    changed = np.abs(rest.astype(int) - opened.astype(int)).max(axis=2) > 8
    moved = np.isin(rig.triangles, list(range(48, 68)) + list(range(5, 12))).any(axis=1)
    region = rig.vertices[np.unique(rig.triangles[moved]), :2]
    low, high = region.min(0) - 2, region.max(0) + 2
    ys, xs = np.nonzero(changed)
    assert len(ys) > 200
    assert xs.min() >= low[0] and xs.max() <= high[0] and ys.min() >= low[1] and ys.max() <= high[1]
    eyes = rig.landmarks[36:48, 1].max()
    assert ys.min() > eyes


def test_open_mouth_shows_a_dark_interior_not_stretched_lips(gl, demo):
    rig = demo.rig
    positions = mouth_opened(rig)
    frame = draw(gl, demo, positions, WHITE)
    centre = (positions[62] + positions[66]) / 2
    x, y = int(round(centre[0])), int(round(centre[1]))
    colour = frame[y - 1 : y + 2, x - 1 : x + 2, :3].reshape(-1, 3).mean(0) / 255
    cavity = np.array(rig.mouth_style.cavity)
    assert np.abs(colour - cavity).max() < 0.15


def test_msaa_smooths_the_mouth_edge(gl, demo):
    positions = mouth_opened(demo.rig)
    def distinct_colours(samples):
        frame = draw(gl, demo, positions, WHITE, samples)
        rows, cols = face_box(demo.rig)
        return len(np.unique(frame[rows, cols, :3].reshape(-1, 3), axis=0))
    assert distinct_colours(4) > distinct_colours(0)


def test_portrait_is_fitted_into_any_canvas():
    scale, shift = fit((400, 200), (200, 200))
    assert np.allclose(scale, 0.5) and np.allclose(shift, [0, 50])


def test_premultiply_round_trip():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (16, 16, 4), dtype=np.uint8)
    image[..., 3] = rng.integers(128, 256, (16, 16))
    assert np.abs(unpremultiply(premultiply(image)).astype(int) - image).max() <= 2

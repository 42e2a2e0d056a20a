"""Facial action units: named, face-sized landmark displacements that motion sources mix.

Each unit is one (68, 3) displacement field at full strength (weight 1) for a particular face.
Fixed units are written once as a table in face units: u along the eye line toward the image's
right, v down the face, w toward the viewer, all in inter-ocular distances (IOD). For a given rest
face the table is turned into pixels with the face's own axes and scale, so the same table opens a
tilted, a tiny or a huge mouth alike. Units that must land exactly on the face's own geometry
(eyelids meeting, inner lips meeting) are computed from the rest landmarks instead.
A motion source then says how much of each unit to use per frame, and `blend` sums them linearly.

What each unit does at weight 1 (IOD = this face's inter-ocular distance in pixels):
    jaw_open    the inner lips part by JAW_OPEN_GAP = 0.35 IOD: the lower lip drops 0.32 IOD, the
                chin 0.28 IOD (jaw points 4-12 taper toward the ears), the upper lip lifts 0.03 IOD,
                the mouth corners drop 0.14 IOD and come in 0.03 IOD.
    lip_wide    the corners move 0.08 IOD outward along the eye line, the lips thin by 0.02 IOD each
                ("ee").
    lip_round   the corners come 0.10 IOD inward, the lips push 0.10 IOD toward the viewer and part
                by 0.06 IOD ("oo").
    lip_press   the inner lips meet (each facing pair at its midpoint, closing the rest gap exactly)
                and each lip loses 30% of its thickness as it is tucked in (p, b, m).
    smile       the corners rise 0.08 IOD and move 0.07 IOD outward, the cheeks (jaw points 2-5,
                11-14) lift and widen by up to 0.02 IOD.
    blink_right, blink_left
                the upper lid (37, 38 / 43, 44) meets the lower lid (41, 40 / 47, 46) exactly, at a
                point BLINK_LOWER_RISE = 20% of the way up from the lower lid.
    brow_raise  the brows rise by up to 0.12 IOD (least at the outer ends).
    brow_frown  the brows lower by up to 0.09 IOD and their inner ends draw 0.05 IOD together.
    upper_lip_raise
                the middle of the upper lip lifts 0.06 IOD (outer edge) and 0.05 IOD (inner edge) and
                flares 0.02 IOD toward the viewer, baring the upper teeth ("sh", "f").
    lower_lip_tuck
                the lower lip rolls up and back under the upper teeth: its inner edge rises 0.08 IOD
                and goes 0.08 IOD back, its outer edge rises 0.10 IOD and goes 0.06 IOD back ("f", "v").

`close_lips` is not a unit: it brings the inner lips of any mouth shape together, so that a
closure (p, b, m) still closes when other units have opened the jaw.
"""
import numpy as np

from puppet.landmarks import (
    EYELID_PAIRS,
    INNER_LIP_PAIRS,
    JAW,
    LEFT_BROW,
    LEFT_EYE,
    N_LANDMARKS,
    NOSE_BRIDGE,
    RIGHT_BROW,
    RIGHT_EYE,
    face_axes,
    face_scale,
)

# Each landmark's mirror image across the face's midline (iBUG-68); midline points map to themselves.
MIRROR = np.array(
    [*reversed(JAW), *reversed(LEFT_BROW), *reversed(RIGHT_BROW), *NOSE_BRIDGE, 35, 34, 33, 32, 31,
     45, 44, 43, 42, 47, 46, 39, 38, 37, 36, 41, 40,
     54, 53, 52, 51, 50, 49, 48, 59, 58, 57, 56, 55, 64, 63, 62, 61, 60, 67, 66, 65]
)
assert sorted(MIRROR) == list(range(N_LANDMARKS)) and all(MIRROR[MIRROR] == range(N_LANDMARKS))
assert set(MIRROR[list(RIGHT_EYE)]) == set(LEFT_EYE)

# jaw_open, in IOD.
UPPER_LIP_LIFT = 0.03  # the upper inner lip rises this much
LOWER_LIP_DROP = 0.32  # the lower inner lip drops this much
JAW_OPEN_GAP = UPPER_LIP_LIFT + LOWER_LIP_DROP  # 0.35: how far the inner lips part
CHIN_DROP = 0.28  # the chin (jaw point 8); jaw points 4-7 taper toward the ears
JAW_TAPER = (0.15, 0.4, 0.7, 0.92, 1.0)  # share of CHIN_DROP for jaw points 4..8
JAW_BACK = 0.1  # the jaw swings back: depth lost per unit of drop
CORNER_DROP = 0.14  # mouth corners drop this much
CORNER_IN = 0.03  # and come in this much

# lip_press.
PRESS_TUCK = 0.3  # share of each lip's rest thickness lost when the lips are pressed together
# Outer-lip points and the inner-lip point each one sits above (upper lip) or below (lower lip).
OUTER_OVER_INNER = ((49, 61), (50, 61), (51, 62), (52, 63), (53, 63),
                    (59, 67), (58, 67), (57, 66), (56, 65), (55, 65))

# close_lips: the lips meet this far down from the upper inner lip (the lower lip, carried by the
# jaw, travels most of the way).
LIP_MEET = 0.3

# blinks.
BLINK_LOWER_RISE = 0.2  # the lids meet this far up from the lower lid (share of the rest opening)

UNITS = ("jaw_open", "lip_wide", "lip_round", "lip_press", "smile",
         "blink_right", "blink_left", "brow_raise", "brow_frown", "upper_lip_raise", "lower_lip_tuck")


def _symmetric(moves: dict[int, tuple[float, float, float]]) -> np.ndarray:
    """(68, 3) float32 face-unit table from moves of the subject's right-side and midline points.

    Each given point's mirror moves the same way with u negated; u > 0 on the right side means
    "toward the midline".
    """
    table = np.zeros((N_LANDMARKS, 3), np.float32)
    for index, (u, v, w) in moves.items():
        table[index] = (u, v, w)
        table[MIRROR[index]] = (-u if MIRROR[index] != index else u, v, w)
    return table


def _jaw_open() -> np.ndarray:
    def drop(amount):  # points carried by the jaw move down and, as it swings, back
        return (0.0, amount, -JAW_BACK * amount)

    lift = (0.0, -UPPER_LIP_LIFT, 0.0)
    moves = {4 + i: drop(CHIN_DROP * share) for i, share in enumerate(JAW_TAPER)}
    moves |= {61: lift, 62: lift, 49: (0.0, -0.7 * UPPER_LIP_LIFT, 0.0), 50: lift, 51: lift}
    moves |= {67: drop(LOWER_LIP_DROP), 66: drop(LOWER_LIP_DROP)}
    moves |= {59: drop(0.8 * LOWER_LIP_DROP), 58: drop(LOWER_LIP_DROP), 57: drop(LOWER_LIP_DROP + 0.01)}
    moves |= {48: (CORNER_IN, CORNER_DROP, 0.0), 60: (CORNER_IN, CORNER_DROP, 0.0)}
    return _symmetric(moves)


def _lip_wide() -> np.ndarray:
    return _symmetric({
        48: (-0.08, 0.0, -0.02), 60: (-0.07, 0.0, -0.02),
        49: (-0.05, 0.02, -0.01), 50: (-0.025, 0.02, 0.0), 51: (0.0, 0.02, 0.0),
        59: (-0.05, -0.02, -0.01), 58: (-0.025, -0.02, 0.0), 57: (0.0, -0.02, 0.0),
        61: (-0.04, 0.0, 0.0), 67: (-0.04, 0.0, 0.0),
    })


def _lip_round() -> np.ndarray:
    return _symmetric({
        48: (0.10, 0.0, 0.06), 60: (0.08, 0.0, 0.06),
        49: (0.06, -0.01, 0.08), 50: (0.02, -0.02, 0.10), 51: (0.0, -0.02, 0.10),
        59: (0.06, 0.02, 0.08), 58: (0.02, 0.035, 0.10), 57: (0.0, 0.04, 0.10),
        61: (0.05, -0.02, 0.08), 62: (0.0, -0.02, 0.08),
        67: (0.05, 0.04, 0.08), 66: (0.0, 0.04, 0.08),
    })


def _smile() -> np.ndarray:
    return _symmetric({
        48: (-0.07, -0.08, -0.03), 60: (-0.06, -0.07, -0.03),
        49: (-0.03, -0.04, -0.01), 50: (-0.01, -0.015, 0.0), 51: (0.0, -0.01, 0.0),
        59: (-0.035, -0.035, -0.01), 58: (-0.01, -0.01, 0.0), 57: (0.0, -0.005, 0.0),
        61: (-0.025, -0.03, 0.0), 62: (0.0, -0.01, 0.0), 67: (-0.025, -0.025, 0.0), 66: (0.0, -0.005, 0.0),
        2: (-0.01, -0.01, 0.0), 3: (-0.02, -0.02, 0.01), 4: (-0.02, -0.02, 0.01), 5: (-0.01, -0.01, 0.0),
    })


def _upper_lip_raise() -> np.ndarray:
    return _symmetric({
        48: (0.0, -0.01, 0.0), 49: (0.0, -0.04, 0.01), 50: (0.0, -0.06, 0.02), 51: (0.0, -0.06, 0.02),
        60: (0.0, -0.01, 0.0), 61: (0.0, -0.045, 0.01), 62: (0.0, -0.05, 0.01),
    })


def _lower_lip_tuck() -> np.ndarray:
    return _symmetric({
        48: (0.0, -0.01, 0.0), 60: (0.0, -0.01, 0.0),
        59: (0.0, -0.07, -0.04), 58: (0.0, -0.10, -0.06), 57: (0.0, -0.10, -0.06),
        67: (0.0, -0.07, -0.07), 66: (0.0, -0.08, -0.08),
    })


def _brow_raise() -> np.ndarray:
    return _symmetric({17: (0.0, -0.08, 0.0), 18: (0.0, -0.11, 0.0), 19: (0.0, -0.12, 0.0),
                       20: (0.0, -0.12, 0.0), 21: (0.0, -0.10, 0.0)})


def _brow_frown() -> np.ndarray:
    return _symmetric({17: (0.0, 0.02, 0.0), 18: (0.01, 0.04, 0.0), 19: (0.02, 0.06, 0.0),
                       20: (0.035, 0.08, 0.0), 21: (0.05, 0.09, 0.01)})


def _to_pixels(table: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(68, 3) float32 pixel displacements from a (68, 3) face-unit table, for this rest face."""
    scale = face_scale(rest)
    axes = face_axes(rest)  # rows: eye line, down the face
    xy = table[:, :2] @ axes * scale
    return np.column_stack([xy, table[:, 2] * scale]).astype(np.float32)


def _blink(rest: np.ndarray, pairs: tuple[tuple[int, int], ...]) -> np.ndarray:
    """(68, 3) float32 pixels: each (upper, lower) lid pair meets at BLINK_LOWER_RISE up the opening."""
    offsets = np.zeros((N_LANDMARKS, 3), np.float32)
    for upper, lower in pairs:
        meet = rest[lower] + BLINK_LOWER_RISE * (rest[upper] - rest[lower])
        offsets[upper] = meet - rest[upper]
        offsets[lower] = meet - rest[lower]
    return offsets


def _lip_press(rest: np.ndarray) -> np.ndarray:
    """(68, 3) float32 pixels: facing inner-lip points meet at their midpoint, the outer lips follow
    them and close PRESS_TUCK of the way (down the face) toward the inner lip line."""
    down = np.concatenate([face_axes(rest)[1], [0.0]])
    offsets = np.zeros((N_LANDMARKS, 3), np.float32)
    for upper, lower in INNER_LIP_PAIRS:
        offsets[upper] = 0.5 * (rest[lower] - rest[upper])
        offsets[lower] = 0.5 * (rest[upper] - rest[lower])
    for outer, inner in OUTER_OVER_INNER:
        thickness = float((rest[inner] - rest[outer]) @ down)  # > 0 for the upper lip, < 0 for the lower
        offsets[outer] = offsets[inner] + PRESS_TUCK * thickness * down
    return offsets


def unit_offsets(rest: np.ndarray) -> dict[str, np.ndarray]:
    """Each action unit's displacement at weight 1 for this face.

    rest: (68, 3) float32 rest landmarks, image pixels (x right, y down, z toward the viewer).
    Returns {name: (68, 3) float32 pixel displacements in the head frame} for every name in UNITS.
    """
    rest = np.asarray(rest, dtype=np.float32)
    tables = {"jaw_open": _jaw_open(), "lip_wide": _lip_wide(), "lip_round": _lip_round(),
              "smile": _smile(), "brow_raise": _brow_raise(), "brow_frown": _brow_frown(),
              "upper_lip_raise": _upper_lip_raise(), "lower_lip_tuck": _lower_lip_tuck()}
    units = {name: _to_pixels(table, rest) for name, table in tables.items()}
    units["lip_press"] = _lip_press(rest)
    units["blink_right"] = _blink(rest, EYELID_PAIRS[:2])
    units["blink_left"] = _blink(rest, EYELID_PAIRS[2:])
    return {name: units[name] for name in UNITS}


def blend(units: dict[str, np.ndarray], weights: dict[str, np.ndarray]) -> np.ndarray:
    """(T, 68, 3) float32 pixel offsets: the weighted sum of action units, frame by frame.

    units:   {name: (68, 3) float32} as returned by `unit_offsets`.
    weights: {name: (T,) float32} per-frame strength of each unit (units not named stay at 0);
             at least one entry, all of the same length T.
    """
    if not weights:
        raise ValueError("blend needs at least one weight track to know the frame count")
    unknown = set(weights) - set(units)
    if unknown:
        raise KeyError(f"unknown action units {sorted(unknown)}; known: {sorted(units)}")
    names = list(weights)
    matrix = np.stack([np.asarray(weights[name], np.float32) for name in names], axis=1)  # (T, U)
    basis = np.stack([units[name] for name in names])  # (U, 68, 3)
    return np.einsum("tu,unc->tnc", matrix, basis).astype(np.float32)


def close_lips(points: np.ndarray, amount: np.ndarray) -> np.ndarray:
    """(T, 68, 3) float32 offsets that bring the inner lips of each frame's mouth together.

    points: (T, 68, 3) float32 landmarks in any frame and unit (pixels, or IOD face units), the
            mouth shapes to close (e.g. rest + blended unit offsets).
    amount: (T,) float32 in [0, 1]: 0 leaves a frame alone, 1 makes each facing inner-lip pair meet
            LIP_MEET of the way from the upper to the lower lip; the outer lip points move with the
            inner point they sit over, so the lips keep their thickness.
    """
    points = np.asarray(points, np.float32)
    amount = np.asarray(amount, np.float32)[:, None]
    offsets = np.zeros_like(points)
    for upper, lower in INNER_LIP_PAIRS:
        opening = points[:, lower] - points[:, upper]
        offsets[:, upper] = amount * LIP_MEET * opening
        offsets[:, lower] = -amount * (1.0 - LIP_MEET) * opening
    for outer, inner in OUTER_OVER_INNER:
        offsets[:, outer] = offsets[:, inner]
    return offsets

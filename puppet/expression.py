"""Expressions: named moods (brows, eye openness, mouth corners) as mixes of action units, layered
on top of any motion; a live window eases from one to the next.

Weights are those of `puppet.articulation` units; "eyes" drives both blink units at once, so a
positive weight narrows the eyes (the cheeks of a smile push the lids up) and a negative one opens
them wider than drawn. Speech still moves the mouth: an expression only shifts where it rests.
"""
import math

import numpy as np

from puppet.articulation import blend, unit_offsets
from puppet.errors import PuppetError

EXPRESSIONS: dict[str, dict[str, float]] = {
    "neutral": {},
    "happy": {"smile": 1.3, "brow_raise": 0.25, "eyes": 0.2},
    "angry": {"brow_frown": 1.4, "smile": -0.6, "eyes": -0.1, "lip_press": 0.3},
    "surprised": {"brow_raise": 1.0, "eyes": -0.35, "jaw_open": 0.1, "lip_round": 0.3},
    "sad": {"brow_frown": -1.0, "smile": -1.0, "eyes": 0.2},
}
EASE_SECONDS = 0.15  # time constant of the change from one expression to the next


def weights(name: str) -> dict[str, float]:
    """The unit weights of a named expression ("eyes" expanded into both blink units)."""
    if name not in EXPRESSIONS:
        raise PuppetError(f"unknown expression {name!r}; choose from {', '.join(EXPRESSIONS)}")
    mix = dict(EXPRESSIONS[name])
    eyes = mix.pop("eyes", 0.0)
    if eyes:
        mix |= {"blink_right": eyes, "blink_left": eyes}
    return mix


def expression_offsets(rest: np.ndarray, name: str) -> np.ndarray:
    """(68, 3) float32 pixel offsets in the head frame of a named expression on a face with (68, 3) rest landmarks."""
    mix = weights(name)
    if not mix:
        return np.zeros_like(np.asarray(rest, np.float32))
    return blend(unit_offsets(rest), {unit: np.array([w], np.float32) for unit, w in mix.items()})[0]


class ExpressionBlend:
    """The current expression of a live face, easing toward the chosen one over EASE_SECONDS."""

    def __init__(self, rest: np.ndarray, name: str = "neutral"):
        """rest: (68, 3) float32 rest landmarks, image pixels."""
        self.targets = {expression: expression_offsets(rest, expression) for expression in EXPRESSIONS}
        weights(name)
        self.name = name
        self.current = self.targets[name].copy()
        self.time = None

    def choose(self, name: str) -> None:
        weights(name)
        self.name = name

    def offsets(self, time: float) -> np.ndarray:
        """(68, 3) float32 pixel offsets at `time` seconds (increasing between calls)."""
        step = 0.0 if self.time is None else max(time - self.time, 0.0)
        self.time = time
        follow = 1.0 - math.exp(-step / EASE_SECONDS)
        self.current += follow * (self.targets[self.name] - self.current)
        return self.current

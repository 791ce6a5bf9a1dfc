"""The `ellipse` shape: center + R(rotation) (a cos t, b sin t) for t from `start` to `start + sweep`, as chords.

Over the parameter t, ||c''(t)|| = sqrt(a^2 cos^2 t + b^2 sin^2 t) = sqrt((a^2 + b^2)/2 + (a^2 - b^2)/2 cos 2t),
whose exact maximum over any interval comes from the largest cos 2t there: the chord bound needs nothing else.
"""

from __future__ import annotations

import math

import numpy as np

from codegen.shapes.context import MAX_CHORDS, ChordError, Pen, max_cos, split_chords, within_a_turn
from codegen.toolpath.items import Item


def ellipse(shape, pen: Pen) -> list[Item]:
    a, b = float(shape.a), float(shape.b)
    rotation = math.radians(within_a_turn(shape.rotation))
    start_deg, sweep_deg = within_a_turn(shape.start), float(shape.sweep)
    start, end = math.radians(start_deg), math.radians(start_deg + sweep_deg)
    mean, half = (a * a + b * b) / 2.0, (a * a - b * b) / 2.0
    shift = 0.0 if half >= 0.0 else math.pi  # the largest of -|half| cos u is where cos(u - pi) is largest

    def curvature(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        return np.sqrt(mean + abs(half) * max_cos(2.0 * lo - shift, 2.0 * hi - shift))

    try:
        ts, deviation = split_chords(curvature, min(start, end), max(start, end), pen.tolerance)
    except ChordError:  # the bounds are exact and finite: only the count can fail
        raise pen.error(shape, f"ellipse needs more than {MAX_CHORDS} chords to stay within the tolerance "
                               f"{pen.tolerance:g} mm") from None
    if end < start:
        ts = ts[::-1]
    cos_r, sin_r = math.cos(rotation), math.sin(rotation)

    def trace(t: np.ndarray) -> np.ndarray:
        u, v = a * np.cos(t), b * np.sin(t)
        return np.column_stack([shape.center[0] + cos_r * u - sin_r * v, shape.center[1] + sin_r * u + cos_r * v])

    return pen.curve(shape, ts, trace, deviation, close=abs(sweep_deg) >= 360.0)  # a whole turn closes exactly

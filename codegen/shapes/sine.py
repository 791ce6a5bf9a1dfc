"""The `sine` shape: y = y0 + A sin(omega (x - x0) + phase) for x from x0 to x0 + length, as chords.

With x as the parameter, c''(x) = (0, -A omega^2 sin(theta)), so the chord bound over an interval needs the
exact largest |sin theta| there: 1 where theta passes an odd multiple of pi/2, else the larger end value.
"""

from __future__ import annotations

import math

import numpy as np

from codegen.shapes.context import MAX_CHORDS, ChordError, Pen, max_cos, split_chords, within_a_turn
from codegen.toolpath.items import Item


def sine(shape, pen: Pen) -> list[Item]:
    x0, y0 = float(shape.origin[0]), float(shape.origin[1])
    amplitude, omega = float(shape.amplitude), float(shape.omega)
    phase = math.radians(within_a_turn(shape.phase))
    x1 = x0 + float(shape.length)
    peak = abs(amplitude) * omega * omega

    def curvature(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        t0, t1 = omega * (lo - x0) + phase, omega * (hi - x0) + phase
        t0, t1 = np.minimum(t0, t1), np.maximum(t0, t1)
        largest_sin = max_cos(t0 - math.pi / 2, t1 - math.pi / 2)
        largest_minus_sin = max_cos(t0 + math.pi / 2, t1 + math.pi / 2)
        return peak * np.maximum(largest_sin, largest_minus_sin)

    try:
        xs, deviation = split_chords(curvature, min(x0, x1), max(x0, x1), pen.tolerance)
    except ChordError:  # the bounds are exact and finite: only the count can fail
        raise pen.error(shape, f"sine needs more than {MAX_CHORDS} chords to stay within the tolerance "
                               f"{pen.tolerance:g} mm") from None
    if x1 < x0:
        xs = xs[::-1]
    return pen.curve(shape, xs, lambda x: np.column_stack([x, y0 + amplitude * np.sin(omega * (x - x0) + phase)]),
                     deviation)

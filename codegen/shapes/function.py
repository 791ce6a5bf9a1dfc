"""The `function` shape: the points (x0 + x, y0 + f(x)) for x from `from` to `to`, as chords.

Every chord's deviation is proven with the expression's interval enclosures: the chord bound
h^2/8 * max |f''| where f'' can be bounded; elsewhere (kinks, infinite slopes) a chord is proven on its own
with the smaller of max f - min f and h * (max f' - min f') / 4, which only need f, or f', bounded.
Both bound the vertical distance to the chord, so they bound the distance too.
"""

from __future__ import annotations

import numpy as np

from codegen.job.calculus import bound, derivative
from codegen.shapes.context import MAX_CHORDS, ChordError, Pen, split_chords
from codegen.toolpath.items import Item

_NEAR = 1e-9  # relative half-width of the interval looked at when telling why a bound failed


def function(shape, pen: Pen) -> list[Item]:
    f = shape.expr
    slope = derivative(f)
    bend = derivative(slope)
    start, stop = float(shape.x[0]), float(shape.x[1])
    x0, y0 = float(shape.origin[0]), float(shape.origin[1])

    def values(x: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):
            y = np.asarray(f.evaluate(x), dtype=float)
        bad = np.flatnonzero(~np.isfinite(y))
        if bad.size:
            where = x[bad][np.argmin(np.abs(x[bad] - start))]  # the first one along the drawing
            raise pen.error(shape, f"function y is undefined at x={where:g} (y = {shape.y})")
        return y

    def curvature(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        low, high = _enclose(bend, lo, hi)
        size = np.maximum(np.abs(low), np.abs(high))
        known = np.flatnonzero(np.isfinite(size))
        defined, _ = _enclose(f, lo[known], hi[known])
        size[known[np.isnan(defined)]] = np.nan  # f'' can outlive f's domain (log u -> u'/u): no bound there
        return size

    def fallback(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        low, high = _enclose(f, lo, hi)
        slope_low, slope_high = _enclose(slope, lo, hi)
        with np.errstate(invalid="ignore"):
            by_value = high - low
            by_slope = (hi - lo) * (slope_high - slope_low) / 4.0
        return np.fmin(by_value, by_slope)

    values(np.array([start, stop]))
    try:
        xs, deviation = split_chords(curvature, min(start, stop), max(start, stop), pen.tolerance,
                                     fallback=fallback, probe=values)
    except ChordError as err:
        raise pen.error(shape, _why(f, err, pen.tolerance, shape.y, abs(stop - start))) from None
    if stop < start:
        xs = xs[::-1]
    return pen.curve(shape, xs, lambda x: np.column_stack([x0 + x, y0 + values(x)]), deviation)


def _enclose(expr, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The expression's enclosure on each [lo_i, hi_i]; nan where it has none."""
    low, high = np.full(lo.shape, np.nan), np.full(lo.shape, np.nan)
    for i, (a, b) in enumerate(zip(lo.tolist(), hi.tolist())):
        found = bound(expr, a, b)
        if found is not None:
            low[i], high[i] = found
    return low, high


def _why(f, err: ChordError, tolerance: float, text: str, span: float) -> str:
    if err.reason == "count":
        return (f"function y needs more than {MAX_CHORDS} chords to stay within the tolerance {tolerance:g} mm "
                f"(y = {text})")
    t = 0.0 if abs(err.t) <= 1e-12 * span else err.t  # converging on 0 without reaching it
    near = _NEAR * max(1.0, abs(err.t))
    if bound(f, err.t - near, err.t + near) is None:
        return f"function y is not defined or not bounded near x={t:g} (y = {text})"
    return f"function y: cannot bound the curvature near x={t:g} (y = {text})"

"""The drawing context the shape builders share, and the chord splitter of the curved shapes.

`Pen` knows where the tool is, the feeds and the machine's tolerance, and makes the toolpath items:
travel moves (tool off) and drawn lines (tool on), with every coordinate as a 4-vector [x, y, z, e] in mm.

`split_chords` cuts a parameter range into chords whose distance from the curve is provably within the
tolerance, using the chord bound: over [t0, t0 + h] a C2 curve stays within h^2/8 * max ||c''|| of its chord.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from codegen.errors import Diagnostic, JobError
from codegen.toolpath.items import FINE_STEPS, Curve, Item, Line

SAME_POINT = 1e-9  # mm: closer than this, the tool is already there
MAX_CHORDS = 100_000  # proven pieces per curve; far more chords than any target's flash holds
MAX_DEPTH = 60  # bisection levels: no piece narrower than 2^-60 of the range
MAX_LOST = 1024  # pieces at once where nothing is known: more is no isolated point but a curve beyond proof
_SHRINK = 1.0 - 1e-9  # keeps h^2/8 * bound strictly below the tolerance despite rounding


@dataclass
class Pen:
    position: np.ndarray  # 4-vector, mm
    tolerance: float  # mm
    draw_feed: float  # mm/s
    travel_feed: float  # mm/s, math.inf: as fast as the machine allows
    motors: tuple[str, ...]
    has_z: bool

    def error(self, shape, message: str) -> JobError:
        return JobError([Diagnostic(shape.source, message)])

    def feed(self, shape) -> float:
        """The shape's own drawing feed (mm/min in the job) in mm/s, else the program's."""
        own = getattr(shape, "feed", None)
        return self.draw_feed if own is None else own / 60.0

    def z(self, shape) -> float:
        """The height a 2-D shape is drawn at: its own `z`, else the current one."""
        return self.check_z(shape, self.position[2] if shape.z is None else float(shape.z))

    def check_z(self, shape, z: float) -> float:
        if z != 0.0 and not self.has_z:
            raise self.error(shape, f"{shape.kind} needs z={z:g} mm, but the machine has no z motor "
                                    f"(motors: {', '.join(self.motors)})")
        return z

    def point(self, shape, p, z: float | None = None) -> np.ndarray:
        """A job point as a 4-vector: a third number is its z, else `z`, else the shape's draw height."""
        if len(p) > 2:
            height = self.check_z(shape, float(p[2]))
        else:
            height = self.z(shape) if z is None else z
        return np.array([float(p[0]), float(p[1]), height, 0.0])

    def travel(self, shape, target: np.ndarray, feed: float | None = None) -> list[Line]:
        """A tool-off move from the current point to `target`, or nothing when the tool is already there."""
        if np.linalg.norm(target - self.position) <= SAME_POINT:
            return []
        speed = self.travel_feed if feed is None else feed
        return [Line(self.position.copy(), target.copy(), speed, False, shape.source, "travel")]

    def line(self, shape, start: np.ndarray, end: np.ndarray) -> list[Line]:
        """A drawn straight move, or nothing when it has no length."""
        if np.linalg.norm(end - start) <= SAME_POINT:
            return []
        return [Line(start.copy(), end.copy(), self.feed(shape), True, shape.source, shape.kind)]

    def curve(self, shape, params: np.ndarray, trace: Callable[[np.ndarray], np.ndarray],
              deviation: float, close: bool = False) -> list[Item]:
        """Travel to the curve's start, then draw the chords between `trace(params)` ((n, 2) points) as a
        `Curve` at the draw height; `close` makes the last point exactly the first (a whole turn)."""
        z = self.z(shape)
        xy = trace(params)
        if close:
            xy[-1] = xy[0]
        points = np.zeros((len(xy), 4))
        points[:, :2] = xy
        points[:, 2] = z
        steps = np.arange(FINE_STEPS + 1) / FINE_STEPS
        between = params[:-1, None] + (params[1:] - params[:-1])[:, None] * steps[None, :]
        fine = np.zeros(between.shape + (3,))
        fine[..., :2] = trace(between.ravel()).reshape(between.shape + (2,))
        fine[..., 2] = z
        items: list[Item] = self.travel(shape, points[0])
        if np.abs(points - points[0]).max() > SAME_POINT:
            items.append(Curve(points, deviation, self.feed(shape), True, shape.source, fine, shape.kind))
        return items


def within_a_turn(degrees: float) -> float:
    """An angle in degrees brought within (-360, 360), exactly (fmod is exact and 360 is a float): a start angle
    or phase of 1e18 degrees would otherwise swallow the sweep added to it and every x in sin(omega x + phase)."""
    return math.fmod(float(degrees), 360.0)


def max_cos(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The exact largest cos(u) for u in each [lo_i, hi_i]."""
    turn = 2.0 * math.pi
    return np.where(np.ceil(lo / turn) * turn <= hi, 1.0, np.maximum(np.cos(lo), np.cos(hi)))


class ChordError(Exception):
    """The splitter could not prove a bound near parameter `t` (or would need too many chords)."""

    def __init__(self, t: float, reason: str):
        self.t = t
        self.reason = reason  # "curvature" | "count"
        super().__init__(f"{reason} near t={t:g}")


Bounds = Callable[[np.ndarray, np.ndarray], np.ndarray]


def split_chords(curvature: Bounds, lo: float, hi: float, tolerance: float, *,
                 fallback: Bounds | None = None,
                 probe: Callable[[np.ndarray], None] | None = None) -> tuple[np.ndarray, float]:
    """Chord ends lo = t0 < t1 < ... < tn = hi and the largest proven chord deviation (<= tolerance).

    `curvature(a, b)` bounds ||c''|| on each [a_i, b_i] (nan or inf: unknown there). Where it is unknown,
    `fallback(a, b)` may bound a chord's deviation directly (such pieces become chords of their own), or
    return nan: nothing about the curve is known there. `probe(t)` sees every bisection point and may raise
    when the curve is undefined there.
    First the range is bisected until every piece is proven; then chords are laid greedily over the
    pieces' bounds, each as long as the largest bound it spans allows (the fewest chords those bounds permit).
    """
    finest = (hi - lo) * 2.0 ** -MAX_DEPTH
    a, b = np.array([lo]), np.array([hi])
    smooth: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    fixed: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    count = 0
    while a.size:
        if count + a.size > MAX_CHORDS:
            raise ChordError(float(0.5 * (a[0] + b[0])), "count")
        h = b - a
        with np.errstate(invalid="ignore", over="ignore"):
            bound = np.asarray(curvature(a, b), dtype=float)
            good = h * h / 8.0 * bound <= tolerance * _SHRINK
        smooth.append((a[good], b[good], bound[good]))
        count += int(good.sum())
        rest = ~good
        found_a, found_b = np.empty(0), np.empty(0)
        if fallback is not None:
            unknown = np.flatnonzero(rest & ~np.isfinite(bound))
            dev = np.asarray(fallback(a[unknown], b[unknown]), dtype=float)
            ok = dev <= tolerance
            fixed.append((a[unknown[ok]], b[unknown[ok]], dev[ok]))
            count += int(ok.sum())
            lost = unknown[np.isnan(dev)]
            rest[unknown[ok]] = rest[lost] = False
            found_a, found_b = _isolate(fallback, a[lost], b[lost], finest, probe)
        a, b = _halve(a[rest], b[rest], finest, probe)
        a, b = np.concatenate([a, found_a]), np.concatenate([b, found_b])
    return _lay_chords(smooth, fixed, lo, hi, tolerance)


def _halve(a: np.ndarray, b: np.ndarray, finest: float, probe) -> tuple[np.ndarray, np.ndarray]:
    mid = 0.5 * (a + b)
    stuck = (b - a <= finest) | (mid <= a) | (mid >= b)
    if stuck.any():
        raise ChordError(float(mid[stuck][0]), "curvature")
    if probe is not None and mid.size:
        probe(mid)
    return np.concatenate([a, mid]), np.concatenate([mid, b])


def _isolate(fallback: Bounds, a: np.ndarray, b: np.ndarray, finest: float, probe):
    """Bisect the pieces where nothing is known, depth first, until every half knows something; those halves.

    A point where the curve cannot be bounded at all (a pole) is so found at once, before the pieces around
    it have cost the chords that lead up to it."""
    found_a, found_b = [np.empty(0)], [np.empty(0)]
    while a.size:
        if a.size > MAX_LOST:
            raise ChordError(float(0.5 * (a[0] + b[0])), "curvature")
        a, b = _halve(a, b, finest, probe)
        lost = np.isnan(np.asarray(fallback(a, b), dtype=float))
        found_a.append(a[~lost])
        found_b.append(b[~lost])
        a, b = a[lost], b[lost]
    return np.concatenate(found_a), np.concatenate(found_b)


def _lay_chords(smooth, fixed, lo: float, hi: float, tolerance: float) -> tuple[np.ndarray, float]:
    pieces = [(s, e, w, False) for part in smooth for s, e, w in zip(*(x.tolist() for x in part))]
    pieces += [(s, e, d, True) for part in fixed for s, e, d in zip(*(x.tolist() for x in part))]
    pieces.sort()
    allowed = 8.0 * tolerance * _SHRINK

    def reach_of(bound: float) -> float:
        return math.sqrt(allowed / bound) if bound > 0.0 else math.inf

    ends, worst = [lo], 0.0
    start, top = lo, 0.0  # the open chord: where it starts, the largest curvature bound it spans so far
    for a, b, value, alone in pieces:
        if alone:  # a piece proven without a curvature bound is a chord by itself
            if start < a:
                ends.append(a)
                worst = max(worst, (a - start) ** 2 / 8.0 * top)
            ends.append(b)
            worst = max(worst, value)
            start, top = b, 0.0
            continue
        while True:
            both = max(top, value)
            if start + reach_of(both) >= b:  # the chord runs on past this piece
                top = both
                break
            if start + reach_of(both) < a:  # this piece's bound would not even let it reach the piece
                end, bound = a, top
            else:
                end, bound = start + reach_of(both), both
            ends.append(end)
            worst = max(worst, (end - start) ** 2 / 8.0 * bound)
            start, top = end, 0.0
    if start < hi:
        ends.append(hi)
        worst = max(worst, (hi - start) ** 2 / 8.0 * top)
    return np.array(ends), worst

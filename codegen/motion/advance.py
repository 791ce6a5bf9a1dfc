"""Klipper's smooth pressure advance on the host: the extruder axis of the motion the blocks are cut from.

On the plan's clock the extruder's nominal position e(t) is piecewise quadratic (codegen/motion/shaped_motion.py
`planned_motion`). On a piece whose segment extrudes (e forward) while x or y moves (Klipper's "can pressure
advance"), the extruder leads by K times its velocity: f(t) = e(t) + K e'(t), K the segment's (the job's, or the
last M900 / M572 before it); elsewhere f = e. The extruder then follows f averaged with a triangular weight of
half width h = smooth_time / 2 (klippy/chelper/kin_extruder.c; our code):

    g(t) = integral of f(x) (h - |t - x|) / h^2 dx over [t - h, t + h]

The triangle is a box of width h convolved with itself, so g'' = (f(t + h) - 2 f(t) + f(t - h)) / h^2: g is
piecewise quartic, with breaks at f's breaks and h either side, and its third derivative is linear between them.
The blocks are cut from quadratic pieces (shaped_blocks.py), so each quartic piece is split into pieces short
enough that the quadratic through g at their ends and middle stays within the tolerance: that interpolation
strays at most max|g'''| L^3 / (72 sqrt 3) on a piece of length L. g is evaluated exactly (`smoothed`, the
integral over the f pieces under the triangle: in C, codegen/native/advance.c, or numpy over all pairs of a time
and a piece without it).

g reads f up to h ahead, so the motion carrying it runs at least h behind the plan (ShapingSettings.shift): no
step comes before the program starts, and a window's shaped motion up to its end reads only its own plan.

With K 0 Klipper sets the smoothing time to 0 too (klippy/kinematics/extruder.py), and its extruder is the
nominal one. Here a stretch of the plan (a window with its tail, or an era's whole plan) none of whose segments
has a K other than 0 plays the nominal extruder (`smooths`: K alone decides, as in Klipper, where retractions and
moves of e alone are smoothed too), on the same delayed clock; and once an era of the input shapers smooths, its
windows smooth on to its end (codegen/pipeline/shaping.py: a window's tail says so). A known difference from
Klipper: where K changes between 0 and another value mid-program (M900, M572), Klipper's smoothing stops and
starts there, the extruder jumping by the difference; ours stays on throughout, from the first window with a K
other than 0 to the era's end. A kept build's formula (codegen/verify/advance.py) is nominal up to that window
too (codegen/pipeline/windows.py Totals.smoothed_from).
"""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass

import numpy as np

from codegen.native import contiguous, library, pointer
from codegen.toolpath.segments import Segments

INTERPOLATION_BOUND = 1.0 / (72.0 * math.sqrt(3.0))  # a 3-point quadratic's error per max|g'''| L^3
MAX_SPLIT = 4096  # pieces of one quartic piece at most (a guard: a sane motion needs a few)


@dataclass(frozen=True)
class AdvanceSettings:
    """The smoothing time (s; K travels with the segments) and how far (mm of extruder) the quadratic pieces may
    stray from the exact formula."""

    smooth_time: float
    tolerance_mm: float

    @property
    def half(self) -> float:
        return 0.5 * self.smooth_time


@dataclass(frozen=True)
class Quadratics:
    """One axis, piecewise quadratic: on piece k from breaks[k], position + velocity dt + accel dt^2 / 2; before
    the first break it rests at the first position, after the last at `end`."""

    breaks: np.ndarray  # (K + 1,)
    position: np.ndarray  # (K,)
    velocity: np.ndarray
    accel: np.ndarray

    @property
    def end(self) -> float:
        h = self.breaks[-1] - self.breaks[-2]
        return float(self.position[-1] + self.velocity[-1] * h + 0.5 * self.accel[-1] * h * h)

    def piece_of(self, t: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self.breaks, t, side="right") - 1, 0, len(self.position) - 1)

    def at(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        inside = np.clip(t, self.breaks[0], self.breaks[-1])
        k = self.piece_of(inside)
        dt = inside - self.breaks[k]
        return self.position[k] + self.velocity[k] * dt + 0.5 * self.accel[k] * dt * dt


def can_advance(segments: Segments) -> np.ndarray:
    """(n,) the segments pressure advance applies to: e forward while x or y moves (Klipper's flag)."""
    move = segments.end - segments.start
    return (move[:, 3] > 0) & np.any(move[:, :2] != 0, axis=1)


def advanced_source(breaks: np.ndarray, position: np.ndarray, velocity: np.ndarray, accel: np.ndarray,
                    origin: np.ndarray, segments: Segments, half: float) -> Quadratics:
    """f = e + K e' of the plan's extruder pieces (`origin`: each piece's segment), resting a triangle's width
    before and after (so that every time g needs lies on a piece)."""
    k = np.where(can_advance(segments), segments.advance, 0.0)[origin]
    p, v, a = position + k * velocity, velocity + k * accel, accel
    end = Quadratics(breaks, p, v, a).end
    reach = 2.0 * half
    return Quadratics(np.concatenate([[breaks[0] - reach], breaks, [breaks[-1] + reach]]),
                      np.concatenate([[p[0]], p, [end]]), np.concatenate([[0.0], v, [0.0]]),
                      np.concatenate([[0.0], a, [0.0]]))


def smooths(origin: np.ndarray, segments: Segments) -> bool:
    """The extruder of the plan pieces whose segments are `origin` is smoothed: some segment has a K other than 0
    (Klipper keys its smoothing on K alone, retractions and moves of e alone included)."""
    return bool(np.any(segments.advance[origin] != 0))


def smoothed(f: Quadratics, t: np.ndarray, half: float) -> np.ndarray:
    """g at times t (N,): f under the triangle of half width `half` centred on each, exactly (half 0: f itself,
    Klipper's extruder with K 0). In one pass in C (codegen/native/advance.c) where the helper could be built,
    else in numpy (`smoothed_numpy`)."""
    if half == 0:
        return f.at(t)
    lib = library("advance")
    if lib is None:
        return smoothed_numpy(f, t, half)
    t, breaks, position, velocity, accel = contiguous(np.float64, t, f.breaks, f.position, f.velocity, f.accel)
    g = np.empty(len(t))
    lib.smoothed(ctypes.c_int64(len(t)), pointer(t), ctypes.c_int64(len(position)),
                 *map(pointer, (breaks, position, velocity, accel)), ctypes.c_double(half), pointer(g))
    return g


def smoothed_numpy(f: Quadratics, t: np.ndarray, half: float) -> np.ndarray:
    """`smoothed` in numpy, over all pairs of a time and a piece under its triangle."""
    t = np.asarray(t, dtype=float)
    lo, hi = f.piece_of(t - half), f.piece_of(t + half)
    count = hi - lo + 1
    sample = np.repeat(np.arange(len(t)), count)
    piece = lo[sample] + np.arange(len(sample)) - np.repeat(np.cumsum(count) - count, count)
    centre = t[sample]
    reference = f.at(t)  # g - f(t) is small: the sums keep their precision
    d = centre - f.breaks[piece]
    c0 = f.position[piece] + f.velocity[piece] * d + 0.5 * f.accel[piece] * d * d - reference[sample]
    c1 = f.velocity[piece] + f.accel[piece] * d
    c2 = 0.5 * f.accel[piece]
    u0 = np.clip(f.breaks[piece] - centre, -half, half)  # the piece under the triangle, from its centre
    u1 = np.clip(f.breaks[piece + 1] - centre, -half, half)
    area = (_weighted(c0, c1, c2, half, 1.0, u0, np.minimum(u1, 0.0))
            + _weighted(c0, c1, c2, half, -1.0, np.maximum(u0, 0.0), u1))
    return reference + np.bincount(sample, weights=area, minlength=len(t)) / (half * half)


def _weighted(c0, c1, c2, half: float, side: float, u0, u1) -> np.ndarray:
    """The integral of (half + side u)(c0 + c1 u + c2 u^2) from u0 to u1 (0 where u1 <= u0)."""
    q0, q1, q2, q3 = half * c0, half * c1 + side * c0, half * c2 + side * c1, side * c2
    u1 = np.maximum(u1, u0)

    def antiderivative(u):
        return u * (q0 + u * (q1 / 2 + u * (q2 / 3 + u * q3 / 4)))

    return antiderivative(u1) - antiderivative(u0)


def advanced_extruder(breaks: np.ndarray, position: np.ndarray, velocity: np.ndarray, accel: np.ndarray,
                      origin: np.ndarray, segments: Segments, settings: AdvanceSettings,
                      smooth: bool | None = None) -> Quadratics:
    """The advanced extruder on the plan's clock, in quadratic pieces within settings.tolerance_mm of g, from a
    triangle's half width before the plan's first break to as far after its last. The plan's extruder pieces:
    `breaks` (K + 1,), `position`, `velocity`, `accel` (K,), `origin` their segments. `smooth`: whether it is
    smoothed (None: `smooths`); if not, it is the nominal extruder, the plan's pieces."""
    half = settings.half
    if not (smooths(origin, segments) if smooth is None else smooth):  # resting as far on either side as g does
        end = Quadratics(breaks, position, velocity, accel).end
        return Quadratics(np.concatenate([[breaks[0] - half], breaks, [breaks[-1] + half]]),
                          np.concatenate([[position[0]], position, [end]]), np.concatenate([[0.0], velocity, [0.0]]),
                          np.concatenate([[0.0], accel, [0.0]]))
    f = advanced_source(breaks, position, velocity, accel, origin, segments, half)
    quartic = np.unique((breaks[:, None] + np.array([-half, 0.0, half])[None, :]).ravel())
    begin, length = quartic[:-1], np.diff(quartic)
    third = np.maximum(np.abs(_third_derivative(f, begin, begin + 0.5 * length, half)),
                       np.abs(_third_derivative(f, quartic[1:], begin + 0.5 * length, half)))
    longest = np.cbrt(settings.tolerance_mm / (INTERPOLATION_BOUND * np.maximum(third, 1e-300)))
    split = np.clip(np.ceil(length / longest), 1, MAX_SPLIT).astype(np.int64)
    first = np.repeat(begin, split)
    rank = np.arange(len(first)) - np.repeat(np.cumsum(split) - split, split)
    fine = np.append(first + np.repeat(length / split, split) * rank, quartic[-1])
    h = np.diff(fine)
    values = smoothed(f, np.concatenate([fine, fine[:-1] + 0.5 * h]), half)
    g0, g1, middle = values[:len(h)], values[1:len(h) + 1], values[len(h) + 1:]
    a = 4.0 * (g0 - 2.0 * middle + g1) / (h * h)
    return Quadratics(fine, g0, (g1 - g0) / h - 0.5 * a * h, a)


def _third_derivative(f: Quadratics, t: np.ndarray, inside: np.ndarray, half: float) -> np.ndarray:
    """g''' at t (N,) = (f'(t + h) - 2 f'(t) + f'(t - h)) / h^2, each f' on the piece that holds `inside` shifted
    alike (a quartic piece of g lies on one piece of f at every shift)."""
    total = np.zeros(len(t))
    for shift, weight in ((-half, 1.0), (0.0, -2.0), (half, 1.0)):
        k = f.piece_of(inside + shift)
        total += weight * (f.velocity[k] + f.accel[k] * (t + shift - f.breaks[k]))
    return total / (half * half)


@dataclass(frozen=True)
class AdvanceReference:
    """What an advanced extruder's pulses are held against: f on the plan's clock (`advanced_source`), the shaped
    clock's delay, and the G-code line of every plan piece (from its break)."""

    source: Quadratics
    half: float  # s, the triangle's (0: the nominal extruder, unsmoothed)
    shift: float  # s the shaped clock (the pulses') runs behind the plan's
    piece_breaks: np.ndarray  # (K + 1,) the plan's pieces
    piece_line: np.ndarray  # (K,)
    begin: float = -np.inf  # s, the shaped clock's stretch it answers for (a window's: the plan before it is gone)
    end: float = np.inf

    def worst(self, time: np.ndarray, direction: np.ndarray, after: np.ndarray,
              steps_per_mm: float) -> tuple[float, float, int]:
        """The extruder's pulses (times on the shaped clock, directions, absolute positions in steps after each):
        the largest distance (steps) of g from the extruder's position at a pulse, its time on the shaped clock and
        its G-code line (0: none); (0, 0, 0) without pulses. At a pulse the position is both the one before it
        and the one after, so the distance is to the nearer: 0 while g lies between them (a step made where g
        crosses the half step has 0), one step when the pulse comes a step and a half early or late."""
        if not len(time):
            return 0.0, 0.0, 0
        plan_time = np.asarray(time, dtype=float) - self.shift
        boundary = after - 0.5 * direction  # between the positions before and after
        distance = np.maximum(np.abs(smoothed(self.source, plan_time, self.half) * steps_per_mm - boundary) - 0.5, 0.0)
        k = int(np.argmax(distance))
        piece = np.clip(np.searchsorted(self.piece_breaks, plan_time[k], side="right") - 1, 0,
                        len(self.piece_line) - 1)
        return float(distance[k]), float(time[k]), int(self.piece_line[piece])


def advance_reference(breaks: np.ndarray, position: np.ndarray, velocity: np.ndarray, accel: np.ndarray,
                      origin: np.ndarray, segments: Segments, half: float, shift: float,
                      span: tuple[float, float] = (-np.inf, np.inf), smooth: bool | None = None) -> AdvanceReference:
    """The reference of the plan's extruder pieces (as `advanced_extruder` takes them, `smooth` too), for the
    pulses in `span` (s, shaped clock); unsmoothed, the nominal extruder (half 0)."""
    if smooths(origin, segments) if smooth is None else smooth:
        source = advanced_source(breaks, position, velocity, accel, origin, segments, half)
    else:
        source, half = Quadratics(breaks, position, velocity, accel), 0.0
    return AdvanceReference(source, half, shift, breaks, segments.line[origin], *span)

"""Where a linear machine's shaped motion is cut into blocks whose slaves stay near their chords: Douglas and
Peucker's simplification over quadratic pieces (codegen/motion/shaped_blocks.py says why).

Each block between two bounds is cut at the point where a slave strays furthest from the block's chord (slave
against master, in steps: the Bresenham line) while that is more than `limit` steps, or at its middle where the
master makes more steps than a block holds; the parts are cut the same way, at most MAX_DEPTH times deep.
Blocks are independent, so the cuts are made block by block in C (codegen/native/chordcuts.c, a depth-first
walk), or round by round in numpy, every block of a round at once; both evaluate the same quadratics in the same
order and give the same bounds (tests/motion/test_shaped_native.py).

The motion is read in motor steps, uncut: a block may begin and end inside a piece. A motor's position at time t
is its piece's quadratic at t, the piece being the one that holds t (at a break, the one that begins there).
"""

from __future__ import annotations

import ctypes

import numpy as np

from codegen.motion.blocks import MAX_MODULUS
from codegen.native import contiguous, library, pointer

MAX_DEPTH = 64  # cuts of a block, one within the other (a guard: a sane motion needs far fewer)


def chord_bounds(breaks: np.ndarray, p: np.ndarray, v: np.ndarray, a: np.ndarray, bounds: np.ndarray,
                 limit: float, fresh: np.ndarray | None = None) -> np.ndarray:
    """The bounds (s, sorted) of the blocks after every cut: `breaks` (K + 1,) and the motors' positions at each
    piece's start, velocities and accelerations `p`, `v`, `a` (K, M) in steps; `bounds` the blocks' ends before
    (the motion's ends among them); `fresh` (B,) the blocks to cut (None: all; the others are known to need
    none)."""
    fresh = np.ones(len(bounds) - 1, dtype=bool) if fresh is None else fresh
    lib = library("chordcuts")
    if lib is None:
        return chord_bounds_numpy(breaks, p, v, a, bounds, limit, fresh)
    breaks, bounds = contiguous(np.float64, breaks, bounds)
    p, v, a = contiguous(np.float64, p, v, a)
    fresh, = contiguous(np.uint8, fresh)
    capacity = 4 * len(bounds) + 1024
    while True:
        out = np.empty(capacity)
        count = lib.chord_cuts(ctypes.c_int64(len(breaks) - 1), ctypes.c_int64(p.shape[1]), pointer(breaks),
                               pointer(p), pointer(v), pointer(a), ctypes.c_int64(len(bounds)), pointer(bounds),
                               pointer(fresh), ctypes.c_double(limit), ctypes.c_double(MAX_MODULUS - 1), ctypes.c_int64(MAX_DEPTH),
                               pointer(out), ctypes.c_int64(capacity))
        if count >= 0:
            return out[:count]
        capacity *= 4


def chord_bounds_numpy(breaks: np.ndarray, p: np.ndarray, v: np.ndarray, a: np.ndarray, bounds: np.ndarray,
                       limit: float, fresh: np.ndarray) -> np.ndarray:
    """`chord_bounds` in numpy: each round cuts every block made by the round before, once."""
    for _ in range(MAX_DEPTH):
        which = np.flatnonzero(fresh)
        if not len(which):
            break
        extra = _cuts(breaks, p, v, a, bounds[which], bounds[which + 1], limit)
        if not len(extra):
            break
        grown = np.unique(np.concatenate([bounds, extra]))
        new = ~np.isin(grown, bounds)
        bounds, fresh = grown, new[:-1] | new[1:]
    return bounds


def _position(breaks: np.ndarray, p: np.ndarray, v: np.ndarray, a: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, M) the motors at times t (N,), each on the piece that holds it."""
    piece = np.clip(np.searchsorted(breaks, t, side="right") - 1, 0, len(p) - 1)
    dt = (t - breaks[piece])[:, None]
    return p[piece] + v[piece] * dt + 0.5 * a[piece] * dt * dt


def _cuts(breaks, p, v, a, t0: np.ndarray, t1: np.ndarray, limit: float) -> np.ndarray:
    """The cut of each block [t0, t1] that needs one: at its worst stray, or at its middle where it is too long."""
    x0, x1 = _position(breaks, p, v, a, t0), _position(breaks, p, v, a, t1)
    rows = np.arange(len(t0))
    span_steps = np.abs(np.round(x1) - np.round(x0))
    master = np.argmax(span_steps, axis=1)
    worst, worst_time = _strays(breaks, p, v, a, t0, t1, x0, x1, master)
    bad = (worst > limit) & ((x1 - x0)[rows, master] != 0)
    long = span_steps.max(axis=1) > MAX_MODULUS - 1
    times = np.where(bad, worst_time, 0.5 * (t0 + t1))[bad | long]
    inside = (times > t0[bad | long]) & (times < t1[bad | long])
    return times[inside]


def _strays(breaks, p, v, a, t0, t1, x0, x1, master):
    """Each block's largest distance (steps) of a slave from its chord, and its time: on every part of a piece
    in the block the offset from the chord is a quadratic, largest at an end or where its slope is 0."""
    first = np.clip(np.searchsorted(breaks, t0, side="right") - 1, 0, len(p) - 1)
    last = np.maximum(np.searchsorted(breaks, t1, side="left") - 1, first)  # the last piece beginning before t1
    count = last - first + 1
    block = np.repeat(np.arange(len(t0)), count)
    piece = first[block] + np.arange(len(block)) - np.repeat(np.cumsum(count) - count, count)
    begin = np.maximum(breaks[piece], t0[block])
    h = (np.minimum(breaks[piece + 1], t1[block]) - begin)[:, None]
    dt = (begin - breaks[piece])[:, None]
    start = p[piece] + v[piece] * dt + 0.5 * a[piece] * dt * dt
    speed = v[piece] + a[piece] * dt
    accel = a[piece]
    rows = np.arange(len(t0))
    span = (x1 - x0)[rows, master][:, None]
    ratio = np.divide(x1 - x0, span, out=np.zeros_like(x0), where=span != 0)[block]  # slave steps per master step
    u = master[block][:, None]
    off = start - x0[block] - ratio * (np.take_along_axis(start, u, axis=1) - x0[block, master[block]][:, None])
    c1 = speed - ratio * np.take_along_axis(speed, u, axis=1)
    c2 = accel - ratio * np.take_along_axis(accel, u, axis=1)
    tau = np.divide(-c1, c2, out=np.zeros_like(c1), where=c2 != 0)
    tau = np.where((tau > 0) & (tau < h), tau, 0.0)
    inside = np.abs(off + c1 * tau + 0.5 * c2 * tau * tau)
    at_start = np.where((piece == first[block])[:, None], 0.0, np.abs(off))
    stray = np.maximum(inside, at_start)
    k = np.arange(len(block))
    motor = np.argmax(stray, axis=1)
    worst = stray[k, motor]
    worst_time = begin + np.where(inside[k, motor] >= at_start[k, motor], tau[k, motor], 0.0)
    order = np.lexsort((worst, block))  # per block, its worst piece last (of equals, the latest)
    pick = order[np.cumsum(count) - 1]
    return worst[pick], worst_time[pick]

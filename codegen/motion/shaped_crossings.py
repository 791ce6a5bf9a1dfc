"""The time of every master event of a linear machine's shaped blocks: where the master's exact shaped motion
crosses its half step (the quadratic of its piece solved), as Klipper times its steps.

Progress along each block's master is monotone, so all pieces of all blocks sort on one key, the block's offset
plus the master's progress (kept non-decreasing against rounding), and so do the events' targets: in C
(codegen/native/shapedtimes.c) one walk along both, in numpy a search; both give the same bits
(tests/motion/test_shaped_native.py).
"""

from __future__ import annotations

import ctypes

import numpy as np

from codegen.native import contiguous, library, pointer


def shaped_crossings(breaks: np.ndarray, p: np.ndarray, v: np.ndarray, a: np.ndarray, bounds: np.ndarray,
                     x0: np.ndarray, steps: np.ndarray, master: np.ndarray, moving: np.ndarray,
                     count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Time and phase (0 speeding up, 1 steady, 2 slowing down) of every event of the `moving` blocks (their
    `count` events each, in order): event k (1-based) where the master has gone k - 1/2 steps past its rounded
    start. The motion: `breaks` (K + 1,), motor positions, velocities and accelerations `p`, `v`, `a` (K, M) in
    steps, cut at every block's bounds; x0 (B, M) each block's motors at its start (steps)."""
    piece_block = np.searchsorted(bounds, breaks[:-1], side="right") - 1
    rows = np.arange(len(x0))
    sign = np.sign(steps[rows, master]).astype(float)
    origin = x0[rows, master]
    offset = np.concatenate([[0.0], np.cumsum(np.abs(steps[rows, master]) + 2.0)])  # room for each block's span
    u = master[piece_block]
    s = sign[piece_block]
    pieces = np.arange(len(piece_block))
    progress = s * (p[pieces, u] - origin[piece_block])
    key = np.maximum.accumulate(offset[piece_block] + np.maximum(progress, 0.0))
    speed, accel = s * v[pieces, u], s * a[pieces, u]
    base = sign * (np.round(origin) - origin)
    first = np.searchsorted(breaks, bounds[:-1])  # each block's pieces
    last = np.searchsorted(breaks, bounds[1:]) - 1
    lib = library("shapedtimes")
    if lib is None:
        return _crossings_numpy(breaks, key, progress, speed, accel, offset, base, first, last, moving, count)
    time, phase = np.empty(int(count.sum())), np.empty(int(count.sum()), dtype=np.int8)
    moving, count, first, last = contiguous(np.int64, moving, count, first, last)
    breaks, key, progress, speed, accel, offset, base = contiguous(np.float64, breaks, key, progress, speed, accel,
                                                                   offset, base)
    lib.shaped_crossings(ctypes.c_int64(len(moving)), *map(pointer, (moving, count, offset, base, first, last)),
                         ctypes.c_int64(len(key)), *map(pointer, (key, progress, speed, accel, breaks, time, phase)))
    return time, phase


def _crossings_numpy(breaks, key, progress, speed, accel, offset, base, first, last, moving, count):
    block = np.repeat(moving, count)
    k = np.arange(len(block)) - np.repeat(np.cumsum(count) - count, count) + 1.0  # event number in its block
    target = base[block] + k - 0.5
    piece = np.searchsorted(key, offset[block] + target, side="right") - 1
    piece = np.clip(piece, first[block], last[block])
    speed, accel = speed[piece], accel[piece]
    ahead = np.maximum(target - progress[piece], 0.0)
    root = np.sqrt(np.maximum(speed * speed + 2.0 * accel * ahead, 0.0))
    tau = np.divide(2.0 * ahead, speed + root, out=np.zeros_like(ahead), where=speed + root > 0)
    h = breaks[piece + 1] - breaks[piece]
    time = breaks[piece] + np.clip(tau, 0.0, h)
    return time, np.where(accel > 0, 0, np.where(accel < 0, 2, 1)).astype(np.int8)

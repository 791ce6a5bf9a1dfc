"""Timing windows that keep every motor's rate: the compressor's windows narrowed where 8 of a motor's steps come
near its limit.

A window of 5 % of the gap before each event lets the emitted events move either way: 8 consecutive steps of a
motor come closer by the late side of their first event's window plus the early side of their last event's. Over
7 gaps of a steady rate that is 10 % of one gap, 1.43 %, and more where the last gap is the longest (a slave's
steps where the master changes, at a block start, come unevenly): ideal times that keep the limit could be played
over it. So each end of every 8 steps gets half of what its ideal times leave below the limit (the slack; steps
already played, before the window, leave theirs to the step in the window): the emitted 8 steps then never come
closer than the limit allows. A window keeps at least half a tick either way (it must hold a whole tick), so where
the ideal times themselves leave less than a tick, the emitted ones may come up to one tick closer.
"""

from __future__ import annotations

import numpy as np

from codegen.motion.blocks import Events
from codegen.motion.planner import RATE_WINDOW
from codegen.tables.schedule import FRAC_ONE

LEAST_TICKS = 0.5  # the narrowest window either way


def rate_windows(events: Events, ideal: np.ndarray, win: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 max_rate: np.ndarray, tick_hz: int, base: int, prior: list[np.ndarray] | None = None) \
        -> tuple[np.ndarray, np.ndarray]:
    """The windows [lo, hi] (positions, from tick `base`, as compress makes them of the `ideal` ticks and the
    half-widths `win`) narrowed so that no motor's 8 consecutive steps come closer than `max_rate` (steps/s)
    allows; `prior`: per motor, the ticks of its last steps before the window (up to 7)."""
    early, late = win.copy(), win.copy()
    for m, mine in enumerate(_stepping(events)):
        shortest = RATE_WINDOW * tick_hz / max_rate[m]  # ticks 8 steps must span at least
        t = ideal[mine]
        if len(mine) > RATE_WINDOW:
            half = 0.5 * (t[RATE_WINDOW:] - t[:-RATE_WINDOW] - shortest)
            late[mine[:-RATE_WINDOW]] = np.minimum(late[mine[:-RATE_WINDOW]], half)
            early[mine[RATE_WINDOW:]] = np.minimum(early[mine[RATE_WINDOW:]], half)
        before = np.zeros(0) if prior is None else np.asarray(prior[m], dtype=float)[-RATE_WINDOW:]
        j = np.arange(RATE_WINDOW - len(before), min(RATE_WINDOW, len(mine)))  # steps whose 8 began before
        if len(j):  # the steps before are played: all the slack is the step's in the window
            start = before[j - (RATE_WINDOW - len(before))]
            early[mine[j]] = np.minimum(early[mine[j]], ideal[mine[j]] - start - shortest)
    early, late = np.maximum(early, LEAST_TICKS), np.maximum(late, LEAST_TICKS)
    narrow_lo, narrow_hi = early < win, late < win
    lo, hi = lo.copy(), hi.copy()
    lo[narrow_lo] = FRAC_ONE * np.ceil(ideal[narrow_lo] - early[narrow_lo] - base).astype(np.int64)
    hi[narrow_hi] = FRAC_ONE * np.floor(ideal[narrow_hi] + late[narrow_hi] - base).astype(np.int64) + FRAC_ONE - 1
    return lo, hi


def _stepping(events: Events):
    """Per motor, the events it steps at (codegen/motion/blocks.py `bresenham`, one motor at a time: a window's
    events can be millions)."""
    count = np.diff(events.block_first)
    block = np.repeat(np.arange(len(count)), count)
    first = events.block_first[:-1][block]
    i = np.arange(len(block), dtype=np.float64) - first + 1.0
    modulus = events.block_modulus[block].astype(np.float64)
    for m in range(events.block_steps.shape[1]):
        d = np.abs(events.block_steps[:, m]).astype(np.float64)[block]
        done = np.ceil((i * d - events.block_init[block, m]) / modulus)  # its steps after each event of the block
        before = np.concatenate([[0.0], done[:-1]])
        before[i == 1.0] = 0.0
        yield np.flatnonzero(done != before)

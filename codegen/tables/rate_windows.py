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

Most 8 steps are far from their motor's limit, and a window's events can be millions: only the 8 steps that can
narrow a window are looked at. A motor steps at most once an event, so 8 of its steps come at 8 events at least;
blocks where no 8 events come within the limit plus two windows keep their windows, and in the others a motor's
steps are found from their numbers (the inverse of the player's Bresenham), never event by event.
"""

from __future__ import annotations

import numpy as np

from codegen.motion.blocks import Events
from codegen.motion.planner import RATE_WINDOW
from codegen.tables.schedule import FRAC_ONE

LEAST_TICKS = 0.5  # the narrowest window either way
MARGIN = 1e-9  # of the ticks compared: the bound's rounding differs from the exact test's by far less


def rate_windows(events: Events, ideal: np.ndarray, win: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 max_rate: np.ndarray, tick_hz: int, base: int, prior: list[np.ndarray] | None = None) \
        -> tuple[np.ndarray, np.ndarray]:
    """The windows [lo, hi] (positions, from tick `base`, as compress makes them of the `ideal` ticks, which never
    decrease, and the half-widths `win`) narrowed so that no motor's 8 consecutive steps come closer than
    `max_rate` (steps/s) allows; `prior`: per motor, the ticks of its last steps before the window (up to 7)."""
    near = _span_bound(ideal, win)
    block_near = np.full(len(events.block_modulus), np.inf)
    nonempty = np.diff(events.block_first) > 0
    if np.any(nonempty):
        block_near[nonempty] = np.minimum.reduceat(near, events.block_first[:-1][nonempty])
    early, late = [], []  # (events, slack) pairs: the least slack of each event's early and late side wins
    for m in range(events.block_steps.shape[1]):
        shortest = RATE_WINDOW * tick_hz / max_rate[m]  # ticks 8 steps must span at least
        steps = _MotorSteps(events, m)
        bound = shortest + MARGIN * (shortest + np.max(win, initial=0.0))
        k, at = steps.within(block_near < bound)
        close = near[at] < bound  # the steps that may begin or end 8 near the limit
        k = k[close]
        for start, end in ((k, k + RATE_WINDOW), (k - RATE_WINDOW, k)):
            both = (start >= 0) & (end < steps.total)
            first, last = steps.event(start[both]), steps.event(end[both])
            half = 0.5 * (ideal[last] - ideal[first] - shortest)
            late.append((first, half))
            early.append((last, half))
        before = np.zeros(0) if prior is None else np.asarray(prior[m], dtype=float)[-RATE_WINDOW:]
        j = np.arange(RATE_WINDOW - len(before), min(RATE_WINDOW, steps.total))  # steps whose 8 began before
        if len(j):  # the steps before are played: all the slack is the step's in the window
            at = steps.event(j)
            early.append((at, ideal[at] - before[j - (RATE_WINDOW - len(before))] - shortest))
    at, slack = _least(early, win)
    if len(at):  # the caller's windows stay as they were
        lo = lo.copy()
        lo[at] = FRAC_ONE * np.ceil(ideal[at] - slack - base).astype(np.int64)
    at, slack = _least(late, win)
    if len(at):
        hi = hi.copy()
        hi[at] = FRAC_ONE * np.floor(ideal[at] + slack - base).astype(np.int64) + FRAC_ONE - 1
    return lo, hi


def _span_bound(ideal: np.ndarray, win: np.ndarray) -> np.ndarray:
    """Per event, a bound below which no motor's 8 steps that begin or end at it span, less both their windows:
    8 steps come at 8 events at least, and neither window is wider than the wider of those 8 events' ends. The
    `ideal` ticks never decrease, so the bound's rounding never puts it above the exact span's."""
    if len(ideal) <= RATE_WINDOW:
        return np.full(len(ideal), np.inf)
    near = np.empty(len(ideal))
    wider = np.maximum(win[RATE_WINDOW:], win[:-RATE_WINDOW], out=near[:-RATE_WINDOW])  # near's room, for now
    span = ideal[RATE_WINDOW:] - ideal[:-RATE_WINDOW]
    span -= np.multiply(wider, 2.0, out=wider)
    near[:-RATE_WINDOW] = span  # the 8 that begin at each event ...
    near[-RATE_WINDOW:] = np.inf
    np.minimum(near[RATE_WINDOW:], span, out=near[RATE_WINDOW:])  # ... and those that end there
    return near


def _least(slacks: list[tuple[np.ndarray, np.ndarray]], win: np.ndarray):
    """The events whose least slack narrows their window (below `win`, at least LEAST_TICKS), and that width."""
    at = np.concatenate([np.zeros(0, dtype=np.int64)] + [a for a, _ in slacks])
    slack = np.concatenate([np.zeros(0)] + [s for _, s in slacks])
    order = np.argsort(at, kind="stable")
    at, slack = at[order], slack[order]
    group = np.flatnonzero(np.diff(at, prepend=-1))
    at = at[group]
    slack = np.maximum(np.minimum.reduceat(slack, group), LEAST_TICKS) if len(group) else slack
    narrow = slack < win[at]
    return at[narrow], slack[narrow]


class _MotorSteps:
    """One motor's steps in a window, numbered from 0, and the event each happens at (codegen/motion/blocks.py
    `bresenham`: after i events of a block it has stepped ceil((i*d - init) / N) times, at most once an event,
    so its step s of the block comes at event floor((s*N + init) / d), counted from 0)."""

    def __init__(self, events: Events, m: int):
        self.first = events.block_first[:-1]
        self.steps = np.abs(events.block_steps[:, m]).astype(np.int64)
        self.modulus = events.block_modulus.astype(np.int64)
        self.init = events.block_init[:, m].astype(np.int64)
        self.done = np.cumsum(self.steps)  # its steps after each block
        self.total = int(self.done[-1]) if len(self.done) else 0

    def _at(self, block: np.ndarray, s: np.ndarray) -> np.ndarray:
        return self.first[block] + (s * self.modulus[block] + self.init[block]) // self.steps[block]

    def within(self, blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The numbers and events of its steps in the blocks where `blocks` (B,) bool."""
        chosen = np.flatnonzero(blocks & (self.steps > 0))
        count = self.steps[chosen]
        block = np.repeat(chosen, count)
        s = np.arange(len(block)) - np.repeat(np.cumsum(count) - count, count)
        return self.done[block] - self.steps[block] + s, self._at(block, s)

    def event(self, k: np.ndarray) -> np.ndarray:
        """The events of its steps number `k`."""
        block = np.searchsorted(self.done, k, side="right")
        return self._at(block, k - self.done[block] + self.steps[block])

"""Compression: ideal event times -> rate runs `(interval, add, count)` within a stated timing window.

Every emitted event stays within `window(k)` of its ideal time, where the window is a share of the ideal gap
to the previous event (so motor rates keep their accuracy at any speed), capped by an absolute bound, and
narrowed where 8 of a motor's steps would otherwise come closer than its rate (codegen/tables/rate_windows.py). Events
are never closer than the player's minimum gap: ideal times are first pushed apart where needed (exactly, as a
running maximum), and the push is counted in the timing error the checks report. A pushed event's successors
catch up no faster than every motor's rate allows (a block start can cost the player more than the gap the
plan leaves before it; catching up at the player's own pace would overspeed a motor that runs near its limit).

Runs go on across block starts and motion phases: each is the longest that keeps every one of its events in
its window (codegen/tables/runfit.py, exact integer search), so errors never accumulate from run to run.

The windows and the runs are made in C where the helper builds (codegen/native/runfit.c); numpy's windows and
the Python search are the reference, and give the same bits.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass

import numpy as np

from codegen.motion.blocks import Events
from codegen.motion.planner import quantisation_factor
from codegen.native import contiguous, library, pointer
from codegen.tables.rate_windows import rate_windows
from codegen.tables.runfit import fit_runs, fit_runs_native
from codegen.tables.schedule import FRAC_BITS, FRAC_ONE, MAX_ADD, MAX_COUNT, MAX_INTERVAL, Schedule

# Of a motor's rate that catching up may use (the planner keeps 2 %); the windows then shorten no 8 steps below
# the limit (codegen/tables/rate_windows.py).
RATE_SHARE = 0.985


@dataclass(frozen=True)
class TimingWindow:
    share: float = 0.05  # of the ideal gap to the previous event
    max_us: float = 100.0  # at most: slow moves take fewer runs (a 2 ms gap's 5 % is this)
    min_ticks: float = 2.0  # never tighter than this (the timer itself rounds down to whole ticks)


@dataclass
class Compressed:
    schedule: Schedule
    ideal_ticks: np.ndarray  # (E,) float, after the minimum-gap push
    emitted_ticks: np.ndarray  # (E,) int64, what the player does
    window_ticks: np.ndarray  # (E,)


def spread(ticks: np.ndarray, gap: np.ndarray | float, start: float = -np.inf) -> np.ndarray:
    """e[k] = max(t[k], e[k-1] + gap[k]), e[-1] = `start`: pushes events apart, as a running maximum."""
    total = np.cumsum(np.broadcast_to(np.asarray(gap, dtype=float), ticks.shape))
    pushed = np.maximum.accumulate(ticks - total)
    if np.isfinite(start):
        pushed = np.maximum(pushed, start)
    return pushed + total


def rate_gaps(events: Events, max_rate: np.ndarray, share: float = RATE_SHARE) -> np.ndarray:
    """Per block, the shortest gap (s) between its events that keeps every motor within `share` of its rate
    over any 8 of its steps (a slave steps on at most `steps / modulus` of the events, Bresenham-spread)."""
    steps = np.abs(events.block_steps).astype(float)
    ratio = steps / np.maximum(events.block_modulus, 1)[:, None]
    gap = np.divide(ratio, share * max_rate[None, :] * quantisation_factor(steps), out=np.zeros_like(ratio),
                    where=steps > 0)
    return gap.max(axis=1, initial=0.0)


def compress(events: Events, motors: tuple[str, ...], tick_hz: int, run_gap_ticks: int, block_gap_ticks: int,
             window: TimingWindow = TimingWindow(), final_tool: bool = False, max_rate: np.ndarray | None = None,
             origin_fx: int = 0, block_extra_ticks: np.ndarray | None = None,
             prior_ticks: list[np.ndarray] | None = None) -> Compressed:
    """`run_gap_ticks`: how close the player can make an event that starts a new run; `block_gap_ticks`:
    one that starts a block (both include reading the table; plain events inside a run are cheaper).
    Runs go on across block starts; they are fitted greedily (codegen/tables/runfit.py). `max_rate` (steps/s per
    motor): pushed events catch up within it. `origin_fx` (1/256 tick): where
    the player's clock stands before the first event (the event before, in the window before); every tick
    here counts from the player's tick 0. `block_extra_ticks`: per block, what its first event needs more than
    `block_gap_ticks` (the runtime records the player reads before it: codegen/tables/runtime.py). With `max_rate`,
    the windows also keep every motor's 8 steps within it (codegen/tables/rate_windows.py), those that begin at
    `prior_ticks` too (per motor, its last steps before the first event)."""
    rate_gap = None if max_rate is None else rate_gaps(events, max_rate) * tick_hz
    base = origin_fx >> FRAC_BITS
    fit = (origin_fx - FRAC_ONE * base, base, MAX_COUNT, MAX_ADD, MAX_INTERVAL)
    made = (events, tick_hz, run_gap_ticks, block_gap_ticks, window, rate_gap, origin_fx, block_extra_ticks)
    lib = library("runfit")
    if lib is None:
        needed, ideal, win, lo, hi = numpy_windows(*made)
    else:
        needed, ideal, win, lo, hi = _native_windows(lib, *made)
    if max_rate is not None:
        lo, hi = rate_windows(events, ideal, win, lo, hi, max_rate, tick_hz, base, prior_ticks)
    if lib is None:
        n, interval, add, tick = fit_runs(lo, hi, needed, *fit)
    else:
        n, interval, add, tick = fit_runs_native(lib, lo, hi, needed, *fit)  # hi is ours to overwrite
    schedule = Schedule(
        motors=motors,
        tick_hz=tick_hz,
        block_dirs=np.where(events.block_steps < 0, -1, 1).astype(np.int8),
        block_steps=np.abs(events.block_steps).astype(np.int64),
        block_modulus=events.block_modulus.astype(np.int64),
        block_init=events.block_init.astype(np.int64),
        block_tool=events.block_tool.astype(bool),
        block_events=np.diff(events.block_first).astype(np.int64),
        block_segment=events.block_segment.astype(np.int64),
        run_interval=interval,
        run_add=add,
        run_count=n,
        final_tool=final_tool,
    )
    return Compressed(schedule, ideal, tick, win)


def numpy_windows(events: Events, tick_hz: int, run_gap_ticks: int, block_gap_ticks: int, window: TimingWindow,
                  rate_gap: np.ndarray | None, origin_fx: int, block_extra: np.ndarray | None = None):
    """Every event's fewest ticks after the one before (`needed`), its ideal tick after the push, its timing
    window (ticks), and that window as positions (1/256 tick) counted from tick `origin_fx >> 8` (small
    numbers for the search): lo, hi. `rate_gap`: per block, the gap (ticks) pushed events catch up with at most.
    The reference for the C version (codegen/native/runfit.c, `timing_windows`)."""
    needed = np.full(len(events.time), run_gap_ticks, dtype=np.int64)
    needed[events.block_first[:-1]] = block_gap_ticks + (0 if block_extra is None else block_extra)
    planned = events.time * tick_hz
    origin = origin_fx / FRAC_ONE
    push = 1.1 * needed + 2.0
    if rate_gap is not None:  # a pushed event's successors: never closer than the motors allow, or the plan
        push = np.maximum(push, np.minimum(np.repeat(rate_gap, np.diff(events.block_first)),
                                           np.diff(planned, prepend=origin)))
    ideal = spread(planned, push, origin)
    gaps = np.diff(ideal, prepend=origin)
    win = np.clip(window.share * gaps, window.min_ticks, window.max_us * 1e-6 * tick_hz)
    base = origin_fx >> FRAC_BITS
    lo = FRAC_ONE * np.ceil(ideal - win - base).astype(np.int64)
    hi = FRAC_ONE * np.floor(ideal + win - base).astype(np.int64) + FRAC_ONE - 1
    return needed, ideal, win, lo, hi


def _native_windows(lib, events: Events, tick_hz: int, run_gap_ticks: int, block_gap_ticks: int,
                    window: TimingWindow, rate_gap: np.ndarray | None, origin_fx: int,
                    block_extra: np.ndarray | None = None):
    """`numpy_windows` in C, in one pass."""
    n = len(events.time)
    needed, lo, hi = (np.empty(n, dtype=np.int64) for _ in range(3))
    ideal, win = np.empty(n), np.empty(n)
    block_first, = contiguous(np.int64, events.block_first)
    time, = contiguous(np.float64, events.time)
    rate_gap = None if rate_gap is None else contiguous(np.float64, rate_gap)[0]
    block_extra = None if block_extra is None else contiguous(np.int64, block_extra)[0]
    f64, i64 = ctypes.c_double, ctypes.c_int64
    lib.timing_windows(i64(len(block_first) - 1), *map(pointer, (block_first, time, rate_gap, block_extra)),
                       f64(tick_hz),
                       i64(run_gap_ticks), i64(block_gap_ticks), f64(origin_fx / FRAC_ONE),
                       i64(origin_fx >> FRAC_BITS), f64(window.share), f64(window.min_ticks),
                       f64(window.max_us * 1e-6 * tick_hz), *map(pointer, (needed, ideal, win, lo, hi)))
    return needed, ideal, win, lo, hi

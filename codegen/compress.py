"""Compression: ideal event times -> rate runs `(interval, add, count)` within a stated timing window.

Every emitted event stays within `window(k)` of its ideal time, where the window is a share of the ideal gap
to the previous event (so motor rates keep their accuracy at any speed), capped by an absolute bound. Events
are never closer than the player's minimum gap: ideal times are first pushed apart where needed (exactly, as a
running maximum), and the push is counted in the timing error the checks report. A pushed event's successors
catch up no faster than every motor's rate allows (a block start can cost the player more than the gap the
plan leaves before it; catching up at the player's own pace would overspeed a motor that runs near its limit).

Runs never straddle a block start or a change between accelerating, cruising and decelerating. Their length
comes from the local third difference of the ideal times (the error of a quadratic fit), from the rounding of
`add` and `interval` to 1/256 tick, and from the count limit; runs that still miss the window are halved and
fitted again. The fit itself is exact integer bookkeeping: each run's end lands within n/2 units of 1/256 tick
of its ideal end, so errors never accumulate from run to run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codegen.planner import quantisation_factor
from codegen.runfit import fit_runs
from codegen.schedule import FRAC_BITS, FRAC_ONE, MAX_ADD, MAX_COUNT, MAX_INTERVAL, Schedule
from codegen.stepgen import Events


RATE_SHARE = 0.99  # of a motor's rate that catching up may use (the planner keeps 2 % headroom)


@dataclass(frozen=True)
class TimingWindow:
    share: float = 0.05  # of the ideal gap to the previous event
    max_us: float = 20.0
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


def run_limits(ticks: np.ndarray, window: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """Longest run that may start at each event, from the local smoothness of the ideal times."""
    second, third = np.zeros_like(ticks), np.zeros_like(ticks)
    if len(ticks) > 3:
        second[2:] = np.abs(np.diff(ticks, 2))
        third[3:] = np.abs(np.diff(ticks, 3))
    # Use the larger of neighbouring differences: the quadratic must hold across the run.
    second = np.maximum(second, np.concatenate([second[1:], [0.0]]))
    third = np.maximum(third, np.concatenate([third[1:], [0.0]]))
    with np.errstate(divide="ignore"):
        cubic = np.cbrt(24.0 * window / third)
    rounding_add = np.where(phase == 1, np.inf, np.sqrt(2.0 * FRAC_ONE * window))
    rounding_interval = FRAC_ONE * window
    limit = np.minimum.reduce([cubic, rounding_add, rounding_interval, np.full_like(ticks, MAX_COUNT)])
    limit = np.where(second * FRAC_ONE > MAX_ADD, 1.0, limit)  # `add` cannot bend that fast: one event a run
    return np.maximum(limit, 1.0).astype(np.int64)


def segment_runs(breaks: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """Run start indices: every break starts a run; in between, each event uses up 1/limit of a run, so runs
    are as long as the local limit allows (a run that still misses the window is halved later)."""
    used = np.cumsum(1.0 / limit)
    stretch = np.maximum.accumulate(np.where(breaks, np.arange(len(breaks)), 0))
    base = (used - 1.0 / limit)[stretch]  # what the stretch's predecessors used
    run = np.floor(used - base - 1e-9)
    starts = breaks.copy()
    starts[1:] |= run[1:] != run[:-1]
    return np.flatnonzero(starts)


def fit(starts: np.ndarray, ticks_fx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Integer (interval, add) per run so that each run ends within n/2 units of its ideal end."""
    total = len(ticks_fx)
    ends = np.concatenate([starts[1:], [total]])
    n = ends - starts
    before = np.concatenate([[0.0], ticks_fx])  # before[i] = ideal time of event i-1 (0: timer start)
    y0 = before[starts]
    dn = ticks_fx[ends - 1] - y0
    m = np.maximum(n // 2, 1)
    dm = ticks_fx[starts + m - 1] - y0
    with np.errstate(divide="ignore", invalid="ignore"):
        add = np.where(n >= 2, 2.0 * (dn - n * dm / m) / (n * np.maximum(n - m, 1)), 0.0)
    add = np.clip(np.round(add), -MAX_ADD, MAX_ADD).astype(np.int64)
    tri = n * (n - 1) // 2
    target = (dn - add * tri).tolist()
    counts = n.tolist()
    intervals = [0] * len(counts)
    carry = 0.0  # emitted minus ideal time at the end of the previous run (1/256 tick)
    for r, (z, c) in enumerate(zip(target, counts)):
        z -= carry
        step = round(z / c)
        intervals[r] = step
        carry = step * c - z
    return np.asarray(intervals, dtype=np.int64), add, n


def emitted(starts: np.ndarray, interval: np.ndarray, add: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Event times in 1/256 tick exactly as the player computes them."""
    span = interval * n + add * (n * (n - 1) // 2)
    origin = np.concatenate([[0], np.cumsum(span)[:-1]])
    run = np.repeat(np.arange(len(n)), n)
    k = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + 1
    return origin[run] + k * interval[run] + add[run] * (k * (k - 1) // 2)


def _fit_within(starts: np.ndarray, ideal: np.ndarray, window: np.ndarray, needed: np.ndarray):
    """Fit the runs, halve those that miss the window or the player's gaps, until none does."""
    if len(ideal) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return starts, empty, empty, empty, empty
    for _ in range(64):
        interval, add, n = fit(starts, ideal * FRAC_ONE)
        out = emitted(starts, interval, add, n) >> 8
        bad = (np.abs(out - ideal) > window) | (np.diff(np.concatenate([[0], out])) < needed)
        bad_runs = np.unique(np.searchsorted(starts, np.flatnonzero(bad), side="right") - 1)
        bad_runs = bad_runs[n[bad_runs] > 1]
        if len(bad_runs) == 0:
            return starts, interval, add, n, out
        starts = np.sort(np.concatenate([starts, starts[bad_runs] + n[bad_runs] // 2]))
    raise RuntimeError("rate runs did not converge to the timing window")


def rate_gaps(events: Events, max_rate: np.ndarray, share: float = RATE_SHARE) -> np.ndarray:
    """Per block, the shortest gap (s) between its events that keeps every motor within `share` of its rate
    over any 8 of its steps (a slave steps on at most `steps / modulus` of the events, Bresenham-spread)."""
    steps = np.abs(events.block_steps).astype(float)
    ratio = steps / np.maximum(events.block_modulus, 1)[:, None]
    gap = np.divide(ratio, share * max_rate[None, :] * quantisation_factor(steps), out=np.zeros_like(ratio),
                    where=steps > 0)
    return gap.max(axis=1, initial=0.0)


def compress(events: Events, motors: tuple[str, ...], tick_hz: int, run_gap_ticks: int, block_gap_ticks: int,
             window: TimingWindow = TimingWindow(), final_tool: bool = False,
             cross_blocks: bool = False, max_rate: np.ndarray | None = None, origin_fx: int = 0) -> Compressed:
    """`run_gap_ticks`: how close the player can make an event that starts a new run; `block_gap_ticks`:
    one that starts a block (both include reading the table; plain events inside a run are cheaper).
    `cross_blocks`: the player keeps a run going across block starts (the compact tables): runs are fitted
    greedily (codegen/runfit.py); otherwise every block has runs of its own and its first event is a run by
    itself. `max_rate` (steps/s per motor): pushed events catch up within it. `origin_fx` (1/256 tick): where
    the player's clock stands before the first event (the event before, in the window before); every tick
    here counts from the player's tick 0."""
    needed = np.full(len(events.time), run_gap_ticks, dtype=np.int64)
    needed[events.block_first[:-1]] = block_gap_ticks
    planned = events.time * tick_hz
    origin = origin_fx / FRAC_ONE
    push = 1.1 * needed + 2.0
    if max_rate is not None:  # a pushed event's successors: never closer than the motors allow, or the plan
        rate_gap = np.repeat(rate_gaps(events, max_rate) * tick_hz, np.diff(events.block_first))
        push = np.maximum(push, np.minimum(rate_gap, np.diff(planned, prepend=origin)))
    ideal = spread(planned, push, origin)
    gaps = np.diff(ideal, prepend=origin)
    win = np.clip(window.share * gaps, window.min_ticks, window.max_us * 1e-6 * tick_hz)
    if cross_blocks:
        n, interval, add, out = _greedy_runs(ideal, win, needed, origin_fx)
        starts = np.cumsum(n) - n
    else:
        starts, interval, add, n, out = _block_runs(events, ideal - origin, win, needed)
        out += origin_fx >> 8
    block_runs = np.searchsorted(starts, events.block_first)
    schedule = Schedule(
        motors=motors,
        tick_hz=tick_hz,
        block_dirs=np.where(events.block_steps < 0, -1, 1).astype(np.int8),
        block_steps=np.abs(events.block_steps).astype(np.int64),
        block_modulus=events.block_modulus.astype(np.int64),
        block_init=events.block_init.astype(np.int64),
        block_tool=events.block_tool.astype(bool),
        block_runs=block_runs.astype(np.int64),
        block_segment=events.block_segment.astype(np.int64),
        run_interval=interval,
        run_add=add,
        run_count=n,
        final_tool=final_tool,
        block_events=np.diff(events.block_first).astype(np.int64) if cross_blocks else None,
    )
    return Compressed(schedule, ideal, out, win)


def _greedy_runs(ideal: np.ndarray, win: np.ndarray, needed: np.ndarray, origin_fx: int):
    """(count, interval, add) of every run and every event's tick, each event within its window."""
    base = origin_fx >> FRAC_BITS  # positions count from this tick: small numbers for the search
    lo = FRAC_ONE * np.ceil(ideal - win - base).astype(np.int64)
    hi = FRAC_ONE * np.floor(ideal + win - base).astype(np.int64) + FRAC_ONE - 1
    n, interval, add, tick = fit_runs(lo, hi, needed, origin_fx - FRAC_ONE * base, 0, MAX_COUNT, MAX_ADD,
                                      MAX_INTERVAL)
    return n, interval, add, tick + base


def _block_runs(events: Events, ideal: np.ndarray, win: np.ndarray, needed: np.ndarray):
    """Runs of their own for every block (the older table format): estimated lengths, halved until each fits."""
    total = len(ideal)
    breaks = np.zeros(total, dtype=bool)
    first = events.block_first[:-1]
    breaks[first] = True
    breaks[np.minimum(first + 1, total - 1)] = True  # a block's first event is a run of its own
    breaks[1:] |= events.phase[1:] != events.phase[:-1]
    starts = segment_runs(breaks, run_limits(ideal, win, events.phase))
    return _fit_within(starts, ideal, win, needed)

"""Compression: ideal event times -> rate runs `(interval, add, count)` within a stated timing window.

Every emitted event stays within `window(k)` of its ideal time, where the window is a share of the ideal gap
to the previous event (so motor rates keep their accuracy at any speed), capped by an absolute bound. Events
are never closer than the player's minimum gap: ideal times are first pushed apart where needed (exactly, as a
running maximum), and the push is counted in the timing error the checks report. A pushed event's successors
catch up no faster than every motor's rate allows (a block start can cost the player more than the gap the
plan leaves before it; catching up at the player's own pace would overspeed a motor that runs near its limit).

Runs go on across block starts and motion phases: each is the longest that keeps every one of its events in
its window (codegen/runfit.py, exact integer search), so errors never accumulate from run to run.
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
             origin_fx: int = 0) -> Compressed:
    """`run_gap_ticks`: how close the player can make an event that starts a new run; `block_gap_ticks`:
    one that starts a block (both include reading the table; plain events inside a run are cheaper).
    Runs go on across block starts; they are fitted greedily (codegen/runfit.py). `max_rate` (steps/s per
    motor): pushed events catch up within it. `origin_fx` (1/256 tick): where
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
    n, interval, add, out = _greedy_runs(ideal, win, needed, origin_fx)
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
    return Compressed(schedule, ideal, out, win)


def _greedy_runs(ideal: np.ndarray, win: np.ndarray, needed: np.ndarray, origin_fx: int):
    """(count, interval, add) of every run and every event's tick, each event within its window."""
    base = origin_fx >> FRAC_BITS  # positions count from this tick: small numbers for the search
    lo = FRAC_ONE * np.ceil(ideal - win - base).astype(np.int64)
    hi = FRAC_ONE * np.floor(ideal + win - base).astype(np.int64) + FRAC_ONE - 1
    n, interval, add, tick = fit_runs(lo, hi, needed, origin_fx - FRAC_ONE * base, 0, MAX_COUNT, MAX_ADD,
                                      MAX_INTERVAL)
    return n, interval, add, tick + base

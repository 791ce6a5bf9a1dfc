"""Feed override above 100 %: how far every stretch of a window lets the feed factor go, as ceiling records
(codegen/tables/schedule.py run_ceiling) that the player's factor stays under (codegen/tables/hold.py).

At a steady factor f every motor's velocity scales with f and its acceleration with f^2, so a stretch allows
    f <= max_rate / v8            v8: the motor's rate over any 8 of its steps around the event (the twin's)
    f <= sqrt((1 - RAMP_SHARE) x max_accel x W / dv)
                                  dv: the change of its velocity between consecutive W = 20 ms windows of the
                                  plan's clock (the checks' measure; a corner's jump counts in full)
leaving RAMP_SHARE of the acceleration for the factor's own change. The first and last 2 W of a window keep
F_ONE (their neighbours are not known here), so a window hands the next a ceiling of F_ONE.

The ceiling must come down before the headroom ends: the player's factor falls at its ramp (ramp_k, on the real
clock, which runs faster than the plan's above 100 %; not while the plan brakes where the ramp is gated, nor in a
long wait), so every event's ceiling is the lowest, over the events after it, of their allowance plus the fall
the ramp makes in between. The records then take the override's own steps (the factor cannot be asked for
anything in between): a rise only where the higher step lasts long enough for the ramp to climb one, and every
run of falling steps as one fall to the lowest of them at the first (the factor falls at its ramp whatever it
falls to)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from codegen.motion.planner import ACCEL_WINDOW_S, RATE_WINDOW
from codegen.tables.hold import F_ONE, LONG, RAMP_SHARE, HoldPlan, event_deltas, override_target
from codegen.tables.schedule import FRAC_ONE, Schedule, split_runs
from codegen.tables.twin import Pulses

GRID = 4  # grid points per window W: the checks' windows may start anywhere
EDGE_WINDOWS = 2  # windows at each end of a table window that keep F_ONE


def allowance(schedule: Schedule, delta: np.ndarray, pulses: Pulses, before: np.ndarray, max_rate: np.ndarray,
              max_accel: np.ndarray) -> np.ndarray:
    """(E,) the highest factor (1.0 = 100 %) every motor's limits allow at each event, on a steady factor: the
    events' tick deltas (event_deltas), the window's twin `pulses` (motor positions `before` its first event),
    `max_rate` steps/s and `max_accel` steps/s^2 per motor."""
    tick_hz = schedule.tick_hz
    block = np.repeat(np.arange(schedule.n_blocks), schedule.block_events)
    share = schedule.block_steps / schedule.block_modulus[:, None]  # (B, M) steps per event
    t = np.cumsum(delta) / (FRAC_ONE * tick_hz)  # s from the window's start to each event
    allow = 1.0 / _rate_ratio(pulses, before, max_rate, tick_hz)
    h = ACCEL_WINDOW_S / GRID
    span = EDGE_WINDOWS * ACCEL_WINDOW_S
    if not len(t) or t[-1] <= 2 * span:
        return np.ones(len(delta))
    grid = np.arange(0.0, t[-1] + h, h)
    worst = np.zeros(len(grid) - 2 * GRID)  # the highest dv / (max_accel W) of the pairs of windows from each point
    for m in range(share.shape[1]):
        position = np.cumsum((share[:, m] * schedule.block_dirs[:, m])[block])
        p = np.interp(grid, t, position)
        v = (p[GRID:] - p[:-GRID]) / ACCEL_WINDOW_S
        dv = np.abs(v[GRID:] - v[:-GRID])
        np.maximum(worst, dv / (max_accel[m] * ACCEL_WINDOW_S), out=worst)
    accel_allow = np.sqrt((1.0 - RAMP_SHARE) / np.maximum(worst, 1e-12))
    # An event at t is inside the pairs starting from t - 2 W to t: the lowest of those.
    padded = np.concatenate([np.full(2 * GRID, 1.0), accel_allow, np.full(2 * GRID, 1.0)])
    lowest = padded[2 * GRID:].copy()
    for k in range(1, 2 * GRID + 1):
        np.minimum(lowest, padded[2 * GRID - k:len(padded) - k], out=lowest)
    np.minimum(allow, lowest[np.minimum((t / h).astype(np.int64), len(lowest) - 1)], out=allow)
    allow[(t < span) | (t > t[-1] - span)] = 1.0
    return allow


def _rate_ratio(pulses: Pulses, before: np.ndarray, max_rate: np.ndarray, tick_hz: int) -> np.ndarray:
    """(E,) the highest rate over 8 steps (the checks' measure) / max_rate of any motor's steps around each event:
    of every 8 consecutive steps of a motor whose first is at or before the event and whose last at or after. The
    8 steps may begin in the window before or end in the one after: those are counted as if their steps there came
    at the window's first event, or at its last (they come before it, or after it: no faster than that)."""
    position = pulses.event_position
    worst = np.zeros(len(position))
    if not len(position):
        return np.maximum(worst, 1e-12)
    ends = (np.full(RATE_WINDOW, pulses.event_tick[0]), np.full(RATE_WINDOW, pulses.event_tick[-1]))
    for m in range(position.shape[1]):
        steps = np.diff(position[:, m], prepend=before[m]) != 0  # at most one step per event
        tick = np.concatenate([ends[0], pulses.event_tick[steps], ends[1]])
        ratio = RATE_WINDOW * tick_hz / np.maximum(tick[RATE_WINDOW:] - tick[:-RATE_WINDOW], 1) / max_rate[m]
        base = np.concatenate([ratio[:1], ratio])  # base[j + 1]: the 8 steps from the motor's step j - 8 + 1 on
        highest = base[:len(ratio) - RATE_WINDOW + 1].copy()  # highest[j + 1]: the 8 steps around its step j
        for k in range(1, RATE_WINDOW + 1):
            np.maximum(highest, base[k:k + len(highest)], out=highest)
        np.maximum(worst, highest[np.cumsum(steps)], out=worst)  # [j + 1]: j the last step so far
    return np.maximum(worst, 1e-12)


def ceilings(schedule: Schedule, delta: np.ndarray, add: np.ndarray, plan: HoldPlan,
             allow: np.ndarray) -> np.ndarray:
    """(E,) the ceiling (F) in force at each event: the override's steps under the allowance, lowered early
    enough for the ramp (`delta`, `add`: event_deltas)."""
    top = plan.top
    levels = np.array(sorted({F_ONE} | {override_target(s) for s in range(11, plan.max_step + 1)}))
    allowed = np.clip(np.floor(allow * F_ONE) - 1, F_ONE, top)  # one F of margin for the interrupt's rounding
    # The fall the ramp surely makes over each event: plan time x F_ONE / top (the real clock at the top
    # factor), at most one step's worth; none in a long wait or (gated) while the plan brakes.
    seconds = delta / (FRAC_ONE * schedule.tick_hz)
    fall = np.minimum(plan.ramp_per_second(schedule.tick_hz) * seconds * F_ONE / top, levels[1] - levels[0])
    fall[delta >= LONG] = 0.0
    if plan.gated:
        fall[add > 0] = 0.0
    before = np.concatenate([[0.0], np.cumsum(fall)])  # the fall from the window's start to each event
    reach = np.append(allowed, F_ONE) + before  # each event's allowance (the window's end: F_ONE) ...
    envelope = np.minimum.accumulate(reach[::-1])[::-1] - before  # ... as seen from the events before it
    envelope = np.minimum(envelope[:-1], envelope[1:])  # the ramp moves after the event's delta: one late
    return levels[np.searchsorted(levels, envelope + 1e-9, side="right") - 1]


def records(schedule: Schedule, delta: np.ndarray, plan: HoldPlan, ceiling: np.ndarray) \
        -> tuple[np.ndarray, np.ndarray]:
    """The ceiling records for per-event ceilings: (events, F). Rises that the ramp could not climb a step in
    are left out, and each run of falls becomes one, at its first, to its lowest."""
    change = np.flatnonzero(np.diff(np.concatenate([[F_ONE], ceiling])))
    if not len(change):
        return change, change
    start = np.concatenate([[0.0], np.cumsum(delta / (FRAC_ONE * schedule.tick_hz))])
    climb = (override_target(11) - F_ONE) / plan.ramp_per_second(schedule.tick_hz)  # s of plan time, at least
    at = np.append(change, len(ceiling))
    value = [F_ONE] + [int(ceiling[e]) for e in change]
    length = [0.0] + [start[b] - start[a] for a, b in zip(at[:-1], at[1:])]
    for i in range(1, len(value) - 1):  # a short plateau: no higher than its higher neighbour
        if value[i] > max(value[i - 1], value[i + 1]) and length[i] < climb:
            value[i] = max(value[i - 1], value[i + 1])
    events, factors, i = [], [], 1
    current = F_ONE
    while i < len(value):
        j = i
        if value[i] < current:
            while j + 1 < len(value) and value[j + 1] < value[j]:
                j += 1
        if value[j] != current:
            events.append(int(at[i - 1]))
            factors.append(value[j])
            current = value[j]
        i = j + 1
    return np.array(events, dtype=np.int64), np.array(factors, dtype=np.int64)


def with_ceilings(schedule: Schedule, plan: HoldPlan, pulses: Pulses, before: np.ndarray, max_rate: np.ndarray,
                  max_accel: np.ndarray) -> Schedule:
    """The window's schedule with its ceiling records (none where the override stops at 100 %); its twin's
    `pulses` and the motors' positions `before` it (steps)."""
    if plan.top <= F_ONE or not schedule.n_runs:
        return schedule
    delta, add = event_deltas(schedule)
    ceiling = ceilings(schedule, delta, add, plan, allowance(schedule, delta, pulses, before, max_rate, max_accel))
    events, factors = records(schedule, delta, plan, ceiling)
    if not len(events):
        return schedule
    out, run = split_runs(schedule, events)
    ceiling_of_run = np.full(out.n_runs, -1, dtype=np.int64)
    ceiling_of_run[run] = factors
    return replace(out, run_ceiling=ceiling_of_run)

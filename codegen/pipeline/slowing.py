"""Where and how much a window's plan is slowed when it is played again (codegen/pipeline/windows.py): the
segments under a stretch where the twin's pulses break a motor's rate or acceleration, and those whose table
records the streaming link cannot carry in time; and whether such a stretch reaches back into the window
before.
"""

from __future__ import annotations

import numpy as np

from codegen.link.ring import Shortfall
from codegen.motion.planner import ACCEL_WINDOW_S, RATE_WINDOW
from codegen.tables.twin import Pulses

RETRY_SHARE = 0.95  # of the rate and acceleration those segments (and their neighbours) then aim at


def link_slow_down(plan, shortfalls: list[Shortfall], record_segment: np.ndarray, sizes: np.ndarray,
                    rate: float) -> tuple[np.ndarray, np.ndarray]:
    """From the first stretch that drains the ring on, the segments whose records are denser than the link
    carries, each slowed to the link's bytes a second (the ring absorbs no burst there any more: one round
    suffices where slowing the stretches alone would move each shortfall on); and the segments of each
    stretch, in acceleration, by the time it lacks: records come densest where a motor speeds up from rest (a
    block and a run at once, then short runs), which a lower top speed leaves as it was."""
    n = len(plan.duration)
    span = slice(shortfalls[0].first, None)
    need = np.bincount(record_segment[span], weights=sizes[span], minlength=n)
    speed, accel = np.ones(n), np.ones(n)
    dense = need * 1.0 > plan.duration * rate * RETRY_SHARE
    speed[dense] = plan.duration[dense] * rate * RETRY_SHARE / need[dense]
    for short in shortfalls:
        seconds = short.end_s - short.begin_s
        share = RETRY_SHARE * seconds / (seconds + short.extra_s) if seconds > 0 else RETRY_SHARE
        stretch = slice(record_segment[short.first], record_segment[short.last] + 1)
        accel[stretch] = np.minimum(accel[stretch], share ** 2)  # from rest, a distance takes 1 / sqrt(accel)
    return speed, accel


def slow_down(plan, event_segment: np.ndarray, pulses: Pulses, hits: list, tick_hz: float,
              reach: float | None = None):
    """The share of their peak speed and acceleration the segments under a stretch over a limit keep
    (None where the checks found nothing); `event_segment`: the window's segment of every event. `reach` (s):
    a shaped window's shapers' spread (None: unshaped). Its pulses at a moment t come from the plan between
    t - reach and t, so the segments there are slowed (those under the events would miss a stretch the shaper
    delays)."""
    if not any(len(rate[0]) or len(accel[0]) for rate, accel in hits):
        return None
    n = len(plan.duration)
    speed, accel = np.ones(n), np.ones(n)

    def under(begin: float, end: float) -> slice:
        first, last = np.searchsorted(plan.t_start, [begin - (reach or 0.0), end], side="right") - 1
        return slice(max(first - 1, 0), last + 2)

    for m, ((rate_end, rate_ratio), (begin, accel_ratio)) in enumerate(hits):
        events = pulses.event[pulses.motor == m]
        for end, ratio in zip(rate_end, rate_ratio):
            first = events[max(end - RATE_WINDOW, 0)]
            if reach is None:
                span = slice(max(event_segment[first] - 1, 0), event_segment[events[end]] + 2)
            else:
                span = under(pulses.event_tick[first] / tick_hz, pulses.event_tick[events[end]] / tick_hz)
            speed[span] = np.minimum(speed[span], RETRY_SHARE / ratio)
        for t, ratio in zip(begin, accel_ratio):
            span = under(t, t + 2 * ACCEL_WINDOW_S)
            speed[span] = np.minimum(speed[span], np.sqrt(RETRY_SHARE / ratio))  # bends: v^2
            accel[span] = np.minimum(accel[span], RETRY_SHARE / ratio)
    return None if np.all(speed == 1.0) and np.all(accel == 1.0) else (speed, accel)


def reaches_back(hits: list, t0: float, pulses: Pulses, tick_hz: float, reach: float | None = None) -> bool:
    """Whether a stretch over a limit begins before the window (at `t0`): its first of 8 steps, or its first
    20 ms, in the window before (for a shaped window, `reach` s earlier: slow_down's). Only then is that window
    played again with this one: a stretch of this window's own is slowed in it alone, so a long program whose
    every window is slowed once takes time in proportion."""
    back = reach or 0.0
    for m, ((rate_end, _), (begin, _)) in enumerate(hits):
        if np.any(rate_end < RATE_WINDOW) or np.any(begin - back < t0):
            return True
        if back and len(rate_end):
            first = pulses.event[pulses.motor == m][rate_end - RATE_WINDOW]
            if np.any(pulses.event_tick[first] / tick_hz - back < t0):
                return True
    return False

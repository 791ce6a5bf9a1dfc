"""Event times along curves, from the curve rather than from its chords (for the compact tables).

A curve becomes straight chords, and on each chord the master motor steps at the rate the chord's direction
gives it: at every vertex that rate jumps, so the event times have a kink there and a rate run (linear in its
interval) must end at almost every vertex. The tool really follows the curve, where the master's rate changes
smoothly. So the events of consecutive blocks that meet without a corner, with the same master motor moving the
same way, are timed on a cubic Hermite interpolant t(u) of the master's position u: through every vertex at its
planned time, with the slope there from the planned speed and the mean of the two chords' master rates (for a
circle, exactly the tangent's). Runs then span many chords. Positions do not change, and the checks measure the
pulses against the limits as before.

A group's outer vertices use their own chord's rate; a block whose outer vertex is a standstill keeps the chord
times (a standstill has no finite slope dt/du).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.planner import Plan
from codegen.segments import Segments
from codegen.stepgen import Events

MIN_SPEED = 1e-9  # mm/s: slower than this a vertex is a standstill


def smooth_curve_times(events: Events, segments: Segments, plan: Plan, kin: Kinematics) -> Events:
    n_blocks = len(events.block_segment)
    if n_blocks < 2:
        return events
    seg = events.block_segment
    spm = kin.limits.steps_per_mm
    x0 = kin.to_motor(segments.start[seg]) * spm
    x1 = kin.to_motor(segments.end[seg]) * spm
    steps = events.block_steps
    master = np.argmax(np.abs(steps), axis=1)
    rows = np.arange(n_blocks)
    u0, u1 = x0[rows, master], x1[rows, master]
    sign = np.sign(steps[rows, master])
    moving = (sign != 0) & (segments.dwell[seg] <= 0)
    v_in, v_out = plan.v_entry[seg], plan.v_exit[seg]
    linked = ((seg[1:] == seg[:-1] + 1) & moving[1:] & moving[:-1] & (master[1:] == master[:-1])
              & (sign[1:] == sign[:-1]) & (events.block_tool[1:] == events.block_tool[:-1])
              & ~plan.corner[seg[1:]] & (v_in[1:] > MIN_SPEED))
    has_prev = np.concatenate([[False], linked])
    has_next = np.concatenate([linked, [False]])
    # Master steps per mm of path along each chord, and dt/du at each block's start and end vertex.
    rate = np.abs(u1 - u0) / np.maximum(plan.length[seg], 1e-300)
    rate_in = np.where(has_prev, 0.5 * (rate + np.roll(rate, 1)), rate)
    rate_out = np.where(has_next, 0.5 * (rate + np.roll(rate, -1)), rate)
    with np.errstate(divide="ignore"):
        slope_in = 1.0 / (v_in * rate_in)
        slope_out = 1.0 / (v_out * rate_out)
    t0 = plan.t_start[seg]
    t1 = t0 + plan.duration[seg]
    span = np.abs(u1 - u0)
    secant = np.divide(t1 - t0, span, out=np.zeros(n_blocks), where=span > 0)
    # Fritsch-Carlson: slopes at most 3 secants keep t(u) increasing.
    left = np.where(has_prev, np.minimum(secant, np.roll(secant, 1)), secant)
    right = np.where(has_next, np.minimum(secant, np.roll(secant, -1)), secant)
    smooth = moving & (has_prev | has_next) & np.isfinite(slope_in) & np.isfinite(slope_out) & (span > 0)
    slope_in, slope_out = np.minimum(slope_in, 3.0 * left), np.minimum(slope_out, 3.0 * right)

    count = np.diff(events.block_first)
    block = np.repeat(rows, count)
    k = np.arange(len(block)) - events.block_first[block] + 1.0
    u = np.round(x0[rows, master])[block] + sign[block] * (k - 0.5)  # where each master step happens
    # Rounding puts a step up to half a step past its chord's end: time it on the neighbouring interval.
    d = sign[block] * (u - u0[block])
    before = (d < 0) & has_prev[block]
    after = (d > span[block]) & has_next[block]
    where = block - before + after
    use = smooth[block] & smooth[where]
    j = where[use]
    h = span[j]
    tau = sign[block[use]] * (u[use] - u0[j]) / h
    h00, h10 = (1 + 2 * tau) * (1 - tau) ** 2, tau * (1 - tau) ** 2
    h01, h11 = tau * tau * (3 - 2 * tau), tau * tau * (tau - 1)
    time = events.time.copy()
    time[use] = h00 * t0[j] + h10 * h * slope_in[j] + h01 * t1[j] + h11 * h * slope_out[j]
    return replace(events, time=time)

"""Event times along curves, from the curve rather than from its chords (for the compact tables).

A curve becomes straight chords, and on each chord the master motor makes a fixed number of steps per mm of
path: at every vertex that number jumps, so the event times have a kink there and a rate run (linear in its
interval) must end at almost every vertex. The tool really follows the curve, where the master's share of the
motion changes smoothly. So on consecutive blocks that meet without a corner, with the same master motor moving
the same way, the path position s at which the master reaches position u is a cubic Hermite s(u): through every
vertex, with the slope ds/du there from the mean of the two chords' master steps per mm (for a circle, exactly
the tangent's). Each event's time is then the plan's own time at that path position (its trapezoids, exactly),
so speeds, accelerations and every vertex time stay the plan's; positions do not change.

Curve timing bends the master's rate inside a chord, so it is kept only where it provably keeps every motor
within its limits; elsewhere a block keeps its chord times:
- velocity: the largest du/ds on the chord, times the block's peak speed, for the master and (through the
  block's Bresenham ratio) every slave, within each motor's rate (with the planner's quantisation factor);
- acceleration: the tangential part (plan acceleration times the largest du/ds) plus the bending part (peak
  speed squared times the largest |d2u/ds2|), for every motor, within its acceleration;
- the jump each slave's velocity makes at a vertex no larger than the one chord timing makes there, or within
  what its acceleration allows over the shorter of the two chords.
A block that keeps its chord times leaves its neighbours' slopes as they are: the master's velocity then jumps
at that vertex by half what chord timing makes it jump. The planner keeps 2 % below every limit; curve timing
may use that headroom (for rates up to 98.5 %, the rest for the slaves' steps where blocks meet; the compressor's
windows shorten no 8 steps below the limit: codegen/tables/rate_windows.py).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.blocks import Events
from codegen.motion.planner import ACCEL_WINDOW_S, Plan, quantisation_factor
from codegen.toolpath.segments import Segments

# Of every motor's rate (the rest: the slaves' uneven steps where blocks meet, which the retimed curve does not see).
RATE_SHARE = 0.985
ACCEL_SHARE = 1.0  # of every motor's acceleration: the planner's headroom (its window average is far below)


@dataclass
class CurveBlocks:
    """Per block: whether it keeps curve timing, whether it is joined to the block before / after, the cubic's
    slopes ds/du at its ends, and its master's exact start (steps), span (steps) and direction."""

    smooth: np.ndarray
    has_prev: np.ndarray
    has_next: np.ndarray
    slope_in: np.ndarray
    slope_out: np.ndarray
    u0: np.ndarray
    span: np.ndarray
    sign: np.ndarray


def curve_blocks(block_segment: np.ndarray, block_steps: np.ndarray, block_tool: np.ndarray, segments: Segments,
                 plan: Plan, kin: Kinematics, max_rate: np.ndarray | None = None) -> CurveBlocks | None:
    """Which blocks are timed on the curve, and their cubics (None: no block is)."""
    n_blocks = len(block_segment)
    if n_blocks < 2:
        return None
    seg = block_segment
    spm = kin.limits.steps_per_mm
    x0 = kin.to_motor(segments.start[seg]) * spm
    x1 = kin.to_motor(segments.end[seg]) * spm
    steps = block_steps
    master = np.argmax(np.abs(steps), axis=1)
    rows = np.arange(n_blocks)
    u0 = x0[rows, master]
    span = np.abs(x1[rows, master] - u0)
    sign = np.sign(steps[rows, master])
    length = plan.length[seg]
    moving = (sign != 0) & (segments.dwell[seg] <= 0) & (span > 0) & (length > 0)
    linked = ((seg[1:] == seg[:-1] + 1) & moving[1:] & moving[:-1] & (master[1:] == master[:-1])
              & (sign[1:] == sign[:-1]) & (block_tool[1:] == block_tool[:-1])
              & ~plan.corner[seg[1:]])
    rate = np.divide(span, length, out=np.ones(n_blocks), where=moving)  # master steps per mm of path
    ratio = np.abs(steps) / np.maximum(np.abs(steps[rows, master]), 1)[:, None]  # Bresenham: slave per master
    # A vertex may join its two chords only where the slaves' velocity jump stays acceptable.
    linked &= _jumps_allowed(linked, rate, ratio, plan, seg, kin)
    has_prev = np.concatenate([[False], linked])
    has_next = np.concatenate([linked, [False]])
    secant = 1.0 / rate  # ds/du of the chord
    mean = np.divide(2.0, rate[:-1] + rate[1:])  # ds/du at each vertex between two blocks
    slope_in = np.where(has_prev, np.concatenate([[1.0], mean]), secant)
    slope_out = np.where(has_next, np.concatenate([mean, [1.0]]), secant)
    smooth = moving & (has_prev | has_next)
    rate_limit = kin.limits.max_rate if max_rate is None else max_rate
    smooth &= _within_limits(slope_in, slope_out, secant, span, ratio, steps, plan, seg, kin, rate_limit)
    if not smooth.any():
        return None
    return CurveBlocks(smooth, has_prev, has_next, slope_in, slope_out, u0, span, sign.astype(float))


def smooth_curve_times(events: Events, segments: Segments, plan: Plan, kin: Kinematics) -> Events:
    """The events with their times on the curve where curve timing applies (numpy; `generate(curves=True)`
    does the same, in C where it can)."""
    curve = curve_blocks(events.block_segment, events.block_steps, events.block_tool, segments, plan, kin)
    return events if curve is None else replace(events, time=retime(events, curve, plan))


def retime(events: Events, curve: CurveBlocks, plan: Plan) -> np.ndarray:
    """Every event's time, on the curve where its block keeps curve timing."""
    seg, sign, u0, span = events.block_segment, curve.sign, curve.u0, curve.span
    length = plan.length[seg]
    count = np.diff(events.block_first)
    block = np.repeat(np.arange(len(seg)), count)
    k = np.arange(len(block)) - events.block_first[block] + 1.0
    u = np.round(u0)[block] + sign[block] * (k - 0.5)  # where each master step happens
    # Rounding puts a step up to half a step past its chord's end: time it on the neighbouring piece.
    d = sign[block] * (u - u0[block])
    before = (d < 0) & curve.has_prev[block]
    after = (d > span[block]) & curve.has_next[block]
    where = block - before + after
    use = curve.smooth[block] & curve.smooth[where]
    j = where[use]
    tau = np.clip(sign[block[use]] * (u[use] - u0[j]) / span[j], 0.0, 1.0)
    s = _hermite(tau, span[j], curve.slope_in[j], curve.slope_out[j], length[j])
    time = events.time.copy()
    time[use] = plan.time_at(seg[j], np.clip(s, 0.0, length[j]))
    return time


def _hermite(tau, h, m0, m1, length):
    """s at tau of the cubic through (0, 0) and (h, length) with slopes m0, m1 (ds/du)."""
    h10, h01, h11 = tau * (1 - tau) ** 2, tau * tau * (3 - 2 * tau), tau * tau * (tau - 1)
    return h10 * h * m0 + h01 * length + h11 * h * m1


def _slope_extremes(m0, m1, secant, h):
    """Smallest ds/du on each piece, and the largest |d2s/du2| (linear in tau: at an end)."""
    # ds/du = m0 + b tau + c tau^2 on tau in [0, 1]
    b = 6.0 * secant - 4.0 * m0 - 2.0 * m1
    c = 3.0 * (m0 + m1) - 6.0 * secant
    least = np.minimum(m0, m1)
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = np.where(c > 0, -b / (2.0 * c), -1.0)
    inside = (vertex > 0) & (vertex < 1)
    least = np.where(inside, np.minimum(least, m0 + b * vertex + c * vertex * vertex), least)
    bend = np.divide(np.maximum(np.abs(b), np.abs(b + 2.0 * c)), h, out=np.zeros_like(h), where=h > 0)
    return least, bend


def _path_accel(plan: Plan, seg) -> np.ndarray:
    """The path's acceleration on each block: its segment's, unless the segment only cruises."""
    changing = plan.s_acc[seg] + plan.s_cruise[seg] < plan.length[seg] * (1 - 1e-12)
    return np.where((plan.s_acc[seg] > 0) | changing, plan.accel[seg], 0.0)


def _within_limits(slope_in, slope_out, secant, span, ratio, steps, plan: Plan, seg, kin: Kinematics,
                   rate_limit: np.ndarray):
    """Blocks whose curve timing keeps every motor's velocity and acceleration within its limits."""
    least, bend = _slope_extremes(slope_in, slope_out, secant, span)
    ok = least > 0
    least = np.where(ok, least, 1.0)
    du_ds = 1.0 / least  # the master's largest steps per mm of path on the piece
    d2u = bend / least ** 3  # |d2u/ds2| <= |d2s/du2| / (ds/du)^3
    v = plan.v_peak[seg]
    a = _path_accel(plan, seg)
    max_rate = rate_limit[None, :] * quantisation_factor(steps) * RATE_SHARE
    max_accel = (kin.limits.max_accel * kin.limits.steps_per_mm)[None, :] * ACCEL_SHARE
    velocity = (v * du_ds)[:, None] * ratio
    accel = (a * du_ds + v * v * d2u)[:, None] * ratio
    return ok & np.all(velocity <= max_rate, axis=1) & np.all(accel <= max_accel, axis=1)


def _jumps_allowed(linked, rate, ratio, plan: Plan, seg, kin: Kinematics):
    """At each vertex: a slave's velocity jumps by v * du/ds * (change of its Bresenham ratio) on the curve,
    by v * (change of its steps per mm) on the chords. Joining is allowed where the curve's jump is no larger
    than the chords', or within what the motor's acceleration gives over the shorter chord, or, where that is
    longer than an acceleration window (the jump then falls whole between two windows), within one window's
    acceleration beside the slave's along the path there."""
    v = plan.v_entry[seg[1:]]
    mean_rate = 0.5 * (rate[:-1] + rate[1:])
    curve = (v * mean_rate)[:, None] * np.abs(ratio[1:] - ratio[:-1])
    chord = v[:, None] * np.abs(ratio[1:] * rate[1:, None] - ratio[:-1] * rate[:-1, None])
    max_accel = (kin.limits.max_accel * kin.limits.steps_per_mm)[None, :] * ACCEL_SHARE
    shorter = np.minimum(plan.duration[seg[:-1]], plan.duration[seg[1:]])
    spread = curve <= max_accel * np.minimum(shorter, ACCEL_WINDOW_S)[:, None]
    slave_accel = (_path_accel(plan, seg) * rate)[:, None] * ratio  # steps/s^2
    beside = curve + np.maximum(slave_accel[:-1], slave_accel[1:]) * ACCEL_WINDOW_S <= max_accel * ACCEL_WINDOW_S
    return np.all((curve <= chord * (1 + 1e-9)) | (spread & beside), axis=1) | ~linked

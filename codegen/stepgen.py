"""Step generation: the ideal time of every master event of every block.

Each moving segment is one block: its motors move by the differences of their positions rounded once at the
segment's ends. The master (the motor with most steps) steps when its ideal position along the segment
crosses a half-step point, as Klipper does; the other motors follow by Bresenham on the MCU. A dwell becomes a
block of step-less events that carry its time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.checks import chord_distance
from codegen.planner import Plan
from codegen.schedule import MAX_MODULUS
from codegen.segments import Segments
from codegen.twin import bresenham


@dataclass
class Events:
    """Blocks and the ideal time (s) of each of their events, in program order."""

    block_segment: np.ndarray  # (B,) segment index
    block_steps: np.ndarray  # (B, M) signed steps
    block_modulus: np.ndarray  # (B,)
    block_init: np.ndarray  # (B, M) Bresenham accumulator starts
    block_tool: np.ndarray  # (B,) bool
    block_first: np.ndarray  # (B + 1,) index of each block's first event
    time: np.ndarray  # (E,) s
    phase: np.ndarray  # (E,) 0 accelerating, 1 cruising, 2 decelerating, 3 dwell


def split_long(segments: Segments, kin: Kinematics) -> Segments:
    """Cut segments whose master motor would make more steps than a block holds into equal parts."""
    steps = np.abs(kin.to_steps(segments.end) - kin.to_steps(segments.start)).max(axis=1, initial=0)
    parts = np.maximum(1, -(-steps // (MAX_MODULUS - 1)))
    if np.all(parts == 1):
        return segments
    owner = np.repeat(np.arange(len(parts)), parts)
    rank = np.arange(len(owner)) - np.repeat(np.cumsum(parts) - parts, parts)
    return _cut(segments, owner, rank / parts[owner], (rank + 1) / parts[owner])


def split_at(segments: Segments, which: np.ndarray, fraction: np.ndarray) -> Segments:
    """Cut segments `which` in two at `fraction` of their length (straight, so the path is unchanged)."""
    parts = np.ones(len(segments), dtype=np.int64)
    parts[which] = 2
    owner = np.repeat(np.arange(len(segments)), parts)
    second = np.zeros(len(owner), dtype=bool)
    second[np.cumsum(parts)[which] - 1] = True
    cut = np.ones(len(segments))
    cut[which] = fraction
    f0 = np.where(second, cut[owner], 0.0)
    f1 = np.where(second | (parts[owner] == 1), 1.0, cut[owner])
    return _cut(segments, owner, f0, f1)


def _cut(segments: Segments, owner: np.ndarray, f0: np.ndarray, f1: np.ndarray) -> Segments:
    span = segments.end[owner] - segments.start[owner]
    start = np.where((f0 == 0.0)[:, None], segments.start[owner], segments.start[owner] + f0[:, None] * span)
    end = np.where((f1 == 1.0)[:, None], segments.end[owner], segments.start[owner] + f1[:, None] * span)
    return segments.take(owner, start=start, end=end)


def quantisation_split(segments: Segments, kin: Kinematics, which: np.ndarray) -> np.ndarray:
    """Where to cut segments whose Bresenham staircase strays too far: at the point where the slave with the
    largest rounding mismatch sits exactly on a whole step nearest the middle (its rounding error is zero
    there), or at the middle when no slave crosses a whole step inside."""
    x0 = kin.to_motor(segments.start[which]) * kin.limits.steps_per_mm
    x1 = kin.to_motor(segments.end[which]) * kin.limits.steps_per_mm
    d = np.round(x1) - np.round(x0)
    n = np.abs(d).max(axis=1, keepdims=True)
    exact = x1 - x0
    master_span = np.take_along_axis(np.abs(exact), np.argmax(np.abs(d), axis=1)[:, None], axis=1)
    mismatch = np.abs(np.abs(d) - n * np.divide(np.abs(exact), master_span, out=np.zeros_like(exact),
                                                   where=master_span > 0))
    mismatch[np.abs(d) == n] = -1.0  # masters are never the culprit
    worst = np.argmax(mismatch, axis=1)
    rows = np.arange(len(which))
    a, b = x0[rows, worst], x1[rows, worst]
    k = np.round(0.5 * (a + b))
    inside = (k - np.minimum(a, b) > 1e-9) & (np.maximum(a, b) - k > 1e-9)
    return np.where(inside, np.divide(k - a, b - a, out=np.full(len(a), 0.5), where=b != a), 0.5)


def segment_steps(segments: Segments, kin: Kinematics) -> np.ndarray:
    return kin.to_steps(segments.end) - kin.to_steps(segments.start)


EVENT_CHUNK = 1 << 20  # events timed per pass: small temporaries are reused, large ones cost page faults


def generate(segments: Segments, plan: Plan, kin: Kinematics, steps: np.ndarray,
             max_gap: float) -> Events:
    """`steps` from `segment_steps`; `max_gap` (s) is the longest interval the player can wait between events."""
    n_master = np.abs(steps).max(axis=1, initial=0)
    dwell = segments.dwell > 0
    events_per = np.where(dwell, np.ceil(segments.dwell / max_gap).astype(np.int64), n_master)
    blocks = np.flatnonzero(events_per > 0)
    count = events_per[blocks]
    first = np.concatenate([[0], np.cumsum(count)])
    exact = kin.to_motor(segments.start) * kin.limits.steps_per_mm
    exact_end = kin.to_motor(segments.end) * kin.limits.steps_per_mm
    master = np.argmax(np.abs(steps), axis=1)
    rows = np.arange(len(segments))
    crossing = _Crossings(exact[rows, master], exact_end[rows, master], np.sign(steps[rows, master]))
    time = np.empty(first[-1])
    phase = np.empty(first[-1], dtype=np.int8)
    cut = np.searchsorted(first, np.arange(0, first[-1], EVENT_CHUNK), side="right") - 1
    for lo, hi in zip(cut, np.append(cut[1:], len(blocks))):
        if hi > lo:
            span = slice(first[lo], first[hi])
            time[span], phase[span] = _times(segments, plan, crossing, blocks[lo:hi], count[lo:hi], dwell)
    block_steps = np.where(dwell[blocks][:, None], 0, steps[blocks])
    modulus = np.where(dwell[blocks], 1, n_master[blocks])
    init = bresenham_init(exact[blocks], exact_end[blocks], master[blocks], block_steps, modulus)
    return Events(blocks, block_steps, modulus, init, segments.tool[blocks], first, time, phase)


class _Crossings:
    """The master's exact positions (steps) at the ends of every segment and its direction."""

    def __init__(self, x0: np.ndarray, x1: np.ndarray, sign: np.ndarray):
        self.x0, self.span, self.p0, self.sign = x0, x1 - x0, np.round(x0), sign


def _times(segments: Segments, plan: Plan, master: _Crossings, blocks: np.ndarray, count: np.ndarray,
           dwell: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ideal time and motion phase of the events of some blocks: the master steps where its exact position
    crosses a half-step point (a distance along the exact segment); a dwell's step-less events are spread
    evenly over it, the last at its end."""
    seg = np.repeat(blocks, count)
    k = np.arange(len(seg)) - np.repeat(np.cumsum(count) - count, count) + 1.0  # event number in its block
    span = master.span[seg]
    frac = np.divide(master.p0[seg] + master.sign[seg] * (k - 0.5) - master.x0[seg], span,
                     out=np.zeros_like(span), where=span != 0)
    s = np.clip(frac, 0.0, 1.0) * plan.length[seg]
    time = plan.time_at(seg, s)
    phase = np.where(s < plan.s_acc[seg], 0, np.where(s <= plan.s_acc[seg] + plan.s_cruise[seg], 1, 2))
    is_dwell = dwell[seg]
    if np.any(is_dwell):
        dwell_time = plan.t_start[seg] + segments.dwell[seg] * k / np.repeat(count, count)
        time = np.where(is_dwell, dwell_time, time)
        phase = np.where(is_dwell, 3, phase)
    return time, phase


def staircase_bound(segments: Segments, kin: Kinematics) -> np.ndarray:
    """An upper bound (mm) of `staircase_error` for every segment, without enumerating events.

    After i master events a slave has made c(i) = (i d - init) / N + theta steps, 0 <= theta <= (N - 1) / N,
    while its exact count at that master position is i |slope| + beta (see bresenham_init): the difference
    lies between the extremes of the linear part over 0 <= i <= N, plus theta. The tool is then at most
    that far (in each slave's own direction) from the segment's line."""
    spm = kin.limits.steps_per_mm
    x0, x1 = kin.to_motor(segments.start) * spm, kin.to_motor(segments.end) * spm
    steps = np.round(x1) - np.round(x0)
    master = np.argmax(np.abs(steps), axis=1)
    n = np.maximum(np.abs(steps).max(axis=1, initial=0), 1)
    init = bresenham_init(x0, x1, master, steps.astype(np.int64), n.astype(np.int64))
    rows = np.arange(len(master))
    span = (x1 - x0)[rows, master][:, None]
    slope = np.divide(x1 - x0, span, out=np.zeros_like(x0), where=span != 0)
    mx0 = x0[rows, master][:, None]
    sigma = np.where(steps != 0, np.sign(steps), 1.0)  # the direction counted as + for each slave
    beta = ((x0 - np.round(x0)) + (np.round(mx0) - mx0) * slope) * sigma
    rate = slope * np.sign(steps[rows, master])[:, None] * sigma  # exact slave steps per master step
    nn = n[:, None].astype(float)
    drift = np.abs(steps) - nn * rate  # the linear part's change over the block
    base = -init / nn - beta
    high = (nn - 1) / nn + np.maximum(drift, 0.0) + base
    low = np.minimum(drift, 0.0) + base
    slave = np.arange(steps.shape[1])[None, :] != master[:, None]
    deviation = np.maximum(np.abs(high), np.abs(low))
    # A motor that makes no step stays put: it is exactly as far off as its exact position drifts.
    still = np.maximum(np.abs(beta), np.abs(beta + nn * rate))
    deviation = np.where(slave, np.where(steps == 0, still, deviation), 0.0)
    reach = kin.step_reach()
    return deviation @ reach


STAIRCASE_CHUNK = 1 << 19  # events per pass: small temporaries are reused, large ones cost page faults


def staircase_error(segments: Segments, kin: Kinematics, which: np.ndarray) -> np.ndarray:
    """How far (mm) the Bresenham staircase of each segment in `which` strays from the segment's line: the
    tool's distance to it after every event. Geometry only (no timing), so it is cheap to ask before planning."""
    events = np.abs(segment_steps(segments.take(which), kin)).max(axis=1, initial=0)
    bounds = np.searchsorted(np.cumsum(events), np.arange(STAIRCASE_CHUNK, events.sum() + STAIRCASE_CHUNK,
                                                             STAIRCASE_CHUNK), side="right")
    worst, lo = np.zeros(len(which)), 0
    for hi in np.unique(np.concatenate([np.maximum(bounds, 1), [len(which)]])):
        if hi > lo:
            worst[lo:hi] = _staircase_error(segments.take(which[lo:hi]), kin)
            lo = hi
    return worst


def _staircase_error(part: Segments, kin: Kinematics) -> np.ndarray:
    steps = segment_steps(part, kin)
    exact = kin.to_motor(part.start) * kin.limits.steps_per_mm
    exact_end = kin.to_motor(part.end) * kin.limits.steps_per_mm
    master = np.argmax(np.abs(steps), axis=1)
    modulus = np.maximum(np.abs(steps).max(axis=1, initial=0), 1)
    init = bresenham_init(exact, exact_end, master, steps, modulus)
    block, _, position = bresenham(steps, modulus, init, np.abs(steps).max(axis=1, initial=0))
    before = np.cumsum(steps, axis=0) - steps  # positions add up over the blocks: count each from its start
    motor_mm = (position - before[block] + np.round(exact)[block]) / kin.limits.steps_per_mm
    axes = kin.to_axes(motor_mm, part.start[block])[:, :3]
    dist, _ = chord_distance(axes, block, part, clamp=False)
    worst = np.zeros(len(part))
    has = np.flatnonzero(np.bincount(block, minlength=len(part)))  # blocks are in order: reduce runs of them
    if len(has):
        worst[has] = np.maximum.reduceat(dist, np.searchsorted(block, has))
    return worst


def bresenham_init(x0: np.ndarray, x1: np.ndarray, master: np.ndarray, steps: np.ndarray,
                   modulus: np.ndarray) -> np.ndarray:
    """Accumulator starts that keep each slave near the exact line, not the line between rounded ends.

    When the master reaches step P0 + i, the slave's exact count is i * |slope| + beta (its position minus
    its rounded start). The player makes ceil((i * d - init) / N) steps, about i * d / N - init / N + 1/2.
    The rounded total d differs from N * |slope|, so init centres the difference at the block's middle.
    """
    rows = np.arange(len(master))
    mx0, mx1 = x0[rows, master], x1[rows, master]
    span = (mx1 - mx0)[:, None]
    slope = np.divide(x1 - x0, span, out=np.zeros_like(x0), where=span != 0)
    beta = ((x0 - np.round(x0)) + (np.round(mx0)[:, None] - mx0[:, None]) * slope) * np.sign(steps)
    n = modulus[:, None].astype(float)
    init = np.round(n * (0.5 - beta) + 0.5 * n * (np.abs(steps) - n * np.abs(slope)))
    init = np.where(steps != 0, init, modulus[:, None] >> 1)
    return np.clip(init, 0, modulus[:, None] - 1).astype(np.int64)

"""Blocks whose Bresenham staircase would stray from their segment, and the cuts that keep it close.

A block moves its slaves by Bresenham from rounded ends, so its staircase can stray from the exact segment by
up to a step (more when rounding tilts a short block). `refine` cuts the segments whose staircase strays
further than STAIRCASE_LIMIT steps: `staircase_bound` proves most of them close without enumerating events,
`staircase_error` measures the others event by event. `split_long` cuts segments a block cannot hold, and
`split_kinked` a delta's pieces whose carriages' velocity would step too far where they meet.
"""

from __future__ import annotations

import ctypes

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.blocks import MAX_MODULUS, bresenham, bresenham_init
from codegen.motion.planner import ACCEL_WINDOW_S, segment_lengths
from codegen.motion.stepgen import segment_steps
from codegen.native import contiguous, library, pointer
from codegen.toolpath.segments import Segments

STAIRCASE_LIMIT = 0.85  # steps: blocks whose Bresenham staircase strays further from their segment are cut
REFINE_ROUNDS = 4
KINK_SHARE = 0.5  # of a motor's acceleration the velocity steps between a delta move's pieces may take
KINK_LEAST_STEPS = 16  # master steps: split_kinked makes no shorter parts


def refine(segments: Segments, kin: Kinematics) -> Segments:
    """Cut the blocks whose Bresenham staircase strays too far from their segment (the rounding of a block's
    two ends can tilt it): a few rounds, each looking only at the pieces the previous round cut."""
    limit = STAIRCASE_LIMIT * kin.path_quantum()  # one step of the coarsest motor
    look = np.flatnonzero(staircase_bound(segments, kin) > limit)  # the others provably stay close
    for _ in range(REFINE_ROUNDS):
        bad = look[staircase_error(segments, kin, look) > limit]
        if len(bad) == 0:
            break
        segments = split_at(segments, bad, quantisation_split(segments, kin, bad))
        pieces = bad + np.arange(len(bad))  # where the cut segments' first halves now stand
        look = np.unique(np.concatenate([pieces, pieces + 1]))  # in order: the next round's cuts count on it
    return segments


def split_long(segments: Segments, kin: Kinematics) -> Segments:
    """Cut segments whose master motor would make more steps than a block holds into equal parts."""
    steps = np.abs(kin.to_steps(segments.end) - kin.to_steps(segments.start)).max(axis=1, initial=0)
    parts = np.maximum(1, -(-steps // (MAX_MODULUS - 1)))
    if np.all(parts == 1):
        return segments
    owner = np.repeat(np.arange(len(parts)), parts)
    rank = np.arange(len(owner)) - np.repeat(np.cumsum(parts) - parts, parts)
    return _cut(segments, owner, rank / parts[owner], (rank + 1) / parts[owner])


def split_kinked(segments: Segments, kin: Kinematics) -> Segments:
    """Cut straight pieces where motors are not linear in the axes (a delta's carriages) into equal parts short
    enough that the velocity step each motor makes where two parts meet (the bend times the parts' length, per
    mm/s: the planner's `chord_kinks`) takes at most KINK_SHARE of its acceleration over one window, at the
    fastest the piece may go (its feed, and every motor's velocity). Parts stay at least KINK_LEAST_STEPS of
    the master long: near the region's edge the bend grows without bound."""
    if kin.linear or not len(segments):
        return segments
    length, u = segment_lengths(segments)
    middle = 0.5 * (segments.start + segments.end)
    factors = np.max([kin.motor_factors(u, p) for p in (segments.start, middle, segments.end)], axis=0)
    bend = np.max([kin.motor_bend(u, p) for p in (segments.start, middle, segments.end)], axis=0)
    motor = kin.limits
    v_motor = np.min(np.divide(motor.max_velocity, factors, out=np.full_like(factors, np.inf), where=factors > 0),
                     axis=1)
    moving = (length > 0) & (segments.dwell <= 0)  # a dwell moves no motor: it stays one part
    speed = np.where(moving, np.minimum(segments.feed, v_motor), 0.0)
    step_change = np.where(moving[:, None], speed[:, None] * np.nan_to_num(bend) / ACCEL_WINDOW_S, 0.0)  # per mm
    longest = np.min(np.divide(KINK_SHARE * motor.max_accel, step_change, out=np.full_like(bend, np.inf),
                               where=step_change > 0), axis=1)
    reach = np.max(factors * motor.steps_per_mm, axis=1, initial=0.0)  # steps per mm of the fastest motor
    shortest = np.divide(KINK_LEAST_STEPS, reach, out=np.full(len(reach), np.inf), where=reach > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        parts = np.ceil(length / np.maximum(longest, shortest))
    parts = np.where(np.isfinite(parts) & (parts > 1) & moving, parts, 1).astype(np.int64)
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


STAIRCASE_CHUNK = 1 << 19  # events per pass (numpy): small temporaries are reused, large ones cost page faults


def staircase_error(segments: Segments, kin: Kinematics, which: np.ndarray) -> np.ndarray:
    """How far (mm) the Bresenham staircase of each segment in `which` strays from the segment's line: the
    tool's distance to it after every event. Geometry only (no timing), so it is cheap to ask before planning.
    In C (codegen/native/staircase.c) for linear kinematics where the helper could be built."""
    lib = library("staircase") if kin.linear else None
    if lib is None or len(which) == 0:
        return staircase_error_numpy(segments, kin, which)
    start, end = segments.start[which], segments.end[which]
    steps, modulus, init, first_step = _blocks(start, end, kin)
    motors = steps.shape[1]
    driven = np.isin(np.arange(3), kin.driven_axes).astype(np.int64)
    inverse = np.zeros((3, motors))
    inverse[kin.driven_axes[kin.driven_axes < 3]] = kin.inverse[kin.driven_axes < 3]
    worst = np.empty(len(which))
    steps, modulus, init = contiguous(np.int64, steps, modulus, init)
    first_step, spm, inverse = contiguous(np.float64, first_step, kin.limits.steps_per_mm, inverse)
    driven, = contiguous(np.int64, driven)
    start, end = contiguous(np.float64, start, end)
    lib.staircase_error(ctypes.c_int64(len(which)), ctypes.c_int64(motors),
                        *map(pointer, (steps, modulus, init, first_step, spm, inverse, driven, start, end, worst)))
    return worst


def staircase_error_numpy(segments: Segments, kin: Kinematics, which: np.ndarray) -> np.ndarray:
    """`staircase_error` in numpy, a chunk of events at a time."""
    events = np.abs(segment_steps(segments.take(which), kin)).max(axis=1, initial=0)
    bounds = np.searchsorted(np.cumsum(events), np.arange(STAIRCASE_CHUNK, events.sum() + STAIRCASE_CHUNK,
                                                             STAIRCASE_CHUNK), side="right")
    worst, lo = np.zeros(len(which)), 0
    for hi in np.unique(np.concatenate([np.maximum(bounds, 1), [len(which)]])):
        if hi > lo:
            part = which[lo:hi]
            worst[lo:hi] = _staircase_error(segments.start[part], segments.end[part], kin)
            lo = hi
    return worst


def _blocks(start: np.ndarray, end: np.ndarray, kin: Kinematics) -> tuple[np.ndarray, ...]:
    """The blocks of straight pieces: each motor's steps, the modulus, the accumulators' starts, and each
    motor's rounded start (steps)."""
    steps = kin.to_steps(end) - kin.to_steps(start)
    exact = kin.to_motor(start) * kin.limits.steps_per_mm
    exact_end = kin.to_motor(end) * kin.limits.steps_per_mm
    master = np.argmax(np.abs(steps), axis=1)
    modulus = np.maximum(np.abs(steps).max(axis=1, initial=0), 1)
    return steps, modulus, bresenham_init(exact, exact_end, master, steps, modulus), np.round(exact)


def _staircase_error(start: np.ndarray, end: np.ndarray, kin: Kinematics) -> np.ndarray:
    steps, modulus, init, first_step = _blocks(start, end, kin)
    block, _, position = bresenham(steps, modulus, init, np.abs(steps).max(axis=1, initial=0))
    before = np.cumsum(steps, axis=0) - steps  # positions add up over the blocks: count each from its start
    motor_mm = (position - before[block] + first_step[block]) / kin.limits.steps_per_mm
    a, ab = start[block, :3], (end - start)[block, :3]
    p = _tool(kin, motor_mm, a)
    ap = p - a
    denom = _dot(ab, ab)
    t = np.divide(_dot(ap, ab), denom, out=np.zeros(len(block)), where=denom > 0.0)
    off = p - (a + t[:, None] * ab)
    dist = np.sqrt(_dot(off, off))
    worst = np.zeros(len(start))
    has = np.flatnonzero(np.bincount(block, minlength=len(start)))  # blocks are in order: reduce runs of them
    if len(has):
        worst[has] = np.maximum.reduceat(dist, np.searchsorted(block, has))
    return worst


def _tool(kin: Kinematics, motor_mm: np.ndarray, start: np.ndarray) -> np.ndarray:
    """(N, 3) the tool at motor positions (N, M); axes no motor drives stay at `start` (N, 3). Linear
    kinematics motor by motor, in the order the C version adds them."""
    if not kin.linear:
        return kin.to_axes(motor_mm, np.pad(start, ((0, 0), (0, 1))))[:, :3]
    out = np.array(start, copy=True)
    for row, axis in zip(kin.inverse, kin.driven_axes):
        if axis < 3:
            total = motor_mm[:, 0] * row[0]
            for m in range(1, len(row)):
                total = total + motor_mm[:, m] * row[m]
            out[:, axis] = total
    return out


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1]) + u[:, 2] * v[:, 2]

"""Blocks whose Bresenham staircase would stray from their segment, and the cuts that keep it close.

A block moves its slaves by Bresenham from rounded ends, so its staircase can stray from the exact segment by
up to a step (more when rounding tilts a short block). `refine` cuts the segments whose staircase strays
further than STAIRCASE_LIMIT steps: `staircase_bound` proves most of them close without enumerating events,
`staircase_error` measures the others event by event. `split_long` cuts segments a block cannot hold.
"""

from __future__ import annotations

import numpy as np

from codegen.checks import chord_distance, step_length_mm
from codegen.kinematics.base import Kinematics
from codegen.schedule import MAX_MODULUS
from codegen.segments import Segments
from codegen.stepgen import bresenham_init, segment_steps
from codegen.twin import bresenham

STAIRCASE_LIMIT = 0.85  # steps: blocks whose Bresenham staircase strays further from their segment are cut
REFINE_ROUNDS = 4


def refine(segments: Segments, kin: Kinematics) -> Segments:
    """Cut the blocks whose Bresenham staircase strays too far from their segment (the rounding of a block's
    two ends can tilt it): a few rounds, each looking only at the pieces the previous round cut."""
    limit = STAIRCASE_LIMIT * step_length_mm(kin)
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

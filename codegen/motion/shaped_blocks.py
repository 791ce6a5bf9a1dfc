"""Shaped motion -> blocks a table can hold, and the exact time of every master event.

A block moves its motors by fixed step counts, the slaves coupled to the master by Bresenham, so along a block
every motor must move one way and stay near the straight line (in motor steps) between the block's ends. Shaped
motion is piecewise quadratic in time (codegen/motion/shaped_motion.py); it curves only where the impulses overlap
a corner or an acceleration change, as the delta's carriages curve along a straight move, and it is cut the same
way, into chords:
- where any motor's velocity passes through zero (it turns), where the tool switches, and around rests;
- then, as Douglas and Peucker simplify a polyline, at the point where a slave strays furthest from the chord
  (slave against master, in steps: the Bresenham line) while that is more than CHORD_LIMIT steps, where the
  master makes more steps than a block holds, or where the chord's Bresenham staircase strays
  (codegen/motion/staircase.py's measures).
A block may span many pieces of the shaped motion: a straight cruise is one block whatever its pieces, a curve
as few as its bend needs. Every master event is timed where the master's exact shaped motion crosses its half
step (the quadratic of its piece solved, numpy over all events at once), as Klipper times its steps.

A delta's carriages are not quadratic in time: codegen/motion/shaped_delta.py finds their turns, strays and
crossings numerically; the cuts and blocks are the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.blocks import MAX_MODULUS, Events, bresenham_init
from codegen.motion.shaped_delta import carriage_crossings, carriage_strays, carriage_turns, carriage_ways
from codegen.motion.shaped_motion import Motion, cut
from codegen.motion.staircase import STAIRCASE_LIMIT, staircase_bound, staircase_error
from codegen.toolpath.segments import REF_LINE, Segments

CHORD_LIMIT = 0.5  # steps a slave may stray from its block's chord (the staircase's own error comes on top)
CUT_ROUNDS = 64  # each round cuts every block still too far off once, at its worst point
TURN_MARGIN = 1e-12  # s: a motor's turn this close to a piece's end needs no cut


@dataclass
class ShapedBlocks:
    chords: Segments  # one straight segment per block, with its plan segment's tool, item and line
    steps: np.ndarray  # (B, M) each block's motor steps
    bounds: np.ndarray  # (B + 1,) s: where the blocks begin and end, on the shaped clock
    pieces: Motion  # the shaped motion, cut at every block's end (its origin: each piece's plan segment)
    events: Events  # the blocks that have events, and the time of each


def shaped_blocks(shaped: Motion, segments: Segments, kin: Kinematics, max_gap: float, start: np.ndarray,
                  end: np.ndarray | None = None) -> ShapedBlocks:
    """`segments`: the plan's (the shaped motion's origins); `max_gap` (s): the longest the player waits between
    events (a rest becomes step-less events that carry its time); `start`, `end` (4,): where the tool is at the
    motion's ends, exactly (None: the motion's own end), so that consecutive stretches round their shared point
    alike and the program ends where it says (the shaper's amplitudes sum to 1 only to rounding)."""
    pieces = cut(shaped, _turns(shaped, kin) if kin.linear else carriage_turns(shaped, kin))
    bounds = pieces.breaks[_forced(pieces, segments, kin)]
    fresh = np.ones(len(bounds) - 1, dtype=bool)  # the blocks not yet found close to their chords
    for _ in range(CUT_ROUNDS):
        extra = _cuts(pieces, bounds, fresh, segments, kin, (start, end))
        if not len(extra):
            break
        pieces = cut(pieces, extra)
        grown = np.unique(np.concatenate([bounds, extra]))
        new = ~np.isin(grown, bounds)
        bounds, fresh = grown, new[:-1] | new[1:]  # a block that was not cut stays as close as it was
    chords = _chords(pieces, bounds, segments, (start, end))
    steps = kin.to_steps(chords.end) - kin.to_steps(chords.start)
    events = _events(pieces, bounds, chords, steps, kin, max_gap)
    return ShapedBlocks(chords, steps, bounds, pieces, events)


def motor_motion(motion: Motion, kin: Kinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every piece's motor positions at its start, velocities and accelerations, in steps."""
    to_steps = kin.matrix.T * kin.limits.steps_per_mm[None, :]
    return motion.position @ to_steps, motion.velocity @ to_steps, motion.accel @ to_steps


def _turns(motion: Motion, kin: Kinematics) -> np.ndarray:
    """The times inside pieces where a motor's velocity passes through zero."""
    _, v, a = motor_motion(motion, kin)
    h = np.diff(motion.breaks)[:, None]
    tau = np.divide(-v, a, out=np.full_like(v, -1.0), where=a != 0)
    inside = (tau > TURN_MARGIN) & (tau < h - TURN_MARGIN)
    return motion.breaks[np.nonzero(inside)[0]] + tau[inside]


def _still(motion: Motion, kin: Kinematics) -> np.ndarray:
    """(K,) the pieces where no motor moves."""
    _, v, a = motor_motion(motion, kin)
    return ~np.any((v != 0) | (a != 0), axis=1)


def _forced(motion: Motion, segments: Segments, kin: Kinematics) -> np.ndarray:
    """The breaks every block must end at: the motion's ends, a motor's turn (between pieces that move it opposite
    ways), a rest's ends and where the tool switches."""
    if kin.linear:
        _, v, a = motor_motion(motion, kin)
        h = np.diff(motion.breaks)[:, None]
        way, still = np.sign(v * h + 0.5 * a * h * h), _still(motion, kin)
    else:
        way, still = carriage_ways(motion, kin)
    turns = np.any(way[1:] * way[:-1] < 0, axis=1)
    tool, line = segments.tool[motion.origin], segments.line[motion.origin]
    inner = turns | (still[1:] != still[:-1]) | (tool[1:] != tool[:-1]) | (line[1:] != line[:-1])
    return np.flatnonzero(np.concatenate([[True], inner, [True]]))


def _cuts(motion: Motion, bounds: np.ndarray, fresh: np.ndarray, segments: Segments, kin: Kinematics,
          points: tuple) -> np.ndarray:
    """The times to cut the `fresh` blocks at this round: each whose slave strays too far from its chord at its
    worst point, each with more master steps than a block holds, or (once none of them does) whose staircase
    strays too far, at its middle."""
    which = np.flatnonzero(fresh)
    x0, x1, worst, worst_time = (_linear_strays if kin.linear else carriage_strays)(motion, bounds, which, kin)
    master = np.argmax(np.abs(np.round(x1) - np.round(x0)), axis=1)
    bad = (worst > CHORD_LIMIT) & ((x1 - x0)[np.arange(len(which)), master] != 0)
    out = [worst_time[bad]]
    middle = 0.5 * (bounds[which] + bounds[which + 1])
    long = np.abs(np.round(x1) - np.round(x0)).max(axis=1) > MAX_MODULUS - 1
    out.append(middle[long & ~bad])
    if not np.any(bad | long):
        chords = _chords(motion, bounds, segments, points).take(which)
        limit = STAIRCASE_LIMIT * kin.path_quantum()
        look = np.flatnonzero(staircase_bound(chords, kin) > limit)
        out.append(middle[look[staircase_error(chords, kin, look) > limit]])
    times = np.concatenate(out)
    return times[(times > bounds[0]) & (times < bounds[-1]) & ~np.isin(times, bounds)]


def _linear_strays(motion: Motion, bounds: np.ndarray, which: np.ndarray, kin: Kinematics):
    """For blocks `which`: every motor at their ends (steps), and the largest distance of a slave from its block's
    chord (slave against master) with its time, exact: each piece's offset from the chord is a quadratic."""
    first = np.searchsorted(motion.breaks, bounds[which])
    last = np.searchsorted(motion.breaks, bounds[which + 1])
    count = last - first
    block = np.repeat(np.arange(len(first)), count)
    piece = first[block] + np.arange(len(block)) - np.repeat(np.cumsum(count) - count, count)
    p, v, a = motor_motion(motion, kin)
    h = np.diff(motion.breaks)
    ends = np.vstack([p, p[-1:] + v[-1:] * h[-1] + 0.5 * a[-1:] * h[-1] ** 2])  # (K + 1, M) at every break
    x0, x1 = ends[first], ends[last]
    p, v, a, h = p[piece], v[piece], a[piece], h[piece]
    rows = np.arange(len(first))
    master = np.argmax(np.abs(np.round(x1) - np.round(x0)), axis=1)
    span = (x1 - x0)[rows, master][:, None]
    ratio = np.divide(x1 - x0, span, out=np.zeros_like(x0), where=span != 0)[block]  # (K, M) slave per master
    u = master[block][:, None]
    off = p - x0[block] - ratio * (np.take_along_axis(p, u, axis=1) - x0[block, master[block]][:, None])
    c1 = v - ratio * np.take_along_axis(v, u, axis=1)
    c2 = a - ratio * np.take_along_axis(a, u, axis=1)
    tau = np.divide(-c1, c2, out=np.zeros_like(c1), where=c2 != 0)
    tau = np.where((tau > 0) & (tau < h[:, None]), tau, 0.0)
    inside = np.abs(off + c1 * tau + 0.5 * c2 * tau * tau)
    at_start = np.where((piece == first[block])[:, None], 0.0, np.abs(off))
    stray = np.maximum(inside, at_start)
    worst_motor = np.argmax(stray, axis=1)
    worst = stray[np.arange(len(block)), worst_motor]
    worst_time = motion.breaks[piece] + np.where(inside[np.arange(len(block)), worst_motor] >= at_start[
        np.arange(len(block)), worst_motor], tau[np.arange(len(block)), worst_motor], 0.0)
    order = np.lexsort((worst, block))  # per block, its worst piece last
    pick = order[np.cumsum(count) - 1]
    return x0, x1, worst[pick], worst_time[pick]


def _chords(motion: Motion, bounds: np.ndarray, segments: Segments, points: tuple) -> Segments:
    """Each block as a straight segment between the shaped positions at its ends, carrying its first piece's plan
    segment (tool, item, line); a block where nothing moves is a dwell. `points`: the motion's first and last
    point, exactly (the last None: the motion's own)."""
    first = np.searchsorted(motion.breaks, bounds[:-1])
    at = motion.at(bounds)
    at[0] = points[0]
    if points[1] is not None:
        at[-1] = points[1]
    start, end = at[:-1], at[1:]
    still = np.all(start == end, axis=1)
    n = len(first)
    return segments.take(motion.origin[first], start=start, end=end,
                         dwell=np.where(still, np.diff(bounds), 0.0), ref_kind=np.full(n, REF_LINE),
                         ref_fine=np.full(n, -1, dtype=np.int64))


def _events(motion: Motion, bounds: np.ndarray, chords: Segments, steps: np.ndarray, kin: Kinematics,
            max_gap: float) -> Events:
    """The blocks with events and every event's time: a master step where its exact motion crosses the half
    step; a rest's step-less events spread evenly over it, the last at its end."""
    spm = kin.limits.steps_per_mm
    x0, x1 = kin.to_motor(chords.start) * spm, kin.to_motor(chords.end) * spm
    n_master = np.abs(steps).max(axis=1, initial=0)
    rest = chords.dwell > 0
    count = np.where(rest, np.ceil(chords.dwell / max_gap).astype(np.int64), n_master)
    blocks = np.flatnonzero(count > 0)
    count = count[blocks]
    master = np.argmax(np.abs(steps), axis=1)
    block_steps = np.where(rest[blocks][:, None], 0, steps[blocks])
    modulus = np.where(rest[blocks], 1, n_master[blocks])
    init = bresenham_init(x0[blocks], x1[blocks], master[blocks], block_steps, modulus)
    first_event = np.concatenate([[0], np.cumsum(count)])
    block = np.repeat(blocks, count)
    k = np.arange(first_event[-1]) - np.repeat(first_event[:-1], count) + 1.0  # event number in its block
    time = bounds[block] + np.diff(bounds)[block] * k / np.repeat(count, count)  # a rest's
    phase = np.full(len(block), 3, dtype=np.int8)
    moving = ~rest[block]
    crossings = _crossings if kin.linear else carriage_crossings
    time[moving], phase[moving] = crossings(motion, bounds, x0, steps, master, block[moving], k[moving], kin)
    return Events(blocks, block_steps, modulus, init, chords.tool[blocks], first_event, time, phase)


def _crossings(motion: Motion, bounds: np.ndarray, x0: np.ndarray, steps: np.ndarray, master: np.ndarray,
               block: np.ndarray, k: np.ndarray, kin: Kinematics) -> tuple[np.ndarray, np.ndarray]:
    """Time and phase (0 speeding up, 1 steady, 2 slowing down) of event k (1-based) of each block: where the
    master has gone k - 1/2 steps past its rounded start. Progress along each block's master is monotone, so all
    pieces of all blocks sort on one key, the block's offset plus the master's progress."""
    p, v, a = motor_motion(motion, kin)
    piece_block = np.searchsorted(bounds, motion.breaks[:-1], side="right") - 1
    rows = np.arange(len(x0))
    sign = np.sign(steps[rows, master]).astype(float)
    origin = x0[rows, master]
    offset = np.concatenate([[0.0], np.cumsum(np.abs(steps[rows, master]) + 2.0)])  # room for each block's span
    u = master[piece_block]
    s = sign[piece_block]
    pieces = np.arange(len(piece_block))
    progress = s * (p[pieces, u] - origin[piece_block])
    key = offset[piece_block] + np.maximum(progress, 0.0)
    target = sign[block] * (np.round(origin[block]) - origin[block]) + k - 0.5
    piece = np.searchsorted(key, offset[block] + target, side="right") - 1
    first = np.searchsorted(motion.breaks, bounds[:-1])  # each block's pieces
    last = np.searchsorted(motion.breaks, bounds[1:]) - 1
    piece = np.clip(piece, first[block], last[block])
    speed, accel = s[piece] * v[piece, u[piece]], s[piece] * a[piece, u[piece]]
    ahead = np.maximum(target - progress[piece], 0.0)
    root = np.sqrt(np.maximum(speed * speed + 2.0 * accel * ahead, 0.0))
    tau = np.divide(2.0 * ahead, speed + root, out=np.zeros_like(ahead), where=speed + root > 0)
    h = motion.breaks[piece + 1] - motion.breaks[piece]
    time = motion.breaks[piece] + np.clip(tau, 0.0, h)
    return time, np.where(accel > 0, 0, np.where(accel < 0, 2, 1)).astype(np.int8)

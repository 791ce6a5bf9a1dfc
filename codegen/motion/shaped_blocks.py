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
as few as its bend needs (the cuts: codegen/motion/chord_cuts.py). Every master event is timed where the master's
exact shaped motion crosses its half step (the quadratic of its piece solved: codegen/motion/shaped_crossings.py),
as Klipper times its steps.

A delta's carriages are not quadratic in time: codegen/motion/shaped_delta.py finds their turns, strays and
crossings numerically; the cuts and blocks are the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.blocks import MAX_MODULUS, Events, bresenham_init
from codegen.motion.chord_cuts import chord_bounds
from codegen.motion.shaped_crossings import shaped_crossings
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
    if kin.linear:
        bounds = _linear_bounds(pieces, bounds, segments, kin, (start, end))
        pieces = cut(pieces, bounds)
    else:
        pieces, bounds = _carriage_bounds(pieces, bounds, segments, kin, (start, end))
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


def _linear_bounds(motion: Motion, bounds: np.ndarray, segments: Segments, kin: Kinematics,
                   points: tuple) -> np.ndarray:
    """The blocks of a linear machine: close to their chords (codegen/motion/chord_cuts.py), then each whose
    staircase strays too far cut at its middle, until none does."""
    p, v, a = motor_motion(motion, kin)
    limit = STAIRCASE_LIMIT * kin.path_quantum()
    checked = np.empty(0)  # the bounds whose blocks were found within the staircase limit
    fresh = None  # the blocks to cut to their chords: all at first, then those the staircase cut
    for _ in range(CUT_ROUNDS):
        bounds = chord_bounds(motion.breaks, p, v, a, bounds, CHORD_LIMIT, fresh)
        new = ~np.isin(bounds, checked)
        which = np.flatnonzero(new[:-1] | new[1:])
        chords = _chords(motion, bounds, segments, points, which)
        look = np.flatnonzero(staircase_bound(chords, kin) > limit)
        far = which[look[staircase_error(chords, kin, look) > limit]]
        if not len(far):
            break
        checked = bounds
        bounds = np.unique(np.concatenate([bounds, 0.5 * (bounds[far] + bounds[far + 1])]))
        cut_now = ~np.isin(bounds, checked)
        fresh = cut_now[:-1] | cut_now[1:]
    return bounds


def _carriage_bounds(motion: Motion, bounds: np.ndarray, segments: Segments, kin: Kinematics,
                     points: tuple) -> tuple[Motion, np.ndarray]:
    """The blocks of a delta, cut round by round at their worst strays (numerically: codegen/motion/shaped_delta.py),
    and the motion cut at their ends."""
    fresh = np.ones(len(bounds) - 1, dtype=bool)  # the blocks not yet found close to their chords
    for _ in range(CUT_ROUNDS):
        extra = _cuts(motion, bounds, fresh, segments, kin, points)
        if not len(extra):
            break
        motion = cut(motion, extra)
        grown = np.unique(np.concatenate([bounds, extra]))
        new = ~np.isin(grown, bounds)
        bounds, fresh = grown, new[:-1] | new[1:]  # a block that was not cut stays as close as it was
    return motion, bounds


def _cuts(motion: Motion, bounds: np.ndarray, fresh: np.ndarray, segments: Segments, kin: Kinematics,
          points: tuple) -> np.ndarray:
    """The times to cut the `fresh` blocks at this round: each whose slave strays too far from its chord at its
    worst point, each with more master steps than a block holds, or (once none of them does) whose staircase
    strays too far, at its middle."""
    which = np.flatnonzero(fresh)
    x0, x1, worst, worst_time = carriage_strays(motion, bounds, which, kin)
    master = np.argmax(np.abs(np.round(x1) - np.round(x0)), axis=1)
    bad = (worst > CHORD_LIMIT) & ((x1 - x0)[np.arange(len(which)), master] != 0)
    out = [worst_time[bad]]
    middle = 0.5 * (bounds[which] + bounds[which + 1])
    long = np.abs(np.round(x1) - np.round(x0)).max(axis=1) > MAX_MODULUS - 1
    out.append(middle[long & ~bad])
    if not np.any(bad | long):
        chords = _chords(motion, bounds, segments, points, which)
        limit = STAIRCASE_LIMIT * kin.path_quantum()
        look = np.flatnonzero(staircase_bound(chords, kin) > limit)
        out.append(middle[look[staircase_error(chords, kin, look) > limit]])
    times = np.concatenate(out)
    return times[(times > bounds[0]) & (times < bounds[-1]) & ~np.isin(times, bounds)]


def _chords(motion: Motion, bounds: np.ndarray, segments: Segments, points: tuple,
            which: np.ndarray | None = None) -> Segments:
    """Each block (of `which`; None: all) as a straight segment between the shaped positions at its ends, carrying
    its first piece's plan segment (tool, item, line); a block where nothing moves is a dwell. `points`: the
    motion's first and last point, exactly (the last None: the motion's own)."""
    which = np.arange(len(bounds) - 1) if which is None else which
    start, end = motion.at(bounds[which]), motion.at(bounds[which + 1])
    start[which == 0] = points[0]
    if points[1] is not None:
        end[which == len(bounds) - 2] = points[1]
    still = np.all(start == end, axis=1)
    n = len(which)
    return segments.take(motion.origin[motion.piece_of(bounds[which])], start=start, end=end,
                         dwell=np.where(still, bounds[which + 1] - bounds[which], 0.0),
                         ref_kind=np.full(n, REF_LINE), ref_fine=np.full(n, -1, dtype=np.int64))


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
    still = rest[blocks]
    time, phase = _rest_times(bounds, blocks[still], count[still], first_event[:-1][still], first_event[-1])
    if kin.linear:  # the moving blocks' events, without a per-event index (millions of them)
        moving = slice(None) if not np.any(still) else np.repeat(~still, count)
        time[moving], phase[moving] = shaped_crossings(motion.breaks, *motor_motion(motion, kin), bounds, x0, steps,
                                                       master, blocks[~still], count[~still])
    else:
        block = np.repeat(blocks, count)
        k = np.arange(first_event[-1]) - np.repeat(first_event[:-1], count) + 1.0  # event number in its block
        moving = ~rest[block]
        time[moving], phase[moving] = carriage_crossings(motion, bounds, x0, steps, master, block[moving], k[moving],
                                                         kin)
    return Events(blocks, block_steps, modulus, init, chords.tool[blocks], first_event, time, phase)


def _rest_times(bounds: np.ndarray, blocks: np.ndarray, count: np.ndarray, first: np.ndarray,
                events: int) -> tuple[np.ndarray, np.ndarray]:
    """Every event's time and phase, those of the rests `blocks` (their `count` events from event `first`) filled:
    spread evenly over the rest, the last at its end (phase 3)."""
    time, phase = np.empty(events), np.empty(events, dtype=np.int8)
    k = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count) + 1.0  # event number in its block
    at = np.repeat(first, count) + k.astype(np.int64) - 1
    block = np.repeat(blocks, count)
    time[at] = bounds[block] + (bounds[block + 1] - bounds[block]) * k / np.repeat(count, count)
    phase[at] = 3
    return time, phase

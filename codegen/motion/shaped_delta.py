"""A delta's shaped motion in carriage steps: where its carriages turn, how far they stray from a block's chord,
and when its master carriage crosses each half step.

Shaped motion is piecewise quadratic in x, y, z (codegen/motion/shaped_motion.py); a delta's carriages are its
inverse kinematics, c_i = z + sqrt(rod^2 - |(x, y) - T_i|^2), which are not quadratic in time. So where the linear
kinematics solve quadratics (codegen/motion/shaped_blocks.py), this module samples and solves numerically, numpy
over all pieces, blocks or events at once: a carriage's turn is bracketed by samples of its velocity along each
piece, then solved by Newton's method; a block's largest stray from its chord is taken from samples along its
pieces (the blocks are cut there, so the samples grow finer where it matters); a master event is solved by
Newton's method of second order on the master carriage's exact position. Every Newton step is kept inside the
root's bracket (a bisection where it would leave it).
"""

from __future__ import annotations

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.shaped_motion import Motion

SAMPLES = 16  # intervals per piece at which the carriages are sampled (turns, strays)
NEWTON_ROUNDS = 40  # at most; a root takes a few
CROSSING_STEPS = 1e-6  # steps: how closely a master event's crossing is solved (far below a tick)
TURN_SPEED = 1e-6  # steps/s: a turn's velocity is solved this closely to zero
TURN_GAP = 1e-7  # s: turns closer than this are one (a carriage moves a thousandth of a step in it, or less)
TIME_RESOLUTION = 1e-12  # s: a crossing's bracket this narrow is solved (a root at a piece's very end)


def carriage_steps(motion: Motion, piece: np.ndarray, dt: np.ndarray, kin: Kinematics,
                   motor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, M) every motor's position (steps), velocity and acceleration at dt (N,) s into pieces (N,); with
    `motor` (N,), (N,) each: only that motor's."""
    spm = kin.limits.steps_per_mm if motor is None else kin.limits.steps_per_mm[motor]
    p, v, a, dt = motion.position[piece], motion.velocity[piece], motion.accel[piece], dt[:, None]
    position, speed, accel = kin.carriage_motion(p + (v + 0.5 * a * dt) * dt, v + a * dt, a, motor)
    return position * spm, speed * spm, accel * spm


def carriage_turns(motion: Motion, kin: Kinematics) -> np.ndarray:
    """The times inside pieces where a motor's velocity passes through zero: between two samples of opposite sign,
    by Newton's method (a bisection where its step would leave the bracket). Turns within TURN_GAP of a piece's end
    or of another turn are one (the carriages all turn at once where the effector stops)."""
    h = np.diff(motion.breaks)
    share = np.linspace(0.0, 1.0, SAMPLES + 1)
    piece = np.repeat(np.arange(len(motion)), SAMPLES + 1)
    speed = carriage_steps(motion, piece, (h[:, None] * share[None, :]).ravel(), kin)[1]
    sign = np.sign(speed).reshape(len(motion), SAMPLES + 1, -1)
    which, interval, motor = np.nonzero(sign[:, :-1] * sign[:, 1:] < 0)
    lo, hi = h[which] * share[interval], h[which] * share[interval + 1]
    before, tau = sign[which, interval, motor], 0.5 * (lo + hi)
    todo = np.arange(len(which))
    for _ in range(NEWTON_ROUNDS):
        _, speed, accel = carriage_steps(motion, which[todo], tau[todo], kin, motor[todo])
        done = (np.abs(speed) <= TURN_SPEED) | (hi[todo] - lo[todo] <= TIME_RESOLUTION)
        same = np.sign(speed) == before[todo]
        lo[todo], hi[todo] = np.where(same, tau[todo], lo[todo]), np.where(same, hi[todo], tau[todo])
        todo, speed, accel = todo[~done], speed[~done], accel[~done]
        if not len(todo):
            break
        step = tau[todo] - np.divide(speed, accel, out=np.full(len(todo), np.inf), where=accel != 0)
        tau[todo] = np.where((step > lo[todo]) & (step < hi[todo]), step, 0.5 * (lo[todo] + hi[todo]))
    inside = (tau > TURN_GAP) & (tau < h[which] - TURN_GAP)
    times = np.sort(motion.breaks[which[inside]] + tau[inside])
    return times[np.diff(times, prepend=-np.inf) > TURN_GAP]


def carriage_ways(motion: Motion, kin: Kinematics) -> tuple[np.ndarray, np.ndarray]:
    """(K, M) the way each motor moves along each piece (its turns cut: one way), a piece where it stays taking the
    way it last moved (so that a turn across a carriage's standstill is one), and (K,) the pieces where nothing
    moves."""
    ends = np.vstack([motion.position, motion.end[None, :]])
    way = np.sign(np.diff(kin.to_motor(ends) * kin.limits.steps_per_mm, axis=0))
    last = np.maximum.accumulate(np.where(way != 0, np.arange(len(way))[:, None], 0), axis=0)
    return np.take_along_axis(way, last, axis=0), ~np.any((motion.velocity != 0) | (motion.accel != 0), axis=1)


def carriage_strays(motion: Motion, bounds: np.ndarray, which: np.ndarray, kin: Kinematics):
    """For blocks `which` (between `bounds`): every motor at their ends (steps, (B, M) each), and the largest
    distance (steps) of a slave from its block's chord (slave against master: its Bresenham line) with its time,
    from SAMPLES samples along each of the block's pieces."""
    spm = kin.limits.steps_per_mm
    x0, x1 = kin.to_motor(motion.at(bounds[which])) * spm, kin.to_motor(motion.at(bounds[which + 1])) * spm
    first = np.searchsorted(motion.breaks, bounds[which])
    count = (np.searchsorted(motion.breaks, bounds[which + 1]) - first) * SAMPLES
    block = np.repeat(np.arange(len(which)), count)
    sample = np.arange(len(block)) - np.repeat(np.cumsum(count) - count, count)
    piece = first[block] + sample // SAMPLES
    dt = np.diff(motion.breaks)[piece] * (sample % SAMPLES) / SAMPLES
    p = kin.to_motor(motion.at_piece(piece, dt)) * spm
    rows = np.arange(len(which))
    master = np.argmax(np.abs(np.round(x1) - np.round(x0)), axis=1)
    span = (x1 - x0)[rows, master][:, None]
    ratio = np.divide(x1 - x0, span, out=np.zeros_like(x0), where=span != 0)
    u = master[block]
    off = p - x0[block] - ratio[block] * (p[np.arange(len(block)), u] - x0[block, u])[:, None]
    stray = np.abs(off).max(axis=1)
    worst = np.maximum.reduceat(stray, np.cumsum(count) - count)  # every block has samples: its pieces last
    at = np.flatnonzero(stray == worst[block])
    pick = at[np.unique(block[at], return_index=True)[1]]  # per block, its first worst sample
    return x0, x1, worst, motion.breaks[piece[pick]] + dt[pick]


def carriage_crossings(motion: Motion, bounds: np.ndarray, x0: np.ndarray, steps: np.ndarray, master: np.ndarray,
                       block: np.ndarray, k: np.ndarray, kin: Kinematics) -> tuple[np.ndarray, np.ndarray]:
    """Time and phase (0 speeding up, 1 steady, 2 slowing down) of event k (1-based) of each block: where the
    master carriage has gone k - 1/2 steps past its rounded start. Along a block the master moves one way, so its
    pieces sort on one key (as in shaped_blocks' linear case); inside its piece each event is the root of the
    master's exact position, found by Newton's method of second order (the motion's quadratic about the last
    guess, exact where the carriage is), a bisection of the bracket where a step would leave it."""
    rows = np.arange(len(x0))
    sign = np.sign(steps[rows, master]).astype(float)
    origin = x0[rows, master]
    offset = np.concatenate([[0.0], np.cumsum(np.abs(steps[rows, master]) + 2.0)])  # room for each block's span
    piece_block = np.searchsorted(bounds, motion.breaks[:-1], side="right") - 1
    u = master[piece_block]
    start, start_speed, start_accel = carriage_steps(motion, np.arange(len(motion)), np.zeros(len(motion)), kin)
    progress = sign[piece_block] * (start[np.arange(len(motion)), u] - origin[piece_block])
    key = offset[piece_block] + np.maximum(progress, 0.0)
    target = sign[block] * (np.round(origin[block]) - origin[block]) + k - 0.5
    piece = np.searchsorted(key, offset[block] + target, side="right") - 1
    first = np.searchsorted(motion.breaks, bounds[:-1])  # each block's pieces
    last = np.searchsorted(motion.breaks, bounds[1:]) - 1
    piece = np.clip(piece, first[block], last[block])
    h = motion.breaks[piece + 1] - motion.breaks[piece]
    um, s, aim = master[block], sign[block], origin[block] + sign[block] * target
    step = _quadratic_root(target - progress[piece], s * start_speed[piece, um], s * start_accel[piece, um])
    tau, lo, hi = np.where(np.isfinite(step), np.clip(step, 0.0, h), 0.5 * h), np.zeros(len(block)), h.copy()
    phase = np.ones(len(block), dtype=np.int8)
    todo = np.arange(len(block))
    for _ in range(NEWTON_ROUNDS):
        p, v, a = carriage_steps(motion, piece[todo], tau[todo], kin, um[todo])
        ahead, speed, accel = s[todo] * (aim[todo] - p), s[todo] * v, s[todo] * a
        phase[todo] = np.where(accel > 0, 0, np.where(accel < 0, 2, 1))
        done = (np.abs(ahead) <= CROSSING_STEPS) | ((ahead > 0) & (tau[todo] >= h[todo])) | (
            (ahead < 0) & (tau[todo] <= 0)) | (hi[todo] - lo[todo] <= TIME_RESOLUTION)
        short = ahead > 0
        lo[todo], hi[todo] = np.where(short, tau[todo], lo[todo]), np.where(short, hi[todo], tau[todo])
        todo, ahead, speed, accel = todo[~done], ahead[~done], speed[~done], accel[~done]
        if not len(todo):
            break
        step = tau[todo] + _quadratic_root(ahead, speed, accel)
        inside = (step > lo[todo]) & (step < hi[todo])
        tau[todo] = np.where(inside, step, 0.5 * (lo[todo] + hi[todo]))
    return motion.breaks[piece] + tau, phase


def _quadratic_root(ahead: np.ndarray, speed: np.ndarray, accel: np.ndarray) -> np.ndarray:
    """s: how long a motion at `speed` speeding up by `accel` takes to go `ahead` (negative: back), the root of its
    quadratic without cancellation (inf where it never gets there)."""
    root = np.sqrt(np.maximum(speed * speed + 2.0 * accel * ahead, 0.0))
    return np.divide(2.0 * ahead, speed + root, out=np.full(len(ahead), np.inf), where=speed + root > 0)

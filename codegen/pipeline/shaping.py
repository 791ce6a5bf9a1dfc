"""A window of the plan, shaped: the blocks of its shaped motion with their events, the corners the checks allow
for, and the smoothing (codegen/motion/shaped_motion.py, shaped_blocks.py).

The stages after the planner (codegen/pipeline/windows.py) then compress, play and check the blocks as they would
the plan's own segments (one straight segment a block); where the pulses break a limit, the plan's segments
under them are slowed and the window shaped again. Shaping reads the plan on both sides of every moment (half a
shaper's duration), so a shaped program is planned as one window (codegen/motion/lookahead.py `whole`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.blocks import Events
from codegen.motion.lookahead import Window
from codegen.motion.planner import Plan, segment_lengths
from codegen.motion.shaped_blocks import shaped_blocks
from codegen.motion.shaped_motion import AXES, Motion, ShapingSettings, planned_motion, shape, smoothing
from codegen.toolpath.segments import Segments


@dataclass
class ShapedWindow:
    window: Window  # the blocks as straight segments, their steps and plan (on the shaped clock)
    events: Events  # the blocks' events, each where the shaped master crosses its half step
    origin: np.ndarray  # (n,) the plan's segment (of the window before shaping) under each block's start
    motion: Motion  # the shaped motion, cut at every block's end
    corners_t: np.ndarray  # (J,) s: where the plan's corners' velocity jumps land once shaped
    jumps: np.ndarray  # (J, M) steps/s: each motor's share of them there
    smoothing_mm: float  # the largest distance of the shaped tool from the planned one at the same moment
    smoothing_at: np.ndarray  # (3,) mm: the planned point there
    smoothing_line: int  # its G-code line (0: none)


def shaped_window(window: Window, kin: Kinematics, settings: ShapingSettings, max_gap: float) -> ShapedWindow:
    """`max_gap` (s): the longest the player waits between two events."""
    planned = planned_motion(window.segments, window.plan)
    shaped = shape(planned, settings)
    blocks = shaped_blocks(shaped, window.segments, kin, max_gap)
    corners_t, jumps = shaped_corners(window.plan, kin, settings)
    worst, at, seg = smoothing(shaped, planned, settings)
    origin = blocks.pieces.origin[np.searchsorted(blocks.pieces.breaks, blocks.bounds[:-1])]
    shaped_plan = block_plan(blocks.chords, blocks.bounds)
    return ShapedWindow(Window(window.first, blocks.chords, blocks.steps, shaped_plan, window.curve_cut),
                        blocks.events, origin, blocks.pieces, corners_t, jumps, worst, at,
                        int(window.segments.line[seg]))


def block_plan(chords: Segments, bounds: np.ndarray) -> Plan:
    """The blocks as the reports read a plan: when each begins and how long it lasts (exact), its chord, and its
    mean speed (the events carry the shaped timing itself; nothing plans from this)."""
    length, direction = segment_lengths(chords)
    duration = np.diff(bounds)
    moving = chords.dwell <= 0
    speed = np.divide(length, duration, out=np.zeros(len(length)), where=moving & (duration > 0))
    zero = np.zeros(len(length))
    return Plan(length, direction, speed, speed, speed, np.ones(len(length)), zero, np.where(moving, length, 0.0),
                zero, np.where(moving, duration, 0.0), bounds[:-1].copy(), duration,
                np.ones(len(length) + 1, dtype=bool))


def shaped_corners(plan: Plan, kin: Kinematics, settings: ShapingSettings) -> tuple[np.ndarray, np.ndarray]:
    """The plan's corners (codegen/tables/checks.py `corner_jumps`) shaped: each axis's velocity jump splits into
    its shaper's impulses, a share A_i of it at tau_i after the corner (on the shaped clock); each motor takes
    its axes' shares (a corexy belt both of x and y, at their own times)."""
    j = np.flatnonzero(plan.corner[1:-1] & (plan.v_entry[1:] > 0)) + 1
    change = plan.v_entry[j][:, None] * (plan.direction[j] - plan.direction[j - 1])  # (J, 4) mm/s per axis
    per_axis = np.abs(kin.matrix.T * kin.limits.steps_per_mm[None, :])  # (4, M) steps per mm of each axis
    times, jumps = [], []
    for axis in range(AXES):
        for amplitude, tau in zip(*settings.offsets(axis)):
            times.append(plan.t_start[j] + settings.shift + tau)
            jumps.append(amplitude * np.abs(change[:, axis])[:, None] * per_axis[axis][None, :])
    t = np.concatenate(times)
    order = np.argsort(t, kind="stable")
    return t[order], np.concatenate(jumps)[order]

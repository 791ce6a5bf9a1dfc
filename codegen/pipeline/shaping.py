"""A window of the plan, shaped: the blocks of its shaped motion with their events, the corners the checks allow
for, and the smoothing (codegen/motion/shaped_motion.py, shaped_blocks.py); with pressure advance, its extruder
advanced (codegen/motion/advance.py).

The stages after the planner (codegen/pipeline/windows.py) then compress, play and check the blocks as they would
the plan's own segments (one straight segment a block); where the pulses break a limit, the plan's segments
under them are slowed and the window shaped again.

Windows stay windows. The shaped clock runs `shift` (the largest mean impulse time) behind the plan's, so the
shaped tool at a moment s reads the plan from s - spread to s at the latest: the window that ends at T is final
up to the shaped moment T. So each window plays the shaped motion from where the window before ended to where it
ends itself (the last one until the shaped motion rests), reading back into the plan before it for the shapers'
spread: a window hands the next that tail of its plan and the shaped tool's exact point at its end
(`ShapingTail`), and memory stays bounded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.advance import AdvanceReference, advance_reference, smooths
from codegen.motion.blocks import Events
from codegen.motion.lookahead import Window
from codegen.motion.planner import Plan, segment_lengths
from codegen.motion.shaped_blocks import shaped_blocks
from codegen.motion.shaped_motion import AXES, ShapingSettings, advanced, between, planned_motion, shape, smoothing
from codegen.toolpath.segments import Segments, concat


@dataclass
class ShapingTail:
    """What a shaped window hands the next: its plan's segments over the shapers' spread before its end (the next
    window's impulses read back into them), and the shaped tool's point at its end (the next one's first)."""

    segments: Segments
    plan: Plan
    point: np.ndarray  # (4,) mm
    smooth: bool  # the advanced extruder was smoothed: it stays so to the era's end (codegen/motion/advance.py)


@dataclass
class ShapedWindow:
    window: Window  # the blocks as straight segments, their steps and plan (on the shaped clock)
    events: Events  # the blocks' events, each where the shaped master crosses its half step
    origin: np.ndarray  # (n,) the plan's segment (of the window before shaping) under each block's start
    corners_t: np.ndarray  # (J,) s: where the plan's corners' velocity jumps land once shaped
    jumps: np.ndarray  # (J, M) steps/s: each motor's share of them there
    smoothing_mm: float  # the largest distance of the shaped tool from the planned one at the same moment
    smoothing_at: np.ndarray | None  # (3,) mm: the planned point there (None: nothing is shaped)
    smoothing_line: int  # its G-code line (0: none)
    tail: ShapingTail  # for the next window
    advance: AdvanceReference | None = None  # what the advanced extruder's pulses are held against; None: none


def shaped_window(window: Window, kin: Kinematics, settings: ShapingSettings, max_gap: float,
                  tail: ShapingTail | None, last: bool, settles: bool = False) -> ShapedWindow:
    """`max_gap` (s): the longest the player waits between two events; `tail`: the window before's (None: the
    program's first, or its shapers' era's); `last`: the program's last window (its shaped motion goes on until
    it rests); `settles`: its era's last, which ends in a rest at least the shapers' spread long (an M593's):
    the shaped motion comes to rest within the window and ends where the plan does."""
    segments, plan, before = window.segments, window.plan, 0
    if tail is not None:
        segments, plan, before = concat(tail.segments, segments), Plan.join([tail.plan, plan]), len(tail.segments)
    planned = planned_motion(segments, plan)
    shaped = shape(planned, settings)
    # Smoothed where some K is not 0, and from there on to the era's end (codegen/motion/advance.py).
    smooth = settings.advance is not None and ((tail is not None and tail.smooth) or smooths(planned.origin, segments))
    begin = window.plan.t_start[0]
    span = (begin, shaped.breaks[-1] if last else window.plan.total)
    # The smoothing is of x, y and z: measured before the advanced extruder's finer pieces join theirs.
    worst, at, seg = smoothing(between(shaped, *span), planned, settings) if settings.shaped else (0.0, None, 0)
    if settings.advance is not None:
        shaped = advanced(shaped, planned, segments, settings, smooth)
        span = (begin, shaped.breaks[-1] if last else window.plan.total)
    stretch = between(shaped, *span)
    start = segments.start[0] if tail is None else tail.point
    blocks = shaped_blocks(stretch, segments, kin, max_gap, start, segments.end[-1] if last or settles else None)
    corners_t, jumps = shaped_corners(plan, segments, kin, settings, smooth, before)
    origin = blocks.pieces.origin[np.searchsorted(blocks.pieces.breaks, blocks.bounds[:-1])]
    shaped_plan = block_plan(blocks.chords, blocks.bounds)
    reference = None if settings.advance is None else advance_reference(
        planned.breaks, planned.position[:, 3], planned.velocity[:, 3], planned.accel[:, 3], planned.origin, segments,
        settings.advance.half, settings.shift, (begin, stretch.breaks[-1]), smooth)
    handed = _tail(segments, plan, settings, blocks.chords.end[-1], smooth)
    return ShapedWindow(Window(window.first, blocks.chords, blocks.steps, shaped_plan, window.curve_cut),
                        blocks.events, np.maximum(origin - before, 0), corners_t, jumps, worst, at,
                        int(segments.line[seg]), handed, reference)


def _tail(segments: Segments, plan: Plan, settings: ShapingSettings, point: np.ndarray, smooth: bool) -> ShapingTail:
    """The segments that end within the shapers' spread before the plan's end, `point` and `smooth`."""
    first = int(np.searchsorted(plan.t_start + plan.duration, plan.total - settings.spread - 1e-9))
    first = min(first, len(plan.duration) - 1)
    part = Plan(**{name: getattr(plan, name)[first:] for name in Plan.__dataclass_fields__})
    return ShapingTail(segments.take(np.arange(first, len(segments))), part, point.copy(), smooth)


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


def shaped_corners(plan: Plan, segments: Segments, kin: Kinematics, settings: ShapingSettings,
                   smooth: bool, first: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The plan's corners (codegen/tables/checks.py `corner_jumps`) shaped: each axis's velocity jump splits into
    its shaper's impulses, a share A_i of it at tau_i after the corner (on the shaped clock); each motor takes
    its axes' shares (a corexy belt both of x and y, at their own times; a delta's carriage by its Jacobian at the
    corner). A smoothed extruder's velocity (`smooth`) has no jump: its smoothing spreads every change over the
    smoothing time. `first`: the window's first segment in `plan` (the tail of the window before comes first),
    whose junction with the one before is the window's too: windows end at corners."""
    j = np.flatnonzero(plan.corner[1:-1] & (plan.v_entry[1:] > 0)) + 1
    j = j[j >= first]
    change = plan.v_entry[j][:, None] * (plan.direction[j] - plan.direction[j - 1])  # (J, 4) mm/s per axis
    times, jumps = [], []
    for axis in range(AXES - 1 if smooth else AXES):
        per_mm = kin.motor_factors(np.tile(np.eye(AXES)[axis], (len(j), 1)), segments.start[j])
        per_axis = per_mm * kin.limits.steps_per_mm[None, :]  # (J, M) steps per mm of this axis at each corner
        for amplitude, tau in zip(*settings.offsets(axis)):
            times.append(plan.t_start[j] + settings.shift + tau)
            jumps.append(amplitude * np.abs(change[:, axis])[:, None] * per_axis)
    t = np.concatenate(times)
    order = np.argsort(t, kind="stable")
    return t[order], np.concatenate(jumps)[order]

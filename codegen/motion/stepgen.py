"""Step generation: the ideal time of every master event of every block.

Each moving segment is one block: its motors move by the differences of their positions rounded once at the
segment's ends. The master (the motor with most steps) steps when its ideal position along the segment
crosses a half-step point, as Klipper does; the other motors follow by Bresenham on the MCU. A dwell becomes a
block of step-less events that carry its time.
"""

from __future__ import annotations

import ctypes
from dataclasses import replace

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.blocks import Events, bresenham_init
from codegen.motion.curve_timing import CurveBlocks, curve_blocks, retime
from codegen.motion.planner import Plan
from codegen.native import contiguous, library, pointer
from codegen.toolpath.segments import Segments


def segment_steps(segments: Segments, kin: Kinematics) -> np.ndarray:
    return kin.to_steps(segments.end) - kin.to_steps(segments.start)


EVENT_CHUNK = 1 << 20  # events timed per pass (numpy): small temporaries are reused, large ones cost page faults


def generate(segments: Segments, plan: Plan, kin: Kinematics, steps: np.ndarray, max_gap: float,
             curves: bool = False, max_rate: np.ndarray | None = None) -> Events:
    """`steps` from `segment_steps`; `max_gap` (s) is the longest interval the player can wait between events;
    `curves`: events on curves are timed on the curve (codegen/motion/curve_timing.py) where that keeps every motor
    within `max_rate` (steps/s; default its limit). In one pass in C
    (codegen/native/eventtimes.c) where the helper could be built, else in numpy passes."""
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
    block_steps = np.where(dwell[blocks][:, None], 0, steps[blocks])
    modulus = np.where(dwell[blocks], 1, n_master[blocks])
    init = bresenham_init(exact[blocks], exact_end[blocks], master[blocks], block_steps, modulus)
    tool = segments.tool[blocks]
    curve = curve_blocks(blocks, block_steps, tool, segments, plan, kin, max_rate) if curves else None
    lib = library("eventtimes")
    if lib is not None:
        time, phase = _native_times(lib, segments, plan, crossing, blocks, count, curve)
        return Events(blocks, block_steps, modulus, init, tool, first, time, phase)
    time = np.empty(first[-1])
    phase = np.empty(first[-1], dtype=np.int8)
    cut = np.searchsorted(first, np.arange(0, first[-1], EVENT_CHUNK), side="right") - 1
    for lo, hi in zip(cut, np.append(cut[1:], len(blocks))):
        if hi > lo:
            span = slice(first[lo], first[hi])
            time[span], phase[span] = _times(segments, plan, crossing, blocks[lo:hi], count[lo:hi], dwell)
    events = Events(blocks, block_steps, modulus, init, tool, first, time, phase)
    return events if curve is None else replace(events, time=retime(events, curve, plan))


class _Crossings:
    """The master's exact positions (steps) at the ends of every segment and its direction."""

    def __init__(self, x0: np.ndarray, x1: np.ndarray, sign: np.ndarray):
        self.x0, self.span, self.p0, self.sign = x0, x1 - x0, np.round(x0), sign


def _native_times(lib, segments: Segments, plan: Plan, master: _Crossings, blocks: np.ndarray, count: np.ndarray,
                  curve: CurveBlocks | None) -> tuple[np.ndarray, np.ndarray]:
    events = int(count.sum())
    time, phase = np.empty(events), np.empty(events, dtype=np.int8)
    arrays = contiguous(np.int64, blocks, count)
    arrays += contiguous(np.float64, master.x0, master.span, master.p0, master.sign, plan.length, segments.dwell,
                         plan.v_entry, plan.v_peak, plan.accel, plan.s_acc, plan.s_cruise, plan.t_start)
    if curve is None:
        arrays += [None] * 8
    else:
        arrays += contiguous(np.uint8, curve.smooth, curve.has_prev, curve.has_next)
        arrays += contiguous(np.float64, curve.slope_in, curve.slope_out, curve.u0, curve.span, curve.sign)
    lib.event_times(ctypes.c_int64(len(blocks)), *map(pointer, arrays), pointer(time), pointer(phase))
    return time, phase


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

"""The program's items -> the planner's segments, a batch at a time: straight pieces within the tolerance,
none the player cannot play in one block, every point reachable and within each motor's `range`.

An unreachable point is an error at the shape or G-code line that leaves it (the first of each; at most 20
in all), reported once the whole program has been read (with its G-code errors, which come first); after the
first, no more segments go on to the planner.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Iterator, Mapping

import numpy as np

from codegen.errors import Diagnostic, JobError, SourceRef
from codegen.kinematics.base import Kinematics
from codegen.motion.planner import segment_lengths
from codegen.motion.shaped_motion import settle_time
from codegen.motion.staircase import refine, split_kinked, split_long
from codegen.motion.stepgen import segment_steps
from codegen.overlap import overlapped
from codegen.program.program import Program
from codegen.stopwatch import Stopwatch
from codegen.toolpath.items import Lines
from codegen.toolpath.segments import Flattener, Segments

REACH_SAMPLES = 16  # points along each piece where the kinematics is not linear
MAX_REACH_ERRORS = 20
CHUNK_EVENTS = 1 << 17


@dataclass(frozen=True)
class FrontEndSettings:
    """What the front end needs of the machine: how far a piece may stray from the path, and each motor's range."""

    tolerance_mm: float  # machine.tolerance
    ranges: Mapping[str, tuple[float, float] | None]  # stepper name -> its `range` (mm of motor travel), None: any
    advance: float = 0.0  # s, the pressure advance K the program starts with (M900/M572 change it)
    smooth_time: float = 0.0  # s, pressure advance's smoothing (0: none): an M593's rest lets it settle too


def front_end(settings: FrontEndSettings, kin: Kinematics, program: Program,
              watch: Stopwatch) -> Iterator[tuple[Segments, np.ndarray]]:
    """`pieces`, made in a child process on another core where there is one (codegen/overlap.py); `program`
    knows what the child's copy of it knew when each part was made, `watch` gets its stages' times."""
    def produce():
        own = Stopwatch()
        for part in pieces(settings, kin, program, own):
            yield part, program.state(), None
        yield None, program.state(), own.seconds

    for part, state, seconds in overlapped(produce):
        program.restore(state)
        if part is not None:
            yield part
        else:
            watch.merge(seconds, "front end: ")


def pieces(settings: FrontEndSettings, kin: Kinematics, program: Program,
           watch: Stopwatch | None = None) -> Iterator[tuple[Segments, np.ndarray]]:
    """Segments and their motor steps, a batch of the program's items at a time."""
    watch = watch or Stopwatch()
    flattener, problems = None, []
    batches = program.batches()
    while True:
        with watch("read the program"):
            batch = next(batches, None)
        if batch is None:
            break
        with watch("segments"):
            if flattener is None:
                flattener = Flattener(program.start, settings.tolerance_mm, program.plays_runtime, program.gcode_file,
                                      partial(settle_time, smooth_time=settings.smooth_time), settings.advance)
            first = flattener.items
            segments = drop_empty(flattener(batch))
            program.settings += flattener.settings
            program.shapings += flattener.shapings
            flattener.settings, flattener.shapings = [], []
            found = reach_problems(settings, kin, batch, first, segments)
            if not found:
                segments = kin.subdivide(segments, settings.tolerance_mm)
                segments = refine(split_long(split_kinked(segments, kin), kin), kin)
                found = reach_problems(settings, kin, batch, first, segments)  # a carriage may peak between samples
            problems += found
            parts = [] if problems or not len(segments) else _parts(segments, segment_steps(segments, kin))
        was, now = program.handed_on, program.read_share
        for part in parts:  # each hands on the batch's share up to its last item
            program.handed_on = was + (now - was) * (int(part[0].item[-1]) + 1 - first) / (flattener.items - first)
            yield part
        program.handed_on = now
    if problems:
        raise JobError(sorted(problems, key=lambda d: (d.where.file, d.where.line, d.where.col))[:MAX_REACH_ERRORS])


def _parts(segments: Segments, steps: np.ndarray) -> list[tuple[Segments, np.ndarray]]:
    """Parts of about CHUNK_EVENTS master steps: the windows after the planner, and their memory, stay small."""
    events = np.cumsum(np.abs(steps).max(axis=1, initial=0))
    cuts = np.searchsorted(events, np.arange(CHUNK_EVENTS, events[-1], CHUNK_EVENTS), side="right")
    return [(segments.take(part), steps[part])
            for part in np.split(np.arange(len(segments)), np.unique(cuts[(cuts > 0) & (cuts < len(segments))]))]


def drop_empty(segments: Segments) -> Segments:
    """Remove moves of zero length (nothing to plan, nothing to step)."""
    length, _ = segment_lengths(segments)
    keep = (length > 0) | (segments.dwell > 0)
    if np.all(keep):
        return segments
    return segments.take(np.flatnonzero(keep))


def reach_problems(settings: FrontEndSettings, kin: Kinematics, batch: list, offset: int,
                   segments: Segments) -> list[Diagnostic]:
    """Every point of the path reachable and within each motor's `range`: an error at the item (of `batch`,
    whose first is the program's item `offset`) that leaves it, at its first such point."""
    if not len(segments):
        return []
    # Every piece's end; where motors are not linear in the axes (a delta's carriages rise and fall along a
    # straight line) also points along each piece.
    share = np.linspace(0.0, 1.0, 2 if kin.linear else REACH_SAMPLES + 1)[1:]
    points = np.concatenate([segments.start[:1], (segments.start[:, None, :] + share[None, :, None] * (
        segments.end - segments.start)[:, None, :]).reshape(-1, 4)])
    items = np.concatenate([segments.item[:1], np.repeat(segments.item, len(share))])
    motor = kin.to_motor(points)
    ends = np.concatenate([segments.end[:1], np.repeat(segments.end, len(share), axis=0)])
    at = lambda p: ", ".join(f"{c:.3f}" for c in p[:3])  # noqa: E731
    problems = [(np.flatnonzero(kin.unreachable(points)),
                 lambda k: f"the machine cannot reach ({at(points[k])})" + (
                     "" if np.allclose(points[k], ends[k]) else f" on the way to ({at(ends[k])})"))]
    for m, name in enumerate(kin.motors):
        span = settings.ranges[name]
        if span:
            outside = np.flatnonzero((motor[:, m] < span[0] - 1e-9) | (motor[:, m] > span[1] + 1e-9))
            problems.append((outside, lambda k, m=m, name=name, span=span:
                             f"motor {name} would go to {motor[k, m]:.3f} mm, outside its range "
                             f"[{span[0]:g}, {span[1]:g}]"))
    diagnostics = []
    for where, message in problems:
        _, first = np.unique(items[where], return_index=True)
        diagnostics += [Diagnostic(source_of(batch, items[k] - offset), message(k))
                        for k in where[np.sort(first)][:MAX_REACH_ERRORS]]
    return diagnostics


def source_of(batch: list, index: int) -> SourceRef:
    """Where item `index` of the batch comes from (a Lines item counts as its moves)."""
    for item in batch:
        count = len(item) if isinstance(item, Lines) else 1
        if index < count:
            return item.source(index) if isinstance(item, Lines) else item.source
        index -= count
    raise IndexError(index)

"""The twin a chapter at a time: consecutive final windows of a plan (codegen/pipeline/windows.py Played, as
host_build's `observe` hands them on) joined into chapters of about CHAPTER_PULSES pulses, so that verify compares
a print of any length in bounded memory (codegen/verify/compare.py Comparison).

A chapter's indices (segments, blocks, events) count from its own first; its ticks and positions are the program's.
It knows the segment before it and the one after it (the path check measures steps near its ends against them),
and the runtime records so far are on the twin's clock (`Chapters.timeline`: the heaters' targets and waits).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from codegen.motion.advance import AdvanceReference
from codegen.motion.blocks import Events
from codegen.motion.planner import Plan
from codegen.pipeline.join import join_compressed, join_events, join_plan, join_pulses, join_segments
from codegen.pipeline.windows import Played
from codegen.tables.compress import Compressed
from codegen.tables.laser import played_counts
from codegen.tables.schedule import RT_WAIT, Schedule
from codegen.tables.twin import Pulses
from codegen.toolpath.segments import Segments

CHAPTER_PULSES = 1 << 18  # about 50 MB of working arrays in the comparison


@dataclass
class RuntimeTimeline:
    """Runtime records in order, each at the twin's tick of the last event before its block (0 before the first):
    where the player reads it."""

    command: np.ndarray  # (T,) RT_*
    value: np.ndarray  # (T,)
    tick: np.ndarray  # (T,) int64

    @staticmethod
    def of(schedule: Schedule, event_tick: np.ndarray, origin_tick: int = 0) -> RuntimeTimeline:
        """The records of `schedule` (its events at `event_tick`; `origin_tick`: the last event's before it)."""
        first = np.concatenate([[0], np.cumsum(schedule.events_per_block())])[schedule.runtime_block]
        before = np.concatenate([[origin_tick], event_tick]).astype(np.int64)
        return RuntimeTimeline(schedule.runtime_command.copy(), schedule.runtime_value.copy(), before[first])

    @staticmethod
    def join(parts: list[RuntimeTimeline]) -> RuntimeTimeline:
        if not parts:
            return RuntimeTimeline(*(np.zeros(0, np.int64) for _ in range(3)))
        return RuntimeTimeline(*(np.concatenate([getattr(p, k) for p in parts]) for k in ("command", "value", "tick")))

    def waits(self) -> np.ndarray:
        return np.flatnonzero(self.command == RT_WAIT)


@dataclass
class Chapter:
    segments: Segments
    plan: Plan
    events: Events
    pulses: Pulses  # ticks absolute; event and event_block counted from the chapter's first
    compressed: Compressed
    before: Segments | None  # the last segment before the chapter (None: it begins the program)
    after: Segments | None  # the first segment after it (None: it ends the program)
    first_event: int  # the program's index of its first event
    laser_before: int  # the PWM counts in force when it begins
    last: bool
    planned: tuple[Segments, Plan] | None = None  # a shaped job's segments and plan before shaping
    advance: list[AdvanceReference] = field(default_factory=list)  # its windows' pressure advance formulas

    @property
    def schedule(self) -> Schedule:
        return self.compressed.schedule

    def event_segments(self) -> np.ndarray:
        """The segment (of the chapter's) every event belongs to."""
        block = np.searchsorted(self.events.block_first, np.arange(len(self.events.time)), side="right") - 1
        return self.events.block_segment[block]


def whole_chapter(host, pulses: Pulses | None = None) -> Chapter:
    """A kept host build's whole program as one chapter (with `pulses`: a held run's dilated twin instead)."""
    return Chapter(host.segments, host.plan, host.events, pulses or host.pulses, host.compressed, None, None, 0, 0,
                   True, host.planned)


class Chapters:
    """host_build's `observe`: final windows joined into chapters, each handed to `sink` once the window after it
    has come (or `close`d: the last)."""

    def __init__(self, sink: Callable[[Chapter], None], size: int = CHAPTER_PULSES):
        self.sink, self.size = sink, size
        self.pending: list[Played] = []
        self.pending_pulses = 0
        self.full: list[Played] | None = None  # a chapter's windows, waiting for the segment after them
        self.before: Segments | None = None
        self.events = 0
        self.laser = 0
        self.records: list[RuntimeTimeline] = []  # every window's so far

    def timeline(self) -> RuntimeTimeline:
        """The runtime records of every window so far (the chapters handed out and those after them)."""
        if len(self.records) > 1:
            self.records = [RuntimeTimeline.join(self.records)]
        return RuntimeTimeline.join(self.records)

    def __call__(self, played: Played) -> None:
        self.records.append(RuntimeTimeline.of(played.table_schedule, played.pulses.event_tick,
                                               played.origin_fx >> 8))
        if self.full is not None and len(played.window.segments):
            self._hand(self.full, played.window.segments.take(np.arange(1)), False)
            self.full = None
        self.pending.append(copy.copy(played))  # the stages drop its pulses and events once it is observed
        self.pending_pulses += len(played.pulses.tick)
        if self.pending_pulses >= self.size and self.full is None:
            self.full, self.pending, self.pending_pulses = self.pending, [], 0

    def close(self) -> None:
        if self.full is not None:
            after = self.pending[0].window.segments.take(np.arange(1)) if self.pending else None
            self._hand(self.full, after, not self.pending)
        if self.pending or self.full is None:
            self._hand(self.pending, None, True)
        self.full, self.pending = None, []

    def _hand(self, windows: list[Played], after: Segments | None, last: bool) -> None:
        if not windows:
            return
        pulses = join_pulses(windows)
        segments = join_segments(windows)
        compressed = join_compressed(windows, False, pulses)
        planned = None
        if any(w.planned is not None for w in windows):  # an unshaped era's windows are their own plan
            planned = join_segments(windows, planned=True), join_plan(windows, planned=True)
        chapter = Chapter(segments, join_plan(windows), join_events(windows), pulses, compressed, self.before, after,
                          self.events, self.laser, last, planned,
                          [w.advance for w in windows if w.advance is not None])
        self.events += len(pulses.event_tick)
        if len(compressed.schedule.run_power):
            counts = played_counts(compressed.schedule, self.laser)
            self.laser = int(counts[-1]) if len(counts) else self.laser
        n = len(segments)
        self.before = segments.take(np.arange(n - 1, n)) if n else self.before
        self.sink(chapter)

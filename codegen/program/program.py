"""The program as a stream of toolpath items: its shapes or its G-code (read a batch at a time), where it
starts, and what homing does to it.

Homing before the first move is the firmware's (at power-up) and says where the program starts. A later G28
becomes a straight tool-off move to the home position (homing in the middle of a table is not supported
yet). On a machine that homes at power-up whatever its program says (a delta, or `program.home`), the
program starts where homing leaves the tool; an explicit `program.start` there is where the program begins,
after a tool-off travel move from the home position (on a delta straight down first: its carriages stand at
their tops).
"""

from __future__ import annotations

import math
from dataclasses import replace
from itertools import chain
from typing import Iterator

import numpy as np

from codegen.errors import Diagnostic
from codegen.gcode import GcodeStream
from codegen.kinematics.base import Kinematics
from codegen.program.heaters import HeaterProgram
from codegen.program.homing import HomingSettings, homes
from codegen.shapes import build_toolpath as toolpath_from_shapes
from codegen.toolpath.items import Arc, Curve, Home, Line, Lines, Toolpath, expanded

MOTION = (Line, Lines, Arc, Curve)


class Program:
    """`batches()` yields the items; `start`, `homes_first` and `end` are known once the first batch (for
    `end`: the last) is out, `warnings` and `heater_program` (its heater settings) once every batch is.
    `plays_runtime`: the player plays heater and fan settings at their place (codegen/motion/pieces.py gathers them
    into `settings` as (item index, Output) while it flattens, and a wait rests the plan). `handed_on`: the
    share of the program (0..1) whose segments codegen/motion/pieces.py has handed on, for a progress bar."""

    def __init__(self, job, kin: Kinematics, homing: HomingSettings, strict: bool = False):
        """`job` goes on to the G-code reader and the shapes (codegen/gcode, codegen/shapes); homing and the
        machine's kinematics come in `homing` and `kin`."""
        self.job, self.kin, self.homing = job, kin, homing
        self.always_homes = homes(homing, False)
        self.home = np.array([*job.machine.home_point, 0.0]) if self.always_homes else None
        if self.always_homes:
            start = self.home.copy()
            if job.program.start_source is not None:
                start[:len(job.program.start)] = [float(v) for v in job.program.start]
            self.anchor = start
            job = job.model_copy(update={"program": job.program.model_copy(update={"start": tuple(start[:3])})})
        self.gcode = None if job.program.shapes else GcodeStream(job, strict)
        self.anchored_job = job
        self.start: np.ndarray | None = None
        self.end: np.ndarray | None = None
        self.homes_first = False
        self.heater_program = HeaterProgram()
        self.plays_runtime = False
        self.settings: list = []  # (item index, Output), in program order
        self.shapings: list = []  # the M593s' InputShaping items, in program order: era k begins after the k-th
        self.handed_on = 0.0
        self._warnings: list[Diagnostic] | None = None  # as a child process read them (`restore`)

    @property
    def warnings(self) -> list[Diagnostic]:
        if self._warnings is not None:
            return self._warnings
        return [] if self.gcode is None else self.gcode.warnings

    def state(self) -> tuple:
        """What the batches have found out so far, for a copy of the program in another process."""
        return (self.start, self.end, self.homes_first, self.heater_program, list(self.warnings), self.settings,
                self.handed_on, self.shapings)

    def restore(self, state: tuple) -> None:
        (self.start, self.end, self.homes_first, self.heater_program, self._warnings, self.settings,
         self.handed_on, self.shapings) = state

    @property
    def gcode_file(self) -> str | None:
        """The file its G-code lines are written in (the job file's for inline G-code), if it has any."""
        return None if self.gcode is None else self.gcode.origin.file

    @property
    def read_share(self) -> float:
        """The share of the program's text read into the batches so far (shapes: all of it, in one batch)."""
        return 1.0 if self.gcode is None else self.gcode.read_share

    def batches(self) -> Iterator[list]:
        raw = self._raw()
        first: list = []
        for batch in raw:  # up to the first motion: whether the program homes first
            first += batch
            if any(isinstance(item, (*MOTION, Home)) for item in first):
                break
        start = self.gcode.start if self.gcode is not None else self._shapes_start
        settle = _SettleHomes(start)
        first = settle(first)
        self.heater_program.feed(first)  # in the program's order: before a travel from home below
        self.homes_first, start = settle.homes_first, settle.start
        if self.always_homes:
            first, start = self._from_home(first, start)
        self.start = np.asarray(start, dtype=float)
        self.end = self.start
        for batch in chain([first], map(self._fed_to_heater_program, map(settle, raw))):
            for item in reversed(batch):
                if isinstance(item, MOTION):
                    self.end = item.end
                    break
            if batch:
                yield batch

    def _fed_to_heater_program(self, batch: list) -> list:
        self.heater_program.feed(batch)
        return batch

    def _raw(self) -> Iterator[list]:
        if self.gcode is not None:
            yield from self.gcode.batches()
            return
        toolpath = toolpath_from_shapes(self.anchored_job)
        self._shapes_start = toolpath.start
        yield toolpath.items

    def _from_home(self, items: list, start: np.ndarray) -> tuple[list, np.ndarray]:
        """The items of a machine that homes at power-up: from the home position to where the program starts."""
        home, target = self.home, self.anchor
        if not self.homes_first and np.linalg.norm(target - home) > 1e-9:
            feed = math.inf if self.job.program.travel_feed is None else self.job.program.travel_feed / 60.0
            items = [Line(home, target.copy(), feed, False, self.job.program.start_source, "travel"), *items]
            start = home
        if self.homing.kinematics == "delta" and items:
            if isinstance(items[0], Lines):
                items[:1] = items[0].split_first()
            items[:1] = descend_first(items[0], home)
        return items, start


def descend_first(item, home: np.ndarray) -> list:
    """A delta's carriages stand at their tops once homed: the travel away from home goes straight down to its
    end's height first (every carriage moves down alike), then across."""
    if not (isinstance(item, Line) and not item.tool and np.allclose(item.start, home)):
        return [item]
    below = home.copy()
    below[2] = item.end[2]
    if item.end[2] >= home[2] or np.allclose(below[:2], item.end[:2]):
        return [item]
    return [replace(item, end=below), replace(item, start=below)]


class _SettleHomes:
    """Homes in the item stream: the first, before any move, sets the start; later ones become lines home."""

    def __init__(self, start: np.ndarray):
        self.start, self.here, self.homes_first = np.asarray(start, dtype=float), None, False

    def __call__(self, items: list) -> list:
        out = []
        for item in items:
            if isinstance(item, Home):
                if self.here is None:
                    self.start, self.homes_first = item.position, True
                    continue
                item = Line(self.here, item.position, math.inf, False, item.source, "home")
            if isinstance(item, MOTION):
                self.here = item.end
            out.append(item)
        return out


def whole_toolpath(job, kin: Kinematics, homing: HomingSettings,
                   strict: bool = False) -> tuple[Toolpath, list[Diagnostic], bool]:
    """Every item at once: the toolpath, the front end's warnings, and whether it starts by homing (G28)."""
    program = Program(job, kin, homing, strict)
    items = expanded([item for batch in program.batches() for item in batch])
    start = program.start if program.start is not None else np.zeros(4)
    return Toolpath(start, items), program.warnings, program.homes_first

"""The job file's models (pydantic v2): machine, steppers, delta geometry, program and its shapes.

Every error a model raises is worded for people (the loader adds file:line:col and the dotted path). The
checks that span several keys (the motors of a kinematics, `delta:` only with delta kinematics, exactly one of
`shapes` and `gcode`) run in loader.py over the parsed YAML, so they are reported even when other values in
the same mapping are wrong. `source`, `gcode_source` and `path` are set by the loader.

The models live by part: fields.py (the field types and sane ranges), machine.py, heaters.py, shapes.py,
shaping.py (the input shaper), advance.py (pressure advance); the program and the job here. Everything is
imported from here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

from pydantic import Field, PrivateAttr, field_validator, model_validator

from codegen.errors import SourceRef
from codegen.job.schema.advance import DEFAULT_SMOOTH_TIME, PressureAdvance
from codegen.job.schema.fields import (DEFAULT_BOARDS, KINEMATICS, MOTORS, REACH_MM, REQUIRED_MOTORS, TARGETS, Flag,
                                       Model, Point, Positive, Text, choice, fail)
from codegen.job.schema.heaters import (DEFAULT_MAX_TEMP_C, DEFAULT_SENSOR, HEATERS, BangBang, Control, CustomSensor,
                                        Heater, PidGains, PlantOverrides)
from codegen.job.schema.machine import Delta, FeedHold, Homing, Jog, Laser, Link, Machine, Stepper
from codegen.job.schema.shapes import (SHAPES, Arc, Circle, Ellipse, Function, Line, Points, Polyline, Shape, ShapeItem,
                                       Sine, Travel)
from codegen.job.schema.shaping import SHAPED_AXES, SHAPER_MAX_DAMPING, AxisShaper, InputShaper

__all__ = [
    "TARGETS", "DEFAULT_BOARDS", "KINEMATICS", "MOTORS", "REQUIRED_MOTORS", "HEATERS", "DEFAULT_SENSOR",
    "DEFAULT_MAX_TEMP_C", "SHAPES", "Job", "Program", "Machine", "Stepper", "Delta", "Homing", "Link", "Laser", "Jog",
    "FeedHold", "Heater", "CustomSensor", "PidGains", "BangBang", "Control", "PlantOverrides", "Shape", "Line",
    "Polyline", "Points", "Arc", "Circle", "Ellipse", "Sine", "Function", "Travel", "InputShaper", "AxisShaper",
    "SHAPED_AXES", "SHAPER_MAX_DAMPING", "PressureAdvance", "DEFAULT_SMOOTH_TIME",
]


class Program(Model):
    start: Point = (0.0, 0.0)
    feed: Positive = 1200.0  # mm/min
    travel_feed: Optional[Positive] = None  # mm/min; None: as fast as the machine allows
    s_max: Optional[Positive] = None  # the G-code S of full power; default per dialect: 255 (Marlin), 1000 (Grbl's $30)
    dialect: Optional[choice("marlin", "grbl")] = None  # type: ignore[valid-type]  # None: guessed from the G-code
    home: Flag = False  # home at power-up before the program (delta machines always do)
    shapes: Optional[Annotated[list[ShapeItem], Field(min_length=1)]] = None
    gcode: Optional[Text] = None  # a path relative to the job file, or the G-code itself
    _gcode_source: SourceRef = PrivateAttr(default_factory=lambda: SourceRef("<gcode>"))
    _start_source: Optional[SourceRef] = PrivateAttr(default=None)

    @property
    def start_source(self) -> Optional[SourceRef]:
        """Where the job file gives `start`; None when it does not (the default applies)."""
        return self._start_source

    @start_source.setter
    def start_source(self, value: Optional[SourceRef]) -> None:
        self._start_source = value

    @field_validator("start")
    @classmethod
    def _within_reach(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if any(not abs(c) <= REACH_MM for c in v):  # every position the program reaches from it is checked so
            raise fail("range", f"must be within {REACH_MM:g} mm of the origin (100 m is beyond any machine)")
        return v

    @property
    def gcode_source(self) -> SourceRef:
        """Where the G-code starts: its first line for inline G-code, else the path's value in the job file."""
        return self._gcode_source

    @gcode_source.setter
    def gcode_source(self, value: SourceRef) -> None:
        self._gcode_source = value


class Job(Model):
    name: Text = "job"  # the loader defaults it to the file's stem
    target: choice(*TARGETS) = "avr"  # type: ignore[valid-type]
    board: Text = DEFAULT_BOARDS["avr"]  # default: per target
    machine: Machine
    program: Optional[Program] = None  # only `build --stream` goes without one (load_job checks)
    _path: Path = PrivateAttr(default_factory=Path)

    @property
    def path(self) -> Path:
        """The job file's absolute path."""
        return self._path

    @path.setter
    def path(self, value: Path) -> None:
        self._path = value

    @model_validator(mode="before")
    @classmethod
    def _default_board(cls, data: Any) -> Any:
        target = data.get("target", "avr") if isinstance(data, dict) else None
        if isinstance(target, str) and "board" not in data and target in DEFAULT_BOARDS:  # else: the target's error
            data = {**data, "board": DEFAULT_BOARDS[target]}
        return data

    @field_validator("name")
    @classmethod
    def _file_name(cls, v: str) -> str:
        if any(c in v for c in "/\\\0") or v in (".", ".."):
            raise fail("name", "must be usable as a folder name (no '/' or '\\')")
        if any(not c.isprintable() for c in v):  # an ESC would send terminal codes with every summary printed
            raise fail("name", "must be printable text (no control characters)")
        return v

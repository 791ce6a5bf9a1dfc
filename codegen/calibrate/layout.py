"""Where a calibration pattern goes on the machine, how fast it is drawn, and its G-code.

A printer (a machine with z and an extruder; a delta's carriages give it z) prints the pattern: lines of
LINE_WIDTH_MM at the layer height, the extruder moving as much filament as fills them (relative E, M83). Any other
machine draws it with its tool (M3 down or on, M5 up or off; G0 travels with the tool off), a delta on the bed (z
0: it starts at its top, where only the bed's middle is reachable). The pattern is centred on the middle of the x
and y motors' ranges where the machine gives them (cartesian), on a delta at the bed's middle, else beside where
the program starts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

FILAMENT_MM = 1.75  # diameter
LINE_WIDTH_MM = 0.45  # a 0.4 mm nozzle's line
EDGE_MM = 5.0  # from where the program starts to the pattern, when the machine gives no ranges to centre it in
DELTA_DRAW_Z = 0.0  # mm: where a delta without an extruder draws (the bed)


@dataclass(frozen=True)
class Band:
    """A stretch of the print with one value of the setting: from `begin` to `end` (mm of height, or of y)."""

    value: float
    begin: float
    end: float


@dataclass(frozen=True)
class Calibration:
    """The G-code, its bands in order, and what the bands measure."""

    gcode: str
    bands: tuple[Band, ...]
    place: str  # "height z" or "y": what a band's begin and end are
    setting: str  # "M593 F (Hz)" or "M900 K (s)"

    def table(self) -> str:
        """One line per band: where it is and its value, as the user reads it off the print (a band of no
        extent, a line, by its place alone)."""
        spans = any(band.end != band.begin for band in self.bands)
        head = f"{self.place + ' from (mm)':>16}  {'to (mm)':>8}" if spans else f"{self.place + ' (mm)':>16}"
        rows = [f"{'band':>4}  {head}  {self.setting}"]
        for k, band in enumerate(self.bands):
            where = f"{band.begin:>16.2f}  {band.end:>8.2f}" if spans else f"{band.begin:>16.2f}"
            rows.append(f"{k + 1:>4}  {where}  {number(band.value)}")
        return "\n".join(rows)


def values(start: float, end: float, step: float) -> list[float]:
    """start, start + step, ... up to end (within a millionth of a step), rounded to 6 decimals: no drift."""
    count = math.floor((end - start) / step + 1e-6) + 1
    return [round(start + k * step, 6) for k in range(count)]


def number(value: float) -> str:
    """A G-code number: at most 4 decimals, no trailing zeros, never -0."""
    text = f"{value:.4f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


@dataclass(frozen=True)
class Placement:
    center: tuple[float, float]  # mm, the pattern's middle
    start: tuple[float, ...]  # where the program starts
    printer: bool  # the machine has z and an extruder: it prints, else it draws
    top_speed: float  # mm/s: the slowest x or y motor's (a corexy's belts: a and b; a delta's carriages)
    draw_z: float | None = None  # mm: the height a machine that draws goes down to first (a delta's); None: stays


def placement(machine, start, size: tuple[float, float]) -> Placement:
    """Where a pattern of `size` (mm, x by y) goes on `machine` (the job's) whose program starts at `start`."""
    steppers = machine.steppers
    xy = [name for name in ("x", "y", "a", "b", "c") if name in steppers]
    top_speed = min(float(steppers[name].max_velocity) for name in xy)
    ranges = [steppers[name].range for name in ("x", "y")] if machine.kinematics == "cartesian" else [None]
    if machine.kinematics == "delta":
        center = (0.0, 0.0)  # the bed's middle, under the towers' centre
    elif all(r is not None for r in ranges):
        center = tuple((lo + hi) / 2.0 for lo, hi in ranges)
    else:
        center = (start[0] + EDGE_MM + size[0] / 2.0, start[1] + EDGE_MM + size[1] / 2.0)
    delta = machine.kinematics == "delta"
    printer = "e" in steppers and ("z" in steppers or delta)
    return Placement((float(center[0]), float(center[1])), tuple(float(v) for v in start), printer, top_speed,
                     DELTA_DRAW_Z if delta else None)


class Writer:
    """G-code lines, written as a slicer writes them: absolute coordinates, relative E, feeds in mm/min."""

    def __init__(self, title: str, printer: bool):
        self.lines = [f"; {title}", "G21", "G90"] + (["M83"] if printer else [])
        self.printer = printer
        self.tool = False

    def comment(self, text: str) -> None:
        self.lines.append(f"; {text}")

    def code(self, text: str) -> None:
        self.lines.append(text)

    def travel(self, x: float, y: float, z: float | None = None) -> None:
        """A tool-off move (a drawing machine's tool goes up first)."""
        if self.tool and not self.printer:
            self.code("M5")
            self.tool = False
        self.code(_move("G0", x=x, y=y, z=z))

    def draw(self, x: float, y: float, length: float, speed: float, layer: float = 0.0) -> None:
        """A line to (x, y) of `length` mm at `speed` mm/s: extruded at `layer` mm high, or drawn with the tool."""
        if self.printer:
            self.code(_move("G1", x=x, y=y, e=length * layer * LINE_WIDTH_MM / (math.pi * FILAMENT_MM ** 2 / 4),
                            f=speed * 60.0))
            return
        if not self.tool:
            self.code("M3")
            self.tool = True
        self.code(_move("G1", x=x, y=y, f=speed * 60.0))

    def lift(self, z: float) -> None:
        self.code(_move("G0", z=z))

    def text(self) -> str:
        if self.tool:
            self.code("M5")
            self.tool = False
        return "\n".join(self.lines) + "\n"


def _move(code: str, **words: float | None) -> str:
    return " ".join([code] + [f"{letter.upper()}{number(value)}" for letter, value in words.items()
                              if value is not None])

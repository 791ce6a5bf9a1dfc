"""A program's heater and fan settings (codegen.toolpath.items.Output: M104 / M109 hot end, M140 / M190 bed, M106 /
M107 fan), collected as its batches go by, and what a build says about them.

An AVR flash image plays every setting at its place in the tables (codegen/tables/runtime.py); this module only knows
which outputs the program sets, for the heaters an image runs and for the build's notes and warnings (a board
without heater outputs, a streaming firmware without heaters, a heater the machine does not have).

    collector = HeaterProgram()
    for batch in batches: collector.feed(batch)          # codegen/program/program.py does this, in the front end's process
    collector.first                                     # {"hotend": Output(...), ...}: each heater's first setting
    heater_diagnostics(board, machine_heaters, board_heaters, collector, streamed)  # the notes and warnings
"""

from __future__ import annotations

from dataclasses import dataclass, field

from codegen.errors import Diagnostic
from codegen.heaters.control import DEFAULT_CONTROL
from codegen.job.schema import DEFAULT_SENSOR, HEATERS, Heater
from codegen.toolpath.items import Output

CODES = {("hotend", False): "M104", ("hotend", True): "M109", ("bed", False): "M140", ("bed", True): "M190"}


@dataclass
class HeaterProgram:
    """The heater and fan settings of a program's items, fed batch by batch in program order."""

    first: dict[str, Output] = field(default_factory=dict)  # each heater's first setting, in program order
    sets_fan: bool = False  # the program sets the fan (M106 / M107)

    def feed(self, items: list) -> None:
        for item in items:
            if isinstance(item, Output) and item.name in HEATERS:
                self.first.setdefault(item.name, item)
            elif isinstance(item, Output) and item.name == "fan":
                self.sets_fan = True


def code(item: Output) -> str:
    return CODES[item.name, item.wait]


def _defaults() -> str:
    """The board's default heaters in words (codegen.program.heater_settings)."""
    pid, bang = DEFAULT_CONTROL["hotend"]["pid"], DEFAULT_CONTROL["bed"]["bang_bang"]
    pullup_k = Heater.model_fields["pullup_ohm"].default / 1000
    return (f"hotend and bed: {DEFAULT_SENSOR} on a {pullup_k:g} kOhm pull-up; hot end PID kp {pid['kp']:g}, "
            f"ki {pid['ki']:g}, kd {pid['kd']:g}; bed bang-bang {bang['hysteresis_c']:g} degC")


def heater_diagnostics(board: str, machine_heaters: tuple[str, ...] | None, board_heaters: dict,
                       program: HeaterProgram, streamed: bool) -> list[Diagnostic]:
    """What a build says about the program's heaters, once each, at the G-code that sets them: the board's
    defaults in use (a machine without `heaters:`), settings the image does not play (a board without heater
    outputs, such as the 8051 boards; a heater the machine does not list; `streamed`: a streaming firmware that
    runs no heaters). `board`: the board's name; `machine_heaters`: the heaters of the machine's `heaters:`
    section (None without one)."""
    if not program.first:
        return []
    first = next(iter(program.first.values()))
    where, named = first.source, code(first)
    if not board_heaters:
        return [Diagnostic(where, f"'{named}' ignored (board {board} has no heater outputs: every heater "
                                  "setting of the program is ignored)", "warning")]
    if streamed:
        return [Diagnostic(where, f"'{named}' ignored (the machine's streaming firmware runs heaters only for a "
                                  "machine with an extruder e or a `heaters:` section: every heater setting of the "
                                  "program is ignored)", "warning")]
    out = []
    if machine_heaters is None:
        out.append(Diagnostic(where, f"the machine has no `heaters:` section: board {board}'s defaults are "
                                     f"used ({_defaults()})", "note"))
    listed = HEATERS if machine_heaters is None else machine_heaters
    for name, item in program.first.items():
        if name not in listed or name not in board_heaters:
            out.append(Diagnostic(item.source, f"'{code(item)}' ignored (the machine has no {name} heater: every "
                                               f"{name} setting of the program is ignored)", "warning"))
    return out

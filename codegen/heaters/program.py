"""A program's heater settings (codegen.toolpath.Output: M104 / M109 hot end, M140 / M190 bed), collected as its
batches go by, and what a build says about them.

The flash image plays a program's heaters as a start sequence until the tables carry them: per heater the target
set before the first move (the last one there wins; homing is the firmware's, before the table, so G28 is not a
move), whether any of those waits (M109 / M190: the table starts once the heater has settled), and whether the
program's last setting is 0 (the heater goes off when the table has played). A setting between moves, or a
non-zero one after the last move, is not played, and the build warns at the first; one that repeats the start
target (a sliced file's M109 S205 after its M104 S205 and a move) changes nothing and is not warned about.

    collector = HeaterProgram()
    for batch in batches: collector.feed(batch)          # codegen/program.py does this, in the front end's process
    collector.start                                     # {"hotend": HeaterStart(195.0, True, True), ...}
    heater_diagnostics(job, board_heaters, collector, streamed)   # the build's notes and warnings
"""

from __future__ import annotations

from dataclasses import dataclass, field

from codegen.errors import Diagnostic
from codegen.heaters.control import DEFAULT_CONTROL
from codegen.job.schema import DEFAULT_SENSOR, HEATERS, Heater
from codegen.toolpath import Move, Output

CODES = {("hotend", False): "M104", ("hotend", True): "M109", ("bed", False): "M140", ("bed", True): "M190"}


@dataclass
class HeaterStart:
    """One heater in the start sequence."""

    target_c: float = 0.0  # set before the first move; 0: off
    wait: bool = False  # M109 / M190 before the first move: the table waits until it has settled
    end_off: bool = False  # the program's last setting of it, after the first move, is 0


@dataclass
class HeaterProgram:
    """The heater settings of a program's items, fed batch by batch in program order."""

    start: dict[str, HeaterStart] = field(default_factory=dict)  # every heater the program sets
    first: dict[str, Output] = field(default_factory=dict)  # each heater's first setting, in program order
    between_moves: Output | None = None  # the first setting after the first move that a later move follows
    between_count: int = 0
    moved: bool = False
    since_move: list[Output] = field(default_factory=list)  # the latest move's later settings that change things

    def feed(self, items: list) -> None:
        for item in items:
            if isinstance(item, Move):
                if self.moved and self.since_move:
                    self.between_moves = self.between_moves or self.since_move[0]
                    self.between_count += len(self.since_move)
                self.moved, self.since_move = True, []
            elif isinstance(item, Output) and item.name in HEATERS:
                self.first.setdefault(item.name, item)
                heater = self.start.setdefault(item.name, HeaterStart())
                if not self.moved:
                    heater.target_c = item.value
                    heater.wait = (heater.wait or item.wait) and item.value != 0  # the firmware waits at the last
                else:
                    heater.end_off = item.value == 0
                    if item.value != heater.target_c or (item.wait and not heater.wait):
                        self.since_move.append(item)  # it changes what the image does: not played

    @property
    def unplayed(self) -> tuple[Output | None, int]:
        """The first setting the flash image does not play (between moves, or after the last move other than an
        off) and how many there are."""
        after_last = [item for item in self.since_move if item.value != 0]
        first = self.between_moves or (after_last[0] if after_last else None)
        return first, self.between_count + len(after_last)


def code(item: Output) -> str:
    return CODES[item.name, item.wait]


def _defaults() -> str:
    """The board's default heaters in words (codegen.heaters.settings)."""
    pid, bang = DEFAULT_CONTROL["hotend"]["pid"], DEFAULT_CONTROL["bed"]["bang_bang"]
    pullup_k = Heater.model_fields["pullup_ohm"].default / 1000
    return (f"hotend and bed: {DEFAULT_SENSOR} on a {pullup_k:g} kOhm pull-up; hot end PID kp {pid['kp']:g}, "
            f"ki {pid['ki']:g}, kd {pid['kd']:g}; bed bang-bang {bang['hysteresis_c']:g} degC")


def heater_diagnostics(job, board_heaters: dict, program: HeaterProgram, streamed: bool) -> list[Diagnostic]:
    """What a build says about the program's heaters, once each, at the G-code that sets them: the board's
    defaults in use (a machine without `heaters:`), settings the image does not play (between moves; a board
    without heater outputs, such as the 8051 boards; a heater the machine does not list; the streaming
    firmware)."""
    if not program.first:
        return []
    first = next(iter(program.first.values()))
    where, named = first.source, code(first)
    if not board_heaters:
        return [Diagnostic(where, f"'{named}' ignored (board {job.board} has no heater outputs: every heater "
                                  "setting of the program is ignored)", "warning")]
    if streamed:
        return [Diagnostic(where, f"'{named}' ignored (the streaming firmware does not run heaters yet: every "
                                  "heater setting of the program is ignored)", "warning")]
    out = []
    if job.machine.heaters is None:
        out.append(Diagnostic(where, f"the machine has no `heaters:` section: board {job.board}'s defaults are "
                                     f"used ({_defaults()})", "note"))
    listed = HEATERS if job.machine.heaters is None else tuple(job.machine.heaters)
    for name, item in program.first.items():
        if name not in listed or name not in board_heaters:
            out.append(Diagnostic(item.source, f"'{code(item)}' ignored (the machine has no {name} heater: every "
                                               f"{name} setting of the program is ignored)", "warning"))
    first, count = program.unplayed
    if first is not None:
        times = f"; {count} times" if count > 1 else ""
        out.append(Diagnostic(first.source, f"'{code(first)} S{first.value:g}' ignored (heater settings after the "
                                            "first move are not played yet: the heaters hold their targets from "
                                            "before it until the table has played, and a last setting to 0 turns "
                                            f"one off then){times}", "warning"))
    return out

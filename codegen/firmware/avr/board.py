"""An ATmega2560 board's pins from its targets/<board>.yaml file: the job's motors' sockets, the tool and endstops."""

from __future__ import annotations

import re
from dataclasses import dataclass

from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig, board_socket, load_target


@dataclass(frozen=True)
class Pin:
    name: str  # PF0
    port: str  # F
    bit: int  # 0


@dataclass(frozen=True)
class MotorWiring:
    """A job motor's pins on the board."""

    name: str
    socket: str
    step: Pin
    dir: Pin
    enable: Pin
    invert_dir: bool


@dataclass(frozen=True)
class Endstop:
    """A board's endstop input: a switch read with the internal pull-up."""

    name: str  # x_min, x_max, ...
    pin: Pin
    closed_high: bool  # the level the pin reads while the switch is closed (RAMPS: a switch to ground, low)


@dataclass(frozen=True)
class BoardPins:
    mcu: str
    motors: tuple[MotorWiring, ...]
    tool: Pin
    tool_active_high: bool
    enable_active_low: bool
    endstops: tuple[Endstop, ...] = ()

    def endstop(self, name: str) -> Endstop | None:
        return next((e for e in self.endstops if e.name == name), None)


def parse_pin(text: str) -> Pin:
    match = re.fullmatch(r"P([A-L])([0-7])", str(text).strip())
    if not match:
        raise BuildError(f"bad AVR pin `{text}` in a board file (expected e.g. PF0)")
    return Pin(match.group(0), match.group(1), int(match.group(2)))


def board_pins(config: FirmwareConfig) -> BoardPins:
    board = load_target(config.board)
    motors = []
    for m in config.motors:
        s = board_socket(config.board, board, m)
        motors.append(MotorWiring(m.name, m.socket, parse_pin(s["step"]), parse_pin(s["dir"]),
                                  parse_pin(s["enable"]), m.invert_dir))
    tool = board["tool"]
    return BoardPins(board["mcu"], tuple(motors), parse_pin(tool["pin"]), bool(tool["active_high"]),
                     bool(board["enable_active_low"]), _endstops(config.board, board.get("endstops") or {}))


def _endstops(board: str, table: dict) -> tuple[Endstop, ...]:
    """The board file's `endstops: {x_max: {pin: PE4, closed: low}, ...}`."""
    out = []
    for name, spec in table.items():
        if not isinstance(spec, dict) or set(spec) != {"pin", "closed"} or spec["closed"] not in ("low", "high"):
            raise BuildError(f"board {board}: endstop {name} must read {{pin: PE4, closed: low}} (closed: low or "
                             f"high, the level of the pin while the switch is closed), not {spec!r}")
        out.append(Endstop(str(name), parse_pin(spec["pin"]), spec["closed"] == "high"))
    return tuple(out)

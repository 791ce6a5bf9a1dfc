"""Firmware generation per target: render the player and its tables, compile, measure the fit."""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import yaml

from codegen.errors import BuildError
from codegen.motion.jog import JogPlan
from codegen.paths import targets_dir
from codegen.program.homing import HomingAxis
from codegen.tables.hold import HoldPlan
from codegen.tables.laser import LaserPwm


@dataclass(frozen=True)
class MotorPins:
    """A job motor and the board's stepper socket that drives it."""

    name: str  # the job's motor name: x, y, z, e, a, b, c
    socket: str  # the board's stepper socket: X, Y, Z, E0, E1
    invert_dir: bool = False


@dataclass(frozen=True)
class HeaterFirmware:
    """A heater the firmware controls (codegen/firmware/avr/heaters.py renders it): its pins, the sensor's ADC
    table, the integer control law and the thermal protection (codegen.heaters). Its targets and waits come from
    the table's runtime records.
    Temperatures are int16 deci-degrees (0.1 degC), times are control periods (PID_PERIOD_S = 0.1 s)."""

    name: str  # hotend, bed: names the heater in the sources and in the reports
    pwm_pin: str  # the MOSFET's gate, a hardware PWM pin: PB4 (D10, OC2A), PH5 (D8, OC4C)
    sensor_pin: str  # the thermistor's analog input: PK5 (A13), PK6 (A14)
    table: tuple[int, ...]  # deci-degrees by 10-bit ADC reading (1024 entries), codegen.heaters.sensors
    control: object  # codegen.heaters.control.FixedPid or FixedBangBang
    protection: object  # codegen.heaters.protection.FixedProtection: limits, sensor readings, watch and runaway


@dataclass(frozen=True)
class FirmwareConfig:
    job_name: str
    job_file: str  # shown in the generated header
    target: str  # avr | mcs51
    board: str  # a file stem in targets/
    motors: tuple[MotorPins, ...]  # in the schedule's motor order
    step_pulse_us: float = 2.0
    dir_setup_us: float = 1.0
    homing: tuple[HomingAxis, ...] = ()  # axes homed at power-up, round by round, before the table plays
    start_steps: tuple[int, ...] = ()  # motor positions (steps) where the table starts, for a status display
    baud: int = 0  # the streaming firmware's link (machine.link.baud); 0: the target's default
    heaters: tuple[HeaterFirmware, ...] = ()  # heaters run beside the player (flash image, AVR)
    laser: LaserPwm | None = None  # a PWM laser the player sets at the steps where its power changes (AVR)
    jog: JogPlan | None = None  # jog keys at power-up, before homing and the table (codegen/motion/jog.py)
    hold: HoldPlan | None = None  # feed hold, resume and override keys (codegen/tables/hold.py; AVR flash image)
    hold_override: int = 100  # %: the override the image starts with


@lru_cache(maxsize=None)
def load_target(name: str) -> dict:
    """A targets/<name>.yaml file (an MCU or a board)."""
    path = targets_dir() / f"{name}.yaml"
    if not path.is_file():
        raise BuildError(f"unknown target or board `{name}` (no {path})")
    return yaml.safe_load(path.read_text(encoding="utf-8"))


def board_pin_uses(board: dict, pin: re.Pattern, skip: set[str]) -> dict[str, str]:
    """Every pin (names matching `pin`) the board file gives to something, outside its top-level keys `skip`:
    pin name -> the key path that names it first."""
    uses: dict[str, str] = {}

    def walk(node: object, path: str) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                if path or key not in skip:
                    walk(value, f"{path}.{key}" if path else str(key))
        elif isinstance(node, list):
            for i, value in enumerate(node):
                walk(value, f"{path}[{i}]")
        elif isinstance(node, str) and pin.fullmatch(node.strip()):
            uses.setdefault(node.strip(), path)

    walk(board, "")
    return uses


def board_socket(board_name: str, board: dict, motor: MotorPins) -> dict:
    """The board's stepper socket that drives `motor` (BuildError naming the sockets there are)."""
    sockets = board["steppers"]
    if motor.socket not in sockets:
        raise BuildError(f"board {board_name} has no stepper socket {motor.socket} (has {', '.join(sockets)})")
    return sockets[motor.socket]


@dataclass
class Image:
    """A built firmware image and what it uses of the MCU's memories."""

    hex_path: Path
    elf_path: Path | None
    flash_bytes: int
    ram_bytes: int
    table_bytes: int
    flash_capacity: int
    ram_capacity: int
    sections: dict[str, int] = field(default_factory=dict)  # loadable sections: name -> bytes
    flash_parts: dict[str, int] = field(default_factory=dict)  # every flash byte by what it holds
    ram_parts: dict[str, int] = field(default_factory=dict)  # RAM by what holds it (codegen/firmware/avr/image.py)


def run_tool(cmd: list[str], cwd: Path, what: str, install: str) -> subprocess.CompletedProcess:
    """Run a toolchain command; BuildError with its output when it fails, or naming `install` when missing."""
    try:
        done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    except FileNotFoundError as exc:
        raise BuildError(f"{cmd[0]} not found: install {install}") from exc
    if done.returncode != 0:
        raise BuildError(f"{what} failed:\n{(done.stderr + done.stdout).strip()}")
    return done

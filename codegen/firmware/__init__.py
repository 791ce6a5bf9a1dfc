"""Firmware generation per target: render the player and its tables, compile, measure the fit."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class MotorPins:
    """A job motor and the board's stepper socket that drives it."""

    name: str  # the job's motor name: x, y, z, e, a, b, c
    socket: str  # the board's stepper socket: X, Y, Z, E0, E1
    invert_dir: bool = False


@dataclass(frozen=True)
class FirmwareConfig:
    job_name: str
    job_file: str  # shown in the generated header
    target: str  # avr | mcs51
    board: str  # a file stem in targets/
    motors: tuple[MotorPins, ...]  # in the schedule's motor order
    step_pulse_us: float = 2.0
    dir_setup_us: float = 1.0


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

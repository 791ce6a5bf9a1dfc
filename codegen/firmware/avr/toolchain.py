"""The avr-gcc toolchain both ATmega2560 images build with: compiler flags, running a tool, the integer-only check."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

from codegen.errors import BuildError
from codegen.firmware.config import run_tool

CFLAGS = ("-std=gnu11", "-Os", "-Wall", "-Wextra", "-Werror", "-fno-toplevel-reorder")
ASFLAGS = ("-Wa,--fatal-warnings",)
# libgcc's division and float routines: the firmware does integer arithmetic without division (DESIGN.md).
NOT_INTEGER_ONLY = re.compile(r"^__(u?divmod\w*|u?div[a-z]{2}\d|fp_\w+|fix\w+|float\w+|\w+[sd]f\d?)$")


def run_avr(cmd: list[str], cwd: Path, what: str) -> subprocess.CompletedProcess:
    return run_tool(cmd, cwd, what, "gcc-avr, binutils-avr and avr-libc")


def check_integer_only(elf: Path, cwd: Path) -> None:
    """No division and no float in the image: none of libgcc's routines for them is linked in."""
    out = run_avr(["avr-nm", "--defined-only", elf.name], cwd, "avr-nm").stdout
    found = sorted({line.split()[-1] for line in out.splitlines() if NOT_INTEGER_ONLY.match(line.split()[-1])})
    if found:
        raise BuildError(f"the firmware links division or float routines ({', '.join(found)}): integers only")

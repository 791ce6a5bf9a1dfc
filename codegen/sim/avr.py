"""Run an ATmega2560 firmware.hex in simavr and decode its STEP, DIR and tool pins with exact cycle times.

simavr 1.6 has no usable trace output, so a small C harness (simavr_harness.c, linked with libsimavr) is built
on first use into a cache directory and logs every real pin level change as binary records.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from codegen.errors import BuildError
from codegen.firmware import FirmwareConfig
from codegen.firmware.avr import board_pins, load_target

HARNESS_SOURCE = Path(__file__).with_name("simavr_harness.c")
HARNESS_BUILD = ("gcc", "-O2", "-I/usr/include/simavr")
HARNESS_LIBS = ("-lsimavr", "-lelf")
EDGE_RECORD = np.dtype([("cycle", "<u8"), ("pin", "u1"), ("level", "u1")])
EXIT_STATES = {0: "done", 1: "crashed", 2: "budget"}


@dataclass
class SimTrace:
    """What the simulated firmware did with its pins; step pulses in time order (motors: config order)."""

    state: str  # done | crashed | budget
    cycles: int  # total simulated cycles
    f_cpu: int
    timer_start_cycle: int | None  # the cycle at which Timer1 started counting (tick 0)
    step_cycle: np.ndarray  # (P,) int64, STEP rising edge
    step_motor: np.ndarray  # (P,) int index into config.motors
    step_dir: np.ndarray  # (P,) +1 / -1, DIR at the rising edge with invert_dir undone
    pulse_high_min_cycles: list[int | None]  # per motor; None without pulses
    dir_setup_min_cycles: list[int | None]  # per motor: DIR change to the next STEP rise; None if never
    tool_edges: list[tuple[int, int]]  # (cycle, 1 tool on / 0 off), active level undone


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "printer-codegen"


def harness_binary() -> Path:
    """The compiled harness, keyed by a hash of its source and build command; built atomically if missing."""
    source = HARNESS_SOURCE.read_bytes()
    key = hashlib.sha256(source + " ".join(HARNESS_BUILD + HARNESS_LIBS).encode()).hexdigest()[:16]
    binary = _cache_dir() / f"simavr-harness-{key}"
    if binary.is_file():
        return binary
    binary.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=binary.name + ".", dir=binary.parent)
    os.close(fd)
    cmd = [*HARNESS_BUILD, str(HARNESS_SOURCE), *HARNESS_LIBS, "-o", tmp]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True)
    except FileNotFoundError as exc:
        os.unlink(tmp)
        raise BuildError("gcc not found: the simavr harness needs gcc, libsimavr-dev and libelf-dev") from exc
    if done.returncode != 0:
        os.unlink(tmp)
        raise BuildError(f"building the simavr harness failed (install simavr, libsimavr-dev, libelf-dev):\n"
                         f"{done.stderr.strip()}")
    os.replace(tmp, binary)
    return binary


def _rises_falls(rec: np.ndarray, pin: int) -> tuple[np.ndarray, np.ndarray]:
    mine = rec[rec["pin"] == pin]
    cycles = mine["cycle"].astype(np.int64)
    return cycles[mine["level"] == 1], cycles[mine["level"] == 0]


def simulate(hex_path: Path, config: FirmwareConfig, cycle_budget: int) -> SimTrace:
    """Run `hex_path` until the firmware sleeps with interrupts off; BuildError on a crash or the budget."""
    pins = board_pins(config)
    mcu = load_target(pins.mcu)
    f_cpu = int(mcu["f_cpu"])
    watched = [p for w in pins.motors for p in (w.step, w.dir)] + [pins.tool]
    with tempfile.TemporaryDirectory(prefix="printer-codegen-sim-") as tmp:
        edges_path = Path(tmp) / "edges.bin"
        cmd = [str(harness_binary()), pins.mcu, str(f_cpu), str(hex_path), str(edges_path), str(int(cycle_budget)),
               *[f"{p.port}{p.bit}" for p in watched]]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode not in EXIT_STATES:
            raise BuildError(f"simavr harness failed on {hex_path}:\n{(done.stderr + done.stdout).strip()}")
        rec = np.fromfile(edges_path, dtype=EDGE_RECORD)
    fields = dict(kv.split("=", 1) for kv in done.stdout.strip().splitlines()[-1].split())
    state, cycles = EXIT_STATES[done.returncode], int(fields["cycles"])
    if state == "crashed":
        raise BuildError(f"the firmware crashed in simavr after {cycles} cycles ({hex_path})")
    if state == "budget":
        raise BuildError(f"the firmware did not finish within {cycle_budget} cycles "
                         f"({cycle_budget / f_cpu:.3f} s simulated; {hex_path})")

    step_cycle, step_motor, step_dir, high_min, setup_min = [], [], [], [], []
    for m, wiring in enumerate(pins.motors):
        rise, fall = _rises_falls(rec, 2 * m)
        dir_mine = rec[rec["pin"] == 2 * m + 1]
        dir_cycles, dir_levels = dir_mine["cycle"].astype(np.int64), dir_mine["level"].astype(np.int64)
        # DIR level at each rising edge: the last DIR change before it (pins start low after reset).
        level = np.concatenate([[0], dir_levels])[np.searchsorted(dir_cycles, rise, side="right")]
        step_cycle.append(rise)
        step_motor.append(np.full(len(rise), m, dtype=np.int64))
        step_dir.append(np.where(level ^ int(wiring.invert_dir), 1, -1).astype(np.int64))
        n = min(len(rise), len(fall))
        high_min.append(int((fall[:n] - rise[:n]).min()) if n else None)
        # DIR setup: from each DIR change to the next STEP rise of the same motor.
        nxt = np.searchsorted(rise, dir_cycles, side="right")
        followed = nxt < len(rise)
        setup_min.append(int((rise[nxt[followed]] - dir_cycles[followed]).min()) if followed.any() else None)
    cyc, mot, dirs = (np.concatenate(a) if a else np.zeros(0, np.int64) for a in (step_cycle, step_motor, step_dir))
    order = np.lexsort((mot, cyc))
    tool = rec[rec["pin"] == len(watched) - 1]
    tool_on = tool["level"].astype(int) ^ (0 if pins.tool_active_high else 1)
    timer_start = int(fields.get("timer_start", "-1"))
    return SimTrace(state=state, cycles=cycles, f_cpu=f_cpu,
                    timer_start_cycle=timer_start if timer_start >= 0 else None,
                    step_cycle=cyc[order], step_motor=mot[order], step_dir=dirs[order],
                    pulse_high_min_cycles=high_min, dir_setup_min_cycles=setup_min,
                    tool_edges=[(int(c), int(v)) for c, v in zip(tool["cycle"], tool_on)])

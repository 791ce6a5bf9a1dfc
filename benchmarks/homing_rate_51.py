"""How fast the 8051 image homes, measured step by step in s51 (templates/mcs51/homing.c.j2).

For 1 to 3 homed motors (sockets X, Y, Z with their keys; E0 has none), all with one step interval and switches
that close at different distances, the benchmark finds the shortest interval (machine cycles = timer ticks) at
which every homing step comes one interval after the one before within +-TOLERANCE clocks in each phase, with
the default DIR setup kept at the phase changes; on the at89c52 (SDCC's small memory model) and the stc89c52rc
(large). The homing_event_cycles of targets/at89c52.yaml and stc89c52rc.yaml (seed-51, large, uses at89c52's) are
the larger figure less the STEP pulse, plus one machine cycle of margin, in CPU clocks (12 per machine cycle).

    python benchmarks/homing_rate_51.py
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from shortest import shortest  # noqa: E402 - beside this script

from codegen.errors import BuildError  # noqa: E402
from codegen.firmware.config import FirmwareConfig, MotorPins, load_target  # noqa: E402
from codegen.firmware.mcs51.image import build_image, render_sources  # noqa: E402
from codegen.program.homing import HomingAxis  # noqa: E402
from codegen.sim.mcs51 import SimTrace, simulate  # noqa: E402
from codegen.tables.format import stream_bytes  # noqa: E402
from codegen.tables.schedule import Schedule  # noqa: E402

CLOCKS = 12  # CPU clocks per machine cycle
TOLERANCE = CLOCKS  # the poll loop of 2 machine cycles: a step 0 or 1 cycle after its tick
SOCKETS = (("x", "X", "x_min"), ("y", "Y", "y_min"), ("z", "Z", "z_min"))
BOARDS = ("at89c52", "stc89c52rc")  # the small and the large memory model
BACKOFF = 20
PULSE_TICKS = 2  # FirmwareConfig's default 2 us


def one_step_schedule(n_motors: int) -> Schedule:
    """A table of one event in which motor 0 steps, 2000 ticks after tick 0."""
    z = np.zeros((1, n_motors), dtype=np.int64)
    steps = z.copy()
    steps[0, 0] = 1
    return Schedule(motors=tuple(s[0] for s in SOCKETS[:n_motors]), tick_hz=1_000_000,
                    block_dirs=np.ones((1, n_motors), dtype=np.int8), block_steps=steps,
                    block_modulus=np.array([1]), block_init=z, block_tool=np.zeros(1, dtype=bool),
                    block_events=np.array([1]), block_segment=np.zeros(1, dtype=np.int64),
                    run_interval=np.array([2000 * 256]), run_add=np.array([0]), run_count=np.array([1]))


def homing_trace(board: str, n_motors: int, interval: int, workdir: Path) -> SimTrace:
    """Home n motors towards their min keys (switches 40, 50, ... steps away), then play the one-step table."""
    motors = tuple(MotorPins(name, socket) for name, socket, _ in SOCKETS[:n_motors])
    axes = tuple(HomingAxis((m,), (-1,), SOCKETS[m][2], -1, 500, interval, interval, BACKOFF) for m in range(n_motors))
    cfg = FirmwareConfig("homing_rate_51", "benchmarks/homing_rate_51.py", "mcs51", board, motors, homing=axes)
    sched = one_step_schedule(n_motors)
    mcu = load_target(load_target(board)["mcu"])
    limit, mcu["homing_event_cycles"] = mcu["homing_event_cycles"], [0] * len(SOCKETS)  # measure below the minimum
    try:
        sources = render_sources(sched, cfg)
    finally:
        mcu["homing_event_cycles"] = limit
    image = build_image(sources, workdir, stream_bytes(sched))
    return simulate(image.hex_path, cfg, 10_000_000, switches={m: -(40 + 10 * m) for m in range(n_motors)})


def homing_on_time(board: str, n_motors: int, interval: int, workdir: Path) -> bool:
    try:
        trace = homing_trace(board, n_motors, interval, workdir)
    except BuildError:
        return False
    if trace.homing_failed or any(s is None or s < CLOCKS for s in trace.dir_setup_min_cycles[:n_motors]):
        return False
    for m in range(n_motors):
        home = (trace.step_motor == m) & (trace.step_phase == "home")
        cycles, dirs = trace.step_cycle[home], trace.step_dir[home]
        if len(cycles) != 40 + 10 * m + 2 * BACKOFF:
            return False
        same_phase = dirs[1:] == dirs[:-1]  # the phases alternate directions
        if np.abs(np.diff(cycles)[same_phase] - interval * CLOCKS).max() > TOLERANCE:
            return False
    return True


def homing_fastest(board: str, n_motors: int, workdir: Path, lo: int = 20, hi: int = 4000) -> int:
    return shortest(lambda cycles: homing_on_time(board, n_motors, cycles, workdir), lo, hi,
                    f"homing {n_motors} motor(s)")


def main() -> None:
    print(f"8051 homing at 12 MHz (1 MHz timer ticks) in s51; every homing step one interval after the one before "
          f"within +-{TOLERANCE} clocks")
    with tempfile.TemporaryDirectory(prefix="homing-rate-51-") as tmp:
        figures = []
        for n in range(1, len(SOCKETS) + 1):
            fastest = {board: homing_fastest(board, n, Path(tmp)) for board in BOARDS}
            figures.append((max(fastest.values()) - PULSE_TICKS + 1) * CLOCKS)
            print(f"  {n} motor(s): shortest step interval "
                  + ", ".join(f"{cycles} machine cycles on the {board}" for board, cycles in fastest.items())
                  + f" (with the {PULSE_TICKS}-cycle STEP pulse)")
    print(f"homing_event_cycles: {figures}   # CPU clocks, by the number of homed motors: 1, 2, 3")


if __name__ == "__main__":
    main()

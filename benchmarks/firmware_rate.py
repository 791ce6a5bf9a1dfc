"""How fast the ATmega2560 player steps, measured pulse by pulse in simavr.

Schedules are built by hand: events a constant interval apart in which every motor steps (the Bresenham path
that costs most), on a cartesian RAMPS 1.4 (x, y, z, then E0 and E1). For each case the benchmark finds the
shortest interval, in CPU cycles, at which every pulse still comes at its scheduled tick plus one constant
latency, within +-2 cycles:
  - "run":   one long rate run (the sustained rate);
  - "runs":  a new rate run at every event (a run load from flash each time);
  - "block": a new block at every event, all DIR pins flipping (block and run load: the worst case, which gives
             targets/atmega2560.yaml's min_event_cycles with five motors).
Homing at power-up (templates/avr/homing.c.j2) is measured the same way: the shortest step interval, shared by
1, 3 or 5 homed motors whose switches close at different distances, at which every homing step comes one
interval after the one before within +-2 cycles (in each phase), with the DIR setup of the default 1 us kept at
the phase changes; targets/atmega2560.yaml's homing_event_cycles are these figures less the STEP pulse.

    python benchmarks/firmware_rate.py
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from codegen.errors import BuildError  # noqa: E402
from codegen.firmware import FirmwareConfig, HomingAxis, MotorPins  # noqa: E402
from codegen.firmware.avr import build_image, load_target, render_sources  # noqa: E402
from codegen.schedule import Schedule  # noqa: E402
from codegen.sim.avr import SimTrace, simulate  # noqa: E402

F_CPU = 16_000_000
TOLERANCE = 2  # cycles around the constant latency
SOCKETS = (("x", "X"), ("y", "Y"), ("z", "Z"), ("a", "E0"), ("b", "E1"))
HOMING_SWITCHES = ("x_min", "y_min", "z_min", "x_max", "y_max")  # any free switch will do for E0 and E1
HOMING_BACKOFF = 20  # steps


def config(n_motors: int) -> FirmwareConfig:
    motors = tuple(MotorPins(name, socket) for name, socket in SOCKETS[:n_motors])
    return FirmwareConfig("firmware_rate", "benchmarks/firmware_rate.py", "avr", "ramps-1.4", motors)


def schedule(n_motors: int, interval: int, events: int, mode: str) -> Schedule:
    """`events` events `interval` cycles apart, every motor stepping at each (mode: run, runs or block)."""
    blocks = events if mode == "block" else 1
    per_block = events // blocks
    runs = events if mode != "run" else 1
    dirs = np.where((np.arange(blocks) % 2 == 0)[:, None], 1, -1).repeat(n_motors, axis=1).astype(np.int8)
    return Schedule(
        motors=tuple(name for name, _ in SOCKETS[:n_motors]), tick_hz=F_CPU, block_dirs=dirs,
        block_steps=np.full((blocks, n_motors), per_block, dtype=np.int64),
        block_modulus=np.full(blocks, per_block, dtype=np.int64),
        block_init=np.full((blocks, n_motors), per_block // 2, dtype=np.int64),
        block_tool=np.zeros(blocks, dtype=bool),
        block_runs=np.linspace(0, runs, blocks + 1).astype(np.int64), block_segment=np.zeros(blocks, dtype=np.int64),
        run_interval=np.full(runs, interval * 256, dtype=np.int64), run_add=np.zeros(runs, dtype=np.int64),
        run_count=np.full(runs, events // runs, dtype=np.int64))


def play(n_motors: int, interval: int, events: int, mode: str, workdir: Path) -> SimTrace:
    sched = schedule(n_motors, interval, events, mode)
    image = build_image(render_sources(sched, config(n_motors)), workdir, sched.table_bytes())
    return simulate(image.hex_path, config(n_motors), interval * events * 2 + 1_000_000)


def latencies(trace: SimTrace, interval: int, events: int, n_motors: int) -> list[np.ndarray] | None:
    """Per motor: edge cycle - (tick 0 + scheduled tick) for each pulse; None if pulses are missing."""
    if len(trace.step_cycle) != events * n_motors:
        return None
    ticks = interval * np.arange(1, events + 1)
    return [trace.step_cycle[trace.step_motor == m] - trace.timer_start_cycle - ticks for m in range(n_motors)]


def on_time(n_motors: int, interval: int, events: int, mode: str, workdir: Path) -> bool:
    try:
        trace = play(n_motors, interval, events, mode, workdir)
    except BuildError:  # too fast: a compare set in the past waits a whole timer period, past the budget
        return False
    late = latencies(trace, interval, events, n_motors)
    return late is not None and all(int(np.abs(m - np.median(m)).max()) <= TOLERANCE for m in late)


def fastest(n_motors: int, events: int, mode: str, workdir: Path, lo: int = 40, hi: int = 2000) -> int:
    """The shortest interval (cycles) that plays on time; assumes anything slower also does."""
    if not on_time(n_motors, hi, events, mode, workdir):
        raise BuildError(f"{n_motors} motor(s), mode {mode}: not on time even at {hi} cycles per event")
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if on_time(n_motors, mid, events, mode, workdir):
            hi = mid
        else:
            lo = mid
    return hi


def homing_config(n_motors: int, interval: int) -> FirmwareConfig:
    axes = tuple(HomingAxis(m, HOMING_SWITCHES[m], 1, 500, interval, interval, HOMING_BACKOFF, 0)
                 for m in range(n_motors))
    return FirmwareConfig("homing_rate", "benchmarks/firmware_rate.py", "avr", "ramps-1.4",
                          config(n_motors).motors, homing=axes)


def homing_trace(n_motors: int, interval: int, workdir: Path) -> SimTrace:
    """Home n motors (switches 40, 50, ... steps away), then play a one-event table."""
    sched = schedule(n_motors, 2000, 1, "run")
    cfg = homing_config(n_motors, interval)
    mcu = load_target("atmega2560")
    limit, mcu["homing_event_cycles"] = mcu["homing_event_cycles"], [0] * 5  # measure below the checked minimum
    try:
        sources = render_sources(sched, cfg)
    finally:
        mcu["homing_event_cycles"] = limit
    image = build_image(sources, workdir, sched.table_bytes())
    return simulate(image.hex_path, cfg, 400 * interval * 4 + 1_000_000,
                    switches={m: 40 + 10 * m for m in range(n_motors)})


def homing_on_time(n_motors: int, interval: int, workdir: Path) -> bool:
    try:
        trace = homing_trace(n_motors, interval, workdir)
    except BuildError:
        return False
    setup = int(np.ceil(1.0 * F_CPU / 1e6))
    if trace.homing_failed or any(s is None or s < setup for s in trace.dir_setup_min_cycles):
        return False
    for m in range(n_motors):
        home = (trace.step_motor == m) & (trace.step_phase == "home")
        cycles, dirs = trace.step_cycle[home], trace.step_dir[home]
        if len(cycles) != 40 + 10 * m + 2 * HOMING_BACKOFF:
            return False
        same_phase = dirs[1:] == dirs[:-1]  # the phases alternate directions
        if np.abs(np.diff(cycles)[same_phase] - interval).max() > TOLERANCE:
            return False
    return True


def homing_fastest(n_motors: int, workdir: Path, lo: int = 40, hi: int = 4000) -> int:
    if not homing_on_time(n_motors, hi, workdir):
        raise BuildError(f"homing {n_motors} motor(s): not on time even at {hi} cycles per step")
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if homing_on_time(n_motors, mid, workdir):
            hi = mid
        else:
            lo = mid
    return hi


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="firmware-rate-") as tmp:
        work = Path(tmp)
        print(f"ATmega2560 player at {F_CPU / 1e6:g} MHz in simavr; every pulse on its tick within +-{TOLERANCE} "
              f"cycles; every motor steps at every event")
        for n in (1, 3, 5):
            cycles = fastest(n, 2000, "run", work)
            rate = F_CPU / cycles
            print(f"  {n} motor(s), sustained: {cycles} cycles per event, {rate:,.0f} events/s = {rate:,.0f} steps/s "
                  f"per motor, {rate * n:,.0f} steps/s in total")
        for n in (1, 3, 5):
            print(f"  {n} motor(s), a run load at every event: {fastest(n, 400, 'runs', work)} cycles per event")
        worst = {n: fastest(n, 400, "block", work) for n in (1, 3, 5)}
        for n, cycles in worst.items():
            print(f"  {n} motor(s), a block load at every event (worst case): {cycles} cycles per event")

        for n in (1, 3, 5):
            late = latencies(play(n, 2000, 200, "run", work), 2000, 200, n)
            first = min(int(np.median(m)) for m in late)
            print(f"  {n} motor(s): compare match to the first STEP edge: {first} cycles")
        trace = play(5, worst[5], 400, "block", work)
        late = latencies(trace, worst[5], 400, 5)
        # DIR changes right after the previous event's pulses: compare match to the last DIR write.
        dir_write = max(worst[5] + int(np.median(m)) - s for m, s in zip(late, trace.dir_setup_min_cycles))
        print(f"  5 motors: compare match to the last DIR write of a block load: {dir_write} cycles")
        quiet = play(1, 2000, 200, "run", work)
        print(f"  1 motor: shortest STEP high time: {min(quiet.pulse_high_min_cycles)} cycles")

        pulse = int(np.ceil(2.0 * F_CPU / 1e6))
        for n in (1, 2, 3, 4, 5):
            cycles = homing_fastest(n, work)
            print(f"  homing {n} motor(s): shortest step interval {cycles} cycles ({cycles - pulse} without the "
                  f"{pulse}-cycle STEP pulse)")


if __name__ == "__main__":
    main()

"""verify --vcd: the simulated pins as a VCD waveform for GTKWave, written with pyvcd.

Every pin the simulation recorded (SimTrace.pins: each motor's STEP, DIR and enable and the tool; on the ATmega2560
also the homed axes' endstops, on the 8051 the held pins, coil pins and the display's) is a 1-bit wire at its
level on the pin (no inversion undone), in a scope per motor under the job's name. Beside them `player.run`, 1
from the player's tick 0 (the pulses from there on are the CSV trace's phase `run`), and a PWM laser's compare
value, `laser.duty` (16 bits, counts of its PWM's top).

Time is in ns since reset (timescale 1 ns): a change at cycle c is at c x 1e9 / F_CPU, rounded to the nearest ns.
A cycle is 62.5 ns on the ATmega2560 at 16 MHz and 90.4 ns on an 8051 at 11.0592 MHz (its oscillator clock):
no two cycles share a time, and a time is within 0.5 ns of the CSV trace's.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from codegen import __version__

TIMESCALE = "1 ns"
CHANGES_AT_ONCE = 1 << 16  # changes turned into Python numbers at a time: memory stays small


def nanoseconds(cycle: np.ndarray, f_cpu: int) -> np.ndarray:
    """cycle x 1e9 / f_cpu, rounded to the nearest ns (halves up), exact in int64 for any run's length."""
    whole, part = np.divmod(np.asarray(cycle, dtype=np.int64), f_cpu)
    return whole * 10**9 + (part * 10**9 + f_cpu // 2) // f_cpu


def _identifier(text: str) -> str:
    """`text` as a scope or signal name every VCD reader takes: letters, digits and _."""
    return re.sub(r"\W", "_", text)


def signals(trace) -> list[tuple[str, str, int, int, np.ndarray, np.ndarray]]:
    """(scope below the job's, name, bits, level at reset, cycles, levels) of every signal of the waveform."""
    out = []
    for full, wave in trace.pins.items():
        scope, _, name = full.rpartition(".")
        out.append((_identifier(scope), _identifier(name), 1, wave.initial, wave.cycle, wave.level))
    if trace.timer_start_cycle is not None:
        out.append(("player", "run", 1, 0, np.array([trace.timer_start_cycle]), np.array([1])))
    if len(trace.laser_duty):
        out.append(("laser", "duty", 16, 0, trace.laser_duty[:, 0], trace.laser_duty[:, 1]))
    return out


def write_vcd(path: Path, job_name: str, trace) -> None:
    """The trace's waveform (see the top of this file) to `path`, atomically: a partial file never stands there."""
    from vcd import VCDWriter  # here: verify without --vcd never imports it

    waves = signals(trace)
    top = _identifier(job_name)
    times = [nanoseconds(cycles, trace.f_cpu) for *_, cycles, _ in waves]
    which = [np.full(len(t), k) for k, t in enumerate(times)]
    values = [np.asarray(v, dtype=np.int64) for *_, v in waves]
    times, which, values = (np.concatenate(a) if a else np.zeros(0, np.int64) for a in (times, which, values))
    order = np.argsort(times, kind="stable")  # a signal's changes stay in their order
    partial = path.with_name(f".{path.name}.partial")
    try:
        with (open(partial, "w", encoding="utf-8") as out,
              VCDWriter(out, timescale=TIMESCALE, version=f"printer-codegen {__version__}", check_values=False,
                        comment=f"{job_name}: simulated pins, time from reset") as writer):
            variables = [writer.register_var(f"{top}.{scope}" if scope else top, name, "wire", size=bits, init=initial)
                         for scope, name, bits, initial, _, _ in waves]
            for lo in range(0, len(order), CHANGES_AT_ONCE):
                part = order[lo:lo + CHANGES_AT_ONCE]
                for t, k, v in zip(times[part].tolist(), which[part].tolist(), values[part].tolist()):
                    writer.change(variables[k], t, v)
        partial.replace(path)
    finally:
        partial.unlink(missing_ok=True)

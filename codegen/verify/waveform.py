"""verify --vcd: the simulated pins as a VCD waveform for GTKWave, written with pyvcd: from a run kept whole
(write_vcd), or from the simavr harness's records as they are read (EdgeWaveform: a run compared in bounded memory,
codegen/verify/bounded.py), so that the file grows with the run and the process does not.

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
from codegen.firmware.avr.board import board_pins
from codegen.firmware.avr.player import START_TICKS
from codegen.firmware.config import FirmwareConfig, load_target
from codegen.sim.avr import watched
from codegen.sim.avr_edges import DUTY_HIGH_PIN, DUTY_LOW_PIN, START_PIN

TIMESCALE = "1 ns"
CHANGES_AT_ONCE = 1 << 16  # changes turned into Python numbers at a time: memory stays small


def nanoseconds(cycle: np.ndarray, f_cpu: int) -> np.ndarray:
    """cycle x 1e9 / f_cpu, rounded to the nearest ns (halves up), exact in int64 for any run's length."""
    whole, part = np.divmod(np.asarray(cycle, dtype=np.int64), f_cpu)
    return whole * 10**9 + (part * 10**9 + f_cpu // 2) // f_cpu


def _identifier(text: str) -> str:
    """`text` as a scope or signal name every VCD reader takes: letters, digits and _."""
    return re.sub(r"\W", "_", text)


def _wire(full: str, initial: int = 0) -> tuple[str, str, int, int]:
    scope, _, name = full.rpartition(".")
    return _identifier(scope), _identifier(name), 1, initial


class Waveform:
    """The file, open for changes: `signals` (scope below the job's, name, bits, level at reset) declared first,
    then `write` their changes in time order, then `close` (the file stands at `path` only then: a partial one
    never does; `discard` leaves none)."""

    def __init__(self, path: Path, job_name: str, signals: list[tuple[str, str, int, int]], f_cpu: int):
        from vcd import VCDWriter  # here: verify without --vcd never imports it

        self.path, self.f_cpu = Path(path), f_cpu
        self.partial = self.path.with_name(f".{self.path.name}.partial")
        self.out = open(self.partial, "w", encoding="utf-8")
        self.writer = VCDWriter(self.out, timescale=TIMESCALE, version=f"printer-codegen {__version__}",
                                check_values=False, comment=f"{job_name}: simulated pins, time from reset")
        top = _identifier(job_name)
        self.variables = [self.writer.register_var(f"{top}.{scope}" if scope else top, name, "wire", size=bits,
                                                   init=initial) for scope, name, bits, initial in signals]

    def write(self, cycles: np.ndarray, which: np.ndarray, values: np.ndarray) -> None:
        """Changes in time order: each at a cycle, of signal `which` (its index in `signals`), to a value."""
        times = nanoseconds(cycles, self.f_cpu)
        for lo in range(0, len(times), CHANGES_AT_ONCE):
            part = slice(lo, lo + CHANGES_AT_ONCE)
            for t, k, v in zip(times[part].tolist(), which[part].tolist(), values[part].tolist()):
                self.writer.change(self.variables[k], t, v)

    def close(self) -> None:
        self.writer.close()
        self.out.close()
        self.partial.replace(self.path)

    def discard(self) -> None:
        self.out.close()
        self.partial.unlink(missing_ok=True)


def write_vcd(path: Path, job_name: str, trace) -> None:
    """A whole trace's waveform (see the top of this file) to `path`."""
    waves = [(*_wire(full, wave.initial), wave.cycle, wave.level) for full, wave in trace.pins.items()]
    if trace.timer_start_cycle is not None:
        waves.append(("player", "run", 1, 0, np.array([trace.timer_start_cycle]), np.array([1])))
    if len(trace.laser_duty):
        waves.append(("laser", "duty", 16, 0, trace.laser_duty[:, 0], trace.laser_duty[:, 1]))
    cycles = np.concatenate([np.zeros(0, np.int64)] + [np.asarray(w[4], dtype=np.int64) for w in waves])
    which = np.concatenate([np.zeros(0, np.int64)] + [np.full(len(w[4]), k) for k, w in enumerate(waves)])
    values = np.concatenate([np.zeros(0, np.int64)] + [np.asarray(w[5], dtype=np.int64) for w in waves])
    order = np.argsort(cycles, kind="stable")  # a signal's changes stay in their order
    waveform = Waveform(path, job_name, [w[:4] for w in waves], trace.f_cpu)
    try:
        waveform.write(cycles[order], which[order], values[order])
        waveform.close()
    finally:
        waveform.discard()


class EdgeWaveform:
    """The waveform of an ATmega2560's run from the harness's records (codegen/sim/avr_edges.py), fed in order as
    they are read (`feed`), then `close`d: what it holds is a duty write's low byte whose high byte is still to
    come, and the player's start until the records pass it."""

    def __init__(self, path: Path, job_name: str, config: FirmwareConfig):
        names = [name for name, _ in watched(config)]
        mcu = load_target(board_pins(config).mcu)
        f_cpu = int(mcu["f_cpu"])
        self.start_delay = START_TICKS * (f_cpu // int(mcu.get("tick_hz", f_cpu)))  # a start to the tick 0
        self.wires, self.run_signal = len(names), len(names)
        signals = [_wire(name) for name in names] + [("player", "run", 1, 0)]
        signals += [("laser", "duty", 16, 0)] if config.laser else []
        self.waveform = Waveform(path, job_name, signals, f_cpu)
        self.started = False
        self.pending = np.zeros((3, 0), dtype=np.int64)  # changes not written yet: cycle, signal, value
        self.low = np.zeros(0, dtype=np.int64)  # a duty write's low byte record: cycle, value

    def feed(self, rec: np.ndarray) -> None:
        if not len(rec):
            return
        pin, cycle, level = rec["pin"], rec["cycle"].astype(np.int64), rec["level"].astype(np.int64)
        wire = pin < self.wires
        changes = [self.pending, np.stack([cycle[wire], pin[wire].astype(np.int64), level[wire]])]
        starts = cycle[pin == START_PIN]
        if len(starts) and not self.started:
            changes.append(np.array([[starts[0] + self.start_delay], [self.run_signal], [1]]))
            self.started = True
        low = np.concatenate([self.low, np.stack([cycle, level], axis=1)[pin == DUTY_LOW_PIN].ravel()]).reshape(-1, 2)
        high = level[pin == DUTY_HIGH_PIN]  # each right after its low byte
        n = len(high)
        changes.append(np.stack([low[:n, 0], np.full(n, self.run_signal + 1), low[:n, 1] | high << 8]))
        self.low = low[n:].ravel()
        merged = np.concatenate(changes, axis=1)
        merged = merged[:, np.argsort(merged[0], kind="stable")]
        due = merged[0] <= cycle[-1]  # later records may still come before the rest
        self.waveform.write(*merged[:, due])
        self.pending = merged[:, ~due]

    def close(self) -> None:
        self.waveform.write(*self.pending)
        self.waveform.close()

    def discard(self) -> None:
        self.waveform.discard()

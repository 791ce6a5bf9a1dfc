"""A simulated run read while the simavr harness writes it (codegen/sim/avr_edges.py): its pulses handed out a
chapter at a time, per motor as many as the twin's chapter has (codegen/verify/compare.py Comparison pairs them),
its homing pulses and its clock (the player's timer starts) kept, its slow pins as they come. What it holds of
the run is the pulses read but not yet paired: about a chapter's.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np

from codegen.firmware.avr.board import board_pins
from codegen.firmware.avr.player import START_TICKS
from codegen.firmware.config import FirmwareConfig, load_target
from codegen.sim.avr import PHASE_HOME, SimTrace, watched
from codegen.sim.avr_edges import EdgeDecoder, EdgeFile, RunPins, Steps
from codegen.sim.mcs51_edges import mcs51_run_pins
from codegen.verify.pins import DirWatch, board_driver

MARGIN_CYCLES = 4096  # read this far past a chapter's last pulse: the laser's write after its edge comes with it
BACKLOG = 8  # chapters' worth of pulses the reader holds at most while waiting for a motor's (a run gone wrong)
POLL_S = 0.02  # between looks at a file that had less than a whole read's worth new: the simulator writes on


def run_pins(config: FirmwareConfig) -> RunPins:
    """The edges file's layout of `config`'s target: the simavr harness's (codegen/sim/avr.py `watched`) or the
    one codegen/sim/mcs51_edges.py writes from s51's records."""
    if config.target == "mcs51":
        return mcs51_run_pins(config)
    pins = board_pins(config)
    mcu = load_target(pins.mcu)
    f_cpu = int(mcu["f_cpu"])
    cycles_per_tick = f_cpu // int(mcu.get("tick_hz", f_cpu))
    return RunPins(f_cpu, cycles_per_tick, START_TICKS * cycles_per_tick, tuple(w.invert_dir for w in pins.motors),
                   tuple(name for name, _ in watched(config)), 1 if pins.tool_active_high else 0, 0)


def _cat(parts: list[Steps]) -> Steps:
    return Steps(*(np.concatenate([getattr(p, k) for p in parts]) for k in ("cycle", "motor", "dir")))


class RunReader:
    """`ended()` says the harness has written its last record (the reader then reads what is left and stops);
    `records`, if given, is handed every record as it is read (verify --vcd: codegen/verify/waveform.py); with
    `keep`, the file keeps what has been read (it is read again: codegen/verify/hold_bounded.py)."""

    def __init__(self, edges: Path, config: FirmwareConfig, ended: Callable[[], bool], since: int = 0,
                 records: Callable[[np.ndarray], None] | None = None, keep: bool = False):
        pins = run_pins(config)
        self.f_cpu, self.cycles_per_tick, self.start_to_tick0 = pins.f_cpu, pins.cycles_per_tick, pins.start_to_tick0
        self.motors = len(pins.invert_dir)
        self.decoder = EdgeDecoder(list(pins.invert_dir), list(pins.names[2 * self.motors:]), since,
                                   pins.reset_level)
        self.tool_on_level = pins.tool_on_level
        self.file, self.ended, self.done = EdgeFile(edges, keep=keep), ended, False
        self.records = records
        self.buffer = Steps.empty()  # the run's pulses read, not yet handed out
        self.have = np.zeros(self.motors, dtype=np.int64)  # the buffer's, per motor
        self.home: list[Steps] = []  # pulses before the player's first start: homing's
        self.first_run_cycle: int | None = None
        driver = board_driver(load_target(config.board), self.f_cpu)
        motor_names = [name[:-len(".step")] for name in pins.names[:2 * self.motors:2]]
        self.dir_watches = [] if driver is None else [DirWatch(name, driver, self.f_cpu) for name in motor_names]
        self.wait_s = 0.0  # wall time spent waiting for the harness

    # -- the clock and the slow outputs, as read so far (Comparison's `levels`) --
    @property
    def starts(self) -> np.ndarray:
        return self.decoder.starts()

    @property
    def timer_start_cycle(self) -> int | None:
        """The player's tick 0: START_TICKS ticks after it first started its timer."""
        starts = self.starts
        return int(starts[0]) + self.start_to_tick0 if len(starts) else None

    @property
    def resumes(self) -> tuple[int, ...]:
        """Tick 0 of every restart of the player's timer after its first start (a hold's end)."""
        return tuple(int(s) + self.start_to_tick0 for s in self.starts[1:])

    @property
    def tool_edges(self) -> list[tuple[int, int]]:
        tool = self.decoder.waves()["tool"]
        after = tool.cycle >= self.decoder.since
        return [(int(c), int(v) ^ (1 - self.tool_on_level)) for c, v in zip(tool.cycle[after], tool.level[after])]

    @property
    def laser_duty(self) -> np.ndarray:
        return self.decoder.duty()

    # -- reading --
    def _more(self) -> bool:
        """Read what the harness has written since; False once the run has ended and everything is read."""
        rec = self.file.read()
        if len(rec) < self.file.chunk and not self.done:  # the file's end, for now
            if self.ended():
                self.done = True  # what it wrote before it ended is there: one more read at the least
            else:
                began = time.perf_counter()
                time.sleep(POLL_S)
                self.wait_s += time.perf_counter() - began
            if not len(rec):
                return True
        elif not len(rec):
            return False
        if self.records is not None:
            self.records(rec)
        steps = self.decoder.feed(rec)
        for watch, edges in zip(self.dir_watches, self.decoder.motor_edges):
            watch.add(*edges)
        starts = self.starts
        run = steps.cycle >= starts[0] if len(starts) else np.zeros(len(steps.cycle), dtype=bool)
        if not run.all():
            self.home.append(Steps(steps.cycle[~run], steps.motor[~run], steps.dir[~run]))
        if run.any():
            ran = Steps(steps.cycle[run], steps.motor[run], steps.dir[run])
            self.first_run_cycle = self.first_run_cycle if self.first_run_cycle is not None else int(ran.cycle[0])
            self.buffer = _cat([self.buffer, ran])
            self.have += np.bincount(ran.motor, minlength=self.motors)
        return True

    def take(self, counts: np.ndarray, chapter_pulses: int) -> Steps:
        """The run's next pulses: per motor the next counts[m] (fewer where the run made fewer), in time order."""
        while True:
            if np.all(self.have >= counts):
                last = max((int(self.buffer.cycle[self.buffer.motor == m][c - 1]) for m, c in enumerate(counts) if c),
                           default=0)
                if self.decoder.last_cycle >= last + MARGIN_CYCLES or self.done:
                    break
            elif len(self.buffer.cycle) > BACKLOG * max(chapter_pulses, 1):
                break  # the run went another way: pair what there is, the comparison says what differs
            if not self._more():
                break
        taken = np.zeros(len(self.buffer.cycle), dtype=bool)
        for m, count in enumerate(counts):
            taken[np.flatnonzero(self.buffer.motor == m)[:count]] = True
        out = Steps(self.buffer.cycle[taken], self.buffer.motor[taken], self.buffer.dir[taken])
        self.buffer = Steps(self.buffer.cycle[~taken], self.buffer.motor[~taken], self.buffer.dir[~taken])
        self.have -= np.bincount(out.motor, minlength=self.motors)
        return out

    def forget_duty(self) -> None:
        """Forget the laser's compare writes that no pulse still to come can read (a held run's player writes one
        at every dilated event: the run's length of them); those before the table starts stay (pins.py checks
        them), and so does every write where the player has not started."""
        start = self.timer_start_cycle
        if start is not None:
            upcoming = int(self.buffer.cycle.min()) if len(self.buffer.cycle) else self.decoder.last_cycle
            self.decoder.forget_duty(start, upcoming)

    def homing_steps(self) -> Steps:
        """The pulses before the player's first start (homing's), read so far."""
        return _cat(self.home) if self.home else Steps.empty()

    def rest(self) -> Steps:
        """Every pulse after the last handed out, to the run's end."""
        while self._more():
            pass
        out, self.buffer = self.buffer, Steps.empty()
        self.have[:] = 0
        self.file.close()
        return out

    def trace(self, base: SimTrace) -> SimTrace:
        """`base` (a run's state, cycles and homing fault, as its simulation ends) with what the reader kept: the
        homing pulses, the clock, the pulse widths and DIR setup times, the slow pins."""
        home = self.homing_steps()
        return replace(base, timer_start_cycle=self.timer_start_cycle, resumes=self.resumes,
                       step_cycle=home.cycle, step_motor=home.motor, step_dir=home.dir,
                       step_phase=np.full(len(home.cycle), PHASE_HOME, dtype="<U4"),
                       pulse_high_min_cycles=self.decoder.width_min, dir_setup_min_cycles=self.decoder.setup_min,
                       tool_edges=self.tool_edges, laser_duty=self.laser_duty, laser_top=self.decoder.top(),
                       pins=self.decoder.waves(),
                       dir_watches=tuple(self.dir_watches))

    def clock(self, cycles: np.ndarray, waits: np.ndarray) -> np.ndarray:
        """Simulated cycles on the twin's clock: after the k-th resume moved back by the k-th hold, as the twin
        times the events after a wait from its tick (codegen/verify/heaters.py on_twin_clock)."""
        resumes = np.asarray(self.resumes[:len(waits)], dtype=np.int64)
        if not len(resumes):
            return cycles
        shift = np.concatenate([[0], self.timer_start_cycle + waits[:len(resumes)] * self.cycles_per_tick - resumes])
        return cycles + shift[np.searchsorted(resumes, cycles, side="right")]

"""Closed-loop simulation of the streaming ATmega2560 firmware (codegen/firmware/avr/stream.py): a host with
HostLink's interface (codegen/link/host.py; codegen/link/faults.py's Faulty) talks to the firmware's USART0 in
simavr, in lockstep on simulated time.

The harness's link mode (simavr_link.c) puts the bytes host.transmit(now) gives on the RX line back to back at
10 bit times each and runs until a frame from the firmware has fully arrived or host.wake_at(); then
host.receive(bytes, now) and host.transmit(now) again, with now = cycle / F_CPU. One round trip per frame, not per
byte (a host that wants to act once its bytes have gone out asks to wake then: HostLink.line_free_at). The pins are logged as in codegen/sim/avr.py, so the session's SimTrace goes to
codegen.verify.compare.compare unchanged: timer_start_cycle is the player's tick 0 after START, pulses before it (homing)
are the phase "home", and `resumes` tick 0 of each restart of its timer after a hold (a WAIT record).

A jog firmware's keys are pressed by a key script (`keys`: codegen/sim/keys.py, times from reset), the sessions
coming when they will; jog_positions() reads its jog position counts at the end.

A firmware with heaters runs against a thermal plant per heater (`plants`, `faults`: codegen/sim/avr_plant.py's
plant file in link mode): simulate_stream_heaters gives the session as a HeaterRun, the plant's trace in it.
"""

from __future__ import annotations

import array
import math
import struct
import subprocess
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from codegen.errors import BuildError
from codegen.firmware.avr.board import board_pins
from codegen.firmware.avr.player import START_TICKS
from codegen.firmware.avr.stream import elf_symbols, ring_layout
from codegen.firmware.config import FirmwareConfig, load_target
from codegen.firmware.homing import homing_ticks_bound
from codegen.link import protocol
from codegen.link.host import LinkFigures
from codegen.sim.avr import (HOMING_FAILED, SimTrace, _homing_fault, decode_edges, harness_binary, switch_args,
                             switch_thresholds, watched_pins)
from codegen.sim.avr_edges import EDGE_RECORD, read_edges
from codegen.sim.avr_keys import jog_positions, key_args
from codegen.sim.avr_plant import Fault, HeaterPlant, HeaterRun, _plant_file, _stage_address, read_trace, stopped_safely
from codegen.sim.keys import KeyPress

COMMAND = struct.Struct("<QQBI")  # wake, budget, reset the figures, bytes for the line
ANSWER = struct.Struct("<QBBqIIHIIQIIQII")  # see simavr_link.c
OUT_BYTE = np.dtype([("cycle", "<u8"), ("byte", "u1")])
NO_WAKE = (1 << 64) - 1
NO_FREE = (1 << 32) - 1
BOOT_CYCLES = 1_000_000  # the firmware turns its receiver on within this many cycles of reset
STATES = {0: "running", 1: "done", 2: "crashed"}
FREE_SYMBOL, CHECK_PREFIX = "rb_free", "pl_check_"  # the ring's free space; where the player reads a record


@dataclass(frozen=True)
class Answer:
    """What the harness says after a run: where it stopped and the figures since the last reset."""

    cycle: int
    state: str  # running | done | crashed
    timer_start: int  # the latest start of the player's timer (-1: none yet)
    lost_bytes: int
    max_free: int | None  # the ring's free space when the player went for a record, the most
    sp_min: int  # the lowest stack pointer
    rx_bytes: int  # bytes the line brought
    isr_max: tuple[int, int]  # receive, transmit interrupt: the longest, dispatch to RETI (simavr's cycles)
    isr_cycles: tuple[int, int]  # their total
    isr_count: tuple[int, int]  # how many
    data: bytes  # the firmware's bytes that have arrived
    arrived: np.ndarray  # when each did (cycles)


class StreamSim:
    """One simulated machine running a streaming image: a session per host (`session`), the firmware going on
    between them. Use as a context manager (the harness is a process).

    `switches` as for codegen.sim.avr.simulate: where each homing axis's switch closes, from the machine's start;
    the firmware's ELF must be beside `hex_path` (firmware.elf: the ring's symbols). `plants`: the thermal plant
    behind each of config.heaters (with `faults` injected); plant_trace() reads their trace after the sessions.
    `keys`: a jog firmware's key script (codegen/sim/keys.py); jog_positions() reads its counts after the sessions."""

    def __init__(self, hex_path: Path, config: FirmwareConfig, switches: dict[int, int | None] | None = None,
                 plants: dict[str, HeaterPlant] | None = None, faults: tuple[Fault, ...] = (),
                 keys: list[KeyPress] | None = None):
        pins = board_pins(config)
        mcu = load_target(pins.mcu)
        self.config = config
        self.f_cpu = int(mcu["f_cpu"])
        self.tick_hz = int(mcu.get("tick_hz", self.f_cpu))
        self.layout = ring_layout(config)
        self.switches = {k: 0 for k in range(len(config.homing))} if switches is None else switches
        elf = Path(hex_path).with_suffix(".elf")
        if not elf.is_file():
            raise BuildError(f"{elf} is missing: the simulation reads the ring's addresses from it")
        symbols = elf_symbols(elf)
        checks = [f"check={v}" for name, v in sorted(symbols.items()) if name.startswith(CHECK_PREFIX)]
        if FREE_SYMBOL not in symbols or not checks:
            raise BuildError(f"{elf} is not a streaming image (no {FREE_SYMBOL} or {CHECK_PREFIX}*)")
        self.ring_bytes = symbols["ring_end"] - symbols["ring_start"]
        self._tmp = tempfile.TemporaryDirectory(prefix="printer-codegen-link-")
        self.edges = Path(self._tmp.name) / "edges.bin"
        self._stderr = open(Path(self._tmp.name) / "stderr.txt", "w+b")
        self._plant_log = Path(self._tmp.name) / "plant.txt"
        plant = []
        if plants:
            spec = Path(self._tmp.name) / "plant-spec.txt"
            spec.write_text(_plant_file(config, plants, faults, self.f_cpu, self._plant_log, _stage_address(hex_path)))
            plant = [f"plant={spec}"]
        self._keyed: tuple = ([], [], 0)
        if keys:
            self._keyed = key_args(config, keys, elf, self.f_cpu)
        cmd = [str(harness_binary()), pins.mcu, str(self.f_cpu), str(hex_path), str(self.edges), str(BOOT_CYCLES),
               *switch_args(config, self.switches), f"link={self.layout.byte_cycles}",
               f"free={symbols[FREE_SYMBOL]}", *checks, *plant, *self._keyed[0], *watched_pins(config)]
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr)
        self.last = self._read()
        if self.last.state != "running":
            raise BuildError(f"the streaming firmware {self.last.state} at boot ({hex_path})")

    def __enter__(self) -> StreamSim:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._stop()
        self._stderr.close()
        self._tmp.cleanup()

    def _stop(self) -> None:
        if self._proc.poll() is None:
            self._proc.stdin.close()
            self._proc.wait()

    def plant_trace(self) -> tuple[dict, dict]:
        """The plants' trace (avr_plant.read_trace): the simulation ends here (the plants' end state is written
        as its input closes)."""
        self._stop()
        return read_trace(self._plant_log, len(self.config.heaters), self.f_cpu)

    def jog_positions(self) -> list[int]:
        """The firmware's jog position counts (steps from reset, per jogged motor) as the simulation ends here:
        the harness reports them once its input closes. Only with `keys`."""
        self._proc.stdin.close()
        tail = self._proc.stdout.read().decode()
        self._proc.wait()
        fields = dict(kv.split("=", 1) for kv in tail.split())
        return jog_positions(fields["dump"], *self._keyed[1:])

    def exchange(self, data: bytes, wake: int | None, budget: int, reset: bool = False) -> Answer:
        """Give the line `data`, run until an answer (see the module docstring); wake and budget are cycles."""
        self._proc.stdin.write(COMMAND.pack(NO_WAKE if wake is None else wake, budget, reset, len(data)) + data)
        self._proc.stdin.flush()
        self.last = self._read()
        return self.last

    def _read(self) -> Answer:
        head = self._proc.stdout.read(ANSWER.size)
        if len(head) != ANSWER.size:
            self._stderr.seek(0)
            raise BuildError(f"the simavr harness stopped: {self._stderr.read().decode(errors='replace').strip()}")
        (cycle, state, _why, start, lost, free, sp, rx, rx_max, rx_total, rx_count, tx_max, tx_total, tx_count,
         n) = ANSWER.unpack(head)
        out = np.frombuffer(self._proc.stdout.read(n * OUT_BYTE.itemsize), dtype=OUT_BYTE)
        return Answer(cycle, STATES[state], start, lost, None if free == NO_FREE else free, sp, rx,
                      (rx_max, tx_max), (rx_total, tx_total), (rx_count, tx_count), out["byte"].tobytes(),
                      out["cycle"].astype(np.int64))

    def session(self, host, cycle_budget: int, decode: bool = True) -> tuple[SimTrace, LinkFigures]:
        """Run `host` to its end (host.done) within `cycle_budget` cycles (homing's bound on top, for an image that
        homes); BuildError on a crash or the budget. Without `decode` the trace has no pulses and no pins (the
        caller reads the records itself as they come: codegen/verify/bounded.py), only the session's state, clock
        and ring fills."""
        wall = time.perf_counter()
        start = self.last.cycle
        if self.config.homing:
            bound = homing_ticks_bound(self.config, switch_thresholds(self.config, self.switches), self.tick_hz)
            cycle_budget += bound * (self.f_cpu // self.tick_hz)
        end = start + int(cycle_budget)
        frames = protocol.Parser(protocol.MAX_ANSWER)
        underruns, fault = 0, None
        answer, now = self.last, start / self.f_cpu
        link = getattr(host, "link", host)  # a HostLink, or a wrapper of one (link.faults.Faulty, a test's)
        counted = None  # the latest answer before the stream's last ring went out (the plan's lowest fill too)
        starts: list[int] = []  # every start of the player's timer: START's, then a resume after each hold
        fills = array.array("q")  # cycle, ring bytes held, at each ACK: after every frame it took (8 bytes each)
        reset = True
        while not host.done:
            data = host.transmit(now)
            wake = host.wake_at()
            answer = self.exchange(data, self._wake_cycle(wake, now, answer.cycle), end, reset)
            reset = False
            now = answer.cycle / self.f_cpu
            if answer.timer_start >= start and (not starts or answer.timer_start != starts[-1]):
                starts.append(answer.timer_start)
            if not getattr(link, "in_tail", False):  # hosts that do not know the stream count to the end
                counted = answer
            if answer.data:
                for f in frames.feed(answer.data):
                    underruns += f.kind == protocol.UNDERRUN
                    if f.kind == protocol.ACK:
                        free = int.from_bytes(f.payload[:2], "little")
                        fills.extend((int(answer.arrived[-1]), self.ring_bytes - free))
                    if f.kind == protocol.HOMING_FAILED and f.payload:
                        fault = _homing_fault(self.config, HOMING_FAILED, f.payload[0] & 0x0F, f.payload[0] >> 4)
                host.receive(answer.data, int(answer.arrived[-1]) / self.f_cpu)
            if answer.state == "crashed":
                raise BuildError(f"the streaming firmware crashed in simavr after {answer.cycle} cycles")
            if answer.cycle >= end and not host.done:
                raise BuildError(f"the streaming session did not end within {cycle_budget} cycles "
                                 f"({cycle_budget / self.f_cpu:.3f} s simulated)")
        ticks0 = [s + START_TICKS * (self.f_cpu // self.tick_hz) for s in starts]
        records = read_edges(self.edges) if decode else np.zeros(0, EDGE_RECORD)
        trace = decode_edges(records, self.config, "done", answer.cycle, ticks0[0] if ticks0 else None, fault,
                             since=start)
        trace = replace(trace, resumes=tuple(ticks0[1:]), ring_fill=np.frombuffer(fills, dtype=np.int64).reshape(-1, 2).copy())
        stats = link.stats
        counted = answer if counted is None or link.outcome != "finished" else counted
        figures = LinkFigures(baud=self.layout.baud, bytes=stats.bytes, frames=stats.frames,
                              retransmits=stats.retransmits, min_ring_fill_bytes=self.min_fill(counted),
                              underruns=underruns, lost_bytes=answer.lost_bytes, wall_s=time.perf_counter() - wall)
        return trace, figures

    def _wake_cycle(self, wake: float | None, now: float, cycle: int) -> int | None:
        """The first cycle whose time (cycle / F_CPU, as the host reckons it) is at `wake`; None for a time already
        passed: the host waits for bytes."""
        if wake is None or wake <= now:
            return None
        wake_cycle = max(math.ceil(wake * self.f_cpu), cycle + 1)
        while wake_cycle / self.f_cpu < wake:  # the product rounds
            wake_cycle += 1
        return wake_cycle

    def min_fill(self, answer: Answer) -> int | None:
        """The fewest ring bytes the player held when it went for a record (since the figures' reset)."""
        return None if answer.max_free is None else self.ring_bytes - answer.max_free


def simulate_stream_heaters(hex_path: Path, config: FirmwareConfig, host, cycle_budget: int,
                            plants: dict[str, HeaterPlant], faults: tuple[Fault, ...] = (),
                            switches: dict[int, int | None] | None = None) -> tuple[HeaterRun, LinkFigures]:
    """One session of `host` with a freshly reset streaming firmware that runs heaters, a plant behind each: the
    run as codegen.sim.avr_plant.simulate_heaters gives a flash image's (a trip: the FAULT frame's), and the link's
    figures."""
    with StreamSim(hex_path, config, switches, plants, faults) as sim:
        trace, figures = sim.session(host, cycle_budget)
        return heater_run(sim, getattr(host, "link", host), trace), figures


def heater_run(sim: StreamSim, link, trace: SimTrace) -> HeaterRun:
    """The session that just ended on `sim` (its host's HostLink `link`, its `trace`) as a HeaterRun, the plants'
    trace read: the simulation ends here."""
    per, end = sim.plant_trace()
    config = sim.config
    fault = link.fault
    pins_low, stopped = stopped_safely(end, config)
    return HeaterRun(state="done", seconds=sim.last.cycle / sim.f_cpu,
                     heaters={h.name: per[k] for k, h in enumerate(config.heaters)},
                     trip=fault.reason if fault else None, trip_heater=link.heater_name(fault.heater) if fault else None,
                     trip_s=link.fault_at if fault else None, heater_pins_low=pins_low, steppers_stopped=stopped,
                     stage_max_cycles=end["I"][0], stages=end["I"][1], steps=trace, fan=end["F"])


def simulate_stream(hex_path: Path, config: FirmwareConfig, host, cycle_budget: int,
                    switches: dict[int, int | None] | None = None) -> tuple[SimTrace, LinkFigures]:
    """One session of `host` with a freshly reset streaming firmware (see StreamSim.session)."""
    with StreamSim(hex_path, config, switches) as sim:
        return sim.session(host, cycle_budget)

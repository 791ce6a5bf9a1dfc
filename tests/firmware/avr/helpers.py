"""The ATmega2560 firmware tests' shared parts (tests/firmware/avr/): its clock, hand-made blocks and runs, the
streaming firmware's pulse check against the twin and its scripted host, the jog plotter's job."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import numpy as np

from codegen.link import protocol
from codegen.link.host import HostLink
from codegen.tables.twin import predict
from codegen.targets import target_info
from tests.helpers import make_schedule as hand_schedule

F_CPU, TICK_HZ, BAUD = 16_000_000, 2_000_000, 250_000
CYCLES = F_CPU // TICK_HZ  # CPU cycles per timer tick
BYTE_S = 10 / BAUD
BUDGET = 400_000_000  # cycles: 25 s simulated
make_schedule = partial(hand_schedule, tick_hz=TICK_HZ)
STREAM = target_info("ramps-1.4", stream=True)
MIN_LATE = 8  # cycles from the compare match to the STEP edge, at least
MAX_LATE = STREAM.mcu_data["isr_latency_cycles"]  # at most: the link's interrupts may come first


RUNS = [(3000 * 256, -5000, 30), (1200 * 256 + 100, 3, 300), (70_000 * 256, 0, 2), (800 * 256, 0, 55)]
BLOCKS = [  # (dirs, steps, modulus, init, tool, events) of four motors: a test takes the first n of each motor
    ((1, -1, 1, 1), (10, 4, 0, 10), 10, (5, 2, 5, 3), True, 10),  # short form, x the master (e a master too)
    ((-1, 1, 1, -1), (12, 3, 12, 0), 12, (0, 1, 0, 0), True, 12),
    ((1, -1, 1, 1), (0, 9, 4, 9), 9, (0, 1, 8, 2), True, 9),  # y the master (with one motor: a dwell)
    ((1, 1, -1, 1), (8, 5, 0, 3), 8, (0, 4, 7, 1), False, 8),
    ((-1, 1, 1, 1), (0, 0, 0, 6), 6, (0, 0, 0, 0), False, 6),  # e the master (with fewer motors: a dwell)
    ((1, 1, 1, -1), (300, 299, 1, 150), 300, (150, 0, 299, 7), False, 300),  # long: modulus > 255
    ((1, 1, 1, 1), (0, 0, 0, 0), 1, (0, 0, 0, 0), True, 2),  # a dwell of two events
    ((-1, -1, -1, -1), (40, 40, 39, 1), 40, (0, 39, 20, 39), False, 40),
]


def cut(blocks, n):
    return [(d[:n], s[:n], mod, i[:n], tool, ev) for d, s, mod, i, tool, ev in blocks]


def check_pulses(schedule, trace, prefix=False):
    """The simulated pulses against the twin's: motor, direction, order, and each within the latency of its tick;
    with `prefix`, the first of them (the player stopped early)."""
    twin = predict(schedule)
    for m in range(len(schedule.motors)):
        mine = trace.run_only().step_motor == m
        cycles = trace.run_only().step_cycle[mine]
        ticks, dirs = twin.of_motor(m)
        n = len(cycles) if prefix else len(ticks)
        assert len(cycles) == n <= len(ticks), f"motor {schedule.motors[m]}: pulse count"
        assert np.array_equal(trace.run_only().step_dir[mine], dirs[:n]), f"motor {schedule.motors[m]}: dirs"
        late = cycles - trace.timer_start_cycle - CYCLES * ticks[:n]
        assert len(late) == 0 or MIN_LATE <= late.min() <= late.max() <= MAX_LATE, f"motor {schedule.motors[m]}"
    pulse, setup = F_CPU * 2 // 1_000_000, F_CPU // 1_000_000  # the config's 2 us STEP pulse, 1 us DIR setup
    assert all(h is None or h >= pulse for h in trace.pulse_high_min_cycles)
    assert all(s is None or s >= setup for s in trace.dir_setup_min_cycles)
    return twin


@dataclass
class Scripted:
    """A host that does `actions` (time in s, HostLink method name) at their times, and notes when each kind of
    frame from the firmware came last, and when its frames reach the firmware (the line: 10 bit times a byte)."""

    link: HostLink
    actions: list[tuple[float, str]] = field(default_factory=list)
    arrived: dict[int, float] = field(default_factory=dict)
    sent: dict[int, float] = field(default_factory=dict)  # frame kind: when its last copy's last byte arrives
    parser: protocol.Parser = field(default_factory=lambda: protocol.Parser(protocol.MAX_ANSWER))
    line: protocol.Parser = field(default_factory=protocol.Parser)
    line_free: float = 0.0

    @property
    def done(self) -> bool:
        return self.link.done

    def wake_at(self):
        times = [t for t in (self.link.wake_at(), *(t for t, _ in self.actions[:1])) if t is not None]
        return min(times, default=None)

    def transmit(self, now):
        while self.actions and now >= self.actions[0][0]:
            getattr(self.link, self.actions.pop(0)[1])()
        data = self.link.transmit(now)
        self.line_free = max(self.line_free, now)
        for f in self.line.feed(data):
            self.line_free += (protocol.OVERHEAD_BYTES + len(f.payload)) * BYTE_S
            self.sent[f.kind] = self.line_free
        return data

    def receive(self, data, now):
        self.arrived.update((f.kind, now) for f in self.parser.feed(data))
        self.link.receive(data, now)


# tests/firmware/avr/test_jog.py's plotter (test_stream_jog.py streams it)
JOB = """name: jogavr
target: avr
board: ramps-1.4
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: {spm}, max_velocity: 100, max_accel: 1500, range: [0, 200]}}
    y: {{steps_per_mm: {spm}, max_velocity: 100, max_accel: 1500, range: [0, 200]}}
  jog: {{speeds: [{speeds}]}}
program:
  feed: 1200
  shapes:
    - line: {{from: [0, 0], to: [2, 1]}}
"""

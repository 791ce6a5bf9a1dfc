"""The 8051 streaming firmware tests' shared parts (tests/firmware/mcs51/test_stream.py, test_stream_iram.py): the
clock and the link's baud rate, a board's stream config and image, the hand-made short program, the pulse check
against the twin."""

from __future__ import annotations

from functools import partial

import numpy as np

import codegen.tables.format as tables
from codegen.firmware.config import FirmwareConfig, MotorPins
from codegen.firmware.mcs51.stream import build_stream_image, render_stream_sources
from codegen.link import protocol
from codegen.tables.twin import predict
from tests.helpers import make_schedule as hand_schedule

F_CPU, TICK_HZ, BAUD = 12_000_000, 1_000_000, 9600
CLOCKS = F_CPU // TICK_HZ  # CPU clocks per timer tick (machine cycle)
# Around the constant latency: the step interrupt waits for the instruction of main or of the link's interrupt
# that is running (2 machine cycles at most: neither has MUL or DIV), one more after a RETI, and the sampling.
TOLERANCE = 2 + 4 * CLOCKS
BUDGET = 10 * F_CPU  # clocks: 10 s simulated
MOTORS, SOCKETS = ("a", "b", "c"), ("X", "Y", "Z")
make_schedule = partial(hand_schedule, tick_hz=TICK_HZ)


def config(board="seed-51", homing=(), baud=0, motors=MOTORS):
    pins = tuple(MotorPins(n, s, invert_dir=n == "b") for n, s in zip(motors, SOCKETS))
    return FirmwareConfig("stream", "tests/firmware/mcs51/test_stream.py", "mcs51", board, pins, homing=homing, baud=baud)


def build(cfg, out_dir):
    image = build_stream_image(render_stream_sources(cfg), out_dir)
    return image, cfg


def short_schedule():
    """Short and long blocks and runs, runs going on across blocks, a dwell with waits past 0xFFFF ticks, the tool
    on and off (test_mcs51_firmware's first program)."""
    return make_schedule(MOTORS, [
        ((1, 1, -1), (200, 150, 50), 200, (100, 100, 100), True,
         [(2000 * 256, -1000, 120), (1530 * 256 + 77, 0, 80)]),
        ((1, 1, 1), (0, 0, 0), 1, (0, 0, 0), False, [(70_000 * 256 + 123, 0, 1), (300_000 * 256, -2_000_000, 3)]),
        ((-1, 1, 1), (37, 100, 0), 100, (5, 99, 0), True, [(1500 * 256 + 77, 300, 100)]),
        ((1, -1, 1), (3, 7, 11), 11, (0, 6, 10), False, [(900 * 256, 0, 11)]),
    ], final_tool=True)


def stream_of(schedule):
    return tables.encode(schedule).data + protocol.tail_padding(len(schedule.motors))


def check_pulses(schedule, trace, whole=True):
    """The trace's pulses are the twin's (all of them, or the first ones of each motor), each at 12 x its tick
    after tick 0 plus one constant latency; the number of pulses per motor."""
    twin = predict(schedule)
    late, made = [], []
    for m in range(len(schedule.motors)):
        ticks, dirs = twin.of_motor(m)
        mine = trace.step_motor == m
        made.append(int(mine.sum()))
        assert made[-1] == len(ticks) if whole else made[-1] <= len(ticks), f"motor {m}: pulse count"
        assert np.array_equal(trace.step_dir[mine], dirs[:made[-1]]), f"motor {m}: directions"
        late.append(trace.step_cycle[mine] - trace.timer_start_cycle - CLOCKS * ticks[:made[-1]])
    late = np.concatenate(late)
    if len(late):
        assert 0 < np.median(late) < 20 * CLOCKS and np.ptp(late) <= TOLERANCE, "a pulse off its tick"
    return made


def net_steps(trace):
    return tuple(int(trace.step_dir[trace.step_motor == m].sum()) for m in range(len(MOTORS)))

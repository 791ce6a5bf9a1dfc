"""An 8051 stream's records written as they come (codegen/sim/mcs51_edges.py EdgeRecords, codegen/sim/mcs51_line.py
UartLine) give what the whole run's decoding gives (codegen/sim/mcs51.py trace_of, the line's old reckoning)."""

from __future__ import annotations

import random

import numpy as np
import pytest

from codegen.firmware.config import FirmwareConfig, MotorPins
from codegen.firmware.mcs51.board import board_pins
from codegen.sim.avr_edges import EdgeDecoder, read_edges
from codegen.sim.mcs51 import TAG_TIMER, trace_of
from codegen.sim.mcs51_edges import EdgeRecords, mcs51_run_pins
from codegen.sim.mcs51_line import UartLine

CONFIG = FirmwareConfig("edges", "tests/sim/test_mcs51_edges.py", "mcs51", "seed-51",
                        (MotorPins("x", "X"), MotorPins("y", "Y", invert_dir=True)))


def _records(seed: int) -> np.ndarray:
    """Random latch writes to the ports of the motors', the tool's and the enables' pins, a timer start among them."""
    pins = board_pins(CONFIG)
    ports = sorted({p.port for m in pins["motors"] for p in (m["step"], m["dir"], m["enable"])} | {pins["tool"].port})
    rng = random.Random(seed)
    clock, rows = 0, []
    for k in range(3000):
        clock += rng.randint(1, 40)
        rows.append((clock, TAG_TIMER, 0) if k == 700 else (clock, rng.choice(ports), rng.randint(0, 255)))
    return np.array(rows, dtype=np.int64)


@pytest.mark.parametrize("seed, piece", [(1, 1), (2, 17), (3, 5000)])
def test_the_edges_file_decodes_to_the_whole_runs_pulses_and_pins(tmp_path, seed, piece):
    rec = _records(seed)
    sink = EdgeRecords(tmp_path / "edges.bin", CONFIG)
    for start in range(0, len(rec), piece):
        sink.add(rec[start:start + piece])
    sink.close()
    layout = mcs51_run_pins(CONFIG)
    decoder = EdgeDecoder(list(layout.invert_dir), list(layout.names[4:]), 0, layout.reset_level)
    steps = decoder.feed(read_edges(tmp_path / "edges.bin"))
    start = int(rec[rec[:, 1] == TAG_TIMER, 0][0])
    whole = trace_of(rec, board_pins(CONFIG), 12_000_000, int(rec[-1, 0]), None, start)
    assert len(steps.cycle) > 500
    assert steps.cycle.tolist() == whole.step_cycle.tolist()
    assert steps.motor.tolist() == whole.step_motor.tolist() and steps.dir.tolist() == whole.step_dir.tolist()
    assert decoder.width_min == whole.pulse_high_min_cycles
    assert decoder.setup_min == whole.dir_setup_min_cycles
    assert decoder.starts().tolist() == [start]
    waves = decoder.waves()
    for name in ("tool", "x.enable", "y.enable"):
        assert waves[name].initial == whole.pins[name].initial == 1
        assert waves[name].cycle.tolist() == whole.pins[name].cycle.tolist()
        assert waves[name].level.tolist() == whole.pins[name].level.tolist()


def _lost_whole(arrivals: list[int], reads: list[int], now: int, byte_clocks: int) -> int:
    """The line's reckoning over every byte and read at once (codegen/sim/mcs51_link.py's before UartLine)."""
    done = [t for t in arrivals if t + byte_clocks <= now]
    late = sum(1 for k in range(1, min(len(done), len(reads) + 1)) if reads[k - 1] > done[k])
    return max(late, len(done) - len(reads))


@pytest.mark.parametrize("seed", range(6))
def test_the_lines_lost_bytes_counted_as_they_come_are_the_whole_reckonings(seed):
    rng, byte_clocks = random.Random(seed), 1000
    line, arrivals, reads, now = UartLine(byte_clocks), [], [], 0
    for _ in range(400):
        now += rng.randint(0, 3000)
        if rng.random() < 0.3:
            count = rng.randint(1, 6)
            line.send(count, now)
            for _ in range(count):
                arrivals.append(max(arrivals[-1] if arrivals else 0, now) + byte_clocks)
        if len(reads) < len(arrivals) and rng.random() < 0.7:
            clock = max(now, arrivals[len(reads)]) + rng.choice([0, 0, 500, 1500])  # some late
            reads.append(clock)
            line.reading(clock)
            now = max(now, clock)
        line.judge(now)
        assert line.waiting() == (len(reads) < len(arrivals) - 1)
    expected = _lost_whole(arrivals, reads, now, byte_clocks)
    assert expected > 0
    assert line.lost_bytes(now) == expected
    assert line._judged > len(arrivals) // 2  # the judged bytes are gone: the line holds the rest

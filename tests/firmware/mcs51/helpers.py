"""The 8051 flash player tests' shared parts (tests/firmware/mcs51/): a hand-made schedule's config, its build and
run in s51, the check of every pulse against tests/reference_player.py; the jog plotter's job file."""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np

from codegen.firmware.config import FirmwareConfig, MotorPins
from codegen.firmware.mcs51.image import build_image, render_sources
from codegen.sim.mcs51 import simulate
from codegen.tables.format import stream_bytes
from tests.helpers import make_schedule as hand_schedule
from tests.reference_player import play

CLOCKS = 12  # CPU clocks per timer tick (machine cycle)
TOLERANCE = 2  # clocks around the constant overflow-to-edge latency
# On a board with a display main runs between interrupts: an interrupt waits up to one machine cycle more for the
# end of main's instruction (the display driver has no 4-cycle MUL or DIV).
BUSY_TOLERANCE = TOLERANCE + CLOCKS
make_schedule = partial(hand_schedule, tick_hz=1_000_000)


def config(motors, sockets, board="at89c52", inverted=(), pulse_us=2.0):
    pins = tuple(MotorPins(n, s, invert_dir=n in inverted) for n, s in zip(motors, sockets))
    return FirmwareConfig("test", "tests/firmware/mcs51/test_firmware.py", "mcs51", board, pins, step_pulse_us=pulse_us)


def build_and_run(schedule, cfg, out_dir, budget=400_000_000):
    image = build_image(render_sources(schedule, cfg), out_dir, stream_bytes(schedule))
    return image, simulate(image.hex_path, cfg, budget)


def check_plays(schedule, cfg, trace):
    """Same pulses (motor, dir, order) as the reference, each at 12 x its tick + one constant latency."""
    pulses = play(schedule)
    assert trace.state == "done"
    ticks = np.array([t for t, _, _ in pulses], dtype=np.int64)
    motors = np.array([m for _, m, _ in pulses], dtype=np.int64)
    late = np.zeros(len(pulses), dtype=np.int64)
    for m in range(len(schedule.motors)):
        ref_dirs = [d for _, mm, d in pulses if mm == m]
        mine = trace.step_motor == m
        assert mine.sum() == len(ref_dirs), f"motor {schedule.motors[m]}: pulse count"
        assert np.array_equal(trace.step_dir[mine], ref_dirs), f"motor {schedule.motors[m]}: dirs"
        late[motors == m] = trace.step_cycle[mine] - trace.timer_start_cycle - CLOCKS * ticks[motors == m]
    latency = int(np.median(late)) if len(late) else 0
    tolerance = BUSY_TOLERANCE if cfg.board == "seed-51" else TOLERANCE
    assert np.abs(late - latency).max(initial=0) <= tolerance, "a pulse off its scheduled tick"
    assert len(late) == 0 or 0 < latency < 20 * CLOCKS
    pulse = int(np.ceil(cfg.step_pulse_us * 12))
    assert all(h is None or h >= pulse for h in trace.pulse_high_min_cycles)
    setup = int(np.ceil(cfg.dir_setup_us * 12))
    assert all(s is None or s >= setup for s in trace.dir_setup_min_cycles)
    return latency


# tests/firmware/mcs51/test_jog.py's plotter (tests/firmware/avr/test_stream_jog.py's 8051 refusal too)
JOB = """name: jog51
target: mcs51
board: {board}
machine:
  kinematics: {kinematics}
  steppers:
    {a}: {{steps_per_mm: {spm}, max_velocity: 40, max_accel: 1000, range: [0, 200]}}
    {b}: {{steps_per_mm: {spm}, max_velocity: 40, max_accel: 1000, range: [0, 200]}}
  jog: {{speeds: [150, 600, 2400]}}
program:
  feed: 1200
  shapes:
    - line: {{from: [0, 0], to: [2, 1]}}
"""


def job_file(folder: Path, board: str = "seed-51", kinematics: str = "cartesian", spm: int = 40) -> Path:
    """A plotter whose fastest jog level is its motors' max_velocity (1,568 steps/s at 40 steps/mm)."""
    a, b = ("x", "y") if kinematics == "cartesian" else ("a", "b")
    path = folder / f"jog51-{spm}.yaml"
    path.write_text(JOB.format(board=board, kinematics=kinematics, a=a, b=b, spm=spm))
    return path

"""Homing at power-up on the ATmega2560, end to end with the real avr-gcc and simavr: the harness closes each
homed motor's switch at a chosen position, and the simulated homing steps, their phases, directions and
intervals, the failures and the step table played afterwards are checked against what they must be.
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from codegen.errors import BuildError
from codegen.firmware.avr.image import build_image, render_sources
from codegen.firmware.config import FirmwareConfig, MotorPins
from codegen.firmware.homing import PHASE_PAUSE_US, backoff_limit, homing_steps
from codegen.program.homing import HomingAxis
from codegen.sim.avr import PHASE_HOME, PHASE_RUN, simulate
from codegen.tables.format import stream_bytes
from tests.firmware.avr.helpers import make_schedule
from tests.reference_player import play

F_CPU = 16_000_000
CYCLES = 8  # CPU cycles per Timer1 tick (tick_hz 2 MHz): homing intervals are in ticks, as the player's times
JITTER = 3  # cycles: a homing step's edge around its interval (the OCF1A polling loop is 3 cycles)
LATENCY_TOLERANCE = 4  # cycles around the player's constant compare-match-to-edge latency
PULSE_CYCLES, DIR_SETUP_CYCLES = 32, 16  # 2 us and 1 us at 16 MHz, FirmwareConfig's defaults
PAUSE_CYCLES = int(PHASE_PAUSE_US * F_CPU / 1e6)

# A delta-like machine: towers on X, Y, Z homing up to their max switches, then a small table.
DELTA_SWITCHES = ("x_max", "y_max", "z_max")
DELTA_SCHEDULE = make_schedule(("a", "b", "c"), [
    ((-1, -1, -1), (120, 80, 40), 120, (60, 60, 60), True, [(900 * 256, 0, 120)]),
    ((1, -1, 1), (30, 60, 15), 60, (0, 30, 59), False, [(1200 * 256 + 50, -40, 60)]),
])


def homing(motor, switch, direction, fast, slow, backoff, max_steps=2000):
    return HomingAxis(motors=(motor,), motor_directions=(direction,), switch=switch, direction=direction,
                      max_steps=max_steps, fast_interval=fast, slow_interval=slow, backoff_steps=backoff)


def delta_config(max_steps=2000):
    motors = tuple(MotorPins(n, s) for n, s in zip(("a", "b", "c"), ("X", "Y", "Z")))
    axes = tuple(homing(m, sw, 1, 500, 1500, 50, max_steps) for m, sw in enumerate(DELTA_SWITCHES))
    return FirmwareConfig("delta", "tests/firmware/avr/test_homing.py", "avr", "ramps-1.4", motors, homing=axes)


def build_and_run(schedule, cfg, out_dir, switches, budget=100_000_000):
    image = build_image(render_sources(schedule, cfg), out_dir, stream_bytes(schedule))
    return image, simulate(image.hex_path, cfg, budget, switches=switches)


def home_steps_of(trace, motor):
    mine = (trace.step_motor == motor) & (trace.step_phase == PHASE_HOME)
    return trace.step_cycle[mine], trace.step_dir[mine]


def check_homing(trace, axis, distance):
    """The motor's homing steps: (fast approach, back off, slow approach) counts and directions, the step
    intervals in each phase, the pause between phases, and where it stops (the switch's position)."""
    cycles, dirs = home_steps_of(trace, axis.motors[0])
    fast, back, slow = homing_steps(axis, distance)
    want = [axis.direction] * fast + [-axis.direction] * back + [axis.direction] * slow
    assert dirs.tolist() == want
    assert int(dirs.sum()) * axis.direction == distance  # at the switch again
    for lo, hi, interval in ((0, fast, axis.fast_interval), (fast, fast + back, axis.fast_interval),
                             (fast + back, fast + back + slow, axis.slow_interval)):
        gaps = np.diff(cycles[lo:hi])
        assert len(gaps) == 0 or np.abs(gaps - CYCLES * interval).max() <= JITTER, \
            f"motor {axis.motors[0]}: step intervals"
    # Each phase starts after a pause: at least pause + interval after the motor's previous step.
    for first, interval in ((fast, axis.fast_interval), (fast + back, axis.slow_interval)):
        if 0 < first < len(cycles):
            assert cycles[first] - cycles[first - 1] >= PAUSE_CYCLES + CYCLES * interval - JITTER
    return len(cycles)


def check_run(schedule, trace):
    """The run phase against tests/reference_player.py: same pulses, each at its tick + one constant latency."""
    run = trace.run_only()
    pulses = play(schedule)
    late = np.zeros(len(pulses), dtype=np.int64)
    motors = np.array([m for _, m, _ in pulses])
    ticks = np.array([t for t, _, _ in pulses])
    for m in range(len(schedule.motors)):
        mine = run.step_motor == m
        assert mine.sum() == (motors == m).sum(), f"motor {m}: run-phase pulse count"
        assert run.step_dir[mine].tolist() == [d for _, mm, d in pulses if mm == m]
        late[motors == m] = run.step_cycle[mine] - run.timer_start_cycle - CYCLES * ticks[motors == m]
    latency = int(np.median(late))
    assert 0 < latency < 40 and np.abs(late - latency).max() <= LATENCY_TOLERANCE


def test_delta_homes_to_its_max_switches_then_plays_the_table(tmp_path):
    cfg = delta_config()
    distances = {0: 400, 1: 650, 2: 900}
    image, trace = build_and_run(DELTA_SCHEDULE, cfg, tmp_path, distances)
    assert trace.state == "done" and not trace.homing_failed and trace.homing_fault is None
    for axis in cfg.homing:
        d = distances[axis.motors[0]]
        assert homing_steps(axis, d) == (d, 50, 50)
        assert check_homing(trace, axis, d) == d + 2 * 50
    # Every homing step comes before the table's tick 0, every table step after it.
    home = trace.step_phase == PHASE_HOME
    assert set(trace.step_phase.tolist()) == {PHASE_HOME, PHASE_RUN}
    assert trace.step_cycle[home].max() < trace.timer_start_cycle < trace.step_cycle[~home].min()
    check_run(DELTA_SCHEDULE, trace)
    # STEP and DIR timing over all steps, homing included; the tool stays off until homing is over.
    assert min(trace.pulse_high_min_cycles) >= PULSE_CYCLES
    assert min(trace.dir_setup_min_cycles) >= DIR_SETUP_CYCLES
    assert trace.tool_edges[0][0] > trace.step_cycle[home].max() and trace.tool_edges[0][1] == 1
    # The image: homing code of its own, integers only, same sources every time.
    assert image.flash_parts["homing"] > 0 and sum(image.flash_parts.values()) == image.flash_bytes
    sources = render_sources(DELTA_SCHEDULE, cfg)
    assert sources == render_sources(DELTA_SCHEDULE, cfg) and "home_axes();" in sources["player.c"]
    symbols = subprocess.run(["avr-nm", str(image.elf_path)], capture_output=True, text=True, check=True).stdout
    for helper in ("divmod", "__mul", "sf3", "sqrt", "__fix", "__float"):
        assert helper not in symbols


def test_switches_closed_at_power_up(tmp_path):
    """A carriage already on its switch: no fast steps, the back off goes on until the switch opens (one that
    opens only 71 steps back, past backoff_steps = 50, as with hysteresis), the slow approach closes it again."""
    cfg = delta_config()
    distances = {0: 0, 1: -5, 2: -70}
    image, trace = build_and_run(DELTA_SCHEDULE, cfg, tmp_path, distances)
    assert not trace.homing_failed
    assert [homing_steps(a, distances[a.motors[0]]) for a in cfg.homing] == [(0, 50, 50), (0, 50, 45), (0, 71, 1)]
    for axis in cfg.homing:
        check_homing(trace, axis, distances[axis.motors[0]])
    check_run(DELTA_SCHEDULE, trace)
    # Without `switches`, the machine starts on its switches (position 0); the budget is the table's alone.
    trace = simulate(image.hex_path, cfg, 3_000_000)
    for axis in cfg.homing:
        assert check_homing(trace, axis, 0) == 100
    check_run(DELTA_SCHEDULE, trace)


def test_a_switch_that_never_closes_stops_the_machine(tmp_path):
    cfg = delta_config(max_steps=1000)
    _, trace = build_and_run(DELTA_SCHEDULE, cfg, tmp_path, {0: 400, 2: 900})  # motor b: no switch position
    assert trace.state == "done" and trace.homing_failed
    assert "fast approach" in trace.homing_fault and "motor b (switch y_max)" in trace.homing_fault
    assert trace.timer_start_cycle is None and not (trace.step_phase == PHASE_RUN).any()
    cycles, dirs = home_steps_of(trace, 1)
    assert len(cycles) == 1000 and (dirs == 1).all()  # exactly max_steps, then the error state
    assert len(home_steps_of(trace, 0)[0]) == 400 and len(home_steps_of(trace, 2)[0]) == 900
    assert trace.tool_edges == []


def test_a_switch_stuck_closed_fails_when_backing_off(tmp_path):
    cfg = delta_config()
    stuck = -10**9  # closed everywhere above this: closed from the start, never opens
    _, trace = build_and_run(DELTA_SCHEDULE, cfg, tmp_path, {0: 400, 1: 650, 2: stuck})
    assert trace.homing_failed and "back off" in trace.homing_fault and "motor c" in trace.homing_fault
    cycles, dirs = home_steps_of(trace, 2)
    assert len(cycles) == backoff_limit(cfg.homing[2]) == 100 and (dirs == -1).all()  # no fast steps
    assert not (trace.step_phase == PHASE_RUN).any()


def test_cartesian_homes_x_and_y_to_their_min_switches(tmp_path):
    """Direction -1, different intervals and backoffs per motor, an inverted DIR, the MKS GEN L board file, a
    table that starts with a long wait."""
    sched = make_schedule(("x", "y"), [  # a first event past 0xFFFF ticks: the player starts on its long wait
        ((1, 1), (0, 0), 1, (0, 0), False, [(70_000 * 256 + 9, 0, 1)]),
        ((1, 1), (200, 100), 200, (100, 100), False, [(700 * 256, 0, 200)])])
    motors = (MotorPins("x", "X"), MotorPins("y", "Y", invert_dir=True))
    axes = (homing(0, "x_min", -1, 375, 1125, 30), homing(1, "y_min", -1, 625, 1875, 40))
    cfg = FirmwareConfig("plotter", "tests/firmware/avr/test_homing.py", "avr", "mks-gen-l", motors, homing=axes)
    distances = {0: -300, 1: -120}
    _, trace = build_and_run(sched, cfg, tmp_path, distances)
    assert not trace.homing_failed
    assert check_homing(trace, axes[0], 300) == 300 + 60
    assert check_homing(trace, axes[1], 120) == 120 + 80
    assert home_steps_of(trace, 0)[1][:300].tolist() == [-1] * 300  # towards x_min
    check_run(sched, trace)
    assert min(trace.dir_setup_min_cycles) >= DIR_SETUP_CYCLES and min(trace.pulse_high_min_cycles) >= PULSE_CYCLES


def test_an_image_without_homing_is_unchanged(tmp_path):
    sched = make_schedule(("x",), [((1,), (5,), 5, (2,), False, [(500 * 256, 0, 5)])])
    cfg = FirmwareConfig("plain", "tests/firmware/avr/test_homing.py", "avr", "ramps-1.4", (MotorPins("x", "X"),))
    sources = render_sources(sched, cfg)
    assert "homing.c" not in sources and "home" not in sources["player.c"] and "SWITCH" not in sources["config.h"]
    image = build_image(sources, tmp_path, stream_bytes(sched))
    assert "homing" not in image.flash_parts
    trace = simulate(image.hex_path, cfg, 10_000_000)
    assert trace.step_phase.tolist() == [PHASE_RUN] * 5 and not trace.homing_failed
    with pytest.raises(ValueError, match="does not home"):
        simulate(image.hex_path, cfg, 10_000_000, switches={0: 10})


def test_bad_homing_configs_are_refused_with_every_problem():
    sched = make_schedule(("x", "y"), [((1, 1), (5, 5), 5, (2, 2), False, [(500 * 256, 0, 5)])])
    axes = (homing(0, "x_top", 1, 500, 1000, 10), homing(0, "x_min", 2, 50, 1000, 0),
            homing(5, "y_min", 1, 500, 1000, 10))
    cfg = FirmwareConfig("bad", "t.py", "avr", "ramps-1.4", (MotorPins("x", "X"), MotorPins("y", "Y")), homing=axes)
    with pytest.raises(BuildError) as error:
        render_sources(sched, cfg)
    text = str(error.value)
    for part in ("no endstop `x_top`", "homed twice", "direction must be +1 or -1", "fast_interval = 50",
                 "backoff_steps = 0", "motor index 5 out of range"):
        assert part in text

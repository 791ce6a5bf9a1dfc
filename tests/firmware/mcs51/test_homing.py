"""Homing at power-up on the 8051, end to end with the real SDCC and s51: the s51 script plays each homed motor's
endstop key from its STEP and DIR pins, and the simulated homing steps, their phases, directions and intervals,
the faults and the step table played afterwards are checked against what they must be.
"""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest

from codegen.cli.main import main
from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig, MotorPins
from codegen.firmware.homing import PHASE_PAUSE_US, backoff_limit, homing_steps
from codegen.firmware.mcs51.image import build_image, render_sources
from codegen.firmware.mcs51.sdcc import MAP_FILE
from codegen.program.homing import HomingAxis
from codegen.sim.mcs51 import PHASE_HOME, PHASE_RUN, simulate
from codegen.tables.format import stream_bytes
from tests.firmware.mcs51.helpers import check_plays, make_schedule
from tests.helpers import ROOT

pytestmark = pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None,
                                reason="needs sdcc and s51 (scripts/setup.sh installs them)")

CLOCKS = 12  # CPU clocks per timer tick (machine cycle)
JITTER = CLOCKS  # a homing step comes 0 or 1 machine cycle after its tick (the 2-cycle TF1 poll loop)
PAUSE_CLOCKS = int(PHASE_PAUSE_US) * CLOCKS  # 1 MHz ticks

# A delta-like machine: towers on X, Y, Z homing up to their max keys, then a small table.
DELTA_KEYS = ("x_max", "y_max", "z_max")
DELTA_SCHEDULE = make_schedule(("a", "b", "c"), [
    ((-1, -1, -1), (120, 80, 40), 120, (60, 60, 60), True, [(900 * 256, 0, 120)]),
    ((1, -1, 1), (30, 60, 15), 60, (0, 30, 59), False, [(1200 * 256 + 50, -40, 60)]),
])


def homing(motor, switch, direction, fast, slow, backoff, max_steps=2000):
    return HomingAxis(motors=(motor,), motor_directions=(direction,), switch=switch, direction=direction,
                      max_steps=max_steps, fast_interval=fast, slow_interval=slow, backoff_steps=backoff)


def delta_config(max_steps=2000, board="at89c52"):
    motors = tuple(MotorPins(n, s) for n, s in zip(("a", "b", "c"), ("X", "Y", "Z")))
    axes = tuple(homing(m, key, 1, 1000, 3000, 50, max_steps) for m, key in enumerate(DELTA_KEYS))
    return FirmwareConfig("delta", "tests/firmware/mcs51/test_homing.py", "mcs51", board, motors, homing=axes)


def build_and_run(schedule, cfg, out_dir, switches, budget=100_000_000):
    image = build_image(render_sources(schedule, cfg), out_dir, stream_bytes(schedule))
    return image, simulate(image.hex_path, cfg, budget, switches=switches)


def home_steps_of(trace, motor):
    mine = (trace.step_motor == motor) & (trace.step_phase == PHASE_HOME)
    return trace.step_cycle[mine], trace.step_dir[mine]


def check_homing(trace, axis, distance):
    """The motor's homing steps against homing_steps(): their directions, one interval apart (within JITTER)
    inside each phase, at least the pause and an interval apart from one phase to the next."""
    cycles, dirs = home_steps_of(trace, axis.motors[0])
    fast, back, slow = homing_steps(axis, distance)
    assert dirs.tolist() == [axis.direction] * fast + [-axis.direction] * back + [axis.direction] * slow
    gaps = np.diff(cycles)
    interval = np.array([axis.fast_interval] * (fast + back) + [axis.slow_interval] * slow)[1:] * CLOCKS
    firsts = np.array(sorted({fast, fast + back} - {0, len(cycles)}), dtype=int) - 1  # gaps into a new phase
    inside = np.ones(len(gaps), dtype=bool)
    inside[firsts] = False
    assert np.abs(gaps[inside] - interval[inside]).max(initial=0) <= JITTER, f"motor {axis.motors[0]}: intervals"
    assert np.all(gaps[firsts] >= PAUSE_CLOCKS + interval[firsts] - JITTER), f"motor {axis.motors[0]}: pauses"
    return len(cycles)


def test_delta_homes_to_its_max_keys_then_plays_the_table(tmp_path):
    cfg = delta_config()
    distances = {0: 400, 1: 650, 2: 900}
    image, trace = build_and_run(DELTA_SCHEDULE, cfg, tmp_path, distances)
    assert trace.state == "done" and not trace.homing_failed and trace.homing_fault is None
    for axis in cfg.homing:
        d = distances[axis.motors[0]]
        assert homing_steps(axis, d) == (d, 50, 50)
        assert check_homing(trace, axis, d) == d + 2 * 50
    # Every homing step before the player's timer starts, every table step after it; the table as it must play.
    home = trace.step_phase == PHASE_HOME
    assert set(trace.step_phase.tolist()) == {PHASE_HOME, PHASE_RUN}
    assert trace.step_cycle[home].max() < trace.timer_start_cycle < trace.step_cycle[~home].min()
    check_plays(DELTA_SCHEDULE, cfg, trace.run_only())
    # STEP and DIR timing over all steps, homing included; the tool stays off until homing is over.
    assert min(trace.pulse_high_min_cycles) >= 2 * CLOCKS and min(trace.dir_setup_min_cycles) >= CLOCKS
    assert trace.tool_edges[0][0] > trace.step_cycle[home].max() and trace.tool_edges[0][1] == 1
    # The image: same sources every time, integers only (no SDCC multiply, divide or float helper linked).
    sources = render_sources(DELTA_SCHEDULE, cfg)
    assert sources == render_sources(DELTA_SCHEDULE, cfg) and "home_axes();" in sources["player.c"]
    assert sources["homing.c"].startswith("/* AUTO-GENERATED by printer-codegen")
    linked = (tmp_path / MAP_FILE).read_text()
    for helper in ("__mul", "__div", "__mod", "___fs", "sqrt"):
        assert helper not in linked
    assert image.flash_bytes <= image.flash_capacity


def test_keys_closed_at_power_up(tmp_path):
    """A carriage already on its key: no fast steps, the back off goes on until the key opens (one that opens only
    71 steps back, past backoff_steps = 50, as with hysteresis), the slow approach closes it again."""
    cfg = delta_config()
    distances = {0: 0, 1: -5, 2: -70}
    image, trace = build_and_run(DELTA_SCHEDULE, cfg, tmp_path, distances)
    assert not trace.homing_failed
    assert [homing_steps(a, distances[a.motors[0]]) for a in cfg.homing] == [(0, 50, 50), (0, 50, 45), (0, 71, 1)]
    for axis in cfg.homing:
        check_homing(trace, axis, distances[axis.motors[0]])
    check_plays(DELTA_SCHEDULE, cfg, trace.run_only())
    # Without `switches`, the machine starts on its keys (position 0); the budget is the table's alone.
    trace = simulate(image.hex_path, cfg, 3_000_000)  # the table: 180,000 ticks
    assert [check_homing(trace, axis, 0) for axis in cfg.homing] == [100, 100, 100]


def test_a_key_that_never_closes_stops_the_machine(tmp_path):
    cfg = delta_config(max_steps=1000)
    _, trace = build_and_run(DELTA_SCHEDULE, cfg, tmp_path, {0: 400, 2: 900})  # motor b: no key position
    assert trace.state == "done" and trace.homing_failed
    assert "fast approach" in trace.homing_fault and "motor b (switch y_max)" in trace.homing_fault
    assert trace.timer_start_cycle is None and not (trace.step_phase == PHASE_RUN).any()
    cycles, dirs = home_steps_of(trace, 1)
    assert len(cycles) == 1000 and (dirs == 1).all()  # exactly max_steps, then the fault state
    assert len(home_steps_of(trace, 0)[0]) == 400 and len(home_steps_of(trace, 2)[0]) == 900
    assert trace.tool_edges == []


def test_a_key_stuck_closed_fails_when_backing_off(tmp_path):
    cfg = delta_config(board="seed-51")  # large memory model, L297 enables (active high)
    stuck = -10**9  # closed everywhere above this: closed from the start, never opens
    _, trace = build_and_run(DELTA_SCHEDULE, cfg, tmp_path, {0: 400, 1: 650, 2: stuck})
    assert trace.homing_failed and "back off" in trace.homing_fault and "motor c (switch z_max)" in trace.homing_fault
    cycles, dirs = home_steps_of(trace, 2)
    assert len(cycles) == backoff_limit(cfg.homing[2]) == 100 and (dirs == -1).all()  # no fast steps
    assert not (trace.step_phase == PHASE_RUN).any()


def test_cartesian_homes_x_and_y_to_their_min_keys(tmp_path):
    """Direction -1, different intervals and backoffs per motor, an inverted DIR, a slow interval past 0xFFFF
    ticks (Timer1 waits in parts), the STC89C52RC board (large memory model), a table that starts with a long
    wait."""
    sched = make_schedule(("x", "y"), [
        ((1, 1), (0, 0), 1, (0, 0), False, [(70_000 * 256 + 9, 0, 1)]),
        ((1, 1), (200, 100), 200, (100, 100), False, [(700 * 256, 0, 200)])])
    motors = (MotorPins("x", "X"), MotorPins("y", "Y", invert_dir=True))
    axes = (homing(0, "x_min", -1, 1000, 70_000, 30), homing(1, "y_min", -1, 1500, 4000, 40))
    cfg = FirmwareConfig("plotter", "tests/firmware/mcs51/test_homing.py", "mcs51", "stc89c52rc", motors, homing=axes)
    _, trace = build_and_run(sched, cfg, tmp_path, {0: -300, 1: -120})
    assert not trace.homing_failed
    assert check_homing(trace, axes[0], 300) == 300 + 60
    assert check_homing(trace, axes[1], 120) == 120 + 80
    assert home_steps_of(trace, 0)[1][:300].tolist() == [-1] * 300  # towards x_min
    check_plays(sched, cfg, trace.run_only())


def test_an_image_without_homing_is_unchanged(tmp_path):
    sched = make_schedule(("x",), [((1,), (5,), 5, (2,), False, [(500 * 256, 0, 5)])])
    cfg = FirmwareConfig("plain", "tests/firmware/mcs51/test_homing.py", "mcs51", "at89c52", (MotorPins("x", "X"),))
    sources = render_sources(sched, cfg)
    assert "homing.c" not in sources and "home_axes" not in sources["player.c"]
    image = build_image(sources, tmp_path, stream_bytes(sched))
    trace = simulate(image.hex_path, cfg, 10_000_000)
    assert trace.step_phase.tolist() == [PHASE_RUN] * 5 and not trace.homing_failed
    with pytest.raises(ValueError, match="does not home"):
        simulate(image.hex_path, cfg, 10_000_000, switches={0: 10})


def test_bad_homing_configs_are_refused_with_every_problem():
    sched = make_schedule(("x", "y", "z"), [((1, 1, 1), (5, 5, 5), 5, (2, 2, 2), False, [(500 * 256, 0, 5)])])
    axes = (homing(0, "x_top", 1, 4000, 8000, 10), homing(0, "x_min", 2, 50, 8000, 0),
            homing(5, "y_min", 1, 4000, 8000, 10), homing(1, "y_min", -1, 4000, 8000, 10),
            homing(2, "y_max", 1, 4000, 8000, 10))
    motors = (MotorPins("x", "X"), MotorPins("y", "Y"), MotorPins("z", "Z"))
    cfg = FirmwareConfig("bad", "t.py", "mcs51", "at89c52", motors, homing=axes)
    with pytest.raises(BuildError) as error:
        render_sources(sched, cfg)
    text = str(error.value)
    for part in ("no endstop `x_top` (has x_min, x_max", "homed twice", "direction must be +1 or -1",
                 "fast_interval = 50 timer ticks is outside", "backoff_steps = 0", "motor index 5 out of range",
                 "endstop y_max is on P3.3, the key of motor y too"):
        assert part in text


def test_a_cartesian_job_that_homes_verifies_through_the_cli(tmp_path, capsys):
    job = tmp_path / "arc-home.yaml"
    job.write_text(re.sub(r"^program:\n", "program:\n  home: true\n", (ROOT / "examples" / "arc.yaml").read_text(),
                          flags=re.M))
    trace = tmp_path / "steps.csv"
    code = main([str(a) for a in ("verify", job, "--target", "mcs51", "--out", tmp_path / "out", "--json",
                                  "--trace", trace)])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and result["pass"], result["problems"]
    # Keys 20 and 35 mm from the start (codegen.verify.compare), 3 mm of back off at 80 steps/mm, each way.
    assert result["homing"] == {
        "x": {"steps": 1600 + 2 * 240, "expected_steps": 1600 + 2 * 240, "net": -1600, "expected_net": -1600,
              "switch": "x_min"},
        "y": {"steps": 2800 + 2 * 240, "expected_steps": 2800 + 2 * 240, "net": -2800, "expected_net": -2800,
              "switch": "y_min"}}
    for motor in result["motors"].values():
        assert motor["final"] == motor["expected_final"] and motor["max_timing_error_us"] <= 5.0
    phases = [row.split(",")[3] for row in trace.read_text().splitlines()[1:]]
    homed = sum(m["steps"] for m in result["homing"].values())
    assert phases[:homed] == ["home"] * homed and set(phases[homed:]) == {"run"}

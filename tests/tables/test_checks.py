"""The checks that judge the twin (and the simulator) find what is wrong: each fault below must be reported."""


import numpy as np

from codegen.pipeline.host import trains_from
from codegen.tables.checks import Checker, MotorTrain, check


def judge(h, trains=None, positions=None):
    """The checks on examples/star.yaml's plan (conftest.py's star_host), its twin's pulses or the given ones."""
    if trains is None:
        trains = trains_from(h.pulses.tick / h.target.tick_hz, h.pulses.motor, h.pulses.dir, len(h.kin.motors))
    if positions is None:
        positions = h.pulses.event_position
    return check(trains, positions, h.event_segments(), h.segments, h.plan, h.kin, h.expected_final,
                 h.start_steps, h.job.machine.tolerance)


def test_the_twin_of_the_star_passes(star_host):
    assert judge(star_host).ok


def test_a_lost_step_is_a_wrong_end_position(star_host):
    h = star_host
    trains = trains_from(h.pulses.tick / h.target.tick_hz, h.pulses.motor, h.pulses.dir, 2)
    last = int(trains[0].dir[-1])
    trains[0] = MotorTrain(trains[0].time[:-1], trains[0].dir[:-1])
    found = judge(h, trains=trains)
    assert found.problems[0] == f"motor a ends at step {h.expected_final[0] - last}, the job ends at step " \
                                f"{h.expected_final[0]}"


def test_a_tool_two_steps_off_the_path_is_reported(star_host):
    shifted = star_host.pulses.event_position.copy()
    shifted[len(shifted) // 2:, 0] += 2  # belt a slips two steps half-way
    found = judge(star_host, positions=shifted)
    assert any(p.startswith("the tool strays") for p in found.problems)
    assert found.max_path_error_mm > found.path_limit_mm


def test_steps_too_close_together_exceed_the_rate(star_host):
    h = star_host
    faster = max(h.findings.rate_ratio.values()) / 1.1  # 10 % over the fastest motor's limit
    trains = trains_from(h.pulses.tick / h.target.tick_hz * faster, h.pulses.motor, h.pulses.dir, 2)
    found = judge(h, trains=trains)
    assert any("exceeds its rate over 8 steps" in p for p in found.problems)


def test_a_velocity_jump_off_the_corners_exceeds_the_acceleration(star_host):
    h = star_host
    time = h.pulses.tick / h.target.tick_hz
    time = np.where(time > 1.0, 1.0 + (time - 1.0) * 0.8, time)  # suddenly 25 % faster after one second
    found = judge(h, trains=trains_from(time, h.pulses.motor, h.pulses.dir, 2))
    assert any("exceeds its acceleration" in p for p in found.problems)


def test_a_block_whose_tool_differs_from_the_programs_is_named(star_host):
    """The tables' tool against the program's, block by block across windows (a compressor that inverted it
    passed every other check: the twin and the simulator both follow the tables)."""
    h = star_host
    checker = Checker(h.kin, h.start_steps, 0.0)
    checker.add_tool(np.array([True, False, True]), np.array([True, True, True]))
    checker.add_tool(np.array([False]), np.array([True]))
    assert checker.findings(h.start_steps).problems == [
        "the tables have the tool off in block 1 where the program has it on (1 blocks of 3 in this window differ)"]
    assert star_host.findings.ok  # the real plan's tables agree with its program

"""Where a program starts on a machine that homes at power-up: where homing leaves the tool, unless the job
gives `start`, which it then reaches by a tool-off travel move from there."""

import numpy as np
import pytest

from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.program.program import whole_toolpath
from codegen.toolpath.items import Line

KOSSEL = """
name: kossel
machine:
  kinematics: delta
  steppers:
    a: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
    b: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
    c: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
  delta: {{radius: 105.2, diagonal_rod: 215, height: 250}}
program:
{start}  feed: 3000
  shapes:
    - points: [[0, 0, 10], [30, 20, 15]]
    - circle: {{center: [0, 0], radius: 40, z: 10}}
    - line: {{to: [-20, 30]}}
"""
CARTESIAN = """
name: plotter
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: 80, max_velocity: 100, max_accel: 2000, range: [-5, 200]}}
    y: {{steps_per_mm: 80, max_velocity: 100, max_accel: 2000, range: [-10, 200]}}
program:
{start}  home: {home}
  shapes:
    - line: {{from: [20, 20], to: [60, 40]}}
"""


class Built:
    """The host build and the whole toolpath of a job."""

    def __init__(self, path):
        job = load_job(path)
        self.host = host_build(job)
        self.toolpath = whole_toolpath(job, self.host.kin, self.host.settings.homing)[0]
        self.findings, self.kin, self.start_steps = self.host.findings, self.host.kin, self.host.start_steps


def build(tmp_path, text):
    job = tmp_path / "job.yaml"
    job.write_text(text)
    return Built(job)


def test_a_delta_without_start_starts_where_homing_leaves_it(tmp_path):
    host = build(tmp_path, KOSSEL.format(start=""))
    assert host.findings.ok, host.findings.problems
    assert host.findings.final == host.findings.expected_final
    home = host.kin.home()
    assert np.allclose(host.toolpath.start, home)
    first = host.toolpath.items[0]
    assert isinstance(first, Line) and not first.tool and np.allclose(first.start, home)
    assert np.allclose(first.end[:3], [0, 0, 10])  # straight to the first point
    # Every carriage at the top of its tower: the height plus the rod's rise over the centre, in steps.
    assert host.start_steps.tolist() == np.rint(host.kin.to_motor(home[None, :3])[0] * 80).astype(int).tolist()


def test_an_explicit_start_is_reached_by_travel_after_homing(tmp_path):
    host = build(tmp_path, KOSSEL.format(start="  start: [10, 10, 100]\n"))
    assert host.findings.ok, host.findings.problems
    down, across, to_first = host.toolpath.items[:3]
    # Straight down from home first (the carriages are at their tops), then across to `start`.
    assert np.allclose(down.start, host.kin.home()) and np.allclose(down.end[:3], [0, 0, 100])
    assert np.allclose(across.start[:3], [0, 0, 100]) and np.allclose(across.end[:3], [10, 10, 100])
    for travel in (down, across):  # tool off, positioned at `start` in the job file
        assert not travel.tool and (travel.source.line, travel.source.col) == (11, 10)
    assert np.allclose(to_first.start[:3], [10, 10, 100]) and np.allclose(to_first.end[:3], [0, 0, 10])


@pytest.mark.parametrize("home", [True, False])
def test_cartesian_start_with_and_without_homing(tmp_path, home):
    host = build(tmp_path, CARTESIAN.format(start="", home=str(home).lower()))
    assert host.findings.ok, host.findings.problems
    # Homed: the low ends of the ranges (the min switches); not homed: JOB-FORMAT's default, the origin.
    assert host.toolpath.start[:2].tolist() == ([-5.0, -10.0] if home else [0.0, 0.0])
    assert host.start_steps.tolist() == ([-400, -800] if home else [0, 0])
    assert np.allclose(host.toolpath.items[0].start[:2], host.toolpath.start[:2])


def test_an_explicit_start_without_homing_is_where_the_tool_is(tmp_path):
    host = build(tmp_path, CARTESIAN.format(start="  start: [30, 30]\n", home="false"))
    assert host.toolpath.start[:2].tolist() == [30.0, 30.0] and host.start_steps.tolist() == [2400, 2400]
    assert np.allclose(host.toolpath.items[0].start[:2], [30, 30])


G28_PROGRAM = """
name: plotter
machine:
  kinematics: {kinematics}
  steppers:
{steppers}
program:
  gcode: |
    G28
    G1 X10 F600
    G28 X
    G1 Y5 Z2
"""
CARTESIAN_STEPPERS = """    x: {steps_per_mm: 80, max_velocity: 100, max_accel: 2000, range: [-5, 200]}
    y: {steps_per_mm: 80, max_velocity: 100, max_accel: 2000, range: [-3, 200]}
    z: {steps_per_mm: 400, max_velocity: 10, max_accel: 200, range: [-1, 100]}"""
COREXY_STEPPERS = """    a: {steps_per_mm: 80, max_velocity: 100, max_accel: 2000, range: [-300, 300]}
    b: {steps_per_mm: 80, max_velocity: 100, max_accel: 2000, range: [-300, 300]}
    z: {steps_per_mm: 400, max_velocity: 10, max_accel: 200, range: [-1, 100]}"""


@pytest.mark.parametrize("kinematics, steppers, home, x_steps", [
    ("cartesian", CARTESIAN_STEPPERS, [-5.0, -3.0, -1.0], 2 * 15 * 80),
    ("corexy", COREXY_STEPPERS, [0.0, 0.0, -1.0], 2 * 10 * 80 + 5 * 80)])  # belt a: x there and back, then y
def test_g28_leaves_the_tool_where_homing_does(tmp_path, kinematics, steppers, home, x_steps):
    """The G-code's G28 goes to the min switches, at the low ends of the ranges, as the firmware's homing and
    Klipper's position_endstop do: `G28 / G1 X10` moves x 15 mm from a switch at -5 (Klipper: 1,200 steps)."""
    host = build(tmp_path, G28_PROGRAM.format(kinematics=kinematics, steppers=steppers))
    assert host.findings.ok, host.findings.problems
    assert host.toolpath.start[:3].tolist() == home
    first, back_home, last = [item for item in host.toolpath.items if isinstance(item, Line)]
    assert first.end[:3].tolist() == [10.0, home[1], home[2]]
    assert back_home.end[:3].tolist() == home  # `G28 X` mid-program: x back to its switch
    assert last.end[:3].tolist() == [home[0], 5.0, 2.0]
    assert host.findings.steps["x" if kinematics == "cartesian" else "a"] == x_steps

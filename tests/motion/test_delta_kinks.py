"""A delta's carriages move linearly along each piece of a straight move, so their velocity steps where two pieces
meet: the planner budgets those steps (`chord_kinks`) and the front end cuts pieces short enough for them
(`split_kinked`). The move is the fuzz finding's (tests/data/jobs/found/delta-kinks-on-a-straight-travel.yaml):
a travel across the bed whose motor b (50 mm/s^2) stepped by 1.57 mm/s at a vertex, 2.4 times one window's
acceleration, and failed the host's check by 9.5 % in the whole job."""

import math
import warnings

import numpy as np
import pytest

from codegen.job import load_job
from codegen.motion.planner import ACCEL_WINDOW_S
from codegen.pipeline.host import host_build
from tests.kinematics.test_delta import kossel

JOB = """name: kinks
target: avr
machine:
  kinematics: delta
  steppers:
    a: {steps_per_mm: 80, max_velocity: 60, max_accel: 3000}
    b: {steps_per_mm: 157.5, max_velocity: 20, max_accel: 50}
    c: {steps_per_mm: 200, max_velocity: 500, max_accel: 200}
  tolerance: 0.05
  delta: {radius: 140.0, diagonal_rod: 280.0, height: 150.0}
program:
  shapes:
    - travel: {to: [-18, 62.065, 23.95]}
    - travel: {to: [16.154, 0, 15.47]}
"""


def carriage(point, angle_deg, radius=105.2, rod=215.0):
    """The carriage height over `point` by the JOB-FORMAT formula (the Kossel of tests/kinematics)."""
    tower = radius * np.array([math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))])
    return point[2] + math.sqrt(rod ** 2 - float(np.sum((point[:2] - tower) ** 2)))


def test_chord_kinks_on_a_straight_line_are_the_change_of_the_carriages_chords():
    kin = kossel()
    points = np.array([[-60.0, 10.0, 20.0, 0.0], [0.0, 40.0, 15.0, 0.0], [60.0, 70.0, 10.0, 0.0]])
    kinks = kin.chord_kinks(points[:-1], points[1:])
    length = np.linalg.norm(points[1, :3] - points[0, :3])  # both pieces: the line is cut in its middle
    chords = [[(carriage(b, angle) - carriage(a, angle)) / length for angle in (210.0, 330.0, 90.0)]
              for a, b in zip(points[:-1], points[1:])]
    assert kinks.shape == (1, 4)
    assert kinks[0, :3] == pytest.approx(np.abs(np.subtract(*chords[::-1])), rel=1e-12)
    assert kinks[0, 3] == 0.0  # the extruder is linear
    assert kinks[0, :3] == pytest.approx([0.7117, 0.4346, 0.3436], abs=1e-4)  # 73 mm pieces


def test_chord_kinks_leave_out_the_paths_own_turn_and_still_pieces():
    kin = kossel()
    # A right-angle corner of 1 um pieces: the chords change by 0.33-0.67 (the turn), and by 7e-6 beyond it.
    corner = np.array([[20.0, 0.0, 30.0, 0.0], [20.001, 0.0, 30.0, 0.0], [20.001, 0.001, 30.0, 0.0]])
    assert kin.chord_kinks(corner[:-1], corner[1:]).max() < 1e-5
    still = np.array([[0.0, 0.0, 30.0, 0.0], [0.0, 0.0, 30.0, 1.0], [50.0, 0.0, 30.0, 1.0]])  # extrusion only
    assert np.all(kin.chord_kinks(still[:-1], still[1:]) == 0.0)


def test_the_fuzz_findings_travel_keeps_motor_b_within_its_acceleration(tmp_path):
    """At every vertex of the travel, b's velocity step (v times the change of its chord's mm per path mm) and
    its acceleration along the path over one window stay within what its limit gives over that window."""
    (tmp_path / "kinks.yaml").write_text(JOB)
    host = host_build(load_job(tmp_path / "kinks.yaml"), keep=True)
    segments, plan, kin = host.segments, host.plan, host.kin
    line = np.flatnonzero(segments.item == segments.item[-1])
    chord = (kin.to_motor(segments.end[line]) - kin.to_motor(segments.start[line]))[:, 1] / plan.length[line]
    step = plan.v_entry[line[1:]] * np.abs(np.diff(chord))
    along = plan.accel[line] * np.abs(chord)
    demand = step + np.maximum(along[:-1], along[1:]) * ACCEL_WINDOW_S
    window_budget = 50.0 * ACCEL_WINDOW_S  # b: max_accel 50 mm/s^2
    assert len(line) == 38  # 10 pieces before split_kinked
    assert demand.max() / window_budget == pytest.approx(0.8436, abs=1e-4)  # 2.4017 before
    assert host.findings.accel_ratio["b"] == pytest.approx(0.7126, abs=1e-4)  # the pulses, as the host checks
    assert host.findings.problems == []
    assert plan.total == pytest.approx(13.4481, abs=1e-4)  # 18.7737 s before (slowed by the host's retries)


def test_a_dwell_on_a_delta_is_one_part_without_a_warning(tmp_path):
    """A dwell moves no motor: its speed and reach are 0 or undefined, and split_kinked leaves it whole without
    numpy's divide or invalid-value warnings (they were printed on every delta job with a G4)."""
    (tmp_path / "dwell.yaml").write_text(JOB.replace("  shapes:\n", "  gcode: |\n    G1 X10 Y10 Z20 F3000\n"
                                                     "    G4 P100\n    G1 X0 Y0\n").split("    - travel")[0])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        host = host_build(load_job(tmp_path / "dwell.yaml"), keep=True)
    dwells = np.flatnonzero(host.segments.dwell > 0)
    assert len(dwells) == 1 and host.segments.dwell[dwells[0]] == pytest.approx(0.1)
    assert host.findings.problems == []

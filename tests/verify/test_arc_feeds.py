"""R arcs whose chord is about the circle's diameter, read by the front end (codegen/gcode/arcs.py) and by verify's
second reading (codegen/verify/gcode_reference.py), and the feed check on arcs drawn as chords: the firmware runs
each chord at F (Grbl's $12, JOB-FORMAT.md's `tolerance`), so an arc takes its chords' length over F, less than
the arc's. The property run (seed 1) found a G2 R1.5 on chords of 0.0297 mm failing the check that took the arc's."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from codegen.gcode.arcs import from_radius
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.toolpath.segments import arc_chord_count
from codegen.verify.chapters import whole_chapter
from tests.jobgen import outcome
from tests.verify.test_program_check import checked, reading

COARSE = """name: prop
target: avr
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 200, max_velocity: 146, max_accel: 200}
    y: {steps_per_mm: 200, max_velocity: 150, max_accel: 2204, range: [-13.972, 14.625]}
  junction_deviation: 0.00119
  tolerance: 0.0297
program:
  gcode: |
    G21 G90
    G0 X0.000 Y2.000
    G1 F30
    %s
    G0 X1.5000 Y1.0000
"""
FOUND = "G2 X-1.9747 Y4.0910 R1.5000"  # from (0, 2): a chord of 2.876 mm, 7 chords of 0.366 rad


def expected(chord: float, r: float, clockwise: bool) -> tuple[tuple[float, float], float, float]:
    """Centre, radius and sweep of an R arc from (0, 0) to (chord, 0): an R short of half the chord (by the slack)
    is the half circle on it, as Marlin draws any."""
    rise = math.sqrt(max(r * r - chord * chord / 4, 0.0))
    below = clockwise == (r > 0)  # the short way clockwise passes above the chord, round a centre below it
    short = 2 * math.asin(min(chord / 2 / abs(r), 1.0))
    turn = short if r > 0 else 2 * math.pi - short
    return (chord / 2, -rise if below else rise), max(abs(r), chord / 2), -turn if clockwise else turn


@pytest.mark.parametrize("r", [1.5, -1.5])
@pytest.mark.parametrize("code", ["G2", "G3"])
@pytest.mark.parametrize("chord", [2.9, 2.9999, 3.0, 3.004])
def test_r_arcs_about_the_diameter_read_alike(tmp_path, chord, code, r):
    """Under, at and (by less than the 0.005 mm slack) over the diameter: both readings, the same circle."""
    centre, radius, sweep = expected(chord, r, code == "G2")
    circle = from_radius((0.0, 0.0), (chord, 0.0), r, code == "G2")
    move, = reading(tmp_path, f"{code} X{chord} R{r} F600\n")
    for got_centre, got_radius, got_sweep in ((circle.center, circle.radius, circle.sweep),
                                              (move.arc[0], move.arc[1], move.arc[4])):
        assert got_centre == pytest.approx(centre, abs=1e-7) and got_radius == pytest.approx(radius, abs=1e-9)
        assert got_sweep == pytest.approx(sweep, abs=1e-7)
    assert move.length() == pytest.approx(radius * abs(sweep), abs=1e-6)


def test_an_arc_on_chords_is_as_short_as_its_tolerance_lets_it_be(tmp_path):
    """A half circle of R 1.5: at most a diameter (one chord straying by R), never shorter than chords turning
    2 acos(1 - tolerance / R) each; a helix keeps its rise; a line is what it is."""
    half, helix, line = reading(tmp_path, "G2 X3 R1.5 F600\nG2 X0 Z4 R1.5\nG1 X3\n")
    assert half.length() == half.length(0.0) == pytest.approx(1.5 * math.pi)
    assert half.length(1.5) == half.length(2.0) == pytest.approx(3.0)
    a = math.acos(1 - 0.0297 / 1.5)
    assert half.length(0.0297) == pytest.approx(1.5 * math.pi * math.sin(a) / a)
    assert helix.length(0.0297) == pytest.approx(math.hypot(1.5 * math.pi * math.sin(a) / a, 4.0))
    assert line.length(0.1) == line.length() == 3.0


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("arcs")


@settings(max_examples=40, deadline=None, derandomize=True)
@given(r=st.floats(0.3, 20.0), over=st.floats(-0.05, 0.0099), direction=st.floats(0, 2 * math.pi),
       code=st.sampled_from(["G2", "G3"]), longer=st.booleans(), tolerance=st.floats(1e-4, 0.1))
def test_r_arcs_near_the_diameter_property(folder, r, over, direction, code, longer, tolerance):
    """Chords of 2R - 5 % to 2R + 0.0099 mm (within the slack): the readings agree, and the front end's chords
    are no longer than the arc and no shorter than the feed check lets them be."""
    chord = 2 * r + over * (r if over < 0 else 1)
    end = (round(chord * math.cos(direction), 4), round(chord * math.sin(direction), 4))
    r = -r if longer else r
    circle = from_radius((0.0, 0.0), end, r, code == "G2")
    move, = reading(folder, f"{code} X{end[0]:.4f} Y{end[1]:.4f} R{r!r} F600\n")
    assert move.arc[0] == pytest.approx(circle.center, abs=1e-6) and move.arc[1] == pytest.approx(circle.radius)
    assert move.arc[4] == pytest.approx(circle.sweep, abs=1e-6)
    n = arc_chord_count(circle.radius, circle.sweep, tolerance)
    drawn = 2 * n * circle.radius * math.sin(abs(circle.sweep) / n / 2)
    assert move.length(tolerance) * (1 - 1e-9) <= drawn <= move.length() * (1 + 1e-9)


@pytest.mark.parametrize("arc", [FOUND, "G3 X-3 Y2 R1.5", "G2 X-3 Y2 R1.5", "G2 X-3.008 Y2 R1.5",
                                 "G3 X-2.9 Y2.5 R-1.5"])
def test_arcs_on_coarse_chords_keep_to_their_feed(tmp_path, arc):
    """The property run's invariant (tests/jobgen/): built, every check passed, the tables held against the
    G-code's second reading."""
    assert outcome(COARSE % arc, tmp_path) == "built"


def test_an_arc_faster_than_its_chords_allow_fails(tmp_path):
    (tmp_path / "job.yaml").write_text(COARSE % FOUND)
    host = host_build(load_job(tmp_path / "job.yaml"), keep=True)
    chapter = whole_chapter(host)
    problems, counts = checked(host, chapter)
    assert problems == [] and counts["feeds"] == 1
    events = dataclasses.replace(chapter.events, time=chapter.events.time * 0.98)
    problems, _ = checked(host, dataclasses.replace(chapter, events=events))
    assert len(problems) == 1 and problems[0].startswith(
        f"G-code line 15 ({FOUND}): the move of 3.847 mm takes 7.4") and "along chords of 3.822 mm" in problems[0]

"""verify's second reading of the G-code (codegen/verify/gcode_reference.py) and the played tables held against it
(codegen/verify/program_check.py): the reading on its own, the machine geometry against the planner's kinematics,
and the check on a real build's twin, as planned and with its ends, times and dwells deliberately wrong."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from codegen.job import load_job
from codegen.kinematics import make_kinematics
from codegen.pipeline.host import host_build
from codegen.verify.chapters import whole_chapter
from codegen.verify.gcode_reference import Dwell, Move, Reading
from codegen.verify.program_check import MachineGeometry, ProgramCheck
from tests.helpers import DATA, EXAMPLES

OFFSETS_JOB = DATA / "mutants" / "gcode-offsets.yaml"


def reading(tmp_path: Path, gcode: str, start=(0.0, 0.0, 0.0)) -> list:
    """Every move and dwell of `gcode` (a file beside a job on the mixed example's machine)."""
    (tmp_path / "p.gcode").write_text(gcode)
    text = (EXAMPLES / "gcode" / "mixed.yaml").read_text()
    job_path = tmp_path / "job.yaml"
    machine = text[:text.index("program:")]  # the program's dialect is the G-code's own here: guessed
    job_path.write_text(machine + "program:\n  start: [0, 0, 5]\n  gcode: p.gcode\n")
    return list(Reading(load_job(job_path), start).upto(math.inf))


def test_units_offsets_and_modes(tmp_path):
    moves = reading(tmp_path, "G20 G0 X1 Y0.5\nG21 G92 X5 Y5\nG1 X15 F600\nG91 G1 X-2 Y1\nG90 M220 S50\n"
                              "G1 X10\nM220 B\nM220 S200\nM220 R\nG1 X12\nG4 P250\nG4 S1.5\nM117 X99 Y99\n")
    ends = [(m.line, tuple(round(v, 6) for v in m.end)) for m in moves if isinstance(m, Move)]
    assert ends == [(1, (25.4, 12.7, 0.0)), (3, (35.4, 12.7, 0.0)), (4, (33.4, 13.7, 0.0)),
                    (6, (30.4, 13.7, 0.0)), (10, (32.4, 13.7, 0.0))]
    speeds = [m.speed for m in moves if isinstance(m, Move)]
    assert speeds == [None, 10.0, 10.0, 5.0, 5.0]  # M220 S50, saved (B) and restored (R) around S200
    assert [(d.line, d.seconds) for d in moves if isinstance(d, Dwell)] == [(11, 0.25), (12, 1.5)]


def test_homing_leaves_axes_unknown_until_an_absolute_coordinate(tmp_path):
    moves = reading(tmp_path, "G92 X3\nG28 X\nG1 Y5 F600\nG1 X4\n", start=(10.0, 0.0, 0.0))
    second, third = moves[0].end, moves[1].end
    assert math.isnan(second[0]) and second[1:] == (5.0, 0.0)
    assert third == (4.0, 5.0, 0.0)  # G28 cleared the G92 offset of x


def test_axis_words_beside_other_codes_move_and_dollar_h_homes(tmp_path):
    moves = reading(tmp_path, "G1 F1000\nG64 X5\nG61 Y3\nG40 G91 X1 Z1\nM3 S100 X1\n$H\n$J=G91 X10 F100\nG90 X2\n")
    assert [(m.line, m.end) for m in moves[:-1]] == [(2, (5.0, 0.0, 0.0)), (3, (5.0, 3.0, 0.0)),
                                                     (4, (6.0, 3.0, 1.0)), (5, (7.0, 3.0, 1.0))]
    last = moves[-1]  # $H leaves every axis unknown, $J= moves nothing
    assert last.line == 8 and last.end[0] == 2.0 and math.isnan(last.end[1]) and math.isnan(last.end[2])


@pytest.mark.parametrize("dialect, ends", [("; Grbl\n", [(2, 2.0), (3, 5.0), (4, 7.0)]), ("", [(2, 2.0)])])
def test_axis_words_beside_a_tool_change_move_in_grbl_alone(tmp_path, dialect, ends):
    """Grbl runs the whole block (`T1 Y5` moves); Marlin runs the tool change and skips the rest of its line."""
    moves = reading(tmp_path, f"{dialect}G1 F1000\nG1 Y2\nT1 Y5\nM6 T0 Y7\n")
    assert [(m.line - (dialect != ""), m.end[1]) for m in moves] == ends


@pytest.mark.parametrize("gcode, seconds", [
    ("; Grbl\nG4 P0.5\n", 0.5), ("M104 S200\n$X\nG4 P500\n", 0.5), ("$X\nM104 S200\nG4 P0.5\n", 0.5),
    ("G4 P500\n", 0.5)])
def test_g4_p_counts_the_guessed_dialect_s_unit(tmp_path, gcode, seconds):
    assert [d.seconds for d in reading(tmp_path, gcode)] == [seconds]


def test_grbl_coordinate_systems(tmp_path):
    moves = reading(tmp_path, "G10 L2 P2 X10 Y20\nG55 G0 X1 Y1\nG53 G0 X1 Y1\nG10 L20 P1 X0\nG54 G0 X2\n"
                              "G43.1 Z2\nG0 Z1\n")
    assert [m.end for m in moves] == [(11.0, 21.0, 0.0), (1.0, 1.0, 0.0), (3.0, 1.0, 0.0), (3.0, 1.0, 3.0)]


@pytest.mark.parametrize("code, centre, turns", [
    ("G2 X10 Y10 R10", (10.0, 0.0), -0.25), ("G3 X10 Y10 R10", (0.0, 10.0), 0.25),
    ("G2 X10 Y10 R-10", (0.0, 10.0), -0.75), ("G3 X10 Y10 I10 J0", (10.0, 0.0), 0.75)])
def test_arc_centres(tmp_path, code, centre, turns):
    """From (0, 0) to (10, 10): a negative R takes the longer way round."""
    move, = reading(tmp_path, code + " F600\n")
    assert np.allclose(move.arc[0], centre) and move.arc[1] == pytest.approx(10.0)
    assert move.arc[4] == pytest.approx(turns * 2 * math.pi)


def test_arc_radii_at_the_start_and_the_end(tmp_path):
    """As the front end draws them (tests/gcode/test_arc_spiral.py): an I/J end off the start's circle is a spiral
    to the end's radius; an R short of half the chord by the slack is the half circle on the chord."""
    spiral, half = reading(tmp_path, "G0 X93 Y86.42\nG3 X100 Y85.352 I24 J127 F600\nG0 X0 Y0\nG2 X10 R4.996\n")[1::2]
    assert spiral.arc[0] == pytest.approx((117, 213.42))
    radii = math.hypot(24, 127), math.hypot(17, 128.068)
    assert (spiral.arc[1], spiral.arc[5]) == (pytest.approx(radii[0]), pytest.approx(radii[1]))
    assert spiral.arc[4] == pytest.approx(math.atan2(-128.068, -17) - math.atan2(-127, -24))
    assert half.arc[0] == pytest.approx((5, 0)) and (half.arc[1], half.arc[5]) == (5, 5)
    assert half.arc[4] == pytest.approx(-math.pi)


def test_a_whole_circle_and_the_program_end(tmp_path):
    moves = reading(tmp_path, "G0 X10\n%\nG2 X10 Y0 I-10 J0 F600\nM2\nG1 X50\n")
    assert len(moves) == 2 and moves[1].arc[4] == pytest.approx(-2 * math.pi)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(kind=st.sampled_from(["corexy", "delta"]),
       points=st.lists(st.tuples(*(st.floats(-50, 50),) * 2, st.floats(0, 100)), min_size=1, max_size=20))
def test_the_geometry_agrees_with_the_planners_kinematics(kind, points):
    """Two writings of JOB-FORMAT.md's kinematics: verify's and the planner's give the same steps."""
    path = EXAMPLES / ("kossel-mini.yaml" if kind == "delta" else "star.yaml")
    machine = load_job(path).machine
    kin = make_kinematics(machine)
    xyz = np.array(points, dtype=float)
    axes = np.column_stack([xyz, np.zeros(len(xyz))])
    geometry = MachineGeometry(machine, kin.motors)
    want = kin.to_steps(axes)[:, geometry.index]
    assert np.array_equal(geometry.steps(xyz)[:, :want.shape[1]], want)


@pytest.fixture(scope="module")
def offsets_build():
    host = host_build(load_job(OFFSETS_JOB), keep=True)
    return host, whole_chapter(host)


def checked(host, chapter) -> tuple[list[str], dict]:
    check = ProgramCheck(host)
    check.add(chapter)
    return check.finish(), check.checked


def test_the_planned_tables_pass(offsets_build):
    problems, counts = checked(*offsets_build)
    assert problems == [] and counts == {"ends": 7, "feeds": 5, "arcs": 3, "dwells": 1}


def test_a_move_ending_a_step_off_fails(offsets_build):
    host, chapter = offsets_build
    position = chapter.pulses.event_position.copy()
    position[-1, 0] += 2  # the last move (G0 X0 Y0, after G92 X0 Y0 at 70.4, 17.7) ends 2 steps of x off
    wrong = dataclasses.replace(chapter, pulses=dataclasses.replace(chapter.pulses, event_position=position))
    problems, _ = checked(host, wrong)
    assert problems == ["G-code line 24 (G0 X0 Y0): the tables end the move at steps x 5634, y 1416 where the "
                        "program's end, X70.400 Y17.700 Z0.000 in machine mm, gives x 5632, y 1416 (with G92 and "
                        "coordinate system offsets X70.400 Y17.700 Z0.000)"]


def test_moves_faster_than_their_feed_fail(offsets_build):
    host, chapter = offsets_build
    events = dataclasses.replace(chapter.events, time=chapter.events.time * 0.8)
    problems, _ = checked(host, dataclasses.replace(chapter, events=events))
    assert problems and all("faster than its feed" in p for p in problems)
    assert problems[0].startswith("G-code line 16 (G2 X30 Y30 R20 F1200): the move of 31.416 mm takes")


def test_a_dwell_of_another_length_fails(offsets_build):
    host, chapter = offsets_build
    duration = np.where(chapter.segments.dwell > 0, 1.5, chapter.plan.duration)
    plan = dataclasses.replace(chapter.plan, duration=duration)
    problems, _ = checked(host, dataclasses.replace(chapter, plan=plan))
    assert problems == ["G-code line 20 (G4 P150): the plan dwells 1.5000 s where the program's G4 says 0.1500 s"]


def test_an_arc_off_its_circle_fails(offsets_build):
    host, chapter = offsets_build
    arc = np.flatnonzero(chapter.segments.line[chapter.event_segments()] == 16)
    position = chapter.pulses.event_position.copy()
    position[arc[len(arc) // 2], 1] += 8  # one event of the first arc 0.1 mm off in y
    problems, _ = checked(host, dataclasses.replace(chapter, pulses=dataclasses.replace(chapter.pulses,
                                                                                         event_position=position)))
    assert len(problems) == 1 and problems[0].startswith(
        "G-code line 16 (G2 X30 Y30 R20 F1200): the arc strays 0.0")

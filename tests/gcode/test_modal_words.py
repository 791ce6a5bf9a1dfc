"""No silent loss (issue 28): the axis words on a line whose codes change nothing the plan models (G40, G61, G64,
the modes G17-G19, G20/G21, G90/G91, G93/G94, M3/M5) move in the modal motion, as Grbl and LinuxCNC do."""

from __future__ import annotations

import pytest

from tests.gcode.helpers import MILL, errors, run


def ends(gcode: str, **kw):
    """Every move's (label, end) and the warnings' (line, col, message)."""
    toolpath, warnings = run(gcode, motors=MILL, **kw)
    return ([(i.label, i.end.tolist()) for i in toolpath.items],
            [(w.where.line, w.where.col, w.message) for w in warnings])


def test_axis_words_beside_path_control_and_cutter_compensation_move():
    moved, warned = ends("G1 F1000\nG64 X5\nG61 Y3\nG40 X7 Z1\n")
    assert moved == [("G1", [5, 0, 0, 0]), ("G1", [5, 3, 0, 0]), ("G1", [7, 3, 1, 0])]
    assert warned == [(9, 5, "'G64' ignored (path blending; corners always blend by the junction deviation)"),
                      (10, 5, "'G61' ignored (exact path mode, the only one)"),
                      (11, 5, "'G40' ignored (cutter compensation off, the only mode)")]


def test_the_distance_mode_beside_g40_applies_to_the_axis_words_of_its_line():
    moved, _ = ends("G1 X2 F1000\nG40 G91 X1\nX1\n")
    assert moved == [("G1", [2, 0, 0, 0]), ("G1", [3, 0, 0, 0]), ("G1", [4, 0, 0, 0])]


def test_g64_takes_its_tolerances_and_leaves_the_rest_to_the_line():
    moved, warned = ends("G0 X1\nG64 P0.01 Q0.02 Y2\n")
    assert moved == [("G0", [1, 0, 0, 0]), ("G0", [1, 2, 0, 0])]
    assert [w[:2] for w in warned] == [(9, 5)]


@pytest.mark.parametrize("codes", ["G17", "G90", "G21", "G94", "M3 S100", "M5", "G54"])
def test_axis_words_beside_modal_codes_move(codes):
    moved, _ = ends(f"G1 F600\n{codes} X4 Y2\n")
    assert moved == [("G1", [4, 2, 0, 0])]


def test_axis_words_on_a_g80_line_are_an_error():
    assert errors("G1 F600\nG80 Y2 X1\n", motors=MILL) == [
        (9, 9, "'Y2': G80 on this line cancels the motion mode; axis words need G0, G1, G2 or G3")]


def test_strict_refuses_the_whole_line():
    assert errors("G1 F600\nG64 X5\n", strict=True, motors=MILL) == [
        (9, 5, "'G64' is not accepted with --strict (path blending; corners always blend by the junction deviation)")]


def test_g80_cancels_the_motion_mode_for_the_lines_after_it():
    """Grbl's error 31: after G80, axis words without G0..G3 have no motion to make; G1 brings one back."""
    assert errors("G1 X5 F600\nG80\nX10\n", motors=MILL) == [
        (10, 5, "'X10': G80 cancelled the motion mode; axis words need G0, G1, G2 or G3")]
    moved, _ = ends("G1 X5 F600\nG80\nG0 X10\nY3\n")
    assert moved == [("G1", [5, 0, 0, 0]), ("G0", [10, 0, 0, 0]), ("G0", [10, 3, 0, 0])]


@pytest.mark.parametrize("line", ["T1 Y5", "Y5 M6", "T0 M6 Y5"])
def test_axis_words_beside_a_tool_change_move_in_grbl_and_are_skipped_in_marlin(line):
    """Grbl runs every word of a block (`T1 Y5` moves); Marlin runs one command a line and skips the rest, with a
    note that says which dialect decided it."""
    moved, _ = ends(f"G1 X2 F600\n{line}\n", dialect="grbl")
    assert moved == [("G1", [2, 0, 0, 0]), ("G1", [2, 5, 0, 0])]
    toolpath, diagnostics = run(f"G1 X2 F600\n{line}\n", motors=MILL, dialect=None)
    assert [i.end.tolist() for i in toolpath.items] == [[2, 0, 0, 0]]
    notes = [(d.where.line, d.message.split(":")[0]) for d in diagnostics if d.severity == "note"]
    assert notes[0] == (9, f"words beside {'M6' if 'M6' in line else 'T'} skipped")

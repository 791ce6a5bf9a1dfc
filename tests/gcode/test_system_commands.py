"""Grbl's `$` lines: `$H` homes as G28 does, the others are skipped with a warning or refused, each at its line."""

from __future__ import annotations

import pytest

from codegen.toolpath.items import Home
from tests.gcode.helpers import MILL, PLOTTER, errors, run


def labelled(gcode: str, **kw):
    """(kind, where it ends, homed axes) of every item, and the warnings' (line, col, message)."""
    toolpath, warnings = run(gcode, **kw)
    return ([(type(i).__name__, (i.position if isinstance(i, Home) else i.end).tolist(), getattr(i, "axes", None))
             for i in toolpath.items], [(w.where.line, w.where.col, w.message) for w in warnings])


def test_dollar_h_homes_every_axis_and_dollar_hy_one():
    assert labelled("G0 X5 Y6 Z7\n$H\nG0 X1 Y2\n  $hy\n", motors=MILL) == ([
        ("Line", [5, 6, 7, 0], None), ("Home", [0, 0, 0, 0], ("x", "y", "z")), ("Line", [1, 2, 0, 0], None),
        ("Home", [1, 0, 0, 0], ("y",))], [])


def test_queries_unlock_and_settings_are_warnings_naming_the_job_key():
    _, warned = labelled("$X\n$$\n$#\n$G\n$I\n$110=5000\n$11 = 0.02\n$0=10\n$RST=$\n$N0=G21\n$$\n", motors=PLOTTER)
    assert warned == [
        (8, 5, "'$X' ignored (alarm unlock; there is no alarm state here)"),
        (9, 5, "'$$' ignored (a report query); 2 times"),
        (10, 5, "'$#' ignored (a report query)"),
        (11, 5, "'$G' ignored (a report query)"),
        (12, 5, "'$I' ignored (a report query)"),
        (13, 5, "'$110' ignored (a Grbl setting; the job file gives it: machine.steppers.x.max_velocity (mm/s; "
                "Grbl's is mm/min))"),
        (14, 5, "'$11' ignored (a Grbl setting; the job file gives it: machine.junction_deviation)"),
        (15, 5, "'$0' ignored (a Grbl setting that changes nothing this toolchain models)"),
        (16, 5, "'$RST=$' ignored (restores Grbl's settings; the job file describes the machine)"),
        (17, 5, "'$N0' ignored (a startup block, which Grbl runs at its reset, not here)")]


@pytest.mark.parametrize("line, message", [
    ("$J=G91 X10 F100", "'$J=' is a jog, a move a sender makes at the operator's request, not part of a program: "
                        "write it as G1 (G91 for a relative jog) with its F"),
    ("$C", "'$C' switches Grbl's check mode (it then reads the program without moving): not modelled; remove it"),
    ("$SLP", "'$SLP' puts Grbl to sleep (motors off until a reset): not modelled; remove it"),
    ("$Q", "unknown Grbl command '$Q'"),
    ("$HA", "unknown Grbl command '$HA'"),
])
def test_errors(line, message):
    assert errors(f"G0 X1\n  {line}\n", motors=PLOTTER) == [(9, 7, message)]


def test_strict_refuses_skipped_commands():
    assert errors("$X\n", strict=True, motors=PLOTTER) == [
        (8, 5, "'$X' is not accepted with --strict (alarm unlock; there is no alarm state here)")]

"""`program.dialect` (JOB-FORMAT.md): G4 P in Marlin's milliseconds or Grbl's seconds, S's full scale 255 or 1000,
guessed from the file's first lines with a note where it matters; an S the machine cannot heed is a warning."""

from __future__ import annotations

import textwrap

import pytest

from codegen.errors import JobError
from codegen.gcode.dialect import GUESS_LINES, guess
from codegen.job import load_job
from codegen.toolpath.items import Dwell, Line
from tests.gcode.helpers import MILL, PLOTTER, errors, run

NO_LASER = ("'S' ignored (the machine has no `laser:`, so M3/M4 switch the tool pin on and off only; "
            "`machine.laser: {pwm_hz: 1000}` (a PWM laser) gives power control over S)")


def dwells_and_notes(gcode: str, **kw):
    toolpath, warnings = run(gcode, motors=MILL, **kw)
    return ([i.seconds for i in toolpath.items if isinstance(i, Dwell)],
            [(w.severity, w.where.line, w.where.col, w.message) for w in warnings])


@pytest.mark.parametrize("first, name, line, why", [
    ("$H", "grbl", 2, "'$' is Grbl's"),
    ("G10 L20 P1 X0", "grbl", 2, "'G10 L20' is Grbl's"),
    ("G38.2 Z-5", "grbl", 2, "'G38.' is Grbl's"),
    ("(LaserGRBL header) ; for grbl 1.1", "grbl", 2, "a comment names Grbl"),
    (";FLAVOR:Marlin", "marlin", 2, "the slicer's flavor is Marlin"),
    ("M140 S60", "marlin", 2, "'M140' is Marlin's"),
    ("G29 ; level", "marlin", 2, "'G29' is Marlin's"),
])
def test_the_first_deciding_line_names_the_dialect(first, name, line, why):
    dialect = guess(f"G21\nG90 ; G0 X1\n{first}\nM104 S200\n$X\n")
    assert (dialect.name, dialect.line, dialect.why) == (name, line, why)


def test_the_guess_reads_a_bounded_start():
    assert guess("G1 X1\n" * GUESS_LINES + "$H\n").line is None  # the default, Marlin


def test_a_line_of_unclosed_comments_is_read_in_bounded_time():
    """The long fuzz run's hang: 176 KB of `(` on one line; each `(` searched to the line's end (30 KB: 1.4 s)."""
    found = guess("(" * 200_000 + "G" + "0" * 200_000 + "\nM104 S200\n")
    assert (found.name, found.line, found.why) == ("marlin", 1, "'M104' is Marlin's")


def test_g4_p_is_seconds_in_grbl_milliseconds_in_marlin_with_a_note_once():
    assert dwells_and_notes("; Grbl\nG4 P0.5\nG4 P2\n") == ([0.5, 2.0], [
        ("note", 9, 8, "G4 P in seconds: G-code dialect grbl, guessed from line 8 (a comment names Grbl); "
                       "program.dialect sets it")])
    assert dwells_and_notes("G4 P0.5\nM104 S200\n") == ([0.0005], [
        ("note", 8, 8, "G4 P in milliseconds: G-code dialect marlin, guessed from line 9 ('M104' is Marlin's); "
                       "program.dialect sets it")])
    assert dwells_and_notes("G4 P500\n") == ([0.5], [
        ("note", 8, 8, "G4 P in milliseconds: G-code dialect marlin, the default: none of the first 2000 lines is "
                       "Grbl's or Marlin's alone; program.dialect sets it")])


def test_the_job_s_dialect_wins_without_a_note():
    assert dwells_and_notes("M104 S200\nG4 P0.5\nG4 S1\n", dialect="grbl") == ([0.5, 1.0], [])
    assert dwells_and_notes("; Grbl\nG4 P0.5\n", dialect="marlin") == ([0.0005], [])


def test_s_full_scale_follows_the_dialect_on_a_laser():
    toolpath, warnings = run("$X\nM3 S500\nG1 X1 F600\n", motors=PLOTTER, laser=True)
    assert [i.power for i in toolpath.items if isinstance(i, Line)] == [0.5]  # Grbl's $30: 1000
    assert [(w.severity, w.where.line, w.where.col, w.message) for w in warnings][0] == (
        "note", 9, 8, "S of full power 1000: G-code dialect grbl, guessed from line 8 ('$' is Grbl's); "
                      "program.s_max sets it")
    toolpath, warnings = run("M3 S500\nG1 X1 S100 F600\n", motors=PLOTTER, laser=True, s_max=200)
    assert [i.power for i in toolpath.items if isinstance(i, Line)] == [0.5] and warnings == []


@pytest.mark.parametrize("gcode, line, col", [
    ("M3 S100\nG1 X5 F1000\nM5\n", 8, 8),
    ("G1 X1 F600\nG1 X5 S100\nG1 X6 S10\n", 9, 11),  # a plain line, which the C reads unless watched
])
def test_s_without_a_laser_is_a_warning_at_the_first(gcode, line, col):
    toolpath, warnings = run(gcode, motors=PLOTTER)
    assert [(w.severity, w.where.line, w.where.col, w.message) for w in warnings] == [
        ("warning", line, col, NO_LASER)]
    assert errors(gcode, strict=True, motors=PLOTTER) == [
        (line, col, NO_LASER.replace("ignored", "is not accepted with --strict"))]


def test_the_job_key(tmp_path):
    path = tmp_path / "job.yaml"
    body = """\
        machine:
          kinematics: cartesian
          steppers:
            x: {steps_per_mm: 80, max_velocity: 200, max_accel: 2500}
            y: {steps_per_mm: 80, max_velocity: 200, max_accel: 2500}
        program:
          dialect: DIALECT
          gcode: |
            G4 P1
        """
    path.write_text(textwrap.dedent(body).replace("DIALECT", "grbl"))
    assert load_job(path).program.dialect == "grbl"
    path.write_text(textwrap.dedent(body).replace("DIALECT", "grlb"))
    with pytest.raises(JobError) as caught:
        load_job(path)
    assert [(d.where.line, d.where.col, d.message) for d in caught.value.diagnostics] == [
        (7, 12, "program.dialect: 'grlb' is not one of marlin, grbl (did you mean 'grbl'?)")]

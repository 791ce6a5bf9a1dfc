"""The job file: loading, defaults, and compiler-like diagnostics (exact file:line:col and wording)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

import codegen.paths
from codegen.errors import JobError, SourceRef
from codegen.job import Circle, Function, Job, Line, Program, load_job
from codegen.job.calculus import derivative
from tests.helpers import DATA
from tests.job.jobfiles import STEPPERS, errors, write

DATA = DATA / "jobs"

@pytest.fixture(autouse=True)
def boards(tmp_path_factory, monkeypatch):
    """A targets/ folder of our own: two avr boards, no mcs51 board (so the mcs51 check is skipped)."""
    folder = tmp_path_factory.mktemp("targets")
    for name in ("ramps-1.4", "mks-gen-l"):
        (folder / f"{name}.yaml").write_text(f"name: {name}\ntarget: avr\nmcu: atmega2560\n")
    (folder / "atmega2560.yaml").write_text("name: atmega2560\nf_cpu: 16000000\n")  # an MCU, not a board
    monkeypatch.setattr(codegen.paths, "targets_dir", lambda: folder)
    return folder


# ---- a valid job ----

def test_valid_job_loads_with_defaults_filled():
    before = sorted(p.name for p in DATA.iterdir())
    job = load_job(DATA / "good.yaml")
    assert isinstance(job, Job)
    assert job.path == (DATA / "good.yaml").resolve() and job.path.is_absolute()
    assert (job.name, job.target, job.board) == ("good", "avr", "ramps-1.4")
    m = job.machine
    assert m.kinematics == "cartesian" and m.delta is None
    assert m.motor_names == ("x", "y", "z", "e")  # canonical order, whatever the YAML order
    assert (m.junction_deviation, m.tolerance) == (0.01, 0.002)
    assert m.steppers["y"].invert_dir is True and m.steppers["x"].invert_dir is False
    assert m.steppers["x"].range == (0.0, 200.0) and m.steppers["z"].range is None
    p = job.program
    assert (p.start, p.feed, p.travel_feed, p.gcode) == ((0.0, 0.0), 1200.0, None, None)
    assert [s.kind for s in p.shapes] == [
        "line", "line", "polyline", "points", "arc", "circle", "ellipse", "sine", "function", "travel"]
    line, line2, poly, points, arc, circle, ellipse, sine, function, travel = p.shapes
    assert line.from_ is None and line.to == (10.0, 0.0) and line.feed is None
    assert line2.from_ == (0.0, 5.0) and line2.to == (10.0, 5.0, 1.0) and line2.feed == 600.0
    assert poly.points == [(0.0, 0.0), (5.0, 5.0), (10.0, 0.0)]
    assert points.points == [(100.0, 20.0, 50.0), (-60.0, 70.0, 30.0)] and points.feed is None
    assert (arc.start, arc.sweep, arc.z) == (0.0, -90.0, None)
    assert (circle.start, circle.direction, circle.sweep) == (0.0, "ccw", 360.0)
    assert (ellipse.rotation, ellipse.start, ellipse.sweep) == (30.0, 0.0, 360.0)
    assert (sine.phase, sine.length, sine.z) == (0.0, -40.0, 2.0)
    assert function.origin == (0.0, 0.0) and function.x == (0.0, 10.0)
    assert str(function.expr) == "0.5*x**2 - sin(x)"
    assert function.expr.evaluate(2.0) == pytest.approx(2.0 - math.sin(2.0))
    assert travel.to == (0.0, 0.0)
    # every shape knows where its kind key is
    assert line.source == SourceRef(str(DATA / "good.yaml"), 11, 7)
    assert travel.source == SourceRef(str(DATA / "good.yaml"), 20, 7)
    assert sorted(p.name for p in DATA.iterdir()) == before  # nothing written


def test_delta_job_with_mcs51_target_and_defaults():
    job = load_job(DATA / "delta.yaml")
    assert (job.name, job.target, job.board) == ("tower", "mcs51", "at89c52")  # no mcs51 boards: not checked
    assert job.machine.motor_names == ("a", "b", "c")
    assert job.machine.tolerance == 0.001  # `1e-3` is a number (YAML 1.2), not a string
    assert job.machine.delta.tower_angles == (210.0, 330.0, 90.0)
    assert job.program.start == (0.0, 0.0, 0.0) and job.program.travel_feed == 3000.0


def test_target_override_wins_and_picks_that_targets_default_board():
    job = load_job(DATA / "delta.yaml", target_override="avr")
    assert (job.target, job.board) == ("avr", "ramps-1.4")
    job = load_job(DATA / "good.yaml", "mcs51")
    assert (job.target, job.board) == ("mcs51", "at89c52")


def test_bad_target_override_is_a_diagnostic():
    assert errors(DATA / "good.yaml", "avrr") == [(0, 0, "'avrr' is not one of avr, mcs51 (did you mean 'avr'?)")]


# ---- the contract's example, rendered ----

def test_error_renders_like_a_compiler(monkeypatch):
    monkeypatch.chdir(DATA)
    with pytest.raises(JobError) as info:
        load_job(Path("shape.yaml"))
    assert info.value.exit_code == 2
    assert info.value.render() == (
        "shape.yaml:7:21: error: machine.steppers.y.steps_per_mm: must be > 0\n"
        "      steps_per_mm: 0\n"
        "                    ^"
    )


def test_three_mistakes_give_three_diagnostics_in_order():
    assert errors(DATA / "three_mistakes.yaml") == [
        (2, 15, "machine.kinematics: 'cartesain' is not one of cartesian, corexy, delta "
                "(did you mean 'cartesian'?)"),
        (4, 63, "machine.steppers.x: unknown key 'invert_dri' (did you mean 'invert_dir'?)"),
        (8, 40, "program.shapes[0].circle.radius: must be > 0"),
    ]


def test_missing_key_points_at_the_parent_key():
    assert errors(DATA / "missing_key.yaml") == [(2, 1, "machine: missing key 'steppers'")]


def test_unknown_key_without_a_close_match_lists_the_keys(tmp_path):
    path = write(tmp_path, STEPPERS + "program:\n  shapes:\n    - line: {to: [1, 2], z: 3}\n")
    assert errors(path) == [(8, 26, "program.shapes[0].line: unknown key 'z'; expected feed, to, from")]


def test_a_misspelt_required_key_is_one_diagnostic(tmp_path):
    text = STEPPERS.replace("max_accel: 3000}", "max_acel: 3000}", 1) + "program:\n  gcode: |\n    G0\n"
    path = write(tmp_path, text)
    assert errors(path) == [(4, 46, "machine.steppers.x: unknown key 'max_acel' (did you mean 'max_accel'?)")]
    path.write_text(path.read_text().replace("max_acel", "maximum"))
    assert errors(path) == [
        (4, 5, "machine.steppers.x: missing key 'max_accel'"),
        (4, 46, "machine.steppers.x: unknown key 'maximum'; expected steps_per_mm, max_velocity, max_accel, "
                "range, invert_dir"),
    ]


def test_unknown_and_missing_root_keys(tmp_path):
    path = write(tmp_path, "machin:\n  kinematics: delta\nprogram:\n  shapes: []\n  start: [1]\n")
    assert errors(path) == [
        (1, 1, "unknown key 'machin' (did you mean 'machine'?)"),  # not also "missing key 'machine'"
        (4, 11, "program.shapes: must not be empty"),
        (5, 10, "program.start: expected a list of 2 or 3 numbers"),
    ]


def test_wrong_types_are_named_plainly(tmp_path):
    path = write(tmp_path, """\
        name: 5
        machine:
          kinematics: cartesian
          steppers:
            x: {steps_per_mm: true, max_velocity: fast, max_accel: 3000, range: [10, 0], invert_dir: 1}
            y:
          junction_deviation: .inf
        program:
          feed: -1
          shapes:
            - travel: {to: [1, 2, 3, 4]}
        """)
    assert errors(path) == [
        (1, 7, "name: expected a string"),
        (5, 23, "machine.steppers.x.steps_per_mm: expected a number"),
        (5, 43, "machine.steppers.x.max_velocity: expected a number"),
        (5, 73, "machine.steppers.x.range: must be [min, max] with min < max"),
        (5, 94, "machine.steppers.x.invert_dir: expected true or false"),
        (6, 5, "machine.steppers.y: expected a mapping"),
        (7, 23, "machine.junction_deviation: expected a finite number"),
        (9, 9, "program.feed: must be > 0"),
        (11, 20, "program.shapes[0].travel.to: expected a list of 2 or 3 numbers"),
    ]


# ---- shapes ----

def test_shape_errors():
    assert errors(DATA / "bad_shapes.yaml") == [
        (8, 7, "program.shapes[0]: unknown shape 'circel' (did you mean 'circle'?)"),
        (9, 54, "program.shapes[1].circle.direction: 'clockwise' is not one of ccw, cw"),
        (10, 7, "program.shapes[2]: a shape is a one-key mapping, its kind; found keys 'line', 'to' "
                "(indent the other keys under 'line')"),
        (12, 24, "program.shapes[3].points[1]: expected a list of 2 or 3 numbers"),
        (13, 57, "program.shapes[4].arc.sweep: must be non-zero and at most 360 in magnitude"),
        (14, 42, "program.shapes[5].ellipse.b: must be > 0"),
        (14, 52, "program.shapes[5].ellipse.sweep: must be non-zero and at most 360 in magnitude"),
        (15, 62, "program.shapes[6].sine.length: must not be 0"),
        (16, 27, "program.shapes[7].function.x: must be [from, to] with from != to"),
        (17, 26, "program.shapes[8].polyline.points: expected at least 2 points"),
        (18, 26, "program.shapes[9].line: unknown key 'z'; expected feed, to, from"),
        (19, 20, "program.shapes[10].travel.to: expected a list of 2 or 3 numbers"),
    ]


def test_enum_did_you_mean_and_unknown_shape_without_match(tmp_path):
    path = write(tmp_path, STEPPERS + """\
        program:
          shapes:
            - circle: {center: [0, 0], radius: 5, direction: cww}
            - spiral: {center: [0, 0]}
            - 5
            - points: 7
            - circle:
        """.replace("        ", ""))
    assert errors(path) == [
        (8, 54, "program.shapes[0].circle.direction: 'cww' is not one of ccw, cw (did you mean 'cw'?)"),
        (9, 7, "program.shapes[1]: unknown shape 'spiral'; shapes are line, polyline, points, arc, circle, "
               "ellipse, sine, function, travel"),
        (10, 7, "program.shapes[2]: expected a shape, a one-key mapping such as `line: {to: [10, 0]}`"),
        (11, 15, "program.shapes[3].points: expected a list"),
        (12, 7, "program.shapes[4].circle: expected the circle's keys (a mapping)"),
    ]


def test_expression_errors_point_inside_the_yaml_scalar():
    assert errors(DATA / "bad_expr.yaml") == [
        (8, 23, "program.shapes[0].function.y: unknown name 'sinn' (did you mean 'sin'?)"),  # plain
        (9, 28, "program.shapes[1].function.y: missing ')'"),  # single-quoted: at the closing quote
        (10, 27, "program.shapes[2].function.y: unexpected character '$'"),  # double-quoted
        (12, 16, "program.shapes[3].function.y: expected '(' after 'sin'"),  # block mapping
        (14, 27, "program.shapes[4].function.y: unknown name 'q'"),  # after an escape sequence \t
        (15, 24, "program.shapes[5].function.y: unexpected character \"'\""),  # after a doubled ''
    ]


def test_shapes_constructed_in_python_carry_a_source():
    circle = Circle(center=(0, 0), radius=1)
    assert circle.source == SourceRef("<shape>")
    circle.source = SourceRef("x.yaml", 3, 5)
    assert circle.source == SourceRef("x.yaml", 3, 5)
    assert Line(to=(1, 2), from_=(0, 0)).from_ == (0.0, 0.0)
    assert str(derivative(Function(y="x**2", x=(0, 1)).expr)) == "2*x"
    assert Function(y=2, x=(0, 1)).expr.evaluate(0.5) == 2.0  # `y: 2` in YAML is a number: still an expression
    program = Program(shapes=[circle, Line(to=(1, 2))])
    assert [s.kind for s in program.shapes] == ["circle", "line"] and program.shapes[0] is circle


# ---- rules across keys ----

def test_cross_key_rules(tmp_path):
    (tmp_path / "part.gcode").write_text("G1 X1\n")
    assert errors(DATA / "cross.yaml") == [
        (1, 1, "machine: missing key 'delta' (required for delta kinematics)"),
        (3, 3, "machine.steppers: missing motor 'c' (required for delta kinematics)"),
        (6, 5, "machine.steppers: unknown motor 'x' for delta kinematics; delta motors are a, b, c, e"),
        (10, 3, "program: give either 'shapes' or 'gcode', not both"),
        (10, 10, "program.gcode: no such file 'part.gcode'"),
    ]
    path = write(tmp_path, STEPPERS.replace("    y:", "    yy:") + """\
          delta: {radius: 100, diagonal_rod: 50, height: 10}
        program:
          start: [0, 0]
        """.replace("        ", ""))
    assert errors(path) == [
        (3, 3, "machine.steppers: missing motor 'y' (required for cartesian kinematics)"),
        (5, 5, "machine.steppers: unknown motor 'yy' for cartesian kinematics (did you mean 'y'?)"),
        (6, 3, "machine.delta: only allowed with kinematics: delta"),
        (6, 38, "machine.delta.diagonal_rod: must be > radius (100)"),
        (7, 1, "program: missing key 'shapes' or 'gcode'"),
    ]


def test_corexy_motors(tmp_path):
    path = write(tmp_path, (DATA / "good.yaml").read_text().replace("cartesian", "corexy"))
    assert errors(path) == [
        (4, 3, "machine.steppers: missing motor 'a' (required for corexy kinematics)"),
        (4, 3, "machine.steppers: missing motor 'b' (required for corexy kinematics)"),
        (6, 5, "machine.steppers: unknown motor 'y' for corexy kinematics; corexy motors are a, b, z, e"),
        (7, 5, "machine.steppers: unknown motor 'x' for corexy kinematics; corexy motors are a, b, z, e"),
    ]


# ---- G-code programs ----

def test_inline_gcode_keeps_its_first_line(tmp_path):
    path = write(tmp_path, STEPPERS + "program:\n  gcode: |\n    G1 X10\n    G1 Y10\n")
    job = load_job(path)
    assert job.program.gcode == "G1 X10\nG1 Y10\n" and job.program.shapes is None
    assert job.program.gcode_source == SourceRef(str(path), 8, 5)


def test_gcode_file_is_relative_to_the_job(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "part.gcode").write_text("G1 X1\n")
    path = write(tmp_path, STEPPERS + "program:\n  gcode: sub/part.gcode\n")
    job = load_job(path)
    assert job.program.gcode == "sub/part.gcode"
    assert job.program.gcode_source == SourceRef(str(path), 7, 10)
    path.write_text(path.read_text().replace("sub/", "other/"))
    assert errors(path) == [(7, 10, "program.gcode: no such file 'other/part.gcode'")]


# ---- boards ----

def test_board_must_exist_for_the_target(tmp_path, boards):
    path = write(tmp_path, "board: ramps14\n" + STEPPERS + "program:\n  shapes: [{line: {to: [1, 1]}}]\n")
    assert errors(path) == [(1, 8, "board: unknown board 'ramps14' for target avr (did you mean 'ramps-1.4'?); "
                                   "avr boards: mks-gen-l, ramps-1.4")]
    (boards / "at89c52.yaml").write_text("target: mcs51\n")
    path.write_text(path.read_text().replace("ramps14", "at89c52"))
    assert errors(path) == [(1, 8, "board: 'at89c52' is a board for target mcs51, not avr; "
                                   "avr boards: mks-gen-l, ramps-1.4")]
    assert load_job(path, "mcs51").board == "at89c52"
    path.write_text(path.read_text().replace("at89c52", "mks-gen-l"))
    assert load_job(path).board == "mks-gen-l"


def test_board_check_against_the_real_targets_folder(tmp_path, monkeypatch):
    monkeypatch.undo()
    real = codegen.paths.targets_dir()
    avr = sorted(p.stem for p in real.glob("*.yaml") if "target: avr" in p.read_text())
    path = write(tmp_path, "board: no-such-board\n" + STEPPERS + "program:\n  shapes: [{line: {to: [1, 1]}}]\n")
    if not avr:
        assert load_job(path).board == "no-such-board"  # nothing to check against yet
    else:
        ((line, col, message),) = errors(path)
        assert (line, col) == (1, 8) and message.endswith(f"avr boards: {', '.join(avr)}")


# ---- files that are not jobs ----

def test_missing_file():
    with pytest.raises(JobError) as info:
        load_job(DATA / "no-such-job.yaml")
    (d,) = info.value.diagnostics
    assert d.where == SourceRef(str(DATA / "no-such-job.yaml")) and d.message == "no such file"
    assert info.value.render() == f"{DATA / 'no-such-job.yaml'}: error: no such file"


def test_yaml_syntax_error_is_one_diagnostic_at_pyyamls_mark():
    assert errors(DATA / "bad_yaml.yaml") == [
        (4, 1, "invalid YAML: expected ',' or '}', but got '<scalar>'; while parsing a flow mapping (line 3)"),
    ]


def test_not_a_mapping_empty_and_duplicate_keys(tmp_path):
    assert errors(write(tmp_path, "- 1\n- 2\n")) == [
        (1, 1, "expected a mapping with the keys machine and program (and optionally name, target, board)"),
    ]
    assert errors(write(tmp_path, "")) == [(1, 1, "the job file is empty")]
    again = "    x: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}\n"
    text = STEPPERS + again + "program:\n  gcode: |\n    G0\n"
    assert errors(write(tmp_path, text)) == [
        (6, 5, "machine.steppers: duplicate key 'x' (first given on line 4)"),
    ]


def test_attributes_that_are_not_keys_of_the_file(tmp_path):
    path = write(tmp_path, "path: /etc\n" + STEPPERS + """\
        program:
          shapes:
            - line: {to: [1, 1], source: 3, kind: line, from_: [0, 0]}
            - function: {y: x, x: [0, 1], expr: x}
        """.replace("        ", ""))
    assert errors(path) == [
        (1, 1, "unknown key 'path'; expected name, target, board, machine, program"),
        (9, 26, "program.shapes[0].line: unknown key 'source'; expected feed, to, from"),
        (9, 37, "program.shapes[0].line: unknown key 'kind'; expected feed, to, from"),
        (9, 49, "program.shapes[0].line: unknown key 'from_' (did you mean 'from'?)"),
        (10, 35, "program.shapes[1].function: unknown key 'expr'; expected feed, z, y, x, origin"),
    ]

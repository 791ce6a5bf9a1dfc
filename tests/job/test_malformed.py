"""Job files broken in shape, not in value: each ends in a positioned error, never a traceback (issue 28)."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from codegen.errors import BuildError, JobError
from codegen.job import load_job
from codegen.job.reading import MAX_DEPTH
from codegen.pipeline.host import host_build
from tests.helpers import ROOT

CARTESIAN = """\
name: {name}
machine:
  kinematics: {kinematics}
  steppers:
    x: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
    y: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
program:
  gcode: {gcode}
"""


def errors(path: Path) -> list[tuple[int, int, str]]:
    with pytest.raises(JobError) as info:
        load_job(path)
    return [(d.where.line, d.where.col, d.message) for d in info.value.diagnostics]


def job(tmp_path: Path, name="j", kinematics="cartesian", gcode="|\n    G1 X1 F600", text=None) -> Path:
    path = tmp_path / "job.yaml"
    body = text if text is not None else CARTESIAN.format(name=name, kinematics=kinematics, gcode=gcode)
    path.write_bytes(body.encode("utf-8") if isinstance(body, str) else body)
    return path


def test_a_control_character_is_refused_where_it_stands(tmp_path):
    assert errors(job(tmp_path, name='"a\x1bb"')) == [
        (1, 9, "control character U+001B is not allowed in a YAML file (write it as an escape in a double-quoted "
               "string)")]


def test_a_file_that_is_not_utf8_names_the_line_and_column_of_its_first_bad_byte(tmp_path):
    text = CARTESIAN.format(name="caf\u00e9", kinematics="cartesian", gcode="x").encode("utf-8")
    assert errors(job(tmp_path, text=text.replace("caf\u00e9".encode(), b"caf\xe9"))) == [
        (1, 10, "not UTF-8 text: byte 0xE9 (save the job file as UTF-8)")]


def test_nesting_at_any_depth_is_a_positioned_error(tmp_path):
    for depth in (1000, 100_000):  # PyYAML recursed to its end (300 levels it reads)
        problems = errors(job(tmp_path, gcode="[" * depth))
        bracket = 10 + MAX_DEPTH - 2  # the root and `program:` are two levels already
        assert problems == [(8, bracket, f"nested deeper than {MAX_DEPTH} levels; a job file needs a few")]


def test_kinematics_of_a_wrong_type_lists_the_choices(tmp_path):
    for value in ("[1, 2]", "{x: 1}"):
        assert errors(job(tmp_path, kinematics=value)) == [
            (3, 15, "machine.kinematics: expected one of cartesian, corexy, delta")]


def test_a_target_of_a_wrong_type_is_refused_at_it(tmp_path):
    path = job(tmp_path)
    path.write_text("target: [1, 2]\n" + path.read_text())
    assert [(line, col) for line, col, _ in errors(path)] == [(1, 9)]


def test_towers_in_one_direction_are_refused_at_tower_angles(tmp_path):
    text = (ROOT / "examples" / "kossel-mini.yaml").read_text().replace("[210, 330, 90]", "[0, 5, 120]")
    line = text.splitlines().index("    tower_angles: [0, 5, 120]") + 1
    assert errors(job(tmp_path, text=text)) == [
        (line, 19, "machine.delta.tower_angles: towers 1 and 2 stand 5 deg apart: the three towers must stand in "
                   "three directions at least 10 deg apart (a delta's are usually 120 deg apart)")]


@pytest.mark.parametrize("example", ["kossel-mini.yaml", "line.yaml"])
def test_a_null_program_is_refused_at_it(tmp_path, example):
    text = (ROOT / "examples" / example).read_text()
    text = text[:text.index("\nprogram:")] + "\nprogram: null\n"
    line = text.splitlines().index("program: null") + 1
    assert errors(job(tmp_path, text=text)) == [
        (line, 10, "program: expected a mapping with `shapes` or `gcode` (only `build --stream` goes without one)")]


def test_a_one_line_program_too_long_for_a_file_name_is_refused_at_it(tmp_path):
    (line, col, message), = errors(job(tmp_path, gcode='"G' + "9" * 400 + '\\n"'))
    assert (line, col) == (8, 10)
    assert message == ("program.gcode: cannot read 'G" + "9" * 59 + "...': File name too long (G-code written in "
                       "the job goes in a block scalar, `gcode: |`)")


WRONG = [None, [1, 2], {"a": 1}, "text", "\x07", -1]


def _paths(data, prefix=()):
    if isinstance(data, dict):
        for key, value in data.items():
            yield prefix + (key,)
            yield from _paths(value, prefix + (key,))
    elif isinstance(data, list):
        for i, value in enumerate(data[:2]):
            yield prefix + (i,)
            yield from _paths(value, prefix + (i,))


@pytest.mark.parametrize("example", ["line.yaml", "kossel-mini.yaml"])
def test_a_wrong_type_at_any_key_is_a_diagnostic_or_a_plan(tmp_path, example):
    """Every key of the example, in turn, given each wrong type: loading and planning end in JobError,
    BuildError or a plan, never another exception (scripts/fuzz.py tries more)."""
    source = ROOT / "examples" / example
    base = yaml.safe_load(source.read_text())
    gcode = (base.get("program") or {}).get("gcode")
    if isinstance(gcode, str) and "\n" not in gcode:
        base["program"]["gcode"] = str((source.parent / gcode).resolve())
    tried = 0
    for path in _paths(base):
        for wrong in WRONG:
            data = copy.deepcopy(base)
            holder = data
            for key in path[:-1]:
                holder = holder[key]
            holder[path[-1]] = wrong
            (tmp_path / "j.yaml").write_text(yaml.safe_dump(data))
            try:
                host_build(load_job(tmp_path / "j.yaml"), False, keep=False)
            except (JobError, BuildError):
                pass
            tried += 1
    assert tried >= len(WRONG) * 20


@pytest.mark.parametrize("tag, kind", [("!!timestamp", "timestamp"), ("!!bool", "bool")])
def test_a_tag_pyyaml_cannot_construct_is_an_error_at_its_value(tmp_path, tag, kind):
    """PyYAML raised AttributeError for `!!timestamp x` and KeyError for `!!bool x`."""
    assert errors(job(tmp_path, gcode=f"{tag} x")) == [(8, 10, f"program.gcode: 'x' is not a valid {kind}")]


def test_a_value_yaml_cannot_build_has_one_message(tmp_path):
    """The schema's own message at the same place ('expected a number') came beside the reading's."""
    assert errors(job(tmp_path, gcode="!!int abc")) == [(8, 10, "program.gcode: 'abc' is not a valid int")]


def test_half_a_surrogate_pair_and_control_characters_in_the_name_are_refused(tmp_path):
    """`\\ud800` printed as a UnicodeEncodeError with plan's summary; `\\e[31m` sent terminal codes with it."""
    assert errors(job(tmp_path, name='"\\ud800"')) == [
        (1, 7, "name: \\uD800 is half of a UTF-16 surrogate pair, not a character; write the character itself or "
               "its \\U00XXXXXX escape")]
    assert errors(job(tmp_path, name='"\\e[31mred"')) == [(1, 7, "name: must be printable text (no control characters)")]


def xy_job(x_extra: str = "", y_extra: str = "", program: str = "  gcode: G1 X1 F600\n") -> str:
    """A cartesian x, y job's text; `x_extra`, `y_extra`: more fields of each stepper's mapping."""
    stepper = "{{steps_per_mm: 80, max_velocity: 200, max_accel: 3000{}}}"
    return (f"machine:\n  kinematics: cartesian\n  steppers:\n    x: {stepper.format(x_extra)}\n"
            f"    y: {stepper.format(y_extra)}\nprogram:\n{program}")


def test_a_range_beyond_the_reach_is_refused_at_the_range(tmp_path):
    """The long fuzz run's one traceback: `range: [0, 1e308]` made homing's travel infinite (OverflowError in
    program/homing.py)."""
    text = xy_job(", range: [0, 1.0e+308]", ", range: [-100000, 100000]", "  home: true\n  gcode: G1 X1 F600\n")
    assert errors(job(tmp_path, text=text)) == [
        (4, 70, "machine.steppers.x.range: must be within 100000 mm of the origin (100 m is beyond any machine)")]


def test_a_start_beyond_the_reach_is_refused_at_the_start(tmp_path):
    """The long fuzz run: `start: [10, 1e20]` planned relative moves from there and failed its own checks."""
    text = xy_job(program="  start: [10, 1.0e+20]\n  gcode: G91 G1 X1 F600\n")
    assert errors(job(tmp_path, text=text)) == [
        (7, 10, "program.start: must be within 100000 mm of the origin (100 m is beyond any machine)")]

"""M593 (codegen/gcode/shaper_codes.py): the shapers of the named axes from its place on, Marlin's ZV where the
machine has no type, F0 off, values within the job key's ranges; its F is a frequency, not a feed."""

from __future__ import annotations

from types import SimpleNamespace as NS

import pytest

from codegen.errors import JobError
from codegen.gcode import toolpath_from_gcode
from codegen.toolpath.items import InputShaping, Line, expanded
from tests.gcode.helpers import errors, make_job, run

OFF = (None, None, None)


def shaper_items(gcode: str, shaper=None, **kw) -> tuple[list[InputShaping], list]:
    job = make_job(gcode, **kw)
    job.machine.input_shaper = shaper
    toolpath, warnings = toolpath_from_gcode(job)
    return [item for item in toolpath.items if isinstance(item, InputShaping)], warnings


def machine_shaper(**axes):
    shapers = {a: NS(type=t, freq=f, damping=d) for a, (t, f, d) in axes.items()}
    return NS(axes=shapers, max_smoothing=None)


def test_m593_without_axes_sets_x_and_y_with_marlins_zv_and_says_so():
    got, warnings = shaper_items("G1 X10 F600\nM593 F40 D0.15\nG1 X20\nM593 F52\n")
    assert [(g.shapers, g.before) for g in got] == [
        ((("zv", 40.0, 0.15), ("zv", 40.0, 0.15), None), OFF),
        ((("zv", 52.0, 0.15), ("zv", 52.0, 0.15), None), (("zv", 40.0, 0.15), ("zv", 40.0, 0.15), None))]
    assert [(w.severity, w.where.line, w.where.col, w.message) for w in warnings] == [
        ("note", 9, 5, "M593 shapes x and y with ZV, Marlin's shaper: the machine has no input_shaper type for "
                        "them (machine.input_shaper.x.type sets one)")]


def test_named_axes_keep_the_machines_type_and_f0_turns_one_off():
    shaper = machine_shaper(x=("mzv", 48.0, 0.1), y=("ei", 40.0, 0.2))
    got, warnings = shaper_items("M593 X F60\nM593 Y F0\nM593 D0.05\nM593 Y F35\n", shaper)
    assert [g.shapers for g in got] == [
        (("mzv", 60.0, 0.1), ("ei", 40.0, 0.2), None),
        (("mzv", 60.0, 0.1), None, None),
        (("mzv", 60.0, 0.05), None, None),  # y's damping changes while it is off, for when it is on again
        (("mzv", 60.0, 0.05), ("ei", 35.0, 0.05), None)]
    assert warnings == []  # both axes have the machine's type: no note


def test_only_x_named_leaves_y_as_it_was_and_notes_only_x():
    got, warnings = shaper_items("M593 X F30\n")
    assert got[0].shapers == (("zv", 30.0, 0.1), None, None)
    assert "M593 shapes x with ZV" in warnings[0].message and "for it (machine.input_shaper.x.type" in \
        warnings[0].message


def test_m593_f_is_a_frequency_not_the_feed():
    toolpath, _ = run("G1 X10 F600\nM593 F40\nG1 X20\n")
    moves = [item for item in expanded(toolpath.items) if isinstance(item, Line)]
    assert [move.feed for move in moves] == [10.0, 10.0]  # 600 mm/min, not 40


def test_m593_without_f_or_d_changes_nothing():
    got, _ = shaper_items("M593\nM593 X\n")
    assert got == []


@pytest.mark.parametrize("line, col, message", [
    ("M593 F-5", 10, "'F-5': the shaper frequency must be 0 (off) or from 1 to 1000 Hz"),
    ("M593 F1000.5", 10, "'F1000.5': the shaper frequency must be 0 (off) or from 1 to 1000 Hz"),
    ("M593 F0.5", 10, "'F0.5': the shaper frequency must be 0 (off) or from 1 to 1000 Hz"),
    ("M593 F40 D0", 14, "'D0': the damping ratio of x's shaper (zv) must be > 0 and <= 0.99"),
    ("M593 F40 D1", 14, "'D1': the damping ratio of x's shaper (zv) must be > 0 and <= 0.99"),
    ("M593 Y F40 D-0.1", 16, "'D-0.1': the damping ratio of y's shaper (zv) must be > 0 and <= 0.99"),
    ("M593 X5 Y F40 Q2", 19, "'Q2' is not a parameter of M593"),
    ("G1 X5 M593 F40", 11, "'G1' and 'M593' on one line: both take the axis words"),
])
def test_bad_values_are_errors_at_their_word(line, col, message):
    assert errors(f"G1 X1 F600\n{line}\n") == [(9, col, message)]


def test_damping_beyond_the_machines_type_is_refused():
    job = make_job("M593 X F40 D0.35\n")
    job.machine.input_shaper = machine_shaper(x=("2hump_ei", 40.0, 0.1))
    with pytest.raises(JobError) as caught:
        toolpath_from_gcode(job)
    assert [d.message for d in caught.value.diagnostics] == [
        "'D0.35': the damping ratio of x's shaper (2hump_ei) must be > 0 and <= 0.3"]


def test_a_delta_takes_m593():
    """A delta is shaped in cartesian space (codegen/motion/shaped_delta.py): M593 there as anywhere."""
    got, _ = shaper_items("G1 X10 F600\nM593 F40\n", kinematics="delta", motors=("a", "b", "c"))
    assert [g.shapers for g in got] == [(("zv", 40.0, 0.1), ("zv", 40.0, 0.1), None)]

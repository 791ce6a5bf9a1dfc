"""M900 K (Marlin) and M572 D0 S (RepRapFirmware) on a machine with pressure advance: K from their line on, as a
Limits item the segments carry (codegen/toolpath/segments.py `advance`); D other than 0 and a negative K are
errors at their word."""

from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np
import pytest

from codegen.errors import JobError
from codegen.gcode import toolpath_from_gcode
from codegen.toolpath.items import Limits
from codegen.toolpath.segments import REF_ARC, Flattener
from tests.gcode.helpers import errors as errors_without
from tests.gcode.helpers import make_job


def advancing(gcode: str):
    job = make_job(gcode)
    job.machine.pressure_advance = NS(k=0.05, smooth_time=0.04)
    return job


def run(gcode: str):
    toolpath, warnings = toolpath_from_gcode(advancing(gcode), False)
    assert warnings == []
    return toolpath


def errors(gcode: str) -> list[tuple[int, int, str]]:
    with pytest.raises(JobError) as caught:
        run(gcode)
    return [(d.where.line, d.where.col, d.message) for d in caught.value.diagnostics]


def test_m900_and_m572_set_k_from_their_line():
    limits = [i for i in run("M900 K0.08\nM572 D0 S0.03\nM572 S0.02\nM900\nM900 K0\n").items]
    assert [(type(i), i.advance) for i in limits] == [(Limits, 0.08), (Limits, 0.03), (Limits, 0.02), (Limits, 0.0)]
    assert all(i.max_velocity is None and i.max_accel is None and i.jerk is None for i in limits)


def test_segments_carry_the_k_in_force():
    """The job's K until the first M900, then each code's K, on every piece after it (an arc's chords too)."""
    toolpath = run("M83\nG1 X10 E1 F600\nM900 K0.1\nG1 X20 E1\nG2 X30 Y0 I5 J0 E1\nM572 D0 S0\nG1 Y10 E1\n")
    segments = Flattener(toolpath.start, 0.002, advance=0.05)(toolpath.items)
    arc = segments.ref_kind == REF_ARC
    assert segments.advance[0] == 0.05 and segments.advance[1] == 0.1
    assert np.count_nonzero(arc) > 3 and np.all(segments.advance[arc] == 0.1)
    assert segments.advance[-1] == 0.0 and len(segments) == 3 + np.count_nonzero(arc)


def test_other_extruders_and_negative_k_are_errors_at_their_word():
    assert errors("M572 D1 S0.05\nM900 K-0.1\nM572 D0 S-1\n") == [
        (8, 10, "'D1': the machine has one extruder (D0)"),
        (9, 10, "'K-0.1' must be >= 0"),
        (10, 13, "'S-1' must be >= 0")]


def test_without_pressure_advance_in_the_job_only_off_is_accepted():
    assert errors_without("M900 K0.05\n")[0][2].startswith("'M900 K0.05': pressure (linear) advance needs "
                                                           "machine.pressure_advance in the job")

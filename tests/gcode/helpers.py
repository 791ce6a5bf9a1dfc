"""The G-code interpreter's test helpers (tests/gcode/test_interpreter.py, test_grbl.py): a job of G-code without a
job file, and its items or errors."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace as NS

import pytest

from codegen.errors import JobError, SourceRef
from codegen.gcode import toolpath_from_gcode
from tests.helpers import machine

PRINTER = ("x", "y", "z", "e")
MILL = ("x", "y", "z")
PLOTTER = ("x", "y")


def make_job(gcode: str, motors=PRINTER, start=(0, 0), feed=1200, travel_feed=None, kinematics="cartesian",
             path=Path("/nowhere/job.yaml"), laser=False, **program):
    fake = machine(kinematics, motors)
    fake.laser = NS(pwm_hz=1000) if laser else None
    if kinematics == "delta":
        fake.delta = NS(height=250.0, diagonal_rod=215.0)
        fake.home_point = (0.0, 0.0, 250.0)
    return NS(machine=fake, path=path,
              program=NS(start=start, feed=feed, travel_feed=travel_feed, gcode=gcode,
                         gcode_source=SourceRef("job.yaml", 8, 5), **program))


def run(gcode: str, strict=False, **kw):
    return toolpath_from_gcode(make_job(gcode, **kw), strict)


def items(gcode: str, **kw):
    toolpath, warnings = run(gcode, **kw)
    assert warnings == []
    return toolpath.items


def errors(gcode: str, strict=False, **kw) -> list[tuple[int, int, str]]:
    with pytest.raises(JobError) as caught:
        run(gcode, strict, **kw)
    return [(d.where.line, d.where.col, d.message) for d in caught.value.diagnostics]

"""Small builders shared by the unit tests: machines and toolpaths without a job file."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from codegen.errors import SourceRef
from codegen.kinematics import make_kinematics
from codegen.planner import PlannerLimits, plan
from codegen.staircase import split_long
from codegen.stepgen import segment_steps
from codegen.segments import flatten
from codegen.toolpath import Line, Toolpath

SRC = SourceRef("test.yaml", 1, 1)


def stepper(spm=80.0, vmax=200.0, amax=3000.0):
    return SimpleNamespace(steps_per_mm=spm, max_velocity=vmax, max_accel=amax, invert_dir=False, range=None)


def machine(kinematics="cartesian", motors=("x", "y"), **limits):
    return SimpleNamespace(kinematics=kinematics, motor_names=tuple(motors),
                           steppers={m: stepper(**limits.get(m, {})) for m in motors})


def point(x, y, z=0.0, e=0.0):
    return np.array([x, y, z, e], dtype=float)


def polyline(points, feed, tool=True):
    pts = [point(*p) for p in points]
    return Toolpath(pts[0], [Line(a, b, feed, tool, SRC) for a, b in zip(pts[:-1], pts[1:])])


def planned(toolpath, mach=None, jd=0.01, tolerance=0.002, max_event_rate=np.inf):
    kin = make_kinematics(mach or machine())
    segments = split_long(flatten(toolpath, tolerance), kin)
    steps = segment_steps(segments, kin)
    return kin, segments, steps, plan(segments, kin, steps, PlannerLimits(jd, max_event_rate=max_event_rate))


GCODE_DATA = Path(__file__).resolve().parent / "data" / "gcode"
_PRINTER = """name: {name}
target: {target}
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
    y: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
    z: {{steps_per_mm: 400, max_velocity: 12, max_accel: 400}}
{extruder}program:
  gcode: {gcode}
"""
_EXTRUDER = "    e: {steps_per_mm: 100, max_velocity: 80, max_accel: 5000}\n"


def gcode_job_file(folder: Path, name: str, target: str = "avr", extruder: bool = True) -> Path:
    """A job file in `folder`: a cartesian printer (x, y 80 steps/mm, z 400, e 100 with `extruder`) running the
    G-code file tests/data/gcode/`name`."""
    path = Path(folder) / f"{Path(name).stem}-{target}.yaml"
    path.write_text(_PRINTER.format(name=Path(name).stem, target=target, extruder=_EXTRUDER if extruder else "",
                                    gcode=GCODE_DATA / name))
    return path

"""Small builders shared by the unit tests: machines and toolpaths without a job file."""

from __future__ import annotations

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

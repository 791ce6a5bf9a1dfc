"""Shape jobs for the shape tests: a fake machine and program around the shapes, built into Toolpath items."""

from __future__ import annotations

import math
from types import SimpleNamespace as NS

import numpy as np
import pytest

from codegen.errors import JobError, SourceRef
from codegen.shapes import build_toolpath
from codegen.toolpath.items import Curve
from tests.helpers import machine

TOL = 0.002
SRC = SourceRef("shape.yaml", 7, 5)


def make_job(*shapes, start=(0, 0), motors=("x", "y"), kinematics="cartesian", tol=TOL, feed=1200,
             travel_feed=None):
    fake = machine(kinematics, motors)
    fake.tolerance = tol
    if kinematics == "delta":
        fake.delta = NS(diagonal_rod=215.0)
    return NS(machine=fake,
              program=NS(start=start, feed=feed, travel_feed=travel_feed, shapes=list(shapes)))


def shape(kind, line=7, **fields):
    defaults = {"feed": None, "z": None}
    if kind == "points":
        defaults.pop("feed")
    return NS(kind=kind, source=SourceRef("shape.yaml", line, 5), **{**defaults, **fields})


def line(to, from_=None, **kw):
    return shape("line", to=to, from_=from_, **kw)


def ellipse(**kw):
    fields = {"center": (50, 40), "a": 30, "b": 15, "rotation": 0, "start": 0, "sweep": 360, **kw}
    return shape("ellipse", **fields)


def sine(**kw):
    return shape("sine", **{"origin": (0, 0), "amplitude": 10, "omega": 0.5, "phase": 0, "length": 60, **kw})


def v4(*xyz):
    return np.array([*xyz, *[0.0] * (4 - len(xyz))], dtype=float)


def build(*shapes, **kw):
    return build_toolpath(make_job(*shapes, **kw)).items


def errors_of(*shapes, **kw):
    with pytest.raises(JobError) as caught:
        build(*shapes, **kw)
    return caught.value.diagnostics


def chord_deviation(curve: Curve, params: np.ndarray, at) -> float:
    """The largest distance from the true curve, sampled densely, to the chord between its parameters."""
    u = np.linspace(0.0, 1.0, 65)
    t = params[:-1, None] + (params[1:] - params[:-1])[:, None] * u[None, :]
    true = at(t)  # (n, 65, 2)
    a, b = curve.points[:-1, None, :2], curve.points[1:, None, :2]
    d = b - a
    s = np.clip(((true - a) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-300), 0.0, 1.0)
    return float(np.linalg.norm(true - (a + s[..., None] * d), axis=-1).max())


def uniform_count(length, curvature, tol=TOL):
    return math.ceil(abs(length) / math.sqrt(8 * tol / curvature))


def check_chords(curve, params, at, uniform, tol=TOL):
    deviation = chord_deviation(curve, params, at)
    assert deviation <= tol
    assert 0 < curve.deviation <= tol and deviation <= curve.deviation + 1e-12
    n = len(curve.points) - 1
    assert uniform / 2 <= n <= uniform
    return deviation

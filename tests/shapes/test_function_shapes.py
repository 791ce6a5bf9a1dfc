"""Function shapes -> Toolpath: y = f(x) in chords within the tolerance, its expression's errors at their place."""

from __future__ import annotations

import time

import numpy as np
import pytest

from codegen.job.expr import parse
from codegen.toolpath.items import Curve
from tests.shapes.shape_jobs import (SRC, TOL, build, check_chords, chord_deviation, ellipse, errors_of, line, shape,
                                     uniform_count, v4)

# ---------------------------------------------------------------- functions

def function(text, x, origin=(0, 0)):
    return shape("function", y=text, expr=parse(text), x=x, origin=origin)


def function_at(text, origin=(0, 0)):
    expr = parse(text)

    def at(x):
        return np.stack([origin[0] + x, origin[1] + expr.evaluate(x)], axis=-1)
    return at


WAVE = "5*sin(x/3) + x/10"  # |f''| <= 5/9


@pytest.mark.parametrize("x, origin", [((0, 40), (0, 0)), ((40, -3), (10, -2))])
def test_function_chords_are_within_tolerance_and_end_exactly(x, origin):
    at = function_at(WAVE, origin)
    curve = build(function(WAVE, x, origin), start=tuple(at(np.array(float(x[0])))))[-1]
    assert isinstance(curve, Curve) and curve.label == "function"
    assert np.array_equal(curve.points[0, :2], at(np.array(float(x[0]))))
    assert np.array_equal(curve.points[-1, :2], at(np.array(float(x[1]))))
    xs = curve.points[:, 0] - origin[0]
    assert np.all(np.sign(np.diff(xs)) == np.sign(x[1] - x[0]))
    check_chords(curve, xs, at, uniform_count(x[1] - x[0], 5 / 9))


@pytest.mark.parametrize("text, x, most", [
    ("abs(x)", (-7, 3), 100), ("2*abs(x - 1/3)", (3, -7), 100), ("sqrt(x)", (0, 4), 60), ("x**1.5", (0, 4), 150),
    ("sqrt(4 - x)", (0, 4), 60),
])
def test_function_with_a_kink_or_an_infinite_slope(text, x, most):
    _, curve = build(function(text, x), start=(9, 9))
    xs = curve.points[:, 0]
    assert xs[0] == x[0] and xs[-1] == x[1]
    assert chord_deviation(curve, xs, function_at(text)) <= curve.deviation <= TOL
    assert len(xs) - 1 <= most


@pytest.mark.parametrize("text, x, message", [
    ("1/(x - 1.5)", (0, 3), "function y is undefined at x=1.5"),
    ("log(x)", (-1, 2), "function y is undefined at x=-1"),
    ("sqrt(x) + sqrt(-x)", (-2, 3), "function y is undefined at x=-2"),
    ("tan(x)", (0, 2), "function y is not defined or not bounded near x=1.5708"),
    ("1/x", (-1, 2), "function y is not defined or not bounded near x=0 "),
])
def test_undefined_function_names_its_x(text, x, message):
    (d,) = errors_of(line((1, 1)), function(text, x))
    assert d.where == SRC and message in d.message and text in d.message


def test_function_whose_curvature_cannot_be_bounded():
    (d,) = errors_of(function("sqrt(x*x - 2*x + 1)", (-7, 3)))  # |x - 1|, beyond naive interval arithmetic
    assert "function y: cannot bound the curvature near x=" in d.message
    assert float(d.message.split("x=")[1].split()[0]) == pytest.approx(1, abs=0.01)


# ---------------------------------------------------------------- heights

def test_two_d_shapes_are_drawn_at_the_current_z_unless_they_carry_one():
    xyz = ("x", "y", "z")
    items = build(line((5, 0)), shape("circle", center=(0, 0), radius=5, start=0, direction="ccw", z=2),
                  ellipse(z=2), start=(0, 0, 7), motors=xyz)
    assert np.array_equal(items[0].end, v4(5, 0, 7))
    travel, circle = items[1:3]
    assert not travel.tool and np.array_equal(travel.end, v4(5, 0, 2))  # down to the shape's height
    assert circle.start[2] == 2 and circle.end[2] == 2
    assert np.all(items[-1].points[:, 2] == 2) and np.all(items[-1].points[:, 3] == 0)
    (drawn,) = build(line((5, 0)), start=(0, 0, 7), motors=xyz)
    assert drawn.start[2] == 7


def test_no_z_motor_rejects_every_shape_that_needs_z():
    diagnostics = errors_of(ellipse(z=3), shape("points", line=9, points=[(0, 0, 0), (1, 1, 2)]),
                            shape("arc", line=11, center=(0, 0), radius=1, start=0, sweep=90, z=0))
    assert [d.where.line for d in diagnostics] == [7, 9]
    assert "ellipse needs z=3 mm" in diagnostics[0].message and "no z motor" in diagnostics[0].message
    assert "points needs z=2 mm" in diagnostics[1].message
    assert build(ellipse(z=0))  # z = 0 is fine
    assert build(ellipse(z=3), motors=("a", "b", "c"), kinematics="delta")


def test_a_shape_beyond_the_limits_is_refused_at_the_shape():
    """Issue 28: the shapes get the G-code's limits (codegen/toolpath/limits.py), each reason at the shape."""
    started = time.monotonic()
    diagnostics = errors_of(line((1e10, 5), line=3), line((5, 5), feed=0.000001, line=4),
                            shape("circle", center=(0, 0), radius=20000, start=0, direction="ccw", line=5),
                            shape("arc", center=(2e5, 0), radius=5, start=0, sweep=90, line=6), line((6, 6), line=7))
    assert [(d.where.line, d.message) for d in diagnostics] == [
        (3, "x = 1e+10 mm is beyond the reach of 100000 mm from the origin"),
        (4, "the feed of 1e-06 mm/min makes this move last 13.4 years; the slowest move the tables hold lasts 1 day "
            "(here at least 0.00491 mm/min)"),
        (5, "this arc is 125664 mm long; the longest arc a move may draw is 100000 mm"),
        (6, "x = 200005 mm is beyond the reach of 100000 mm from the origin")]
    assert time.monotonic() - started < 2.0
    assert build(line((99999, 5)))  # within the reach

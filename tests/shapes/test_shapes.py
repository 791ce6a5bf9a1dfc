"""Shapes -> Toolpath: exact end points, travel moves, tools and feeds, arcs, and proven chord deviations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from codegen.shapes import build_toolpath
from codegen.shapes.context import split_chords
from codegen.toolpath.items import Arc, Curve, Line
from tests.shapes.shape_jobs import (SRC, TOL, build, check_chords, ellipse, errors_of, line, make_job, shape, sine,
                                     uniform_count, v4)

# ---------------------------------------------------------------- lines, travel, tools and feeds

def test_start_is_a_four_vector():
    assert np.array_equal(build_toolpath(make_job(start=(3, 4))).start, v4(3, 4))
    assert np.array_equal(build_toolpath(make_job(start=(3, 4, 5), motors=("x", "y", "z"))).start, v4(3, 4, 5))


def test_line_from_the_current_point_has_no_travel():
    (item,) = build(line((10, 20)), start=(1, 2))
    assert isinstance(item, Line) and item.tool and item.label == "line"
    assert np.array_equal(item.start, v4(1, 2)) and np.array_equal(item.end, v4(10, 20))
    assert item.feed == pytest.approx(20.0)  # 1200 mm/min
    assert item.source == SRC


def test_line_with_from_travels_there_first():
    travel, drawn = build(line((10, 0), from_=(5, 5)), travel_feed=6000)
    assert isinstance(travel, Line) and not travel.tool and travel.label == "travel" and travel.source == SRC
    assert np.array_equal(travel.start, v4(0, 0)) and np.array_equal(travel.end, v4(5, 5))
    assert travel.feed == pytest.approx(100.0)
    assert drawn.tool and np.array_equal(drawn.start, v4(5, 5)) and np.array_equal(drawn.end, v4(10, 0))


def test_travel_is_as_fast_as_allowed_without_travel_feed_and_own_feeds_convert():
    travel, drawn = build(line((10, 0), from_=(5, 5), feed=600))
    assert travel.feed == math.inf
    assert drawn.feed == pytest.approx(10.0)


def test_no_travel_between_shapes_that_join():
    items = build(line((10, 0)), line((10, 5), from_=(10, 0)), line((10, 5 + 1e-12), from_=(10, 5 + 1e-12)))
    assert [i.tool for i in items] == [True, True]  # the last is joined within 1e-9 mm and has no length


def test_polyline_travels_to_its_first_point_then_draws():
    items = build(shape("polyline", points=[(1, 1), (2, 1), (2, 3)]))
    assert [i.tool for i in items] == [False, True, True]
    assert np.array_equal(items[0].end, v4(1, 1)) and np.array_equal(items[-1].end, v4(2, 3))
    assert items[1].label == "polyline"


def test_points_in_3d_keep_their_z_and_two_numbers_keep_the_current_z():
    items = build(shape("points", points=[(100, 20, 50), (-60, 70, 30), (0, 0)]),
                  motors=("a", "b", "c"), kinematics="delta")
    assert [i.tool for i in items] == [False, True, True]
    assert np.array_equal(items[0].end, v4(100, 20, 50))
    assert np.array_equal(items[1].end, v4(-60, 70, 30))
    assert np.array_equal(items[2].end, v4(0, 0, 30))


def test_a_single_point_is_only_a_travel():
    (item,) = build(shape("points", points=[(4, 5)]))
    assert not item.tool and np.array_equal(item.end, v4(4, 5))


def test_travel_shape_is_a_tool_off_line():
    (item,) = build(shape("travel", to=(7, 8)), travel_feed=3000)
    assert not item.tool and item.label == "travel" and item.feed == pytest.approx(50.0)
    (item,) = build(shape("travel", to=(7, 8), feed=120), travel_feed=3000)
    assert item.feed == pytest.approx(2.0)
    assert build(shape("travel", to=(0, 0))) == []


# ---------------------------------------------------------------- arcs and circles

def test_arc_is_exact_with_its_angles_in_radians():
    travel, arc = build(shape("arc", center=(10, 20), radius=5, start=30, sweep=120))
    assert isinstance(arc, Arc) and arc.tool and not travel.tool
    a0, a1 = math.radians(30), math.radians(150)
    expected_start = v4(10 + 5 * math.cos(a0), 20 + 5 * math.sin(a0))
    assert np.array_equal(travel.end, expected_start) and np.array_equal(arc.start, expected_start)
    assert np.array_equal(arc.end, v4(10 + 5 * math.cos(a1), 20 + 5 * math.sin(a1)))
    assert arc.center == (10, 20) and arc.radius == 5 and arc.plane == (0, 1)
    assert arc.start_angle == pytest.approx(a0) and arc.sweep == pytest.approx(math.radians(120))
    middle = arc.points(np.array([math.radians(90)]))[0]
    assert middle == pytest.approx(v4(10, 25))


def test_clockwise_arc_passes_below_its_start():
    _, arc = build(shape("arc", center=(0, 0), radius=10, start=0, sweep=-90))
    assert arc.sweep == pytest.approx(-math.pi / 2)
    assert np.allclose(arc.end, v4(0, -10), atol=1e-12)
    middle = arc.points(np.array([arc.start_angle + arc.sweep / 2]))[0]
    assert middle == pytest.approx(v4(10 / math.sqrt(2), -10 / math.sqrt(2)))


@pytest.mark.parametrize("direction, sign", [("ccw", 1), ("cw", -1)])
def test_circle_closes_exactly_and_turns_its_way(direction, sign):
    travel, circle = build(shape("circle", center=(50, 50), radius=20, start=0, direction=direction))
    assert np.array_equal(circle.start, v4(70, 50)) and np.array_equal(circle.end, circle.start)
    assert np.array_equal(travel.end, circle.start)
    assert circle.sweep == pytest.approx(sign * 2 * math.pi)
    quarter = circle.points(np.array([circle.start_angle + circle.sweep / 4]))[0]
    assert quarter == pytest.approx(v4(50, 50 + sign * 20))


def test_circle_start_angle():
    _, circle = build(shape("circle", center=(0, 0), radius=2, start=90, direction="cw"))
    assert circle.start_angle == pytest.approx(math.pi / 2)
    assert np.array_equal(circle.end, circle.start) and circle.start[:2] == pytest.approx([0, 2])


# ---------------------------------------------------------------- chords

def ellipse_params(curve: Curve, e) -> np.ndarray:
    r = math.radians(e.rotation)
    p = curve.points[:, :2] - np.array(e.center)
    u = math.cos(r) * p[:, 0] + math.sin(r) * p[:, 1]
    v = -math.sin(r) * p[:, 0] + math.cos(r) * p[:, 1]
    t = np.unwrap(np.arctan2(v / e.b, u / e.a))
    return t - (t[0] - math.radians(e.start))


def ellipse_at(e):
    r = math.radians(e.rotation)

    def at(t):
        u, v = e.a * np.cos(t), e.b * np.sin(t)
        return np.stack([e.center[0] + math.cos(r) * u - math.sin(r) * v,
                         e.center[1] + math.sin(r) * u + math.cos(r) * v], axis=-1)
    return at


def test_full_ellipse_chords_are_within_tolerance_and_few():
    e = ellipse()
    travel, curve = build(e)
    assert isinstance(curve, Curve) and curve.tool and curve.label == "ellipse" and curve.feed == pytest.approx(20)
    assert np.array_equal(curve.points[0], v4(80, 40)) and np.array_equal(curve.points[-1], curve.points[0])
    assert np.array_equal(travel.end, curve.points[0])
    t = ellipse_params(curve, e)
    assert t[-1] == pytest.approx(2 * math.pi) and np.all(np.diff(t) > 0)
    assert check_chords(curve, t, ellipse_at(e), uniform_count(2 * math.pi, 30)) > TOL / 2


@pytest.mark.parametrize("a, b, rotation, start, sweep", [(30, 15, 25, 40, 200), (10, 40, -60, 300, -250)])
def test_partial_rotated_ellipse(a, b, rotation, start, sweep):
    e = ellipse(a=a, b=b, rotation=rotation, start=start, sweep=sweep)
    _, curve = build(e)
    t = ellipse_params(curve, e)
    at = ellipse_at(e)
    assert np.array_equal(curve.points[0, :2], at(np.array(math.radians(start))))
    assert np.array_equal(curve.points[-1, :2], at(np.array(math.radians(start + sweep))))
    assert t[-1] == pytest.approx(math.radians(start + sweep))
    assert np.all(np.sign(np.diff(t)) == np.sign(sweep))
    check_chords(curve, t, at, uniform_count(math.radians(sweep), max(a, b)))


def sine_at(s):
    phase = math.radians(s.phase)

    def at(x):
        return np.stack([x, s.origin[1] + s.amplitude * np.sin(s.omega * (x - s.origin[0]) + phase)], axis=-1)
    return at


@pytest.mark.parametrize("fields", [{}, {"origin": (20, 5), "length": -45, "phase": 30, "amplitude": -4},
                                    {"omega": 2.0, "amplitude": 1, "length": 7}])
def test_sine_chords_are_within_tolerance_and_end_exactly(fields):
    s = sine(**fields)
    items = build(s, start=s.origin)
    curve = items[-1]
    at = sine_at(s)
    x0, x1 = s.origin[0], s.origin[0] + s.length
    assert curve.points[0, 0] == x0 and curve.points[-1, 0] == x1
    assert np.array_equal(curve.points[-1, :2], at(np.array(float(x1))))
    xs = curve.points[:, 0]
    assert np.all(np.sign(np.diff(xs)) == np.sign(s.length))
    check_chords(curve, xs, at, uniform_count(s.length, abs(s.amplitude) * s.omega ** 2))


def steps(seed):
    """A random step function for ||c''|| (cells 1e-4 to 0.05 wide, values 1 to 1000) and its exact maxima."""
    rng = np.random.default_rng(seed)
    edges = np.concatenate([[0.0], np.cumsum(rng.uniform(1e-4, 0.05, 120))])
    values = 10.0 ** rng.uniform(0, 3, 120)

    def largest(lo, hi):
        first = np.searchsorted(edges, lo, "right") - 1
        last = np.searchsorted(edges, hi, "left") - 1
        return np.array([values[i:max(j, i) + 1].max() for i, j in zip(first, last)])
    return largest, edges[-1], values.max()


@pytest.mark.parametrize("seed", range(5))
def test_a_chord_is_held_to_the_largest_bound_it_crosses(seed):
    curvature, end, top = steps(seed)
    ts, deviation = split_chords(curvature, 0.0, end, TOL)
    h = np.diff(ts)
    proven = h * h / 8 * curvature(ts[:-1], ts[1:])
    assert ts[0] == 0 and ts[-1] == end and np.all(h > 0)
    assert np.all(proven <= TOL) and deviation == pytest.approx(proven.max())
    assert len(h) <= uniform_count(end, top)


@pytest.mark.parametrize("tol", [0.01, 0.0005])
def test_curves_follow_the_machine_tolerance(tol):
    e = ellipse(a=20, b=20)
    _, curve = build(e, tol=tol)
    check_chords(curve, ellipse_params(curve, e), ellipse_at(e), uniform_count(2 * math.pi, 20, tol), tol)


def test_shapes_without_extent_are_only_travel():
    (travel,) = build(shape("arc", center=(0, 0), radius=3, start=90, sweep=0))
    assert np.allclose(travel.end, v4(0, 3), atol=1e-15) and not travel.tool
    assert build(ellipse(sweep=0), ellipse(sweep=0))[0].label == "travel"
    assert len(build(ellipse(sweep=0), ellipse(sweep=0))) == 1


def test_a_curve_needing_too_many_chords_is_refused():
    (d,) = errors_of(sine(length=1e5, omega=3))
    assert d.where == SRC and "sine needs more than 100000 chords" in d.message


def test_flat_sine_is_one_chord():
    (curve,) = build(sine(amplitude=0, length=25))
    assert len(curve.points) == 2 and curve.points[-1, 0] == 25 and curve.deviation == 0

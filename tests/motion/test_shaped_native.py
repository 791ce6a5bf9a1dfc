"""The chord cuts, event times and smoothing of a linear machine's shaped blocks: in C as in numpy, to the last bit, and
every block within its limits afterwards."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import codegen.motion.chord_cuts
import codegen.motion.shaped_crossings
import codegen.motion.shaped_motion
from codegen.motion.blocks import MAX_MODULUS
from codegen.motion.chord_cuts import _position, _strays, chord_bounds, chord_bounds_numpy
from codegen.motion.shaped_blocks import shaped_blocks
from codegen.motion.shaped_motion import ShapingSettings, planned_motion, shape, smoothing
from codegen.motion.shapers import make_shaper
from codegen.native import library
from tests.helpers import machine, planned, polyline

LIMIT = 0.5


def random_motion(seed: int, pieces: int, motors: int):
    """Piecewise quadratic motor motion, continuous in position, with pieces from microseconds to a second."""
    rng = np.random.default_rng(seed)
    h = 10.0 ** rng.uniform(-5, 0, pieces)
    breaks = rng.uniform(-1, 1) + np.concatenate([[0.0], np.cumsum(h)])
    v = rng.normal(0, 3000, (pieces, motors)) * (rng.random((pieces, motors)) < 0.8)
    a = rng.normal(0, 1e5, (pieces, motors)) * (rng.random((pieces, motors)) < 0.7)
    p = np.zeros((pieces, motors))
    p[0] = rng.normal(0, 1000, motors)
    for k in range(1, pieces):
        p[k] = p[k - 1] + v[k - 1] * h[k - 1] + 0.5 * a[k - 1] * h[k - 1] ** 2
    forced = np.unique(np.concatenate([breaks[[0, -1]], rng.choice(breaks, size=max(1, pieces // 4))]))
    return breaks, p, v, a, forced


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), pieces=st.integers(1, 40), motors=st.integers(1, 4))
def test_c_and_numpy_cut_alike(seed, pieces, motors):
    if library("chordcuts") is None:
        return
    breaks, p, v, a, forced = random_motion(seed, pieces, motors)
    c = chord_bounds(breaks, p, v, a, forced, LIMIT)
    py = chord_bounds_numpy(breaks, p, v, a, forced, LIMIT, np.ones(len(forced) - 1, dtype=bool))
    assert np.array_equal(c, py)
    # Blocks not fresh are left as they are; the fresh ones cut as before.
    some = np.arange(len(forced) - 1) % 2 == 0
    partly = chord_bounds(breaks, p, v, a, forced, LIMIT, some)
    assert np.array_equal(partly, chord_bounds_numpy(breaks, p, v, a, forced, LIMIT, some))
    kept = ~some
    assert set(partly) <= set(c)
    assert not np.any(kept[np.searchsorted(forced, np.setdiff1d(partly, forced), side="right") - 1])


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), pieces=st.integers(1, 40), motors=st.integers(2, 4))
def test_every_block_is_close_to_its_chord_and_short_enough(seed, pieces, motors):
    breaks, p, v, a, forced = random_motion(seed, pieces, motors)
    bounds = chord_bounds(breaks, p, v, a, forced, LIMIT)
    assert np.all(np.isin(forced, bounds)) and np.all(np.diff(bounds) > 0)
    t0, t1 = bounds[:-1], bounds[1:]
    x0, x1 = _position(breaks, p, v, a, t0), _position(breaks, p, v, a, t1)
    span = np.abs(np.round(x1) - np.round(x0))
    master = np.argmax(span, axis=1)
    worst, _ = _strays(breaks, p, v, a, t0, t1, x0, x1, master)
    moving = (x1 - x0)[np.arange(len(t0)), master] != 0
    assert np.all(worst[moving] <= LIMIT)
    assert np.all(span.max(axis=1) <= MAX_MODULUS - 1)
    # sampled: no slave strays from the chord by more than the limit between the samples' own rounding
    t = np.linspace(t0, t1, 50).T  # (B, 50)
    x = _position(breaks, p, v, a, t.ravel()).reshape(len(t0), 50, -1)
    rows = np.arange(len(t0))
    ratio = np.divide(x1 - x0, (x1 - x0)[rows, master][:, None], out=np.zeros_like(x0),
                      where=(x1 - x0)[rows, master][:, None] != 0)
    off = x - x0[:, None] - ratio[:, None] * (x[rows, :, master] - x0[rows, master][:, None])[:, :, None]
    assert np.all(np.abs(off[moving]) <= LIMIT + 1e-6 * (1 + np.abs(x[moving]).max(initial=0.0)))


def test_a_straight_cruise_is_one_block_and_a_curve_is_cut():
    breaks = np.array([0.0, 1.0])
    p, v, a = np.array([[0.0, 0.0]]), np.array([[1000.0, 500.0]]), np.zeros((1, 2))
    assert list(chord_bounds(breaks, p, v, a, breaks, LIMIT)) == [0.0, 1.0]
    a = np.array([[0.0, 200.0]])  # the slave runs ahead by 25 steps at the end: a parabola against the master
    bounds = chord_bounds(breaks, p, v, a, breaks, LIMIT)
    assert 4 <= len(bounds) - 1 <= 16


@pytest.mark.parametrize("kinematics", ["cartesian", "corexy"])
def test_shaped_blocks_are_the_same_in_c_and_numpy(kinematics, monkeypatch):
    if any(library(name) is None for name in ("chordcuts", "shapedtimes", "smoothing")):
        pytest.skip("no C compiler")
    motors = ("x", "y") if kinematics == "cartesian" else ("a", "b")
    points = [(10, 10), (60, 10), (60, 60), (10, 60), (10, 30), (40, 31), (41, 35)]
    kin, segments, _, plan = planned(polyline(points, 150.0), machine(kinematics, motors), jd=0.05)
    shaping = ShapingSettings((make_shaper("mzv", 40.0), make_shaper("ei", 55.0), None))
    shaped = shape(planned_motion(segments, plan), shaping)
    planned_now = planned_motion(segments, plan)
    native = shaped_blocks(shaped, segments, kin, 0.01, segments.start[0], segments.end[-1])
    native_smoothing = smoothing(shaped, planned_now, shaping)
    for module in (codegen.motion.chord_cuts, codegen.motion.shaped_crossings, codegen.motion.shaped_motion):
        monkeypatch.setattr(module, "library", lambda name: None)
    numpy = shaped_blocks(shaped, segments, kin, 0.01, segments.start[0], segments.end[-1])
    numpy_smoothing = smoothing(shaped, planned_now, shaping)
    assert native_smoothing[0] == numpy_smoothing[0] > 0.01
    assert np.array_equal(native_smoothing[1], numpy_smoothing[1]) and native_smoothing[2] == numpy_smoothing[2]
    assert len(native.bounds) > 20
    assert np.array_equal(native.bounds, numpy.bounds)
    assert np.array_equal(native.steps, numpy.steps)
    assert np.array_equal(native.events.time, numpy.events.time)
    assert np.array_equal(native.events.phase, numpy.events.phase)

"""Pressure advance's formula and its fit (codegen/motion/advance.py): g, Klipper's smoothed advanced extruder,
evaluated exactly; the quadratic pieces the blocks are cut from within their tolerance of it everywhere."""

from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from codegen.motion.advance import (AdvanceSettings, Quadratics, advance_reference, advanced_extruder, advanced_source,
                                    smoothed, smoothed_numpy)
from codegen.native import library

STEPS_PER_MM = 415.0
FIT_STEPS = 0.05  # the pipeline's (codegen/pipeline/settings.py ADVANCE_FIT_STEPS)


def continuous(lengths, velocity, accel, start=0.0) -> Quadratics:
    """Pieces of the given lengths (s), velocities at their starts and accelerations, positions joined up."""
    lengths, velocity, accel = (np.asarray(a, dtype=float) for a in (lengths, velocity, accel))
    moved = velocity * lengths + 0.5 * accel * lengths**2
    position = start + np.concatenate([[0.0], np.cumsum(moved)[:-1]])
    return Quadratics(np.concatenate([[0.0], np.cumsum(lengths)]), position, velocity, accel)


def brute_force(f: Quadratics, t: np.ndarray, half: float, n: int = 400_001) -> np.ndarray:
    """g by the trapezoidal rule on a fine grid (f continuous: the rule's error is tiny)."""
    u = np.linspace(-half, half, n)
    weight = (half - np.abs(u)) / half**2
    return np.array([np.trapezoid(f.at(ti + u) * weight, u) for ti in t])


def test_smoothed_is_the_triangle_weighted_mean():
    rng = np.random.default_rng(7)
    f = continuous(rng.uniform(0.002, 0.05, 40), rng.uniform(-5, 5, 40), rng.uniform(-2000, 2000, 40), 300.0)
    t = rng.uniform(f.breaks[0] + 0.03, f.breaks[-1] - 0.03, 25)
    assert np.max(np.abs(smoothed(f, t, 0.02) - brute_force(f, t, 0.02))) < 1e-9


def test_smoothing_leaves_lines_and_parabolas_as_klipper_has_them():
    """A constant velocity passes unchanged; a constant acceleration a gains a h^2 / 12 (a / 2 times the triangle's
    variance h^2 / 6)."""
    line = continuous([10.0], [3.0], [0.0])
    parabola = continuous([10.0], [1.0], [500.0])
    t = np.array([1.0, 4.5, 9.0])
    assert np.allclose(smoothed(line, t, 0.02), line.at(t), atol=1e-12, rtol=0)
    assert np.allclose(smoothed(parabola, t, 0.02), parabola.at(t) + 500.0 * 0.02**2 / 12, atol=1e-9, rtol=0)


@pytest.mark.skipif(library("advance") is None, reason="the C helper could not be built (no gcc)")
@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), pieces=st.integers(1, 40), half=st.floats(0.001, 0.1))
def test_smoothed_in_c_is_the_numpy_version(seed, pieces, half):
    """Random piecewise quadratics, not continuous, with pieces far shorter and far longer than the triangle's half
    width (and some of zero length), at unsorted times, some before the first break and after the last."""
    rng = np.random.default_rng(seed)
    lengths = half * rng.choice([0.0, 0.01, 0.3, 1.0, 3.0, 40.0], pieces) * rng.uniform(0.5, 1.5, pieces)
    breaks = 50.0 + np.concatenate([[0.0], np.cumsum(lengths)])
    f = Quadratics(breaks, rng.uniform(-300.0, 300.0, pieces), rng.uniform(-50.0, 50.0, pieces),
                   rng.uniform(-5000.0, 5000.0, pieces))
    t = rng.uniform(breaks[0] - 3.0 * half, breaks[-1] + 3.0 * half, 300)
    t = np.concatenate([t, breaks, breaks + half, breaks - half])
    rng.shuffle(t)
    assert np.max(np.abs(smoothed(f, t, half) - smoothed_numpy(f, t, half))) <= 1e-9


def segments_of(moves: np.ndarray, k: np.ndarray) -> NS:
    """Segments as advanced_source and advance_reference read them: their moves (x, y, z, e), K and lines."""
    return NS(start=np.zeros_like(moves), end=moves, advance=k, line=np.arange(len(moves)))


def test_the_advance_leads_by_k_times_the_extruder_velocity_where_it_applies():
    """An extruding move with x (K applies), a retraction (e backwards: none), an extruding z-only move (none, as
    in Klipper: x or y must move)."""
    moves = np.array([[10.0, 0, 0, 1.0], [0, 0, 0, -1.0], [0, 0, 1.0, 0.5]])
    f = advanced_source(np.array([0.0, 1.0, 2.0, 3.0]), np.array([0.0, 2.0, 1.0]), np.array([2.0, -1.0, 0.5]),
                        np.zeros(3), np.arange(3), segments_of(moves, np.full(3, 0.05)), 0.02)
    assert np.allclose(f.at(np.array([0.5, 1.5, 2.5])), [1.0 + 0.05 * 2.0, 1.5, 1.25])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), k=st.floats(0.0, 0.2), smooth_time=st.floats(0.005, 0.2))
def test_the_quadratic_pieces_stay_within_their_tolerance_of_the_formula(seed, k, smooth_time):
    """Random extruder motion (speeds and accelerations of a print, velocity jumps at corners, retractions, rests),
    random K per segment: the fit against the exact formula at 16 points of every piece and at random times."""
    rng = np.random.default_rng(seed)
    n = 30
    lengths = rng.choice([0.0005, 0.004, 0.03, 0.3], n) * rng.uniform(0.5, 1.5, n)
    velocity = rng.uniform(-40.0, 40.0, n) * rng.choice([0.0, 0.1, 1.0], n)
    accel = rng.uniform(-5000.0, 5000.0, n) * rng.choice([0.0, 0.1, 1.0], n)
    velocity[-1] = accel[-1] = 0.0  # the program ends at rest
    plan = continuous(lengths, velocity, accel, 100.0)
    moves = np.column_stack([rng.choice([0.0, 1.0], n), np.zeros(n), np.zeros(n), rng.choice([-1.0, 1.0], n)])
    segments = segments_of(moves, k * rng.choice([0.0, 1.0, 2.0], n))
    advance = AdvanceSettings(smooth_time, FIT_STEPS / STEPS_PER_MM)
    fit = advanced_extruder(plan.breaks, plan.position, plan.velocity, plan.accel, np.arange(n), segments, advance,
                            smooth=True)  # K 0 everywhere too
    source = advanced_source(plan.breaks, plan.position, plan.velocity, plan.accel, np.arange(n), segments,
                             advance.half)
    share = np.linspace(0.0, 1.0, 16)
    t = np.concatenate([(fit.breaks[:-1, None] + np.diff(fit.breaks)[:, None] * share[None, :]).ravel(),
                        rng.uniform(fit.breaks[0], fit.breaks[-1], 500)])
    error_steps = np.abs(fit.at(t) - smoothed(source, t, advance.half)) * STEPS_PER_MM
    assert error_steps.max() <= FIT_STEPS * (1 + 1e-6) + 1e-7
    assert fit.breaks[0] == plan.breaks[0] - advance.half and fit.breaks[-1] == plan.breaks[-1] + advance.half
    assert abs(fit.end - plan.end) < 1e-9  # at rest a triangle's half width after the plan: where the plan ends


def test_k_0_everywhere_leaves_the_nominal_extruder():
    """As Klipper's smoothing time is 0 with K 0: the plan's own pieces, resting a half width either side (as far
    as g reaches), and a reference of half width 0 (g = e); told to smooth (a window after one with K), the same
    pieces are smoothed."""
    plan = continuous([0.1, 0.2, 0.1], [0.0, 5.0, 5.0], [50.0, 0.0, -50.0])
    moves = np.array([[10.0, 0, 0, 1.0]] * 3)
    segments = segments_of(moves, np.zeros(3))
    advance = AdvanceSettings(0.04, FIT_STEPS / STEPS_PER_MM)
    args = (plan.breaks, plan.position, plan.velocity, plan.accel, np.arange(3), segments)
    nominal = advanced_extruder(*args, advance)
    assert np.array_equal(nominal.breaks[1:-1], plan.breaks) and np.array_equal(nominal.accel[1:-1], plan.accel)
    assert nominal.breaks[[0, -1]] == pytest.approx([-0.02, 0.42]) and np.array_equal(nominal.at(t := np.linspace(
        -0.1, 0.5, 61)), plan.at(t))
    reference = advance_reference(*args, advance.half, 0.02)
    t = np.linspace(-0.1, 0.5, 61)
    assert reference.half == 0.0 and np.array_equal(smoothed(reference.source, t, reference.half), plan.at(t))
    smooth = advanced_extruder(*args, advance, smooth=True)
    assert smooth.breaks[0] == -0.02 and abs(smooth.at(0.1) - plan.at(0.1)) > 1e-4

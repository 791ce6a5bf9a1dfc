"""Angles of many turns (the long fuzz run: a sine of phase 9223372036854775808 deg strayed 0.07 mm from its path,
its plan's own check failed): a shape's start angle, rotation or phase is brought within a turn exactly, so the
shape is the one of the same angle less whole turns, and its chords still follow it."""

from __future__ import annotations

import numpy as np
import pytest

from codegen.job import load_job
from codegen.pipeline.host import host_build
from tests.shapes.test_shapes import build, ellipse, shape, sine

TURNS = 360.0 * 2**50  # a float that is a whole number of turns (floats there are 64 apart: TURNS + 64 is exact)


def points(items) -> np.ndarray:
    return np.concatenate([getattr(i, "points", np.array([i.start, i.end]))[:, :2] for i in items])


@pytest.mark.parametrize("make, field", [(sine, "phase"), (ellipse, "rotation"), (ellipse, "start")])
def test_whole_turns_leave_a_curve_as_it_is(make, field):
    turned, plain = points(build(make(**{field: TURNS + 64.0}))), points(build(make(**{field: 64.0})))
    assert turned.shape == plain.shape and np.abs(turned - plain).max() < 1e-9


def test_an_arc_many_turns_round_ends_where_its_sweep_says():
    arc = shape("arc", center=(0, 0), radius=10, start=TURNS, sweep=90, direction=None)
    (item,) = [i for i in build(arc) if hasattr(i, "sweep")]
    assert np.allclose(item.start[:2], (10, 0), atol=1e-9) and np.allclose(item.end[:2], (0, 10), atol=1e-9)


def test_the_fuzz_runs_sine_plans_within_its_path_limit(tmp_path):
    path = tmp_path / "sine.yaml"
    path.write_text("machine:\n  kinematics: cartesian\n  steppers:\n"
                    "    x: {steps_per_mm: 80, max_velocity: 150, max_accel: 2000}\n"
                    "    y: {steps_per_mm: 80, max_velocity: 150, max_accel: 2000}\n"
                    "program:\n  shapes:\n  - sine: {origin: [20, 40], amplitude: 10, omega: 0.5, "
                    "phase: 9223372036854775808, length: 60}\n")
    host = host_build(load_job(path), keep=False)
    assert host.findings.ok and host.findings.max_path_error_mm <= host.findings.path_limit_mm

"""Input shaping through the whole host pipeline (codegen/pipeline/shaping.py): a shaped job against the same job
unshaped. Shaping moves no step and loses none, the shaped twin plays the unshaped twin's motion convolved with
the shapers (an independent numpy convolution), every limit holds on the shaped pulses, and smoothing is
reported, and limited, as Klipper's theory has it."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codegen.motion.pieces as pieces
from codegen.job import load_job
from codegen.motion.shaped_blocks import CHORD_LIMIT
from codegen.motion.shaped_motion import planned_motion
from codegen.motion.shapers import make_shaper, shape_positions
from codegen.pipeline.host import host_build
from codegen.report.summaries import human_plan, plan_summary

SQUARE = [[10, 10], [60, 10], [60, 60], [10, 60], [10, 30]]  # x and y reverse a whole edge after they stop
ZIGZAG = [[10, 10], [40, 20], [70, 10], [100, 25]]  # corexy's a = x + y and b = x - y never reverse
MOTORS = {"cartesian": ("x", "y"), "corexy": ("a", "b")}
SAMPLE_HZ = 20_000.0
BRESENHAM_STEPS = 1.55  # a slave's largest distance from its block's line at an event, with the sampling's error


def job_text(kinematics="cartesian", points=SQUARE, feed=9000, shaper="{x: {type: mzv, freq: 50}, y: {type: mzv, "
             "freq: 50}}", accel=3000, extra="", velocity=250):
    steppers = "\n".join(f"    {m}: {{steps_per_mm: 80, max_velocity: {velocity}, max_accel: {accel}}}"
                         for m in MOTORS[kinematics])
    shaping = "" if shaper is None else f"  input_shaper: {shaper}\n"
    return (f"machine:\n  kinematics: {kinematics}\n  steppers:\n{steppers}\n{shaping}{extra}"
            f"program:\n  start: {list(points[0])}\n  feed: {feed}\n  shapes:\n    - polyline: {{points: {points}}}\n")


def built(tmp_path: Path, text: str, name: str = "job"):
    path = tmp_path / f"{name}.yaml"
    path.write_text(textwrap.dedent(text))
    return host_build(load_job(path))


def twin_at(host, t: np.ndarray) -> np.ndarray:
    """(N, M) each motor's step count (from the program's start) at times t: the twin's positions after each
    event at the event's ideal time (the compressor's timing is checked on its own), linear between them."""
    time, position = host.events.time, host.pulses.event_position
    columns = []
    for m in range(position.shape[1]):
        moved = np.flatnonzero(np.diff(position[:, m], prepend=0) != 0)
        columns.append(np.interp(t, np.concatenate([[0.0], time[moved]]), np.concatenate([[0], position[moved, m]])))
    return np.stack(columns, axis=1)


def convolved(plain, shapers, planned=None) -> tuple[np.ndarray, np.ndarray]:
    """The unshaped twin's motor positions (or `planned`'s tool positions: segments and their plan) in axes, each
    axis convolved with its shaper in numpy, back in motor steps from the start: sample times (unshaped clock) and
    positions."""
    kin = plain.kin
    spm = kin.limits.steps_per_mm
    duration = plain.totals.duration_s if planned is None else planned[1].total
    t = np.arange(-int(0.05 * SAMPLE_HZ), int((duration + 0.05) * SAMPLE_HZ)) / SAMPLE_HZ
    if planned is not None:
        axes = planned_motion(*planned).at(t)
    else:
        axes = kin.to_axes((twin_at(plain, t) + plain.start_steps) / spm, np.zeros((len(t), 4)))
    for axis, shaper in enumerate(shapers):
        if shaper is not None:
            axes[:, axis] = shape_positions(axes[:, axis], SAMPLE_HZ, shaper)
    return t, kin.to_motor(axes) * spm - plain.start_steps


def assert_shaped_plays_the_convolution(shaped, plain):
    """At every shaped event, every motor as close to its plan's motion (before shaping) convolved in numpy as a
    Bresenham slave keeps to its line (up to a step early, and half a step off where its block's rounded ends tilt
    the line: BRESENHAM_STEPS), plus the bow of its block's chord (CHORD_LIMIT); and, unless the shaped plan was
    slowed to keep a limit, within one step more of the unshaped job's twin convolved (that twin keeps to its own
    motion as closely)."""
    shaping = shaped.settings.stages.shaping
    if not len(shaped.events.time):
        return
    at = shaped.events.time - shaping.shift
    slowed = shaped.totals.duration_s > plain.totals.duration_s + shaping.spread + 1e-9
    for planned, within in ((shaped.planned, BRESENHAM_STEPS + CHORD_LIMIT),
                            (None, 1.0 + BRESENHAM_STEPS + CHORD_LIMIT)):
        if planned is None and slowed:
            continue
        t, reference = convolved(plain, shaping.shapers, planned)
        expected = np.stack([np.interp(at, t, reference[:, m]) for m in range(reference.shape[1])], axis=1)
        assert np.abs(shaped.pulses.event_position - expected).max() <= within


@pytest.mark.parametrize("kinematics, points, shaper", [
    ("cartesian", SQUARE, "{x: {type: mzv, freq: 50}, y: {type: mzv, freq: 50}}"),
    ("corexy", ZIGZAG, "{x: {type: zv, freq: 30}, y: {type: ei, freq: 55, damping: 0.05}}"),
])
def test_shaped_steps_are_the_unshaped_jobs_convolved(tmp_path, kinematics, points, shaper):
    """Where no motor turns back within a shaper's span (a turn closer is cut short: Klipper's smoothing)."""
    shaped = built(tmp_path, job_text(kinematics, points, shaper=shaper), "shaped")
    plain = built(tmp_path, job_text(kinematics, points, shaper=None), "plain")
    assert shaped.findings.ok and plain.findings.ok, shaped.findings.problems
    # Not a step lost or added: each motor's count and its end are the unshaped job's.
    assert shaped.findings.steps == plain.findings.steps
    assert shaped.findings.final == plain.findings.final == shaped.findings.expected_final
    assert_shaped_plays_the_convolution(shaped, plain)
    # Every limit holds on the shaped pulses, and the shaped job lasts the shapers' spread longer.
    f = shaped.findings
    assert max(f.rate_ratio.values()) <= 1.0 and max(f.accel_ratio.values()) <= 1.0
    assert f.max_path_error_mm <= f.path_limit_mm
    spread = shaped.settings.stages.shaping.spread
    assert shaped.totals.duration_s == pytest.approx(plain.totals.duration_s + spread, abs=1e-6)


def test_smoothing_is_reported_at_its_place_as_klippers_theory_has_it(tmp_path):
    """Out and back along x at constant acceleration: the shaped tool falls short of the turn by Klipper's
    180-degree smoothing, there; max_smoothing below it fails the plan and says where."""
    points = [[0, 10], [80, 10], [0, 10]]
    host = built(tmp_path, job_text(points=points, shaper="{x: {type: ei, freq: 40}, y: {type: ei, freq: 40}}"))
    shaper = make_shaper("ei", 40.0)
    accel = 3000.0 * 0.98  # the planner keeps 2 % below the motors' limit
    theory = float(shaper.amplitudes @ (accel / 2 * (shaper.times - shaper.mean_time) ** 2))
    assert host.findings.smoothing_mm == pytest.approx(theory, rel=1e-3)
    assert host.findings.smoothing_at[1] == pytest.approx(10.0)
    summary = plan_summary(host)
    assert summary["input_shaper"]["smoothing_mm"] == pytest.approx(theory, rel=1e-3)
    assert f"smoothing {theory:.4f} mm" in human_plan(summary)
    limited = built(tmp_path, job_text(points=points, shaper="{x: {type: ei, freq: 40}, max_smoothing: 0.01}"))
    assert not limited.findings.ok
    assert limited.findings.problems == [
        f"the input shaper smooths the path by {limited.findings.smoothing_mm:.4f} mm, more than "
        f"machine.input_shaper.max_smoothing (0.01 mm), at ({limited.findings.smoothing_at[0]:.3f}, 10.000, 0.000): "
        f"a higher shaper frequency, a shaper with less smoothing (zv, mzv), or a lower acceleration there"]


def test_unshaped_jobs_plan_as_before(tmp_path):
    """No input_shaper, or one that shapes no axis: the same tables, no smoothing figure."""
    plain = built(tmp_path, job_text(shaper=None), "plain")
    empty = built(tmp_path, job_text(shaper="{max_smoothing: 1}"), "empty")
    assert plain.findings.smoothing_mm is None and "input_shaper" not in plan_summary(plain)
    assert np.array_equal(plain.pulses.tick, empty.pulses.tick) and plain.totals.blocks == empty.totals.blocks


SHAPER_NAMES = ("zv", "mzv", "zvd", "ei", "2hump_ei", "3hump_ei")


def corners_only(points) -> bool:
    """Every vertex a corner (a turn of over 0.6 rad): where the planner takes a vertex as part of a curve, the
    unshaped twin times its steps on the curve (codegen/motion/curve_timing.py), off the plan's chords by a few
    steps, while shaping convolves the plan's own motion."""
    legs = np.diff(np.asarray(points, dtype=float), axis=0)
    legs = legs[np.linalg.norm(legs, axis=1) > 0]
    unit = legs / np.linalg.norm(legs, axis=1)[:, None]
    return bool(np.all(np.sum(unit[1:] * unit[:-1], axis=1) < np.cos(0.6)))


@st.composite
def shaped_jobs(draw):
    kinematics = draw(st.sampled_from(("cartesian", "corexy")))
    count = draw(st.integers(2, 5))
    points = draw(st.lists(st.lists(st.integers(5, 45), min_size=2, max_size=2), min_size=count, max_size=count)
                  .filter(corners_only))
    axes = []
    for axis in ("x", "y"):
        if draw(st.booleans()) or axis == "x":
            name = draw(st.sampled_from(SHAPER_NAMES))
            freq = draw(st.sampled_from((20, 33.3, 50, 71.5, 120)))
            axes.append(f"{axis}: {{type: {name}, freq: {freq}, damping: {draw(st.sampled_from((0.0, 0.1, 0.2)))}}}")
    return kinematics, points, draw(st.sampled_from((1200, 6000, 15000))), "{" + ", ".join(axes) + "}"


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(shaped_jobs())
def test_random_shaped_jobs_keep_every_check_and_play_the_convolution(tmp_path, job):
    kinematics, points, feed, shaper = job
    shaped = built(tmp_path, job_text(kinematics, points, feed, shaper), "shaped")
    plain = built(tmp_path, job_text(kinematics, points, feed, None), "plain")
    assert shaped.findings.ok, shaped.findings.problems
    assert shaped.findings.final == plain.findings.final
    # A reversal closer than a shaper's span is cut short (Klipper's smoothing): never a step more than unshaped,
    # unless a corexy belt sums x and y shaped apart (it then moves where x and y cancelled).
    x, y, _ = shaped.settings.stages.shaping.shapers
    alike = x is not None and y is not None and x.name == y.name and np.array_equal(x.times, y.times)
    if kinematics == "cartesian" or alike:
        assert all(shaped.findings.steps[m] <= plain.findings.steps[m] for m in plain.findings.steps)
    assert_shaped_plays_the_convolution(shaped, plain)


def test_where_shaping_would_break_a_limit_the_plan_slows_down(tmp_path):
    """A corexy corner taken at full speed (a large junction deviation) with x shaped slowly and y not: x's speed
    fades over 0.1 s while y's rises at once, so belt a (x + y) would run at 150 % of its speed through the corner
    (225 mm/s where it may go 200). The plan's segments under that stretch are slowed until every motor keeps its
    limits on the shaped pulses."""
    points, shaper = [[0, 0], [60, 0], [60, 60]], "{x: {type: zv, freq: 5}}"
    extra = "  junction_deviation: 5\n"
    shaped = built(tmp_path, job_text("corexy", points, 9000, shaper, extra=extra, velocity=200), "shaped")
    plain = built(tmp_path, job_text("corexy", points, 9000, None, extra=extra, velocity=200), "plain")
    f = shaped.findings
    assert f.ok and max(f.rate_ratio.values()) <= 1.0 and max(f.accel_ratio.values()) <= 1.0
    assert max(f.rate_ratio.values()) > max(plain.findings.rate_ratio.values())  # shaping made belt a faster
    spread = shaped.settings.stages.shaping.spread
    assert shaped.totals.duration_s > plain.totals.duration_s + spread + 0.05  # and the plan slower for it


def test_a_shaped_program_plays_in_windows_as_in_one(tmp_path, monkeypatch):
    """Each window plays the shaped motion from the window before's end to its own, reading back into that
    window's plan (codegen/pipeline/shaping.py ShapingTail): cut into many windows, a shaped zigzag makes the steps
    of the same job in few, ends where it should, and every event keeps to the plan's motion convolved."""
    points = [[10 + 3 * k, 10 + 40 * (k % 2)] for k in range(12)]
    shaper = "{x: {type: mzv, freq: 50}, y: {type: 2hump_ei, freq: 45}}"
    few = built(tmp_path, job_text("cartesian", points, 9000, shaper), "few")
    monkeypatch.setattr(pieces, "CHUNK_EVENTS", 1500)
    many = built(tmp_path, job_text("cartesian", points, 9000, shaper), "many")
    plain = built(tmp_path, job_text("cartesian", points, 9000, None), "plain")
    assert many.totals.windows >= 4 * few.totals.windows
    assert many.findings.ok, many.findings.problems
    assert many.findings.steps == few.findings.steps and many.findings.final == few.findings.final
    assert many.totals.duration_s == pytest.approx(few.totals.duration_s, abs=1e-9)
    assert many.findings.smoothing_mm == pytest.approx(few.findings.smoothing_mm, rel=1e-6)
    assert_shaped_plays_the_convolution(many, plain)

"""The C helpers (codegen/native/) give what their Python and numpy versions give: the same timing windows and
rate runs to the bit, the same pulses to the bit, the same path distances to rounding; and a build without them
makes the same tables.
"""

import dataclasses

import numpy as np
import pytest

import codegen.motion.stepgen as stepgen
import codegen.pipeline.windows as windows
import codegen.tables.checks as checks
import codegen.tables.compress as compress_module
import codegen.tables.runfit as runfit
import codegen.tables.twin as twin
from codegen.job import load_job
from codegen.motion.stepgen import generate, segment_steps
from codegen.native import library
from codegen.pipeline.host import host_build
from codegen.tables.compress import TimingWindow, compress, numpy_windows, rate_gaps
from codegen.tables.format import stream_bytes
from codegen.tables.schedule import MAX_ADD, MAX_COUNT, MAX_INTERVAL
from tests.helpers import ROOT, gcode_job_file, planned, polyline

EXAMPLES = ["examples/star.yaml", "examples/plotter-set-51.yaml", "examples/delta-seed.yaml",
            "examples/gcode/mixed.yaml", "examples/sine.yaml", "examples/function.yaml"]
CURVED = {"examples/plotter-set-51.yaml", "examples/sine.yaml", "examples/function.yaml", "examples/gcode/mixed.yaml"}

pytestmark = pytest.mark.skipif(any(library(n) is None for n in ("runfit", "twin", "pathcheck", "eventtimes")),
                                reason="the C helpers could not be built (no gcc)")


def windows_of(ticks: np.ndarray, share: float, cap: float, needed: int):
    """Position windows as compress makes them, for ideal ticks."""
    gaps = np.diff(ticks, prepend=0.0)
    win = np.clip(share * gaps, 2.0, cap)
    lo = 256 * np.ceil(ticks - win).astype(np.int64)
    hi = 256 * np.floor(ticks + win).astype(np.int64) + 255
    return lo, hi, np.full(len(ticks), needed, dtype=np.int64)


def both_fits(lo, hi, needed, p0=0, base=0, max_interval=MAX_INTERVAL):
    args = (lo, hi, needed, p0, base, MAX_COUNT, MAX_ADD, max_interval)
    native = runfit.fit_runs(*args)
    room = runfit.leave_room(hi, needed)
    python = runfit.fit_runs_python(lo, room, needed, runfit.add_guess(lo, room), *args[3:])
    return native, python


@pytest.mark.parametrize("seed", range(6))
def test_run_fitting_in_c_is_the_python_algorithm(seed):
    rng = np.random.default_rng(seed)
    # Accelerating, cruising, decelerating stretches with noise and a few abrupt changes of rate.
    gaps = np.concatenate([np.linspace(400, 60, 300), np.full(200, 60.0), np.linspace(60, 900, 250),
                           rng.uniform(30, 2000, 40)]) * rng.uniform(0.5, 2.0)
    ticks = np.cumsum(np.maximum(gaps + rng.normal(0, 0.3, len(gaps)), 24.0))  # pushed apart, as compress does
    lo, hi, needed = windows_of(ticks, 0.05, 200.0, 20)
    p0, base = int(rng.integers(0, 256)), int(rng.integers(0, 10_000))
    native, python = both_fits(lo, hi, needed, p0=p0, base=base)
    for a, b in zip(native, python):
        assert np.array_equal(a, b)
    count, interval, add, tick = native
    tick = tick - base
    assert count.sum() == len(ticks) and np.all(count >= 1)
    assert len(count) < len(ticks) / 8  # runs, not single events
    # Every event at its window and after its gap; the runs replay to the same ticks.
    assert np.all(256 * tick >= lo) and np.all(256 * tick <= hi)
    assert np.all(np.diff(tick, prepend=0) >= needed)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count) + 1
    run = np.repeat(np.arange(len(count)), count)
    span = interval * count + add * (count * (count - 1) // 2)
    origin = p0 + np.concatenate([[0], np.cumsum(span)[:-1]])
    assert np.array_equal((origin[run] + k * interval[run] + add[run] * (k * (k - 1) // 2)) >> 8, tick)


@pytest.mark.parametrize("max_interval", [3000 * 256, 600 * 256, 200 * 256])
def test_run_fitting_in_c_where_the_interval_limit_binds(max_interval):
    """Gaps near and over the longest interval: the C search clamps every event's own interval there too."""
    rng = np.random.default_rng(max_interval)
    gaps = np.concatenate([np.linspace(100, 700, 400), np.linspace(700, 150, 400), rng.uniform(50, 900, 60)])
    ticks = np.cumsum(gaps + rng.normal(0, 0.3, len(gaps)))
    lo, hi, needed = windows_of(ticks, 0.05, 200.0, 20)
    native, python = both_fits(lo, hi, needed, max_interval=max_interval)
    for a, b in zip(native, python):
        assert np.array_equal(a, b)
    assert np.all(native[1] <= max_interval)


def test_an_event_that_cannot_keep_its_window_comes_as_early_as_the_gap_allows():
    ticks = np.array([100.0, 101.0, 102.0, 500.0])
    lo, hi, needed = windows_of(ticks, 0.05, 200.0, 20)
    native, python = both_fits(lo, hi, needed)
    for a, b in zip(native, python):
        assert np.array_equal(a, b)
    first, second, third, last = native[3].tolist()
    assert 95 <= first <= 105 and (second, third) == (first + 20, first + 40) and 475 <= last <= 525


def test_compressed_runs_keep_the_windows_and_the_player_gaps():
    kin, segments, steps, p = planned(polyline([(0, 0), (30, 5), (31, 40), (0, 0)], feed=150))
    events = generate(segments, p, kin, steps, max_gap=1.0)
    c = compress(events, kin.motors, 2_000_000, 25, 50, origin_fx=12345)
    assert np.all(np.abs(c.emitted_ticks - c.ideal_ticks) <= c.window_ticks + 1e-9)
    assert np.all(np.diff(c.emitted_ticks, prepend=12345 >> 8) >= 25)
    assert np.array_equal(twin.predict(c.schedule, 12345).event_tick, c.emitted_ticks)


def recorded_windows(monkeypatch, job) -> list:
    """Every window's compress call of a plan, with what the C helpers made of it."""
    calls = []

    def record(events, *args, **kw):
        made = compress(events, *args, **kw)
        calls.append((events, args, kw, dataclasses.replace(made)))  # the window's records go into made's schedule
        return made

    with monkeypatch.context() as patch:
        patch.setattr(windows, "compress", record)
        host_build(job, keep=False)
    return calls


def gcode_job(tmp_path, name: str, target: str):
    return load_job(gcode_job_file(tmp_path, name, target, extruder=False))


@pytest.mark.parametrize("source", EXAMPLES + ["grbl-cam.gcode avr", "parser/circle-inch.gcode mcs51",
                                               "plotter/shapes.gcode avr", "plotter/shapes.gcode mcs51"])
def test_timing_windows_and_runs_in_c_are_the_numpy_and_python_ones(monkeypatch, tmp_path, source):
    """Real windows: the C windows are numpy's, and the schedule, ideal, window and emitted ticks are those of
    numpy's windows and the Python search, to the bit."""
    name, _, target = source.partition(" ")
    job = load_job(ROOT / name) if not target else gcode_job(tmp_path, name, target)
    calls = recorded_windows(monkeypatch, job)
    assert calls
    lib = library("runfit")
    for events, args, kw, native in calls:
        tick_hz, run_gap, block_gap = args[1:4]
        rate_gap = rate_gaps(events, kw["max_rate"]) * tick_hz
        made = (events, tick_hz, run_gap, block_gap, TimingWindow(), rate_gap, kw["origin_fx"])
        for a, b in zip(compress_module._native_windows(lib, *made), numpy_windows(*made)):
            assert a.dtype == b.dtype and np.array_equal(a, b)
        with monkeypatch.context() as patch:
            for module in (compress_module, runfit):
                patch.setattr(module, "library", lambda name: None)
            python = compress(events, *args, **kw)
        for field in ("ideal_ticks", "window_ticks", "emitted_ticks"):
            assert np.array_equal(getattr(native, field), getattr(python, field)), field
        for field in ("run_count", "run_interval", "run_add", "block_dirs", "block_steps", "block_modulus",
                      "block_init", "block_tool", "block_events", "block_segment"):
            assert np.array_equal(getattr(native.schedule, field), getattr(python.schedule, field)), field


@pytest.mark.parametrize("example", EXAMPLES)
@pytest.mark.parametrize("curves", [False, True])
def test_event_times_in_c_are_the_numpy_ones(planned_example, monkeypatch, example, curves):
    host = planned_example(example.removeprefix("examples/"))
    args = (host.segments, host.plan, host.kin, segment_steps(host.segments, host.kin))
    native = stepgen.generate(*args, max_gap=0.5, curves=curves)
    monkeypatch.setattr(stepgen, "library", lambda name: None)
    numpy_ = stepgen.generate(*args, max_gap=0.5, curves=curves)
    assert np.array_equal(native.time, numpy_.time) and np.array_equal(native.phase, numpy_.phase)
    if curves and example in CURVED:
        assert not np.array_equal(native.time, stepgen.generate(*args, max_gap=0.5).time)


@pytest.mark.parametrize("example", EXAMPLES)
def test_the_twin_in_c_is_the_numpy_twin(planned_example, example):
    host = planned_example(example.removeprefix("examples/"))
    schedule, start = host.compressed.schedule, np.arange(len(host.kin.motors)) * 7
    native, numpy_ = twin.predict(schedule, 1000, start), twin.predict_numpy(schedule, 1000, start)
    for name in ("tick", "motor", "dir", "event", "event_tick", "event_block", "event_position"):
        assert np.array_equal(getattr(native, name), getattr(numpy_, name)), name
    for m in range(len(host.kin.motors)):
        assert all(np.array_equal(a, b) for a, b in zip(native.of_motor(m), numpy_.of_motor(m)))


@pytest.mark.parametrize("example", EXAMPLES)
def test_path_distances_in_c_are_the_numpy_ones(planned_example, example):
    host = planned_example(example.removeprefix("examples/"))
    kin, seg, steps = host.kin, host.event_segments(), host.pulses.event_position
    axes = kin.to_axes((steps + host.start_steps) / kin.limits.steps_per_mm, host.segments.start[seg])
    expect = checks.path_errors_numpy(axes, seg, host.segments, 0.004)
    np.testing.assert_allclose(checks.path_errors(axes, seg, host.segments, 0.004), expect, rtol=0, atol=1e-9)
    np.testing.assert_allclose(checks.step_path_errors(steps, host.start_steps, kin, seg, host.segments, 0.004),
                               expect, rtol=0, atol=1e-9)


@pytest.mark.parametrize("example", ["examples/delta-seed-51.yaml", "examples/star.yaml"])
def test_without_the_helpers_the_tables_are_the_same(planned_example, monkeypatch, example):
    native = planned_example(example.removeprefix("examples/"))  # planned with the helpers, before they go
    job = load_job(ROOT / example)
    for module in (compress_module, runfit, twin, checks, stepgen):
        monkeypatch.setattr(module, "library", lambda name: None)
    python = host_build(job)
    assert stream_bytes(python.compressed.schedule) == stream_bytes(native.compressed.schedule)
    for name in ("run_count", "run_interval", "run_add", "block_steps", "block_init"):
        assert np.array_equal(getattr(python.compressed.schedule, name), getattr(native.compressed.schedule, name))
    assert python.findings.max_path_error_mm == pytest.approx(native.findings.max_path_error_mm, abs=1e-9)
    assert python.findings.problems == native.findings.problems

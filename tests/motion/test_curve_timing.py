"""Curve timing and runs across blocks (the compact tables): event times follow the curve, not its chords, so
rate runs span many chords; every event stays in its window."""

import math

import numpy as np
import pytest

from codegen.job import load_job
from codegen.motion.curve_timing import smooth_curve_times
from codegen.motion.stepgen import generate
from codegen.pipeline.host import host_build
from codegen.tables.compress import compress
from codegen.tables.twin import predict
from codegen.toolpath.items import Arc, Toolpath
from tests.helpers import SRC, planned, point, polyline

TICK = 1_000_000
RUN_GAP, BLOCK_GAP = 130, 300


def circle(r=20.0, feed=25.0):
    return Toolpath(point(r, 0), [Arc(point(r, 0), point(r, 0), (0.0, 0.0), r, 0.0, 2 * math.pi, feed, True, SRC)])


def timed(toolpath):
    kin, segments, steps, p = planned(toolpath, max_event_rate=TICK / (1.25 * RUN_GAP))
    events = generate(segments, p, kin, steps, max_gap=10.0)
    return kin, segments, p, events, smooth_curve_times(events, segments, p, kin)


def in_cruise(events):
    first = events.block_first
    inner = np.zeros(len(events.time), dtype=bool)
    inner[first[2]:first[-3]] = True  # leave out the blocks that start and stop
    return inner & (events.phase == 1)


def test_times_pass_every_vertex_and_bend_smoothly():
    kin, segments, p, chords, smooth = timed(circle())
    assert np.all(np.diff(smooth.time) > 0)
    # Per master step, within the same master: the chords' intervals jump at every vertex, the curve's do not.
    master = np.argmax(np.abs(chords.block_steps), axis=1)
    block = np.repeat(np.arange(len(master)), np.diff(chords.block_first))
    same = (master[block][2:] == master[block][:-2]) & in_cruise(chords)[2:]
    bend_chords = np.abs(np.diff(chords.time, 2))[same]
    bend_smooth = np.abs(np.diff(smooth.time, 2))[same]
    assert bend_chords.max() > 10 * bend_smooth.max()
    # Every event within 0.1 ms of the chord timing (2.5 um of travel at this speed).
    assert np.abs(smooth.time - chords.time).max() < 1e-4
    # Times come from the plan's own trapezoids: the circle starts and ends at rest at the same moments.
    assert abs(smooth.time[0] - chords.time[0]) < 1e-6 and abs(smooth.time[-1] - chords.time[-1]) < 1e-6


def test_lines_and_corners_keep_chord_times():
    square = polyline([(0, 0), (10, 0), (10, 10), (0, 10), (0, 0)], feed=40)
    *_, chords, smooth = timed(square)
    assert np.array_equal(chords.time, smooth.time)


def test_runs_cross_blocks_and_stay_in_their_windows():
    kin, segments, p, chords, smooth = timed(circle())
    on_chords = compress(chords, kin.motors, TICK, RUN_GAP, BLOCK_GAP)
    across = compress(smooth, kin.motors, TICK, RUN_GAP, BLOCK_GAP)
    sched = across.schedule
    assert np.array_equal(sched.events_per_block(), np.diff(smooth.block_first))
    assert np.all(np.abs(across.emitted_ticks - across.ideal_ticks) <= across.window_ticks)
    gaps = np.diff(np.concatenate([[0], across.emitted_ticks]))
    assert np.all(gaps >= RUN_GAP)
    assert sched.n_runs * 3 < sched.n_blocks and sched.n_runs < 0.6 * on_chords.schedule.n_runs  # 63 against 124
    # The twin plays the blocks off the one sequence of runs: the same steps as the chords say.
    pulses = predict(sched)
    assert np.array_equal(pulses.final_positions(), chords.block_steps.sum(axis=0))
    assert np.array_equal(pulses.event_tick, across.emitted_ticks)


ISSUE_MACHINE = """
name: {name}
target: mcs51
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: 40, max_velocity: 40, max_accel: 400, range: [0, 100]}}
    y: {{steps_per_mm: 50, max_velocity: 30, max_accel: 300, range: [0, 100]}}
  junction_deviation: 0.02
  tolerance: 0.01
program:
  start: [0, 0]
  feed: 1500
  shapes:
    - sine: {{origin: [10, 20], amplitude: 6, omega: 0.25, phase: 0, length: 50}}
{more}"""
MORE = """    - line: {to: [70, 70]}
    - arc: {center: [50, 50], radius: 15, start: 0, sweep: 270}
    - ellipse: {center: [40, 40], a: 20, b: 10, rotation: 30}
"""


@pytest.mark.parametrize("more", ["", MORE], ids=["sine", "sine-line-arc-ellipse"])
def test_curve_timing_keeps_every_limit(more, tmp_path):
    """Found by a job written elsewhere: the compact tables broke y's rate (+25 %) and acceleration (+28 %)
    where the chord-timed AVR tables did not."""
    job = tmp_path / "job.yaml"
    job.write_text(ISSUE_MACHINE.format(name="sine", more=more))
    host = host_build(load_job(job))
    assert host.findings.ok, host.findings.problems
    assert max(host.findings.rate_ratio.values()) <= 1.0 and max(host.findings.accel_ratio.values()) <= 1.0
    # Curve timing still does its work: fewer runs than blocks on these curves.
    assert host.schedule.n_runs < 1.5 * host.schedule.n_blocks
    gap = np.abs(host.compressed.emitted_ticks - host.compressed.ideal_ticks)
    assert np.all(gap <= host.compressed.window_ticks)

"""One long move is planned in windows of bounded steps (issue 28): the lookahead ends a window without a corner at
a straight junction between the move's collinear pieces once it holds WINDOW_EVENTS master steps, and the pieces
do not slow there: the plan, the steps and their ideal times are the unsplit window's."""

import numpy as np
import pytest

import codegen.motion.lookahead as lookahead
from codegen.job import load_job
from codegen.motion.blocks import MAX_MODULUS
from codegen.motion.planner import plan, profile
from codegen.pipeline.host import host_build
from codegen.pipeline.windows import Stages
from tests.helpers import DATA
from tests.motion.test_lookahead import planner_input, windowed

JOB = """name: long
target: avr
board: ramps-1.4
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: {spm}, max_velocity: 200, max_accel: 2500}}
    y: {{steps_per_mm: {spm}, max_velocity: 200, max_accel: 2500}}
program:
  gcode: |
    {gcode}
"""
BOUND = 20_000  # master steps: WINDOW_EVENTS for the tests (the pieces of a long move hold MAX_MODULUS - 1 each)


def job_file(tmp_path, gcode, spm=80):
    path = tmp_path / "long.yaml"
    path.write_text(JOB.format(spm=spm, gcode=gcode))
    return path


def master_steps(window):
    return int(np.abs(window.steps).max(axis=1, initial=0).sum())


@pytest.mark.parametrize("gcode, spm", [("G1 X2000 Y700 F6000", 80), ("G1 X3 F6000", 100_000)])
def test_a_long_straight_move_is_planned_in_bounded_windows(tmp_path, monkeypatch, gcode, spm):
    segments, kin, steps, limits = planner_input(job_file(tmp_path, gcode, spm))
    monkeypatch.setattr(lookahead, "WINDOW_EVENTS", BOUND)
    windows = windowed(segments, kin, steps, limits, 1)
    total = int(np.abs(steps).max(axis=1).sum())
    assert len(windows) >= total // (BOUND + MAX_MODULUS)
    assert not any(w.curve_cut for w in windows)
    # Past the bound by at most the segment pushed last and the one after the cut (the last window: both held).
    assert max(master_steps(w) for w in windows) <= BOUND + 2 * (MAX_MODULUS - 1)
    assert np.all(np.abs(steps).max(axis=1) <= MAX_MODULUS - 1)
    whole = plan(segments, kin, steps, limits)
    for field in ("v_entry", "v_peak", "v_exit", "duration", "t_start"):
        joined = np.concatenate([getattr(w.plan, field) for w in windows])
        np.testing.assert_allclose(joined, getattr(whole, field), rtol=1e-12, atol=1e-9, err_msg=field)
    # A straight junction is no corner: it limits no speed beyond its two pieces' own.
    prof = profile(segments, kin, steps, limits)
    assert np.array_equal(prof.w_max[1:-1], np.minimum(prof.w_nominal[:-1], prof.w_nominal[1:]))
    assert all(not w.plan.corner[0] and w.plan.v_entry[0] > 0 for w in windows[1:])


def test_long_chords_of_an_arc_are_cut_inside_a_chord(tmp_path, monkeypatch):
    segments, kin, steps, limits = planner_input(job_file(tmp_path, "G2 X20 Y0 I10 J0 F3000", 100_000))
    monkeypatch.setattr(lookahead, "WINDOW_EVENTS", 4 * BOUND)
    windows = windowed(segments, kin, steps, limits, 1)
    # Chords near 45 degrees hold fewer than MAX_MODULUS steps (one piece each): past twice the bound, a curve cut.
    assert [i for i, w in enumerate(windows) if w.curve_cut] == [14, 48]
    for before, after in zip(windows, windows[1:]):
        if not before.curve_cut:  # the cut joins two pieces of one chord
            assert np.array_equal(before.segments.item[-1:], after.segments.item[:1])
            np.testing.assert_allclose(before.plan.direction[-1], after.plan.direction[0], rtol=0, atol=1e-12)
    assert max(master_steps(w) for w in windows) <= 2 * 4 * BOUND + 2 * (MAX_MODULUS - 1)
    whole = plan(segments, kin, steps, limits)
    joined = np.concatenate([w.plan.t_start for w in windows])
    np.testing.assert_allclose(joined, whole.t_start, rtol=1e-12, atol=1e-9)


def test_a_split_move_plays_the_steps_and_times_of_the_whole_move(tmp_path, monkeypatch):
    path = job_file(tmp_path, "G1 X2000 Y700 F6000")
    whole = host_build(load_job(path), keep=True)
    monkeypatch.setattr(lookahead, "WINDOW_EVENTS", BOUND)
    split = host_build(load_job(path), keep=True)
    assert (whole.totals.windows, split.totals.windows) == (1, 3)
    assert split.totals.duration_s == whole.totals.duration_s
    np.testing.assert_allclose(split.events.time, whole.events.time, rtol=0, atol=1e-12)
    for name in ("block_segment", "block_steps", "block_modulus", "block_init", "block_first"):
        assert np.array_equal(getattr(split.events, name), getattr(whole.events, name)), name
    for name in ("motor", "dir", "event", "event_position"):
        assert np.array_equal(getattr(split.pulses, name), getattr(whole.pulses, name)), name
    assert split.pulses.event_position[-1].tolist() == whole.expected_final.tolist() == [160_000, 56_000]
    # The rate runs start afresh at every window: the ticks move, within the error the runs allow.
    tick_hz = whole.target.tick_hz
    for host in (whole, split):
        assert np.abs(host.pulses.event_tick - host.events.time * tick_hz).max() <= host.totals.max_timing_error_ticks
    assert split.totals.max_timing_error_ticks == whole.totals.max_timing_error_ticks


def _attempts_counted(monkeypatch) -> list[int]:
    """The segments of every window attempt the stages play, in order."""
    played = []
    attempt = Stages._attempt

    def counted(self, window, *rest):
        played.append(len(window.segments))
        return attempt(self, window, *rest)

    monkeypatch.setattr(Stages, "_attempt", counted)
    return played


def test_a_window_slowed_for_a_stretch_of_its_own_is_played_again_alone(monkeypatch):
    """The windows of a 10 km move were each slowed once (coarse motor a 3 % over its rate where its Bresenham phase
    restarts between pieces): the first is planned again alone, not with every window before it (the time then grew
    with the square of the move), and the pieces that go on in its line start as slow: each window after is played
    once."""
    played = _attempts_counted(monkeypatch)
    host = host_build(load_job(DATA / "jobs" / "found" / "corexy-long-move-slowed-every-window.yaml"))
    assert host.findings.ok and host.totals.segments == 32
    assert played == [1, 9, 9, 9, 8, 5]


def test_a_long_move_at_a_coarse_motor_s_rate_goes_on_as_slow_as_its_window_before(monkeypatch):
    """A 65 m move keeps coarse motor a at its rate: once a window is slowed for it, the pieces that go on in its line
    start as slow, so the windows after are played once each, alone (each was played again merged with all the
    windows before: 82 s and 1.6 GB)."""
    played = _attempts_counted(monkeypatch)
    host = host_build(load_job(DATA / "jobs" / "found" / "corexy-coarse-motor-merges-every-window.yaml"), keep=False)
    assert host.findings.ok and host.totals.segments == 201
    # the windows the lookahead made before the first was slowed are merged, then each is played once, alone
    assert max(played[:10]) <= 3 * 9 and max(played[10:]) <= 9 and len(played) <= host.totals.windows + 10

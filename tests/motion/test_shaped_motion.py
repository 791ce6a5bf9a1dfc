"""Shaped motion (codegen/motion/shaped_motion.py) and its blocks (shaped_blocks.py), without the pipeline: the
plan's quadratics against the plan, the exact convolution against a sampled one, smoothing against Klipper's
theory, and the blocks' events against the shaped master's crossings."""

import numpy as np
import pytest

from codegen.motion.shaped_blocks import CHORD_LIMIT, motor_motion, shaped_blocks
from codegen.motion.shaped_motion import ShapingSettings, planned_motion, shape, smoothing
from codegen.motion.shapers import make_shaper, shape_positions
from codegen.motion.shapers import smoothing as klipper_smoothing
from tests.helpers import machine, planned, polyline

SQUARE = [(10, 10), (60, 10), (60, 60), (10, 60), (10, 30)]


def square_plan(feed=150.0, kinematics="cartesian"):
    motors = ("x", "y") if kinematics == "cartesian" else ("a", "b")
    return planned(polyline(SQUARE, feed), machine(kinematics, motors), jd=0.05)


def settings(x=("mzv", 50.0), y=("mzv", 50.0)):
    return ShapingSettings(tuple(None if s is None else make_shaper(*s) for s in (x, y, None)))


def test_the_planned_motion_is_the_plans_own():
    _, segments, _, plan = square_plan()
    motion = planned_motion(segments, plan)
    seg = np.repeat(np.arange(len(plan.length)), 50)
    s = np.tile(np.linspace(0.0, 1.0, 50), len(plan.length)) * plan.length[seg]
    where = segments.start[seg] + plan.direction[seg] * s[:, None]
    assert np.abs(motion.at(plan.time_at(seg, s)) - where).max() < 1e-9
    assert np.allclose(motion.at([-1.0, plan.total + 1.0]), [segments.start[0], segments.end[-1]], atol=1e-12)


@pytest.mark.parametrize("shapers", [(("mzv", 50.0), ("mzv", 50.0)), (("zv", 35.0), ("3hump_ei", 60.0)),
                                     (("ei", 40.0), None)])
def test_the_exact_convolution_is_the_sampled_one(shapers):
    """Each axis shaped in pieces equals numpy's convolution of the sampled plan (linear between samples at 100 kHz:
    within the sampling's own error), on the shaped clock; unshaped axes only move later."""
    _, segments, _, plan = square_plan()
    shaping = settings(*shapers)
    motion = planned_motion(segments, plan)
    shaped = shape(motion, shaping)
    rate = 100_000.0
    t = np.arange(-5_000, int((plan.total + 0.05) * rate)) / rate
    sampled = motion.at(t)
    for axis in range(2):
        shaper = shaping.shapers[axis]
        expected = sampled[:, axis] if shaper is None else shape_positions(sampled[:, axis], rate, shaper)
        assert np.abs(shaped.at(t + shaping.shift)[:, axis] - expected).max() < 1e-4
    assert np.allclose(shaped.at([shaped.breaks[-1]])[0], segments.end[-1])


def test_smoothing_on_a_reversal_is_klippers():
    """At a reversal under constant acceleration the shaped tool falls short by sum A_i a/2 (T_i - mean)^2, the
    180-degree part of Klipper's smoothing: a long move out and back at 1000 mm/s^2."""
    mach = machine(x={"amax": 1000.0}, y={"amax": 1000.0})
    _, segments, _, plan = planned(polyline([(0, 0), (40, 0), (0, 0)], 600.0), mach)
    accel = plan.accel[0]  # the planner keeps 2 % below the motors' limit
    assert accel == plan.accel[1] and plan.v_peak[0] / accel > 0.1  # accelerating far longer than any shaper
    for name in ("zv", "mzv", "ei", "2hump_ei"):
        shaper = make_shaper(name, 40.0)
        shaping = ShapingSettings((shaper, shaper, None))
        motion = planned_motion(segments, plan)
        worst, at, _ = smoothing(shape(motion, shaping), motion, shaping)
        reversal = float(shaper.amplitudes @ (accel / 2 * (shaper.times - shaper.mean_time) ** 2))
        assert worst == pytest.approx(reversal, rel=1e-3)
        assert reversal <= klipper_smoothing(shaper, accel, 0.0) + 1e-12  # Klipper's figure is the larger part


def test_blocks_hold_every_master_crossing_and_stay_near_their_chords():
    kin, segments, _, plan = square_plan(kinematics="corexy")
    shaping = settings(("zv", 30.0), ("ei", 55.0))
    shaped = shape(planned_motion(segments, plan), shaping)
    blocks = shaped_blocks(shaped, segments, kin, 0.01, segments.start[0], segments.end[-1])
    events = blocks.events
    spm = kin.limits.steps_per_mm
    # Steps telescope: the blocks move every motor from the start to the end, rounded once.
    assert np.array_equal(blocks.steps.sum(axis=0), kin.to_steps(segments.end[-1:])[0] - kin.to_steps(
        segments.start[:1])[0])
    # Every event: the master at its half step, exactly, at the event's time.
    count = np.diff(events.block_first)
    block = np.repeat(np.arange(len(count)), count)
    k = np.arange(len(block)) - events.block_first[block] + 1
    master = np.argmax(np.abs(events.block_steps), axis=1)[block]
    x0 = kin.to_motor(blocks.chords.start[events.block_segment]) * spm
    sign = np.sign(events.block_steps[block, master])
    crossing = np.round(x0[block, master]) + sign * (k - 0.5)
    exact = kin.to_motor(shaped.at(events.time)) * spm
    assert np.abs(exact[np.arange(len(block)), master] - crossing).max() < 1e-6
    # Every slave within CHORD_LIMIT of the chord, master against slave, at every piece break of its block.
    p, _, _ = motor_motion(blocks.pieces, kin)
    owner = np.searchsorted(blocks.bounds, blocks.pieces.breaks[:-1], side="right") - 1
    x0, x1 = kin.to_motor(blocks.chords.start) * spm, kin.to_motor(blocks.chords.end) * spm
    m = np.argmax(np.abs(blocks.steps), axis=1)
    rows = np.arange(len(m))
    ratio = (x1 - x0) / np.where((x1 - x0)[rows, m] != 0, (x1 - x0)[rows, m], 1.0)[:, None]
    off = p - x0[owner] - ratio[owner] * (p[np.arange(len(owner)), m[owner]] - x0[owner, m[owner]])[:, None]
    moving = np.abs(blocks.steps).max(axis=1)[owner] > 0
    assert np.abs(off[moving]).max() <= CHORD_LIMIT + 1e-9

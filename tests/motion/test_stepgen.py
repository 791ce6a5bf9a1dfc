"""Blocks and step times: rounding once, half-step crossings, Bresenham starts, the staircase bound."""


import numpy as np
import pytest

from codegen.kinematics import make_kinematics
from codegen.motion.blocks import MAX_MODULUS
from codegen.motion.staircase import STAIRCASE_LIMIT, refine, split_long, staircase_bound, staircase_error
from codegen.motion.stepgen import generate, segment_steps
from codegen.toolpath.segments import flatten
from tests.helpers import ROOT, machine, planned, polyline


def random_segments(kin_name="cartesian", motors=("x", "y"), n=3000, seed=5):
    rng = np.random.default_rng(seed)
    pts = np.cumsum(rng.uniform(-2.0, 2.0, size=(n + 1, 2)), axis=0) + 100.0
    kin = make_kinematics(machine(kin_name, motors))
    return kin, flatten(polyline(pts, feed=100), 0.002)


def test_master_steps_when_its_exact_position_crosses_half_steps():
    # x from 0.2 mm to 1.2 mm at 10 steps/mm: positions 2 .. 12, crossings at 2.5, 3.5, ... 11.5 steps.
    kin, segments, steps, p = planned(polyline([(0.2, 0), (1.2, 0)], feed=5), machine(x={"spm": 10}, y={"spm": 10}))
    events = generate(segments, p, kin, steps, max_gap=1.0)
    assert steps.tolist() == [[10, 0]]
    crossing_mm = (np.arange(10) + 2.5) / 10 - 0.2
    assert np.allclose(events.time, p.time_at(np.zeros(10, int), crossing_mm))


def test_positions_round_once_from_exact_coordinates():
    kin = make_kinematics(machine())
    segments = flatten(polyline([(0, 0), (0.0062, 0), (0.0124, 0), (0.0186, 0)], feed=5), 0.002)
    steps = segment_steps(segments, kin)
    # 80 steps/mm: 0.496, 0.992, 1.488 steps round to 0, 1, 1: no drift from adding rounded increments.
    assert steps[:, 0].tolist() == [0, 1, 0]


def test_long_moves_split_into_blocks_a_modulus_can_hold():
    kin = make_kinematics(machine(x={"spm": 400}, y={"spm": 400}))
    segments = split_long(flatten(polyline([(0, 0), (200, 3)], feed=50), 0.002), kin)
    steps = segment_steps(segments, kin)
    assert len(segments) == 3
    assert np.abs(steps).max() < MAX_MODULUS
    assert steps.sum(axis=0).tolist() == [80000, 1200]


@pytest.mark.parametrize("kind, motors", [("cartesian", ("x", "y")), ("corexy", ("a", "b"))])
def test_staircase_bound_is_an_upper_bound(kind, motors):
    kin, segments = random_segments(kind, motors)
    bound = staircase_bound(segments, kin)
    actual = staircase_error(segments, kin, np.arange(len(segments)))
    assert np.all(actual <= bound + 1e-12)
    assert np.mean(bound) < 2 * np.mean(actual)  # and not a useless one


def test_centred_bresenham_start_keeps_within_a_step():
    kin, segments = random_segments()
    actual = staircase_error(segments, kin, np.arange(len(segments)))
    assert actual.max() <= 1.05 / 80  # at most about one step, even before refining


def test_refine_cuts_every_block_within_the_staircase_limit_and_keeps_the_path():
    kin, segments = random_segments(n=2000, seed=9)
    refined = refine(segments, kin)
    assert len(refined) > len(segments)
    error = staircase_error(refined, kin, np.arange(len(refined)))
    assert error.max() <= STAIRCASE_LIMIT / 80
    # Cuts lie on the segments: the path's corners are all still there, in order.
    assert np.allclose(refined.end[-1], segments.end[-1]) and np.allclose(refined.start[0], segments.start[0])
    assert np.allclose(refined.start[1:], refined.end[:-1])


def test_refine_keeps_every_block_of_a_slicer_file_within_the_staircase_limit():
    """Found by the windowed pipeline: a round's cuts were located as if the previous round's pieces came in
    order, so a second cut could miss its piece (the Benchy's line 16785 stayed 3 % over the limit)."""
    from codegen.job import load_job
    from codegen.kinematics import make_kinematics
    from codegen.motion.pieces import drop_empty
    from codegen.pipeline.settings import homing_settings
    from codegen.program.program import whole_toolpath
    from codegen.toolpath.segments import flatten

    root = ROOT
    job = load_job(root / "examples" / "printers" / "benchy-mini.yaml")
    kin = make_kinematics(job.machine)
    refined = refine(drop_empty(flatten(whole_toolpath(job, kin, homing_settings(job))[0], job.machine.tolerance)), kin)
    limit = STAIRCASE_LIMIT * 0.01  # 100 steps/mm
    doubtful = np.flatnonzero(staircase_bound(refined, kin) > limit)  # the others are provably within
    assert staircase_error(refined, kin, doubtful).max() <= limit

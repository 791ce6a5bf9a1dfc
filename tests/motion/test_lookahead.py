"""The lookahead plans a program a window at a time, and the windows join into the whole program's plan: the
same junction speeds, peaks and durations (to rounding), and the same corners."""


import numpy as np
import pytest

import codegen.motion.lookahead as lookahead
from codegen.job import load_job
from codegen.kinematics import make_kinematics
from codegen.motion.lookahead import Lookahead
from codegen.motion.pieces import pieces
from codegen.motion.planner import plan
from codegen.pipeline.settings import front_end_settings, homing_settings, planner_limits
from codegen.program.program import Program
from codegen.targets import target_info
from codegen.toolpath.segments import concat
from tests.helpers import ROOT, gcode_job_file


def planner_input(path):
    """The planner's input for the whole program: segments, kinematics, steps, limits."""
    job = load_job(path)
    kin = make_kinematics(job.machine)
    chunks = list(pieces(front_end_settings(job), kin, Program(job, kin, homing_settings(job))))
    segments, steps = concat(*(c[0] for c in chunks)), np.concatenate([c[1] for c in chunks])
    return segments, kin, steps, planner_limits(job, kin, target_info(job.board))


def windowed(segments, kin, steps, limits, chunk):
    ahead, windows = Lookahead(kin, limits), []
    for lo in range(0, len(segments), chunk):
        part = np.arange(lo, min(lo + chunk, len(segments)))
        windows += ahead.push(segments.take(part), steps[part])
    return [*windows, *ahead.close()]


def assert_joins_into(windows, whole):
    sizes = [len(w.segments) for w in windows]
    assert [w.first for w in windows] == np.concatenate([[0], np.cumsum(sizes)[:-1]]).tolist()
    assert sum(sizes) == len(whole.length)
    # The whole program's passes sum the gains of every segment before: v^2 to ~1e-8 of that sum, the
    # windows' sums are shorter (and their rounding smaller).
    for field in ("v_entry", "v_peak", "v_exit"):
        joined = np.concatenate([getattr(w.plan, field) for w in windows])
        np.testing.assert_allclose(joined ** 2, getattr(whole, field) ** 2, rtol=1e-8, atol=1e-6, err_msg=field)
    for field in ("duration", "t_start"):
        joined = np.concatenate([getattr(w.plan, field) for w in windows])
        np.testing.assert_allclose(joined, getattr(whole, field), rtol=1e-7, atol=1e-7, err_msg=field)
    corners = np.concatenate([w.plan.corner[:-1] for w in windows] + [windows[-1].plan.corner[-1:]])
    assert np.array_equal(corners, whole.corner)
    for before, after in zip(windows, windows[1:]):  # each window starts as the one before ends
        assert before.plan.v_exit[-1] == after.plan.v_entry[0]
        assert before.plan.corner[-1] and after.plan.corner[0]


@pytest.mark.parametrize("name, chunk", [
    ("plotter/shapes.gcode", 1), ("plotter/shapes.gcode", 37), ("slicer/puzzle-cura.gcode", 37),
    ("slicer/puzzle-cura.gcode", 4096), ("laser/hiking.gcode", 37), ("slicer/benchy-arcs-arcwelder.gcode", 4096)])
def test_windows_of_real_gcode_join_into_the_whole_plan(tmp_path, name, chunk):
    segments, kin, steps, limits = planner_input(gcode_job_file(tmp_path, name))
    windows = windowed(segments, kin, steps, limits, chunk)
    assert len(windows) > (1 if chunk == 4096 else 3)
    assert_joins_into(windows, plan(segments, kin, steps, limits))


@pytest.mark.parametrize("example", ["examples/kossel-mini.yaml", "examples/star.yaml", "examples/plotter-set.yaml",
                                     "examples/function.yaml", "examples/delta-seed.yaml"])
def test_windows_of_shapes_join_into_the_whole_plan(example):
    segments, kin, steps, limits = planner_input(ROOT / example)
    assert_joins_into(windowed(segments, kin, steps, limits, 5), plan(segments, kin, steps, limits))


def test_a_long_curve_is_cut_at_a_settled_junction(monkeypatch):
    segments, kin, steps, limits = planner_input(ROOT / "examples/kossel-mini.yaml")
    monkeypatch.setattr(lookahead, "MAX_HELD", 8)
    windows = windowed(segments, kin, steps, limits, 3)
    assert any(w.curve_cut for w in windows)
    whole = plan(segments, kin, steps, limits)
    joined = np.concatenate([w.plan.v_entry for w in windows])
    np.testing.assert_allclose(joined, whole.v_entry, rtol=1e-8, atol=1e-7)

"""Delta jobs through the host pipeline: reachability errors at the job's lines, carriage limits, homing."""

from pathlib import Path

import pytest

from codegen.errors import JobError
from codegen.job import load_job
from codegen.pipeline.host import host_build
from tests.helpers import ROOT

KOSSEL = (ROOT / "examples" / "kossel-mini.yaml").read_text()


def kossel_with(tmp_path, shapes: str) -> Path:
    head = KOSSEL[:KOSSEL.index("  shapes:")]
    job = tmp_path / "kossel.yaml"
    job.write_text(head + "  shapes:\n" + shapes)
    return job


def test_an_unreachable_point_is_an_error_at_its_shape(tmp_path):
    job = kossel_with(tmp_path, "    - line: {from: [0, 0, 5], to: [20, 0, 5]}\n"
                                "    - points: [[0, 0, 10], [180, 0, 10]]\n")
    with pytest.raises(JobError) as error:
        host_build(load_job(job))
    (d,) = error.value.diagnostics
    line = job.read_text().splitlines().index("    - points: [[0, 0, 10], [180, 0, 10]]") + 1
    assert (d.where.line, d.where.col) == (line, 7)
    assert d.message.startswith("the machine cannot reach (")  # the first point of the move out of reach
    assert d.message.endswith(" on the way to (180.000, 0.000, 10.000)")


def test_a_straight_move_whose_carriage_peaks_above_its_tower_is_an_error(tmp_path):
    # Both ends are reachable, but c's carriage rises above its top in the middle (its arm gets steeper).
    job = kossel_with(tmp_path, "    - line: {from: [-60, 80, 228], to: [60, 80, 228]}\n")
    with pytest.raises(JobError) as error:
        host_build(load_job(job))
    assert "the machine cannot reach" in error.value.diagnostics[0].message


def test_delta_homes_first_and_ends_exactly(planned_example):
    host = planned_example("delta-seed.yaml")
    assert host.findings.ok, host.findings.problems
    assert [h.switch for h in host.homing] == ["x_max", "y_max", "z_max"]
    assert all(h.direction == 1 for h in host.homing)
    assert host.start_steps.tolist() == [10828, 10828, 10828]  # homed: the seed's 10,828 steps to the top
    assert host.findings.final == host.findings.expected_final


def test_fast_straight_moves_near_the_edge_keep_carriage_acceleration(tmp_path):
    job = kossel_with(tmp_path, "    - line: {from: [-70, -60, 2], to: [70, -60, 2], feed: 18000}\n")
    host = host_build(load_job(job))
    assert host.findings.ok, host.findings.problems
    assert max(host.findings.accel_ratio.values()) <= 1.0
    assert host.findings.max_path_error_mm <= 0.05

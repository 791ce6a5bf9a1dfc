"""Pressure advance in simavr (codegen/verify/advance.py): the image plays the advanced extruder, and verify holds
every simulated extruder pulse against Klipper's formula."""

from __future__ import annotations

import json
import shutil

import pytest

from tests.helpers import run_cli as run
from tests.pipeline.test_advance import job_text

pytestmark = pytest.mark.skipif(shutil.which("simavr") is None, reason="needs simavr")

GCODE = "G90\nM83\nG1 X60 Y10 E2 F3000\nG1 X60 Y50 E2\nG1 E-1 F2100\nG1 X20 Y20 F9000\nG1 E1 F2100\n" \
        "M572 D0 S0.08\nG2 X40 Y40 I10 J10 E1.5 F2400\n"


def test_an_advanced_job_verifies_in_simavr_within_a_step_of_the_formula(tmp_path, capsys):
    job = tmp_path / "advanced.yaml"
    job.write_text(job_text(GCODE, "{k: 0.05, smooth_time: 0.03}", extra="  input_shaper: {x: {type: mzv, freq: "
                                                                             "50}, y: {type: mzv, freq: 50}}\n"))
    code, out, _ = run(capsys, "verify", job, "--out", tmp_path / "out", "--json")
    result = json.loads(out)
    assert code == 0 and result["pass"] is True, result["problems"]
    assert 0.0 < result["pressure_advance_steps"] <= 1.0
    e = result["motors"]["e"]
    assert e["final"] == e["expected_final"] == round(5.5 * 415)
    assert e["steps"] > e["final"] and e["max_rate_ratio"] <= 1.0 and e["max_accel_ratio"] <= 1.0

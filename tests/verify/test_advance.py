"""Pressure advance in simavr (codegen/verify/advance.py): the image plays the advanced extruder, and verify holds
every simulated extruder pulse against Klipper's formula."""

from __future__ import annotations

import json
import shutil

import pytest
import yaml

from tests.helpers import DATA, EXAMPLES
from tests.helpers import run_cli as run
from tests.pipeline.test_advance import job_text

GCODE = "G90\nM83\nG1 X60 Y10 E2 F3000\nG1 X60 Y50 E2\nG1 E-1 F2100\nG1 X20 Y20 F9000\nG1 E1 F2100\n" \
        "M572 D0 S0.08\nG2 X40 Y40 I10 J10 E1.5 F2400\n"


@pytest.mark.skipif(shutil.which("simavr") is None, reason="needs simavr")
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


@pytest.mark.skipif(shutil.which("s51") is None, reason="needs s51")
def test_the_8051s_late_block_loads_keep_the_extruder_on_the_formula(tmp_path, capsys):
    """Puzzle-cura's last 62 lines on the 8051, shaped and advanced: its short shaped blocks load slower than their
    events come, so events play up to 378 us late and catch up over the next blocks. Each extruder pulse is held
    against the formula at its planned time (it was 1.30 steps off at its played time), and the lag carried from
    block to block is the loads' (the timing rule had wanted each shaped block caught up by its end)."""
    lines = (DATA / "gcode" / "slicer" / "puzzle-cura.gcode").read_text().splitlines()[34200:34262]
    job = yaml.safe_load((EXAMPLES / "printers" / "benchy-mini.yaml").read_text())
    job.update(name="puzzle-end", target="mcs51")
    job["machine"]["input_shaper"] = {axis: {"type": "mzv", "freq": 50} for axis in "xy"}
    job["machine"]["pressure_advance"] = {"k": 0.05}
    job["program"] = {"gcode": "\n".join(["G92 E3201.76849", "G0 Z23.8", *lines]) + "\n"}
    path = tmp_path / "puzzle-end.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    code, out, _ = run(capsys, "plan", path, "--json")
    assert code == 0 and json.loads(out)["max_timing_error_us"] > 300  # the late loads are there
    code, out, _ = run(capsys, "verify", path, "--out", tmp_path / "out", "--json")
    result = json.loads(out)
    assert code == 0 and result["pass"] is True, result["problems"]
    assert 0.0 < result["pressure_advance_steps"] <= 1.0

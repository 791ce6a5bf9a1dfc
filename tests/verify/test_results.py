"""What `verify` reports: motor ends counted from where the program began (CLI.md), and never a figure it did
not measure. The simulator is the real simavr; a mismatch is made by removing one real simulated step."""

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest

from codegen.cli.main import main
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.sim.avr import simulate
from codegen.verify.compare import compare, simulated_switches
from codegen.verify.results import verify_json
from tests.helpers import run_cli as run

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")
OFF_ORIGIN = """
name: off-origin
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 80, max_velocity: 100, max_accel: 2000}
    y: {steps_per_mm: 80, max_velocity: 100, max_accel: 2000}
program:
  start: [10, 5]
  shapes:
    - line: {to: [30, 15]}
"""


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    folder = tmp_path_factory.mktemp("off-origin")
    job = folder / "job.yaml"
    job.write_text(OFF_ORIGIN)
    assert main(["build", str(job), "--out", str(folder / "out")]) == 0
    return job, folder / "out"


def test_final_counts_from_where_the_program_began(built, capsys):
    job, out = built
    code, text, _ = run(capsys, "verify", job, "--out", out, "--json")
    result = json.loads(text)
    assert code == 0, result["problems"]
    x, y = result["motors"]["x"], result["motors"]["y"]
    assert (x["final"], x["expected_final"], x["end_position"], x["expected_end_position"]) == (1600, 1600, 2400, 2400)
    assert (y["final"], y["expected_final"], y["end_position"]) == (800, 800, 1200)
    assert result["not_compared"] == []
    code, text, _ = run(capsys, "plan", job, "--json")
    assert json.loads(text)["motors"]["x"]["final"] == 1600
    code, text, _ = run(capsys, "verify", job, "--out", out)
    assert "x: 1600 steps, net +1600 (job: +1600), ends at step 2400" in text


def test_a_lost_step_is_reported_without_unmeasured_figures(built, capsys):
    job, out = built
    host = host_build(load_job(job))
    switches = simulated_switches(host)
    budget = int((host.plan.total * 1.2 + 1.0) * host.target.f_cpu)
    trace = simulate(out / "firmware.hex", host.firmware_config(), budget, switches=switches)
    lost = int(np.flatnonzero(trace.step_motor == 0)[700])  # one of x's steps never happened
    keep = np.arange(len(trace.step_cycle)) != lost
    trace = replace(trace, step_cycle=trace.step_cycle[keep], step_motor=trace.step_motor[keep],
                    step_dir=trace.step_dir[keep], step_phase=trace.step_phase[keep])
    verdict = compare(host, trace, switches)
    assert not verdict.ok
    assert "motor x: the simulator made 1599 steps, the twin predicted 1600" in verdict.problems
    assert verdict.not_compared == [
        "timing of motor x: its steps cannot be paired (1599 simulated, 1600 predicted)",
        "path error: the simulated steps do not pair with the twin's, so they cannot be placed on the path's "
        "segments"]
    assert "y" in verdict.timing_error_us  # y's steps pair: its timing is measured
    result = verify_json(host, verdict, type("Image", (), {"flash_bytes": 0, "ram_bytes": 0})())
    assert result["max_path_error_mm"] is None and result["motors"]["x"]["max_timing_error_us"] is None
    assert result["motors"]["x"]["final"] == 1599 and result["motors"]["y"]["max_timing_error_us"] is not None
    assert "nan" not in json.dumps(result).lower()

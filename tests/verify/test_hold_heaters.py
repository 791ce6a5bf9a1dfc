"""Feed hold beside heaters (an ATmega2560 flash image or streaming firmware that runs its heaters from main's
idle loop): main polls the hold keys right after every step interrupt there too; verify heats the simulated
plants, takes the waits' holds out of the run (codegen/verify/hold_runs.py HeatedRun, StreamRun) and compares every pulse
of a held, overridden or paused run with the dilated twin."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from codegen.cli.main import _build, main
from codegen.errors import BuildError
from codegen.job import load_job
from codegen.verify.hold import hold_verify

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")

PRINTER = """name: {name}
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: 80, max_velocity: 100, max_accel: 1000}}
    y: {{steps_per_mm: 80, max_velocity: 100, max_accel: 1000}}
  feed_hold: {{}}
program:
  gcode: |
    M104 S200
    M109 S200
    G1 X10 F600
    G1 X40 Y20 F3000
{middle}    G1 X0 Y30
    G1 X30 Y0
    G1 X0 Y0
"""


def _built(tmp_path: Path, name: str, middle: str = ""):
    path = tmp_path / f"{name}.yaml"
    path.write_text(PRINTER.format(name=name, middle=middle))
    return _build(load_job(path), str(tmp_path / name), reuse=False, strict=False)[:2]


def _exact_and_within_limits(result: dict, timing_us: float = 1.0) -> None:
    assert result["pass"], result["problems"]
    for motor in result["motors"].values():
        assert motor["final"] == motor["expected_final"]
        assert motor["max_timing_error_us"] <= timing_us
        assert motor["max_accel_ratio"] <= 1.0 and motor["max_rate_ratio"] <= 1.0


def test_a_printer_held_mid_move_after_heating_rests_and_resumes_exactly(tmp_path):
    host, image = _built(tmp_path, "hot")
    assert host.hold_plan is not None and "hotend" in [h.name for h in host.heaters]
    result, _ = hold_verify(host, image, 1.5, None)
    _exact_and_within_limits(result)
    hold = result["hold"]
    assert hold["ramp_s"] - 0.001 < hold["stopping_s"] < hold["ramp_s"] + 0.15
    assert result["heaters"]["hotend"]["target_c"] == 200.0
    assert [h["heaters"] for h in result["holds"]] == [["hotend"]] and result["holds"][0]["waited_s"] > 10
    # the run took the plan's time, the hold's stop and stand and its speeding up again
    assert result["duration_s"] > host.plan.total + (hold["resume_s"] - hold["at_rest_s"])


def test_m0_in_a_heated_job_parks_until_resume(tmp_path):
    host, image = _built(tmp_path, "hot-pause", "    M0\n")
    result, _ = hold_verify(host, image, None, None)
    _exact_and_within_limits(result)
    assert [r["kind"] for r in result["hold"]["rests"]] == ["pause"]


def test_a_hold_before_the_heaters_last_wait_is_refused_with_its_times(tmp_path, capsys):
    host, image = _built(tmp_path, "hot-twice", "    M109 S210\n")
    with pytest.raises(BuildError, match=r"a key pressed 0\.500 s into the job, before the heaters' last wait"):
        hold_verify(host, image, 0.5, None)
    job = tmp_path / "hot-twice.yaml"
    assert main(["verify", str(job), "--out", str(tmp_path / "hot-twice"), "--hold", "3.0"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("PASS hot-twice") and "hold: at rest" in out and "heater hotend" in out


STREAMED = """name: hot-stream
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000, range: [0, 200]}
    y: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000, range: [0, 200]}
    z: {steps_per_mm: 400, max_velocity: 10, max_accel: 200, range: [0, 100]}
    e: {steps_per_mm: 100, max_velocity: 50, max_accel: 3000}
  feed_hold: {}
program:
  gcode: |
    M140 S60
    M104 S200
    M190 S60
    M109 S200
    G1 X20 Y10 F6000
    G1 X40 Y30 E2 F3000
    G1 X10 Y40 E4
    G1 X0 Y0 E5
    M104 S0
    M140 S0
"""


def test_a_streamed_printer_held_over_the_link_after_heating(tmp_path, capsys):
    """The streaming firmware with heaters: HOLD and RESUME frames after the bed's and the hot end's waits."""
    path = tmp_path / "hot-stream.yaml"
    path.write_text(STREAMED)
    code = main(["verify", str(path), "--stream", "--hold", "0.3", "--json", "--out", str(tmp_path / "out")])
    result = json.loads(capsys.readouterr().out)
    _exact_and_within_limits(result, timing_us=5.0 + 15.0)  # the stream's latency: a link interrupt, the poll
    assert code == 0
    assert [h["heaters"] for h in result["holds"]] == [["bed"], ["hotend"]]
    assert result["hold"]["at_rest_s"] > result["hold"]["hold_s"] and result["link"]["retransmits"] == 0

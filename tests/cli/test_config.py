"""`printer-codegen config`: the normalized job with every default, the board's pins for it, YAML that loads back
as a job planning to the same result, and the loader's errors for a bad job (no compiler, no simulator)."""

from pathlib import Path

import pytest
import yaml

from codegen.cli.main import main
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.report.summaries import plan_summary
from tests.helpers import ROOT, STAR

STAR_POINTS = [[100.0, 180.0], [147.023, 35.279], [23.915, 124.721], [176.085, 124.721], [52.977, 35.279],
               [100.0, 180.0]]


def config(capsys, job: Path, *args: str) -> tuple[str, dict]:
    assert main(["config", str(job), *args]) == 0
    text = capsys.readouterr().out
    return text, yaml.safe_load(text)


@pytest.fixture
def star(tmp_path) -> Path:
    path = tmp_path / "star.yaml"
    path.write_text(STAR)
    return path


def test_every_default_and_the_boards_pins(capsys, star):
    text, doc = config(capsys, star)
    assert list(doc) == ["name", "target", "board", "machine", "program", "board_info"]
    assert (doc["name"], doc["target"], doc["board"]) == ("star", "avr", "ramps-1.4")
    machine = doc["machine"]
    stepper = {"steps_per_mm": 80.0, "max_velocity": 400.0, "max_accel": 8000.0, "range": None, "invert_dir": False}
    assert machine["steppers"] == {"a": stepper, "b": stepper}
    assert (machine["kinematics"], machine["junction_deviation"], machine["tolerance"]) == ("corexy", 0.02, 0.002)
    assert (machine["step_pulse_us"], machine["dir_setup_us"]) == (2.0, 1.0)
    assert machine["homing"] == {"speed": 20.0, "slow_speed": 2.0, "backoff": 3.0}
    assert machine["link"] == {"baud": None}  # the target's rate
    assert machine["delta"] is machine["jog"] is machine["heaters"] is machine["laser"] is None
    assert doc["program"] == {"start": [100.0, 100.0], "feed": 18000.0, "travel_feed": None, "s_max": None,
                              "dialect": None, "home": False, "shapes": [{"polyline": {"points": STAR_POINTS}}]}
    assert "    a: {steps_per_mm: 80.0, max_velocity: 400.0, max_accel: 8000.0, range: null, invert_dir: false}" \
        in text.splitlines()
    board = doc["board_info"]
    assert {k: board[k] for k in ("name", "mcu", "target", "f_cpu", "flash_bytes", "ram_bytes")} == {
        "name": "ramps-1.4", "mcu": "atmega2560", "target": "avr", "f_cpu": 16_000_000, "flash_bytes": 262144,
        "ram_bytes": 8192}
    pins = board["pins"]
    assert pins["steppers"] == {"a": {"socket": "X", "step": "PF0", "dir": "PF1", "enable": "PD7"},
                                "b": {"socket": "Y", "step": "PF6", "dir": "PF7", "enable": "PF2"}}
    assert pins["enable_active_low"] is True
    assert pins["endstops"] == {"x_min": {"pin": "PE5", "closed": "low"}, "y_min": {"pin": "PJ1", "closed": "low"}}
    assert pins["tool"] == {"pin": "PB5", "active_high": True}
    assert pins["laser_pwm"] == "PL4"
    assert pins["heaters"] == {"hotend": {"pwm": "PB4", "sensor": "PK5"}, "bed": {"pwm": "PH5", "sensor": "PK6"}}
    assert pins["fan"] == "PH6"
    assert pins["jog_keys"]["direct"]["start"] == "PL6"
    assert pins["link"] == {"usart": 0, "rx": "PE0", "tx": "PE1"}
    assert config(capsys, star)[0] == text  # deterministic


@pytest.mark.parametrize("target", ["avr", "mcs51"])
def test_the_printed_job_loads_back_and_plans_the_same(capsys, star, target):
    _, doc = config(capsys, star, "--target", target)
    assert doc["target"] == target
    del doc["board_info"]
    again = star.with_name("again.yaml")
    again.write_text(yaml.safe_dump(doc, sort_keys=False))
    before = plan_summary(host_build(load_job(star, target), keep=False))
    after = plan_summary(host_build(load_job(again), keep=False))
    assert after["duration_s"] == before["duration_s"] > 0
    assert after == before  # steps, finals, table bytes, the checks


def test_an_8051_delta_that_homes(capsys, tmp_path):
    job = tmp_path / "delta.yaml"
    text = (ROOT / "examples" / "delta-seed-51.yaml").read_text()
    job.write_text(text.replace("  start: [0, 0, 523.168]   # homed: every carriage at its top\n", ""))
    assert "start:" not in job.read_text()
    _, doc = config(capsys, job)
    assert "start" not in doc["program"]  # it starts where homing leaves it: a `start` would add a travel move
    pins = doc["board_info"]["pins"]
    assert (doc["board_info"]["name"], doc["board_info"]["mcu"], doc["board_info"]["f_cpu"]) == \
        ("seed-51", "at89c52", 12_000_000)
    assert pins["steppers"]["c"] == {"socket": "Z", "step": "P1.4", "dir": "P1.5", "enable": "P1.7"}
    assert pins["enable_active_low"] is False
    assert list(pins["endstops"]) == ["x_max", "y_max", "z_max"]
    assert pins["lcd"] == {"mode": "4bit", "rs": "P2.1", "e": "P2.2", "data": ["P2.4", "P2.5", "P2.6", "P2.7"]}
    assert pins["link"] == {"rx": "P3.0", "tx": "P3.1"}  # the 8051's UART
    assert "heaters" not in pins and "laser_pwm" not in pins
    del doc["board_info"]
    again = tmp_path / "again.yaml"
    again.write_text(yaml.safe_dump(doc, sort_keys=False))
    assert load_job(again).program.start_source is None


def test_coil_sockets(capsys, tmp_path):
    job = tmp_path / "coil.yaml"
    job.write_text("target: mcs51\nboard: coil-51\nmachine:\n  kinematics: cartesian\n  steppers:\n"
                   "    x: {steps_per_mm: 20, max_velocity: 10, max_accel: 50}\n"
                   "    y: {steps_per_mm: 20, max_velocity: 10, max_accel: 50, invert_dir: true}\n"
                   "program:\n  shapes:\n    - line: {to: [5, 5]}\n")
    _, doc = config(capsys, job)
    assert doc["machine"]["steppers"]["y"]["invert_dir"] is True
    assert doc["program"]["shapes"] == [{"line": {"to": [5.0, 5.0]}}]  # no feed: the program's
    assert doc["board_info"]["pins"]["steppers"] == {
        "x": {"socket": "X", "coils": ["P2.0", "P2.1", "P2.2", "P2.3"]},
        "y": {"socket": "Y", "coils": ["P2.4", "P2.5", "P2.6", "P2.7"]}}
    assert "endstops" not in doc["board_info"]["pins"]


def test_gcode_inline_and_in_a_file(capsys, tmp_path):
    (tmp_path / "part.gcode").write_text("G1 X5 Y5 F600\n")
    job = tmp_path / "inline.yaml"
    job.write_text("machine:\n  kinematics: cartesian\n  steppers:\n"
                   "    x: {steps_per_mm: 80, max_velocity: 100, max_accel: 1000}\n"
                   "    y: {steps_per_mm: 80, max_velocity: 100, max_accel: 1000}\n"
                   "  heaters:\n    bed: {control: {bang_bang: {hysteresis_c: 2}}}\n"
                   "program:\n  gcode: |\n    G21 G90\n    G1 X10 Y0 F1200\n    G1 X10 Y10\n")
    text, doc = config(capsys, job)
    assert "  gcode: |\n    G21 G90\n    G1 X10 Y0 F1200\n    G1 X10 Y10\n" in text
    assert doc["machine"]["heaters"] == {"bed": {
        "sensor": "EPCOS 100K B57560G104F", "pullup_ohm": 4700.0, "control": {"pid": None, "bang_bang": {
            "hysteresis_c": 2.0}}, "max_power": 1.0, "min_temp_c": 5.0, "max_temp_c": None, "plant": None}}
    del doc["board_info"]
    again = tmp_path / "again.yaml"
    again.write_text(yaml.safe_dump(doc, sort_keys=False))
    assert load_job(again).program.gcode == load_job(job).program.gcode
    job.write_text(job.read_text().split("  gcode: |")[0] + "  gcode: part.gcode\n")
    assert config(capsys, job)[1]["program"]["gcode"] == "part.gcode"  # relative to the job file, as written


def test_a_bad_job_is_refused_as_plan_refuses_it(capsys, tmp_path):
    job = tmp_path / "bad.yaml"
    job.write_text("machine:\n  kinematics: cartesian\n  steppers:\n"
                   "    x: {steps_per_mm: 80, max_velocity: -1, max_accel: 100}\n"
                   "    y: {steps_per_mm: 80, max_velocity: 10, max_accel: 100}\n"
                   "program:\n  shapes:\n    - line: {to: [1, 2]}\n")
    assert main(["config", str(job)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.splitlines() == [f"{job}:4:41: error: machine.steppers.x.max_velocity: must be > 0",
                                "    x: {steps_per_mm: 80, max_velocity: -1, max_accel: 100}",
                                " " * 40 + "^"]
    assert main(["plan", str(job)]) == 2
    assert capsys.readouterr().err.splitlines() == err.splitlines()

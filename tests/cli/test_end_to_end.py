"""End to end: the real avr-gcc and the real simavr, through the command line users run."""

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from codegen.cli.main import main
from codegen.targets import target_info
from tests.helpers import ROOT
from tests.helpers import run_cli as run

EXAMPLES = sorted((ROOT / "examples").glob("*.yaml")) + sorted((ROOT / "examples" / "gcode").glob("*.yaml"))

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


@pytest.fixture(scope="module")
def verified(tmp_path_factory):
    """verify --json of an example, run once per module: (exit code, the JSON, the output folder)."""
    done: dict[Path, tuple[int, dict, Path]] = {}

    def get(example: Path) -> tuple[int, dict, Path]:
        if example not in done:
            out = tmp_path_factory.mktemp(example.stem)
            buffer = io.StringIO()
            with contextlib.redirect_stdout(buffer):
                code = main(["verify", str(example), "--out", str(out), "--json"])
            done[example] = code, json.loads(buffer.getvalue()), out
        return done[example]
    return get


@pytest.mark.parametrize("example", EXAMPLES, ids=lambda p: p.stem)  # examples/printers: plan only
def test_every_example_verifies_in_simavr(example, verified):
    code, result, tmp_path = verified(example)
    assert code == 0, result["problems"]
    assert result["pass"] is True
    latency_us = target_info(result["board"]).isr_latency_us  # constant: the player's
    for name, motor in result["motors"].items():
        assert motor["final"] == motor["expected_final"], name
        assert motor["max_timing_error_us"] <= 5.0 + latency_us
        assert motor["max_rate_ratio"] <= 1.0
        assert motor["max_accel_ratio"] <= 1.0
        assert motor["min_pulse_us"] >= 2.0
    assert result["max_path_error_mm"] <= result["path_limit_mm"]
    assert abs(result["duration_s"] - result["planned_duration_s"]) <= 0.01 * result["planned_duration_s"]
    assert (tmp_path / "firmware.hex").is_file() and (tmp_path / "report.json").is_file()


def test_the_laser_example_burns_at_its_power(verified):
    code, result, _ = verified(ROOT / "examples" / "gcode" / "laser-hiking.yaml")
    assert code == 0, result["problems"]
    assert result["laser"]["max_power_error_pct"] == 0.0  # M3 S255 of 255: full power exactly, 0 in between
    assert result["laser"]["cuts"] > 40


def test_build_is_deterministic_and_reports_every_byte(tmp_path, capsys):
    job = ROOT / "examples" / "arc.yaml"
    first, second = tmp_path / "one", tmp_path / "two"
    assert run(capsys, "build", job, "--out", first)[0] == 0
    assert run(capsys, "build", job, "--out", second)[0] == 0
    names = sorted(p.name for p in first.iterdir() if p.name != "report.json")
    assert "firmware.hex" in names and "firmware.elf" in names
    for name in names:
        assert (first / name).read_bytes() == (second / name).read_bytes(), name
    report = json.loads((first / "report.json").read_text())
    image = report["image"]
    assert sum(image["flash_parts"].values()) == image["flash_bytes"]  # every byte accounted for
    assert image["flash_parts"]["table"] == image["table_bytes"]
    assert 0 < image["table_bytes"] < image["flash_bytes"] <= image["flash_capacity"] == 262144
    assert report["plan"]["pass"] is True


def test_trace_csv_has_one_row_per_step(tmp_path, capsys):
    trace = tmp_path / "steps.csv"
    code, out, _ = run(capsys, "verify", ROOT / "examples" / "line.yaml", "--out", tmp_path / "b",
                       "--json", "--trace", trace)
    assert code == 0
    result = json.loads(out)
    rows = trace.read_text().splitlines()
    assert rows[0] == "time_s,motor,dir,phase"
    assert len(rows) - 1 == sum(m["steps"] for m in result["motors"].values())
    t, motor, direction, phase = rows[1].split(",")
    assert motor in ("x", "y") and direction in ("1", "-1") and phase == "run" and float(t) > 0


def test_misspelt_key_is_exit_2_with_position_and_no_image(tmp_path, capsys):
    job = tmp_path / "bad.yaml"
    job.write_text((ROOT / "examples" / "line.yaml").read_text().replace("max_accel: 2000, range",
                                                                          "max_acel: 2000, range", 1))
    code, _, err = run(capsys, "build", job, "--out", tmp_path / "out")
    assert code == 2
    assert "bad.yaml:8:" in err and "max_acel" in err and "max_accel" in err
    assert not (tmp_path / "out").exists()


def test_bad_expression_points_at_its_column(tmp_path, capsys):
    job = tmp_path / "bad.yaml"
    text = (ROOT / "examples" / "function.yaml").read_text()
    job.write_text(text.replace("exp(-x / 30)", "exq(-x / 30)"))
    code, _, err = run(capsys, "plan", job)
    assert code == 2
    line = next(i for i, l in enumerate(job.read_text().splitlines(), 1) if "exq" in l)
    col = job.read_text().splitlines()[line - 1].index("exq") + 1
    assert f"bad.yaml:{line}:{col}: error:" in err
    assert "exp" in err


def test_job_too_big_for_flash_is_exit_1_with_sizes_and_no_image(tmp_path, capsys):
    job = tmp_path / "big.yaml"
    job.write_text("""
name: big
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 80, max_velocity: 150, max_accel: 2000}
    y: {steps_per_mm: 80, max_velocity: 150, max_accel: 2000}
program:
  feed: 3000
  shapes:
    - sine: {origin: [0, 100], amplitude: 60, omega: 1.3, phase: 0, length: 1000}
""")  # about 314 KB of tables (the compact stream, on curves timed along the curve)
    code, _, err = run(capsys, "build", job, "--out", tmp_path / "out")
    assert code == 1
    assert "262144" in err and "bytes" in err
    assert not (tmp_path / "out" / "firmware.hex").exists()


def test_tool_pin_follows_draw_and_travel(verified, planned_example):
    from codegen.sim.avr import simulate

    code, _, out = verified(ROOT / "examples" / "plotter-set.yaml")  # its image, built as `build` builds it
    assert code == 0
    host = planned_example("plotter-set.yaml")
    trace = simulate(out / "firmware.hex", host.firmware_config(), 10 * 16_000_000 * 60)
    levels = [level for _, level in trace.tool_edges]
    tool = host.schedule.block_tool.astype(int).tolist()
    changes = [b for a, b in zip([0] + tool, tool + [0]) if a != b]
    assert levels == changes  # on for each of the 5 shapes, off for each travel between them and at the end
    assert levels.count(1) == 5


def test_a_program_that_moves_nothing_plays_nothing(tmp_path, capsys):
    job = tmp_path / "still.yaml"
    job.write_text((ROOT / "examples" / "line.yaml").read_text().replace(
        "- line: {from: [10, 10], to: [90, 55]}", "- travel: {to: [0, 0]}"))
    code, out, _ = run(capsys, "verify", job, "--out", tmp_path / "out", "--json")
    result = json.loads(out)
    assert code == 0 and result["pass"]
    assert all(m["steps"] == 0 and m["final"] == 0 for m in result["motors"].values())


def test_target_override_never_builds_for_the_wrong_chip(tmp_path, capsys):
    code, _, err = run(capsys, "build", ROOT / "examples" / "line.yaml", "--target", "mcs51", "--out", tmp_path)
    assert code == 2 and "line.yaml:4:8: error: board: 'ramps-1.4' is a board for target avr, not mcs51" in err
    assert not (tmp_path / "firmware.hex").exists()


@pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None, reason="needs sdcc and s51")
@pytest.mark.parametrize("example", ["arc", "star"])
def test_small_jobs_verify_on_the_8051_in_s51(example, tmp_path, capsys):
    job = tmp_path / f"{example}.yaml"  # without the star's feed hold keys: the 8051's player has no hold yet
    job.write_text((ROOT / "examples" / f"{example}.yaml").read_text().replace("  feed_hold: {}", "  # feed_hold"))
    code, out, _ = run(capsys, "verify", job, "--target", "mcs51", "--out", tmp_path / "out", "--json")
    result = json.loads(out)
    assert code == 0, result["problems"]
    for motor in result["motors"].values():
        assert motor["final"] == motor["expected_final"]
        assert motor["max_timing_error_us"] <= 5.0 and motor["max_rate_ratio"] <= 1.0
    assert result["max_path_error_mm"] <= result["path_limit_mm"]
    assert result["image"]["flash_bytes"] <= 8192


@pytest.mark.skipif(shutil.which("sdcc") is None, reason="needs sdcc")
def test_a_job_too_big_for_the_8051_is_refused_with_sizes(tmp_path, capsys):
    code, _, err = run(capsys, "build", ROOT / "examples" / "plotter-set.yaml", "--target", "mcs51",
                       "--out", tmp_path)
    assert code == 1 and "does not fit" in err and "8192" in err
    assert not (tmp_path / "firmware.hex").exists()


def test_plan_says_when_the_tables_alone_overflow_the_flash(capsys):
    """`plan` tells before `build` does: the seed plotter set's tables are more than the AT89C52's code memory."""
    job = ROOT / "examples" / "stream" / "plotter-set-seed51.yaml"
    code, out, _ = run(capsys, "plan", job, "--json")
    tables = json.loads(out)["table_bytes"]
    assert code == 0 and tables > 8192
    code, out, _ = run(capsys, "plan", job)
    assert code == 0 and out.splitlines()[-1] == (f"  too big for a flash image: the tables alone are {tables} bytes, "
                                                  "the at89c52 has 8192; stream the job (--stream)")


def test_driver_timing_from_the_job_holds_in_the_simulator(tmp_path, capsys):
    job = tmp_path / "slow-drivers.yaml"
    job.write_text((ROOT / "examples" / "star.yaml").read_text().replace(
        "junction_deviation: 0.02", "junction_deviation: 0.02\n  step_pulse_us: 6\n  dir_setup_us: 4"))
    code, out, _ = run(capsys, "verify", job, "--out", tmp_path / "out", "--json")
    result = json.loads(out)
    assert code == 0, result["problems"]
    for motor in result["motors"].values():
        assert motor["min_pulse_us"] >= 6.0
        assert motor["min_dir_setup_us"] >= 4.0


def test_sliced_benchy_plans_near_the_slicer_estimate_and_does_not_fit(tmp_path, capsys):
    job = ROOT / "examples" / "printers" / "benchy-mini.yaml"
    code, out, err = run(capsys, "plan", job, "--json")
    assert code == 0
    result = json.loads(out)
    slicer = 38 * 60 + 43  # "; estimated printing time (normal mode) = 38m 43s"
    assert abs(result["duration_s"] - slicer) <= 0.10 * slicer
    assert "warning: 'M73' ignored" in err
    assert (result["mcu"], result["flash_bytes"]) == ("atmega2560", 262144) and result["table_bytes"] > 262144
    code, _, err = run(capsys, "build", job, "--out", tmp_path)
    assert code == 1
    assert "does not fit in flash" in err and "262144" in err and str(result["table_bytes"]) in err
    assert not (tmp_path / "firmware.hex").exists()


def test_a_point_outside_a_motor_range_is_an_error_at_its_shape(tmp_path, capsys):
    job = tmp_path / "far.yaml"
    job.write_text((ROOT / "examples" / "line.yaml").read_text().replace("to: [90, 55]", "to: [90, 255]"))
    code, _, err = run(capsys, "build", job, "--out", tmp_path / "out")
    assert code == 2
    assert "far.yaml:15:7: error: motor y would go to 255.000 mm, outside its range [0, 200]" in err
    assert not (tmp_path / "out").exists()


def test_delta_homing_with_a_switch_that_never_closes_fails_verification(verified, planned_example):
    from codegen.sim.avr import simulate
    from codegen.verify.compare import compare, simulated_switches

    code, _, out = verified(ROOT / "examples" / "kossel-mini.yaml")  # its image, built as `build` builds it
    assert code == 0
    host = planned_example("kossel-mini.yaml")
    switches = simulated_switches(host)
    switches[2] = None  # tower c's switch is broken
    trace = simulate(out / "firmware.hex", host.firmware_config(), 16_000_000 * 60, switches=switches)
    verdict = compare(host, trace, switches)
    assert trace.homing_failed and not verdict.ok
    assert any(p.startswith("homing failed in the fast approach: motor c") for p in verdict.problems), verdict.problems
    c = host.homing[2]
    assert verdict.homing["c"]["steps"] == c.max_steps  # it gave up after the tower's travel, no endless motion
    assert not np.any(np.asarray(trace.step_phase) == "run")  # and played nothing of the program


def test_trace_marks_homing_steps(tmp_path, capsys):
    trace = tmp_path / "steps.csv"
    code, out, _ = run(capsys, "verify", ROOT / "examples" / "delta-seed.yaml", "--out", tmp_path / "b",
                       "--json", "--trace", trace)
    result = json.loads(out)
    assert code == 0, result["problems"]
    phases = [row.split(",")[3] for row in trace.read_text().splitlines()[1:]]
    homing = sum(m["steps"] for m in result["homing"].values())
    assert phases[:homing] == ["home"] * homing and set(phases[homing:]) == {"run"}
    assert len(phases) - homing == sum(m["steps"] for m in result["motors"].values())


def test_delta_seed_51_homes_plays_and_shows_its_positions(verified):
    """The seed delta on its 8051 board: keys as switches, L297 half-steps, the LCD decoded in s51 showing every
    carriage's final position (steps)."""
    code, result, tmp_path = verified(ROOT / "examples" / "delta-seed-51.yaml")
    assert code == 0, result["problems"]
    final = [result["motors"][m]["end_position"] for m in "abc"]  # the display shows absolute steps
    assert result["display"] == [f"A{final[0]:>6} B{final[1]:>6} ", f"C{final[2]:>6}" + " " * 9]
    assert set(result["homing"]) == {"a", "b", "c"}
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["image"]["flash_bytes"] <= 8192 and report["image"]["sections"]["iram_used"] <= 256


def test_plotter_set_fits_one_8051_image(verified, tmp_path, capsys):
    """The seed plotter's five drawings in one 8 KB image; with the default tolerance the tables alone are too big
    and the build says so."""
    code, _, out = verified(ROOT / "examples" / "plotter-set-51.yaml")
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    assert report["image"]["flash_bytes"] <= 8192 and report["image"]["flash_parts"]["table"] > 5000
    fine = tmp_path / "fine.yaml"
    fine.write_text((ROOT / "examples" / "plotter-set-51.yaml").read_text().replace("tolerance: 0.0125", "tolerance: 0.002"))
    code, out, err = run(capsys, "build", fine, "--out", tmp_path / "fine")
    assert code == 1 and "8192" in err and "machine.tolerance" in err
    assert not (tmp_path / "fine" / "firmware.hex").exists()


SHAPED = """\
name: shaped-square
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
    y: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
  input_shaper: {x: {type: mzv, freq: 50}, y: {type: ei, freq: 40}, max_smoothing: 0.5}
program:
  start: [10, 10]
  feed: 6000
  shapes:
    - polyline: {points: [[10, 10], [60, 10], [60, 60], [10, 60], [10, 10]]}
    - circle: {center: [35, 35], radius: 20}
"""


def test_a_shaped_job_verifies_in_simavr(tmp_path, capsys):
    """Input shaping (issue 29): the image plays the shaped steps the twin predicts, every limit holds on the
    simulated pulses, and `plan` reports the smoothing."""
    job = tmp_path / "shaped.yaml"
    job.write_text(SHAPED)
    code, out, _ = run(capsys, "verify", job, "--out", tmp_path / "out", "--json")
    result = json.loads(out)
    assert code == 0 and result["pass"] is True, result["problems"]
    for motor in result["motors"].values():
        assert motor["final"] == motor["expected_final"]
        assert motor["max_rate_ratio"] <= 1.0 and motor["max_accel_ratio"] <= 1.0
    assert result["max_path_error_mm"] <= result["path_limit_mm"]
    code, out, _ = run(capsys, "plan", job, "--json")
    shaper = json.loads(out)["input_shaper"]
    assert code == 0 and 0.0 < shaper["smoothing_mm"] < 0.5
    assert shaper["axes"]["y"] == {"type": "ei", "freq_hz": 40.0, "damping": 0.1}


def test_a_shaped_gcode_job_verifies_against_its_program(tmp_path, capsys):
    """The G-code read again (codegen/verify/program_check.py) with the shaper's smoothing as its room: arcs,
    a helix, dwells, G91, G20 and the laser, shaped on x and y."""
    job = tmp_path / "mixed-shaped.yaml"
    job.write_text((ROOT / "examples" / "gcode" / "mixed.yaml").read_text().replace(
        "  laser: {pwm_hz: 1000}", "  laser: {pwm_hz: 1000}\n  input_shaper: {x: {type: mzv, freq: 50}, "
        "y: {type: zvd, freq: 45}}"))
    code, out, _ = run(capsys, "verify", job, "--out", tmp_path / "out", "--json")
    result = json.loads(out)
    assert code == 0 and result["pass"] is True, result["problems"]

"""Heaters through the command line, with the real avr-gcc and simavr: a sliced file's start sequence builds into
the flash image's tables as runtime records (pins from the board file), `verify` runs it against the thermal
plants, holds at its waits, reports each heater and still compares the pulses with the twin; `--fault` trips the
protection; settings between moves are played; a job without heaters builds as before."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from codegen.cli.main import main
from codegen.firmware.avr.image import render_sources
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.tables.schedule import RT_TARGET_BED, RT_TARGET_HOTEND, RT_WAIT
from tests.helpers import GCODE_DATA
from tests.helpers import run_cli as run

CURA = GCODE_DATA / "slicer" / "puzzle-cura.gcode"
CURA_START_LINES = 32  # M190 S50, M104 S195, M109 S195, G28 X0 Y0, G28 Z0, ... and the skirt's first moves
JOB = """name: {name}
target: {target}
{board}machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
    y: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
{heaters}program:
  gcode: {gcode}
"""
HEATER_FILES = ["heaters.c", "heaters.h", "heaters_hook.S", "heaters_table.c"]

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


def job_file(folder: Path, name: str, gcode: str, target: str = "avr", heaters: str = "",
             board: str = "") -> Path:
    """A cartesian printer (x, y; z and e as well for the sliced file) running `gcode`, written beside it."""
    (folder / f"{name}.gcode").write_text(gcode)
    text = JOB.format(name=name, target=target, board=board, heaters=heaters, gcode=f"{name}.gcode")
    if "G1 Z" in gcode:
        text = text.replace("program:", "    z: {steps_per_mm: 400, max_velocity: 12, max_accel: 400}\n"
                                        "    e: {steps_per_mm: 100, max_velocity: 80, max_accel: 5000}\nprogram:")
    path = folder / f"{name}.yaml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def cura(tmp_path_factory) -> Path:
    """Cura's start code and the skirt's first moves, without its end code: the image holds its heaters."""
    start = "".join(CURA.read_text().splitlines(keepends=True)[:CURA_START_LINES])
    assert start.startswith(";FLAVOR:RepRap\n;TIME:3485\n;Generated with Cura_SteamEngine 2.3.1\n"
                            "M190 S50\nM104 S195\nM109 S195\n") and "M104 S0" not in start
    return job_file(tmp_path_factory.mktemp("cura"), "cura-start", start)


@pytest.fixture(scope="module")
def cura_verified(cura, tmp_path_factory) -> dict:
    """`verify --json --trace` of the Cura start, once for the tests below."""
    trace = tmp_path_factory.mktemp("trace") / "trace.csv"
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["verify", str(cura), "--out", str(cura.parent / "out"), "--json", "--trace", str(trace)])
    return {"code": code, "result": json.loads(out.getvalue()), "err": err.getvalue(), "trace": trace,
            "out": cura.parent / "out"}


def test_cura_start_heats_waits_then_moves_like_the_twin(cura, cura_verified):
    """Both heaters reach their targets within the issue's limits; the player holds at the start sequence's
    waits in program order (homing first, then M190 for the bed, then M109 for the hot end, which M104 only sets
    after M190: Marlin's order too), each hold in the result; the pulses are the twin's from the last resume; the
    image holds its heaters after the table, so the run ends after it without a budget failure."""
    result = cura_verified["result"]
    gcode = cura.with_suffix(".gcode")
    assert cura_verified["err"].splitlines()[::3] == [
        f"{gcode}:19:1: warning: 'M117' ignored (display message)",
        f"{gcode}:4:1: note: the machine has no `heaters:` section: board ramps-1.4's defaults are used (hotend "
        "and bed: EPCOS 100K B57560G104F on a 4.7 kOhm pull-up; hot end PID kp 35, ki 2.5, kd 80; bed bang-bang "
        "0.5 degC)"]
    assert cura_verified["code"] == 0 and result["pass"] and result["problems"] == []
    hot, bed = result["heaters"]["hotend"], result["heaters"]["bed"]
    print(hot, bed, result["table_start_s"], result["holds"])
    assert (hot["target_c"], hot["trip"], bed["target_c"], bed["trip"]) == (195.0, None, 50.0, None)
    assert (hot["time_to_target_s"], hot["settled_s"], bed["time_to_target_s"], bed["settled_s"]) == (
        79.299, 150.0, 68.247, 71.8)  # the default plants and gains from 25 degC, each from when it was set
    assert hot["overshoot_c"] <= 3.0 and hot["band_c"] <= 1.0  # the limits (0.0 and 0.98 degC)
    assert bed["overshoot_c"] <= 1.5 and bed["band_c"] <= 1.5  # bang-bang, 0.5 degC of hysteresis (0.70, 0.98)
    assert [h["heaters"] for h in result["holds"]] == [["bed"], ["hotend"]]
    bed_hold, hot_hold = result["holds"]
    assert bed_hold["at_s"] < bed["settled_s"] <= bed_hold["at_s"] + bed_hold["waited_s"] < hot_hold["at_s"]
    assert hot_hold["at_s"] + hot_hold["waited_s"] == pytest.approx(result["table_start_s"], abs=0.01)
    assert result["faults"] == [] and all(m["max_timing_error_us"] < 2 for m in result["motors"].values())
    assert result["duration_s"] == pytest.approx(result["planned_duration_s"], rel=1e-3)

    rows = [line.split(",") for line in cura_verified["trace"].read_text().splitlines()[1:]]
    first_home = next(float(t) for t, _, _, phase in rows if phase == "home")
    first_run = next(float(t) for t, _, _, phase in rows if phase == "run")
    assert first_home < bed_hold["at_s"]  # homing (G28 X0 Y0, G28 Z0) before the table
    assert hot["settled_s"] < result["table_start_s"] < first_run < result["table_start_s"] + 0.01


def test_report_and_plan_account_for_the_heaters(cura, cura_verified, capsys):
    """report.json: the heaters' code and ADC tables in flash, their variables in RAM, every byte counted;
    plan --json: each heater's settings and waits in the tables, its last target, its pins and ADC table."""
    image = json.loads((cura_verified["out"] / "report.json").read_text())["image"]
    flash, ram = image["flash_parts"], image["ram_parts"]
    assert flash["heater_tables"] == 4096 and 1500 < flash["heaters"] < 3000
    assert sum(flash.values()) == image["flash_bytes"] and sum(ram.values()) == image["ram_bytes"]
    assert 100 < ram["heaters"] < image["ram_bytes"]
    code, out, _ = run(capsys, "plan", cura, "--json")
    assert code == 0 and json.loads(out)["heaters"] == {
        "hotend": {"settings": 2, "waits": 1, "last_target_c": 195.0, "pwm_pin": "PB4", "sensor_pin": "PK5",
                   "table_bytes": 2048},
        "bed": {"settings": 1, "waits": 1, "last_target_c": 50.0, "pwm_pin": "PH5", "sensor_pin": "PK6",
                "table_bytes": 2048}}


def test_thermistor_open_during_the_moves_trips_and_stops(cura, cura_verified, capsys):
    """The hot end's thermistor opens halfway through the table: sensor_open within a period, every heater pin
    low, the steppers stopped, the pulses before the trip the twin's first; exit 1 with the reason."""
    result = cura_verified["result"]
    at = result["table_start_s"] + result["planned_duration_s"] / 2
    code, out, _ = run(capsys, "verify", cura, "--out", cura.parent / "out", "--json", "--fault",
                       f"thermistor-open@{at:.2f}")
    result = json.loads(out)
    print(result["trip"], {m: v["steps"] for m, v in result["motors"].items()})
    assert code == 1 and not result["pass"]
    assert result["trip"]["reason"] == "sensor_open" and result["trip"]["heater"] == "hotend"
    assert round(at, 2) <= result["trip"]["time_s"] <= round(at, 2) + 0.11
    assert result["heater_pins_low"] and result["steppers_stopped"]
    assert result["problems"] == [f"heater hotend tripped: sensor_open at {result['trip']['time_s']:.2f} s simulated"]
    made = {m: (v["steps"], v["planned_steps"]) for m, v in result["motors"].items()}
    assert 0 < sum(s for s, _ in made.values()) < sum(p for _, p in made.values())
    assert all(v["max_timing_error_us"] is None or v["max_timing_error_us"] < 2 for v in result["motors"].values())
    assert result["heaters"]["hotend"]["trip"] == "sensor_open" and result["heaters"]["bed"]["trip"] is None
    assert result["faults"] == [{"name": "thermistor-open", "heater": "hotend", "at_s": round(at, 2)}]


def test_a_dead_heater_trips_heating_failed_before_any_move(cura, cura_verified, capsys):
    """heater-dead@0: once the bed's wait is over, M104 / M109 set the hot end's target, and it does not rise
    2 degC within 20 s while the player holds for it."""
    code, out, _ = run(capsys, "verify", cura, "--out", cura.parent / "out", "--fault", "heater-dead@0")
    lines = out.splitlines()
    print("\n".join(lines))
    bed_hold = cura_verified["result"]["holds"][0]
    assert code == 1 and lines[:7] + lines[8:] == [
        f"FAIL cura-start: {cura.parent / 'out' / 'firmware.hex'} in simavr, 0.0000 s simulated, "
        f"{cura_verified['result']['planned_duration_s']:.4f} s planned",
        "  heater hotend tripped: heating_failed at 91.90 s simulated; every heater pin low, steppers stopped",
        "  x: 0 of 4688 steps before the trip",
        "  y: 0 of 5645 steps before the trip",
        "  z: 0 of 11920 steps before the trip",
        "  e: 0 of 1613 steps before the trip",
        "  heater hotend: 195 degC not reached, overshoot 0.00 degC, trip: heating_failed",
        f"  hold at {bed_hold['at_s']:.2f} s simulated for {bed_hold['waited_s']:.2f} s: waited for bed",
        "  fault heater-dead on hotend at 0 s: tripped heating_failed at 91.90 s"]
    assert lines[7].startswith("  heater bed: 50 degC reached in 68.2 s, settled at 71.8 s, overshoot 0.70 degC")


@pytest.mark.parametrize("spec, message", [
    ("thermistor-opn@3", "argument --fault: unknown fault 'thermistor-opn' (did you mean 'thermistor-open'?); "
                         "faults: thermistor-open, thermistor-short, heater-dead, thermistor-loose"),
    ("thermistor-open@-1", "argument --fault: 'thermistor-open@-1': the time after @ must be simulated seconds >= 0"),
    ("thermistor-open", "argument --fault: 'thermistor-open' is not NAME[:HEATER]@SECONDS (NAME: thermistor-open, "
                        "thermistor-short, heater-dead, thermistor-loose), e.g. thermistor-open:bed@30"),
])
def test_a_bad_fault_is_a_usage_error(cura, capsys, spec, message):
    with pytest.raises(SystemExit) as exit_:
        main(["verify", str(cura), "--fault", spec])
    assert exit_.value.code == 2 and capsys.readouterr().err.splitlines()[-1].endswith(message)


def test_a_fault_on_a_heater_the_image_lacks_is_bad_input(tmp_path, capsys):
    job = job_file(tmp_path, "hot", "M109 S200\nG1 X10 F3000\n", heaters="  heaters: {hotend: {}}\n")
    code, _, err = run(capsys, "verify", job, "--out", tmp_path / "out", "--fault", "thermistor-open:bed@3")
    assert code == 2
    assert err == "--fault: error: 'thermistor-open:bed@3': the image has no heater 'bed' (it has hotend)\n"


def test_heater_settings_between_moves_are_played(tmp_path, capsys):
    """A program that heats on a machine without `heaters:`: one note that the board's defaults are used, and
    every setting, between moves too, a runtime record at its place (no warning)."""
    gcode = "M104 S200\nM140 S60\nG1 X10 F3000\nM104 S200\nM104 S210\nG1 X20\nM140 S70\nG1 X30\nM104 S0\n"
    job = job_file(tmp_path, "mid", gcode)
    code, _, err = run(capsys, "plan", job)
    g = tmp_path / "mid.gcode"
    assert code == 0 and err == (
        f"{g}:1:1: note: the machine has no `heaters:` section: board ramps-1.4's defaults are used (hotend and "
        "bed: EPCOS 100K B57560G104F on a 4.7 kOhm pull-up; hot end PID kp 35, ki 2.5, kd 80; bed bang-bang "
        "0.5 degC)\nM104 S200\n^\n")
    host = host_build(load_job(job))
    assert [h.name for h in host.heaters] == ["hotend", "bed"]
    sched = host.schedule
    assert list(zip(sched.runtime_block, sched.runtime_command, sched.runtime_value)) == [
        (0, RT_TARGET_HOTEND, 2000), (0, RT_TARGET_BED, 600), (1, RT_TARGET_HOTEND, 2000),
        (1, RT_TARGET_HOTEND, 2100), (2, RT_TARGET_BED, 700), (3, RT_TARGET_HOTEND, 0)]


def test_the_settings_cross_from_the_front_end_process(tmp_path, monkeypatch):
    """The front end may run in a child process: its heater settings and warnings reach the build either way."""
    gcode = "M190 S60\nM109 S210\n" + "".join(f"G1 X{k % 50} Y{k % 7} F6000\n" for k in range(1, 9000)) + \
            "M140 S50\nG1 X0 Y0\nM104 S0\nM140 S0\n"
    job = load_job(job_file(tmp_path, "long", gcode))
    child = host_build(job, keep=False)
    monkeypatch.setenv("PRINTER_CODEGEN_JOBS", "1")
    here = host_build(job, keep=False)
    assert child.heater_program == here.heater_program and child.warnings == here.warnings
    for field in ("item", "command", "value"):
        assert np.array_equal(getattr(child.runtime, field), getattr(here.runtime, field))
    assert list(zip(here.runtime.command, here.runtime.value)) == [
        (RT_TARGET_BED, 600), (RT_WAIT, 2), (RT_TARGET_HOTEND, 2100), (RT_WAIT, 1), (RT_TARGET_BED, 500),
        (RT_TARGET_HOTEND, 0), (RT_TARGET_BED, 0)]
    assert [h.name for h in here.heaters] == ["hotend", "bed"]
    assert [(w.where.line, w.severity) for w in here.warnings] == [(1, "note")]


def test_8051_boards_have_no_heaters(tmp_path, capsys):
    """A program that heats on an 8051 board: a warning, the image without heaters; a machine that lists
    `heaters:` there: an error at the key (exit 2)."""
    job = job_file(tmp_path, "m51", "M109 S200\nG1 X10 F3000\n", target="mcs51", board="board: at89c52\n")
    code, _, err = run(capsys, "plan", job)
    assert code == 0 and err == (f"{tmp_path / 'm51.gcode'}:1:1: warning: 'M109' ignored (board at89c52 has no "
                                 "heater outputs: every heater setting of the program is ignored)\nM109 S200\n^\n")
    assert host_build(load_job(job), keep=False).heaters == ()
    listed = job_file(tmp_path, "m51h", "G1 X10 F3000\n", target="mcs51", board="board: at89c52\n",
                      heaters="  heaters: {bed: {}}\n")
    code, _, err = run(capsys, "plan", listed)
    assert code == 2 and err == (f"{listed}:9:13: error: machine.heaters: board 'at89c52' has no bed heater (it "
                                 "has no heater outputs)\n  heaters: {bed: {}}\n            ^\n")


def test_a_job_without_heaters_builds_as_before(tmp_path, capsys):
    """No heater or fan code and no `heaters:`: no heater runtime, the sources of a config without heaters, no
    heater bytes in the report (the fan, M106, brings the runtime: its records need it)."""
    fan = host_build(load_job(job_file(tmp_path, "fan", "M106 S255\nG1 X10 F3000\nM107\n")))
    assert [h.name for h in fan.heaters] == ["hotend", "bed"] and list(fan.schedule.runtime_value) == [255, 0]
    job = job_file(tmp_path, "cold", "G1 X10 F3000\nG1 Y10\n")
    host = host_build(load_job(job))
    assert host.heaters == () and host.warnings == []
    sources = render_sources(host.schedule, host.firmware_config())
    assert sorted(sources) == ["config.h", "player.c", "player_isr.S", "table.c", "table.h"]
    assert not any("heater" in text for text in sources.values())
    code, _, _ = run(capsys, "build", job, "--out", tmp_path / "out")
    image = json.loads((tmp_path / "out" / "report.json").read_text())["image"]
    assert code == 0 and sorted(image["flash_parts"]) == ["player", "ram_initial_values", "table",
                                                           "vectors_startup_libgcc"]
    assert sorted(image["ram_parts"]) == ["other", "player"] and not any(
        (tmp_path / "out" / name).exists() for name in HEATER_FILES)

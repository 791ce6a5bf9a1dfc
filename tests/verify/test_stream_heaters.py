"""The streaming ATmega2560 firmware of a printer, with its heaters (issue 12), with the real avr-gcc and simavr: the
job's heater settings and waits go over the link as runtime records and play at their place, a thermal plant sits
behind each heater's ADC input and PWM pin, the player holds at the waits and its pulses are still the twin's,
STATUS answers carry the temperatures, and every fault of a plant ends in a FAULT frame: every heater off, the
steppers stopped, the positions reported those the pulses made. ABORT turns the heaters off too."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import codegen.tables.format as tables
from codegen.cli.main import main
from codegen.cli.stream import _firmware, streamed_host
from codegen.job import load_job
from codegen.link import protocol
from codegen.link.host import HostLink
from codegen.link.serial_port import status_line
from codegen.pipeline.streaming import stream_chunks, stream_setup
from codegen.sim.avr_link import StreamSim, simulate_stream_heaters
from codegen.sim.avr_plant import Fault
from codegen.verify.compare import simulated_switches
from codegen.verify.heaters import job_plants
from tests.firmware.avr.helpers import Scripted

F_CPU = 16_000_000
PRINTER = """name: {name}
target: avr
board: ramps-1.4
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000, range: [0, 200]}}
    y: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000, range: [0, 200]}}
    z: {{steps_per_mm: 400, max_velocity: 10, max_accel: 200, range: [0, 100]}}
    e: {{steps_per_mm: 100, max_velocity: 50, max_accel: 3000}}
program:
  gcode: |
{gcode}"""
# Heat both (the bed first, as Marlin waits), move, raise the hot end mid-job and wait for it, cool down.
START = ["M140 S60", "M104 S200", "M190 S60", "M109 S200", "M106 S128", "G1 X20 Y10 F6000", "G1 X40 Y30 E2 F3000",
         "M104 S205", "G1 X10 Y40 E4", "M109 S205", "G1 X0 Y0 E5", "M107"]
COOL = ["M104 S0", "M140 S0"]
HOLD_S = 60  # a dwell at the end while the hot end holds 205 degC: the thermistor falls out there

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


def printer(folder: Path, name: str, lines: list[str]) -> Path:
    path = folder / f"{name}.yaml"
    path.write_text(PRINTER.format(name=name, gcode="".join(f"    {line}\n" for line in lines)))
    return path


def verify(job: Path, *extra) -> tuple[int, dict]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["verify", "--stream", str(job), "--out", str(job.parent / job.stem), "--json", *extra])
    return code, json.loads(out.getvalue())


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("stream-heaters")


@pytest.fixture(scope="module")
def job(folder) -> Path:
    return printer(folder, "printer", START + COOL)


@pytest.fixture(scope="module")
def verified(job) -> tuple[int, dict]:
    return verify(job)


def test_the_printer_heats_holds_at_each_wait_and_moves_like_the_twin(verified):
    code, result = verified
    assert code == 0 and result["pass"] and result["problems"] == []
    holds = result["holds"]
    assert [h["heaters"] for h in holds] == [["bed"], ["hotend"], ["hotend"]]
    assert 60 < holds[0]["waited_s"] < 120  # the bed from 25 to 60 degC, then 3 s within 2 degC
    assert holds[1]["waited_s"] < 0.01  # the hot end heated beside it
    assert 2 < holds[2]["waited_s"] < 10  # 200 -> 205 degC
    hot, bed = result["heaters"]["hotend"], result["heaters"]["bed"]
    assert (hot["target_c"], hot["trip"], bed["target_c"], bed["trip"]) == (205.0, None, 60.0, None)
    assert hot["overshoot_c"] <= 3.0 and hot["band_c"] <= 1.0 and bed["band_c"] <= 1.5
    assert [f["duty"] for f in result["fan"]] == [0.5, 0.0]  # M106 S128 (8-bit: 128 / 256), M107
    assert {m: v["final"] for m, v in result["motors"].items()} == {"x": 0, "y": 0, "z": 0, "e": 500}
    link = result["link"]
    assert link["underruns"] == 0 and link["lost_bytes"] == 0 and link["retransmits"] == 0


def test_the_plan_carries_the_settings_and_the_firmware_runs_the_heaters(job, folder, capsys):
    assert main(["plan", "--stream", str(job), "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert plan["heaters"]["hotend"]["waits"] == 2 and plan["heaters"]["bed"]["waits"] == 1
    assert main(["build", "--stream", str(job), "--out", str(folder / "built")]) == 0
    report = json.loads((folder / "built" / "report.json").read_text())
    assert {"heaters.c", "heaters_hook.S", "heaters_table.c"} <= set(report["sources"])
    assert report["image"]["flash_parts"]["heater_tables"] == 2 * 2048  # an int16 per ADC reading, per heater


def test_a_plotter_streaming_firmware_runs_no_heaters_and_says_so(folder, job, capsys):
    """A machine without an extruder or `heaters:`: its heater codes are warned about once, and its identity is
    not a printer's."""
    plotter = folder / "plotter.yaml"
    plotter.write_text(PRINTER.format(name="plotter", gcode="    M104 S200\n    G1 X10 F3000\n")
                       .replace("    e: {steps_per_mm: 100, max_velocity: 50, max_accel: 3000}\n", ""))
    assert main(["plan", "--stream", str(plotter)]) == 0
    err = capsys.readouterr().err
    assert err.count("warning") == 1 and "'M104' ignored (the machine's streaming firmware runs heaters only " \
                                           "for a machine with an extruder e or a `heaters:` section" in err
    assert stream_setup(load_job(plotter)).config.heaters == ()
    a = stream_setup(load_job(plotter)).identity
    b = stream_setup(load_job(job)).identity
    assert a != b


@pytest.mark.parametrize("fault, heater, reason, within", [
    ("thermistor-open@103", "hotend", "sensor_open", (103.0, 103.12)),  # while it moves: one period later
    ("heater-dead@0", "hotend", "heating_failed", (20.0, 20.12)),  # no rise of 2 degC in the first 20 s
    ("thermistor-short:bed@50", "bed", "sensor_short", (50.0, 50.12)),
    # Falls out during the wait for 205 degC, before it is reached: watched from there (Marlin would not).
    ("thermistor-loose@105", "hotend", "heating_failed", (125.0, 125.12)),
    # Falls out while the hot end holds 205 degC: 4 degC below for 40 s.
    ("thermistor-loose@120", "hotend", "thermal_runaway", (160.0, 160.12)),
])
def test_a_fault_trips_and_the_frame_says_where_the_machine_stopped(folder, fault, heater, reason, within):
    job = printer(folder, f"fault-{reason}", START + [f"G4 S{HOLD_S}"] + COOL)
    code, result = verify(job, "--fault", fault)
    print(result["trip"], result["problems"], {m: v["steps"] for m, v in result["motors"].items()})
    assert code == 1 and not result["pass"]
    trip = result["trip"]
    assert (trip["reason"], trip["heater"]) == (reason, heater)
    assert within[0] <= trip["time_s"] <= within[1]
    assert result["heater_pins_low"] and result["steppers_stopped"]
    # The only problem is the trip: the pulses before it are the twin's first, and the positions in the FAULT
    # frame are where they took the motors.
    assert result["problems"] == [f"heater {heater} tripped: {reason} at {trip['time_s']:.2f} s simulated"]
    assert result["heaters"][heater]["trip"] == reason


@pytest.fixture(scope="module")
def session(job):
    """The job's streaming firmware, its tables and what a host needs for them."""
    loaded = load_job(job)
    setup = stream_setup(loaded)
    image, _ = _firmware(loaded, setup, str(job.parent / "session"))
    host = streamed_host(loaded, setup, False, keep=True)
    return loaded, setup, image, host


def scripted(setup, host, actions) -> Scripted:
    data = tables.encode(host.schedule).data
    link = HostLink(stream_chunks(data, len(host.kin.motors)), len(host.kin.motors), setup.identity,
                    10 / setup.layout.baud, host.link_plan.prefill_bytes, payload=setup.budget.payload,
                    stream_bytes=host.link_plan.stream_bytes, heaters=("hotend", "bed"))
    return Scripted(link, actions=list(actions))


def test_status_during_the_wait_reports_temperatures_and_targets(session):
    loaded, setup, image, host = session
    script = scripted(setup, host, [(30.0, "request_status")])
    run, _ = simulate_stream_heaters(image.hex_path, setup.config, script, 200 * F_CPU,
                                     job_plants(loaded, setup.config), (), simulated_switches(host))
    status = script.link.status
    assert script.link.outcome == "finished" and status.state == "playing"
    (hot, hot_target), (bed, bed_target) = status.heaters
    assert (hot_target, bed_target) == (200.0, 60.0)
    at = np.searchsorted(run.heaters["hotend"].read_s, 30.0)  # the firmware's own readings at 30 s
    for temp, name in ((hot, "hotend"), (bed, "bed")):
        readings = setup.config.heaters[("hotend", "bed").index(name)].table
        near = [readings[r] / 10 for r in run.heaters[name].reading[at - 2:at + 1]]
        assert min(near) <= temp <= max(near)
    assert 25 < bed < 60 and 25 < hot < 200
    assert status_line(status, ("x", "y", "z", "e"), ("hotend", "bed")) == (  # as `stream` shows it
        f"playing, ring {status.fill} B, x +0 y +0 z +0 e +0, hotend {hot:.1f}/200 degC, bed {bed:.1f}/60 degC")


def test_abort_during_the_wait_stops_and_turns_the_heaters_off(session):
    loaded, setup, image, host = session
    script = scripted(setup, host, [(30.0, "abort")])
    with StreamSim(image.hex_path, setup.config, simulated_switches(host), job_plants(loaded, setup.config)) as sim:
        sim.session(script, 60 * F_CPU)
        aborted = sim.last.cycle
        sim.exchange(b"", aborted + 2 * F_CPU, aborted + 3 * F_CPU)  # 2 s more, nothing on the line
        per, end = sim.plant_trace()
    assert script.link.outcome == "aborted" and script.link.position == (0, 0, 0, 0)
    assert all(end["H"][k] == 0 for k in (0, 1))
    for trace in per.values():  # heating until the ABORT, off from the frame on
        assert trace.duty[trace.time_s < 29.9].max() > 0
        after = trace.time_s >= aborted / F_CPU
        assert after.sum() >= 19 and np.all(trace.duty[after] == 0)


def test_a_trip_between_jobs_is_reported_and_nothing_plays_after_it(folder):
    """A job that leaves its heaters on: the thermistor opens after it has finished; the firmware reports the
    trip at once (FAULT, while idle), and answers the next session's START with it again."""
    job = printer(folder, "keeps-hot", START)
    loaded = load_job(job)
    setup = stream_setup(loaded)
    image, _ = _firmware(loaded, setup, str(folder / "keeps-hot-fw"))
    host = streamed_host(loaded, setup, False, keep=True)
    faults = (Fault("hotend", "thermistor-open", 120.0),)
    with StreamSim(image.hex_path, setup.config, simulated_switches(host), job_plants(loaded, setup.config),
                   faults) as sim:
        first = scripted(setup, host, [])
        sim.session(first, 200 * F_CPU)
        assert first.link.outcome == "finished" and sim.last.cycle < 120 * F_CPU
        idle = sim.exchange(b"", 125 * F_CPU, 130 * F_CPU)  # nothing on the line: the firmware alone
        frames = protocol.Parser(protocol.MAX_ANSWER).feed(idle.data)
        assert [f.kind for f in frames] == [protocol.FAULT]
        fault = protocol.Fault.parse(frames[0].payload, 4)
        assert (fault.reason, fault.heater, fault.position) == ("sensor_open", 0, first.link.position)
        second = scripted(setup, host, [])
        sim.session(second, 10 * F_CPU)
        assert second.link.outcome == "fault" and second.link.fault.reason == "sensor_open"
        assert "heater hotend tripped: sensor_open" in second.link.message
        per, end = sim.plant_trace()
    assert all(end["H"][k] == 0 for k in (0, 1))


def test_a_machine_with_one_heater_on_another_board(folder):
    """`heaters:` lists the hot end only, on an MKS GEN L: the firmware counts one heater's RAM (an odd .data) and
    the bed's codes are warned about."""
    job = folder / "one-heater.yaml"
    job.write_text(PRINTER.format(name="one-heater", gcode="".join(f"    {line}\n" for line in START + COOL))
                   .replace("board: ramps-1.4", "board: mks-gen-l")
                   .replace("program:", "  heaters:\n    hotend: {max_temp_c: 260}\nprogram:"))
    code, result = verify(job)
    assert code == 0 and result["pass"] and list(result["heaters"]) == ["hotend"]
    assert [h["heaters"] for h in result["holds"]] == [["hotend"], ["hotend"]]


DELTA = """name: delta-printer
target: avr
board: ramps-1.4
machine:
  kinematics: delta
  steppers:
    a: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
    b: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
    c: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
    e: {steps_per_mm: 100, max_velocity: 50, max_accel: 3000}
  delta: {radius: 105.2, diagonal_rod: 215, height: 250, tower_angles: [210, 330, 90]}
program:
  start: [0, 0, 250]
  gcode: |
    M109 S200
    G1 Z5 F6000
    G1 X30 Y0 E2 F3000
    G1 X0 Y0 Z20
"""


def test_a_delta_homes_with_its_heaters_on_and_a_trip_then_stops_the_homing(folder):
    """The first job leaves the hot end at 200 degC; the second homes at its START (seconds of busy-waiting in
    homing.c) with the heaters still run, and the thermistor that opens during that homing trips at once: FAULT,
    not ABORTED, the homing stopped."""
    job = folder / "delta-printer.yaml"
    job.write_text(DELTA)
    loaded = load_job(job)
    setup = stream_setup(loaded)
    assert setup.config.homing and [h.name for h in setup.config.heaters] == ["hotend", "bed"]
    image, _ = _firmware(loaded, setup, str(folder / "delta-fw"))
    host = streamed_host(loaded, setup, False, keep=True)
    first = scripted(setup, host, [])  # a run without the fault says when the first job ends (runs are exact)
    with StreamSim(image.hex_path, setup.config, simulated_switches(host), job_plants(loaded, setup.config)) as sim:
        sim.session(first, 200 * F_CPU)
        ended = sim.last.cycle / F_CPU
    assert first.link.outcome == "finished"
    at = ended + 1.0  # one second into the second session's homing (it takes about 4 s)
    first, second = scripted(setup, host, []), scripted(setup, host, [])
    with StreamSim(image.hex_path, setup.config, simulated_switches(host), job_plants(loaded, setup.config),
                   (Fault("hotend", "thermistor-open", at),)) as sim:
        sim.session(first, 200 * F_CPU)
        begun = sim.last.cycle / F_CPU
        sim.session(second, 20 * F_CPU)
        per, end = sim.plant_trace()
    assert second.link.outcome == "fault" and second.link.fault.reason == "sensor_open"
    assert protocol.STARTED not in second.arrived and at <= second.link.fault_at <= at + 0.12  # within its homing
    reads = per[0].read_s[(per[0].read_s > begun) & (per[0].read_s < at)]
    assert len(reads) >= 8 and np.all(np.abs(np.diff(reads) - 0.1) < 0.01)  # a period's reading every 0.1 s
    assert all(end["H"][k] == 0 for k in (0, 1))

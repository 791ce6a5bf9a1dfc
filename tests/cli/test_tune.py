"""`printer-codegen tune`: the tune firmware with the real avr-gcc, its relay in simavr against the thermal plant
(the gains against the Python relay's, and what they do), the protection stopping a dead heater, no division or
float in the image, and the host's bias update against Marlin's formula."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from dataclasses import replace
from fractions import Fraction

import pytest
import yaml

from codegen.cli.main import main
from codegen.firmware.avr.toolchain import NOT_INTEGER_ONLY, check_integer_only
from codegen.firmware.avr.tune import build_tune_image, tune_setup
from codegen.heaters.control import fixed_gains
from codegen.heaters.plant import heating_figures, simulate
from codegen.heaters.tuning import Relay, RelayLoop, Switch, marlin_bias, relay_test
from codegen.job import load_job
from codegen.link import protocol
from codegen.link.tune import READY, STARTED, TuneHost
from codegen.pipeline.host import host_build
from codegen.sim.avr_plant import Fault, HeaterPlant, heater_summary, simulate_heaters
from codegen.sim.avr_tune import TuneSim, simulate_tune
from codegen.sim.pty_bridge import PtyBridge
from codegen.verify.heaters import job_plants
from tests.helpers import HEATERS_JOB, ROOT

JOB = ROOT / "examples" / "printers" / "benchy-mini.yaml"  # RAMPS 1.4, no `heaters:`: the board's defaults

TUNED_GCODE = "M109 S210\nM190 S60\nG1 X10 F3000\nG4 S30\nG1 X0\n"
needs_tools = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                 reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


def marlin(bias: int, d: int, t_high: int, t_low: int, max_pow: int = 255) -> tuple[int, int]:
    """Marlin's PID_autotune, literally: bias += (d * (t_high - t_low)) / (t_low + t_high) in C's long division;
    LIMIT(bias, 20, max_pow - 20); d = (bias > max_pow >> 1) ? max_pow - 1 - bias : bias."""
    q = Fraction(d * (t_high - t_low), t_low + t_high)
    bias += int(q)  # int() of a Fraction truncates towards zero, as C does
    bias = min(max(bias, 20), max_pow - 20)
    return bias, (max_pow - 1 - bias if bias > max_pow >> 1 else bias)


@pytest.fixture(scope="module")
def hotend_image(tmp_path_factory):
    image = tune_setup(load_job(JOB), "hotend")
    return image, build_tune_image(image, tmp_path_factory.mktemp("tune"))


@needs_tools
def test_sim_tune_gains_match_the_python_relay_and_hold_the_hot_end(tmp_path, capsys):
    code = main(["tune", str(JOB), "--sim", "--json", "--out", str(tmp_path)])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and result["outcome"] == "finished" and len(result["cycles"]) == 5
    heater = tune_setup(load_job(JOB), "hotend").heater
    python = relay_test(heater.plant, heater.sensor, 210.0).gains()
    sim = result["gains"]
    for name, reference in zip(("kp", "ki", "kd"), python):
        assert sim[name] == pytest.approx(reference, rel=0.10), name
    fig = heating_figures(simulate(heater.plant, fixed_gains(sim["kp"], sim["ki"], sim["kd"]), 300, heater.sensor,
                                   210.0), 210.0)
    assert fig.overshoot_c <= 3.0 and fig.band_c <= 1.0
    assert result["check"]["overshoot_c"] == pytest.approx(fig.overshoot_c)
    machine = yaml.safe_load(result["snippet"])  # ready to paste under machine:
    assert machine["heaters"]["hotend"]["control"]["pid"]["kp"] == pytest.approx(sim["kp"], rel=1e-3)
    assert machine["heaters"]["bed"]["control"] == {"bang_bang": {"hysteresis_c": 0.5}}
    # The firmware with those gains, in simavr against the plant: 25 -> 210 degC (alone: its figures count from
    # 25 degC) within 3 degC of overshoot, then held within 1 degC from 30 s after it first came within 1 degC
    # (through the bed's wait and the moves); the bed to 60 degC.
    job = tmp_path / "tuned.yaml"
    job.write_text(HEATERS_JOB.format(name="tuned", target="avr", heaters=result["snippet"]))
    (tmp_path / "tuned.gcode").write_text(TUNED_GCODE)
    assert main(["build", str(job), "--out", str(tmp_path / "tuned")]) == 0
    host = host_build(load_job(job))
    config = host.firmware_config()
    run = simulate_heaters(tmp_path / "tuned" / "firmware.hex", config, 250.0, job_plants(host.job, config))
    hot, bed = heater_summary(run, "hotend", 210.0), heater_summary(run, "bed", 60.0)
    print("tuned", sim, hot, bed)
    assert run.trip is None and 30 < hot["time_to_target_s"] < 120 and bed["time_to_target_s"] is not None
    assert hot["overshoot_c"] <= 3.0 and hot["band_c"] <= 1.0 and bed["band_c"] <= 1.5


@needs_tools
def test_a_dead_heater_stops_the_tune_with_the_protections_reason(hotend_image):
    image, hex_path = hotend_image
    dead = HeaterPlant(replace(image.heater.plant, heater_w=0.0), image.heater.sensor, image.heater.pullup_ohm)
    host = TuneHost("hotend", 210.0)
    run = simulate_tune(hex_path, image, host, dead)
    assert host.outcome == "tripped" and host.trip == "heating_failed"
    assert 20.0 <= run.seconds <= 21.0  # Marlin's WATCH_TEMP_PERIOD: no 2 degC rise within 20 s
    assert not host.relay.cycles


@needs_tools
@pytest.mark.parametrize("fault, reason", [("thermistor-open", "sensor_open"), ("thermistor-short", "sensor_short")])
def test_a_thermistor_fault_mid_relay_stops_the_tune(hotend_image, fault, reason):
    image, hex_path = hotend_image
    host = TuneHost("hotend", 210.0)
    run = simulate_tune(hex_path, image, host, HeaterPlant(image.heater.plant, image.heater.sensor),
                        faults=(Fault("hotend", fault, 100.0),))  # in the relay's first cycles
    assert host.outcome == "tripped" and host.trip == reason and host.switches
    assert run.plant.duty[-1] == 0 and run.plant.duty_s[-1] <= 100.2


@needs_tools
def test_the_tune_firmware_links_no_division_or_float(hotend_image):
    _image, hex_path = hotend_image
    elf = hex_path.with_suffix(".elf")
    check_integer_only(elf, elf.parent)  # the build's own check, again on the image it left
    symbols = subprocess.run(["avr-nm", "--defined-only", str(elf)], capture_output=True, text=True,
                             check=True).stdout.split("\n")
    names = [line.split()[-1] for line in symbols if line.strip()]
    assert {"main", "__vector_25", "__vector_32"} <= set(names)  # USART0_RX and TIMER3_COMPA: its interrupts
    assert not [n for n in names if NOT_INTEGER_ONLY.match(n)]


@needs_tools
def test_the_firmwares_relay_is_relay_loop_and_the_hosts_bias_updates_are_marlins(hotend_image):
    image, hex_path = hotend_image
    host = TuneHost("hotend", 210.0, cycles=5)
    run = simulate_tune(hex_path, image, host, HeaterPlant(image.heater.plant, image.heater.sensor))
    # The C relay switched where RelayLoop does on the same readings, the host's answers applied at once.
    table, relay = image.heater.table(), Relay()
    loop = RelayLoop(2100, relay.bias, relay.d)
    switches = []
    for adc in run.plant.adc[:host.switches[-1].period + 1]:
        s = loop.step(int(table[adc]))
        if s is not None:
            switches.append(s)
            update = relay.switch(s)
            if update is not None:
                loop.bias, loop.d = update
    assert switches == host.switches
    # Each cycle's duties follow from the phases before it by Marlin's formula.
    heatings = [s for s in host.switches if s.heating]
    coolings = [s for s in host.switches if not s.heating]
    bias = d = 127
    for k, cycle in enumerate(host.relay.cycles):  # cycle k: heating phase k + 1, cooling phase k + 1
        assert (cycle.high_duty, cycle.low_duty) == (bias + d, bias - d)
        bias, d = marlin(bias, d, coolings[k + 1].length, heatings[k + 1].length)


def test_marlin_bias_truncates_towards_zero_like_c():
    for case in [(127, 127, 820, 50), (100, 100, 40, 60), (200, 54, 1, 2), (30, 30, 1, 50), (235, 19, 7, 3)]:
        assert marlin_bias(*case) == marlin(*case), case


def test_the_relay_loop_reports_what_the_host_needs():
    """The firmware's relay (RelayLoop, which tune.c mirrors) on a made-up reading: its switches, in order."""
    loop, relay = RelayLoop(2100, 127, 127, dwell=2), Relay()
    readings = [2000, 2050, 2110, 2120, 2105, 2090, 2080, 2095, 2115, 2101, 2099, 2060]
    switches = [s for s in (loop.step(t) for t in readings) if s is not None]
    assert switches == [Switch(2, False, 2, 2110), Switch(5, True, 3, 2000), Switch(8, False, 3, 2120),
                        Switch(10, True, 2, 2080)]
    assert [relay.switch(s) for s in switches] == [None, None, None, marlin_bias(127, 127, 3, 2)]
    assert relay.cycles[0].t_max_c == 212.0 and relay.cycles[0].t_min_c == 208.0


@needs_tools
def test_tune_over_a_port_and_ctrl_c_turns_the_heater_off(hotend_image, tmp_path):
    """The real command on a pseudo-terminal whose other end is the tune firmware in simavr, paced to the wall
    clock (codegen/sim/pty_bridge.py): Ctrl-C 3 s into the relay sends OFF, the heater goes off, exit 130."""
    image, hex_path = hotend_image
    h = image.heater
    sim = TuneSim(hex_path, image, HeaterPlant(h.plant, h.sensor, h.pullup_ohm))
    try:
        with PtyBridge(motors=0, deadline_s=30.0, interrupt=(STARTED, 3.0)) as bridge:
            process = subprocess.Popen([sys.executable, "-m", "codegen", "tune", str(JOB), "--port", bridge.port,
                                        "--quiet", "--out", str(tmp_path)], stdout=subprocess.PIPE,
                                       stderr=subprocess.PIPE, text=True, cwd=ROOT)
            bridge.attach(process)
            sim.drive(bridge, limit_s=30.0)
            out, err = process.communicate(timeout=10)
        sim.close()
        log = sim.plant_log()
    finally:
        sim.close()
        sim.cleanup()
    assert process.returncode == 130, err
    assert "stopped" in out and bridge.interrupted_at is not None
    assert log.temp_c.max() > 30.0  # it heated for 3 s at full power
    assert log.duty[-1] == 0 and bridge.interrupted_at < log.duty_s[-1] < bridge.interrupted_at + 0.5


def test_the_host_refuses_a_board_without_the_right_tune_firmware():
    streaming = TuneHost("hotend", 210.0)
    streaming.transmit(0.0)  # HELLO
    streaming.receive(protocol.frame(protocol.IDENT, 1, bytes(8)), 0.01)
    assert streaming.outcome == "failed" and "streaming firmware" in streaming.error
    bed = TuneHost("hotend", 210.0)
    bed.transmit(0.0)
    bed.receive(protocol.frame(READY, 0, bytes([1]) + (1250).to_bytes(2, "little") + bytes([50])), 0.01)
    assert bed.outcome == "failed" and "of the bed" in bed.error
    silent = TuneHost("hotend", 210.0)
    for k in range(60):
        silent.transmit(k * 0.25)
    assert silent.outcome == "failed" and "flash the tune firmware" in silent.error

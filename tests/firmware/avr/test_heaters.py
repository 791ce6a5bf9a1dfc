"""The ATmega2560 heater runtime against thermal plants in simavr, with the real avr-gcc: heating and holding,
the duty sequence against the host's control laws, the thermal protection's trips, and a start sequence that
waits for the heaters before the table plays (its pulses still the twin's)."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest

from codegen.firmware.avr.heaters import SLICE_CYCLES, heater_firmware
from codegen.firmware.avr.image import build_image, render_sources
from codegen.firmware.config import FirmwareConfig, MotorPins
from codegen.gcode import toolpath_from_gcode
from codegen.heaters.control import bang_bang, pid_reference
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.program.heater_settings import HeaterSettings, heater_settings
from codegen.sim.avr_plant import Fault, HeaterPlant, heater_summary, simulate_heaters
from codegen.tables.format import stream_bytes
from codegen.tables.runtime import runtime_records
from codegen.tables.schedule import HEATER_COMMANDS, RT_WAIT, WAIT_MASKS
from codegen.targets import board_heater_pins
from codegen.toolpath.segments import Flattener
from codegen.verify.compare import compare, simulated_switches
from codegen.verify.heaters import on_twin_clock, settled_at
from tests.helpers import ROOT, gcode_job_file, make_schedule
from tests.reference_player import play

F_CPU = 16_000_000
CYCLES_PER_TICK = 8  # the player's 2 MHz tick
HOOK_CHECK_CYCLES = 33  # heaters_hook.S's longest way with interrupts off when it runs no stage (cli .. sei; ret)
HOOK_CYCLES = 77  # heaters_hook.S around a stage: from the check's TCNT1 read to the call, and from the return to
#                   the next check's TCNT1 read or the SEI's RET

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


@pytest.fixture(scope="module")
def settings() -> dict[str, HeaterSettings]:
    """The board's defaults (a job without `heaters:`): the hot end and the bed."""
    job = load_job(ROOT / "examples" / "star.yaml")
    return heater_settings(job)


def with_targets(schedule, targets, wait, end_off):
    """`schedule` behind runtime records at its start (each heater's target, then one WAIT for all of them when
    `wait`) and, with `end_off`, every heater off before the end marker."""
    rows = [(0, HEATER_COMMANDS[name], round(10 * t)) for name, t in targets.items()]
    if wait:
        rows.append((0, RT_WAIT, sum(WAIT_MASKS[name] for name in targets)))
    if end_off:
        rows += [(schedule.n_blocks, HEATER_COMMANDS[name], 0) for name in targets]
    block, command, value = (np.array(c, dtype=np.int64) for c in zip(*rows))
    return replace(schedule, runtime_block=block, runtime_command=command, runtime_value=value)


def image(tmp_path, settings, schedule, motors, targets, wait=True, end_off=False, config=None):
    pins = board_heater_pins("ramps-1.4")
    heaters = tuple(heater_firmware(settings[name], pins[name]) for name in targets)
    schedule = with_targets(schedule, targets, wait, end_off)
    if config is None:
        config = FirmwareConfig("heaters", "tests/firmware/avr/test_heaters.py", "avr", "ramps-1.4",
                                tuple(MotorPins(m, m.upper()) for m in motors))
    config = replace(config, heaters=heaters)
    return build_image(render_sources(schedule, config), tmp_path, stream_bytes(schedule)), config


def plants(settings, config, **start_c):
    return {h.name: HeaterPlant(settings[h.name].plant, settings[h.name].sensor, settings[h.name].pullup_ohm,
                                start_c.get(h.name)) for h in config.heaters}


def short_table():
    """x: 100 steps 1 ms apart."""
    return make_schedule(("x",), [((1,), (100,), 100, (0,), False, [(2000 * 256, 0, 100)])])


def long_table():
    """x: 1500 steps 40 ms apart (long waits: Timer1's compare B counts their periods), a minute of play."""
    return make_schedule(("x",), [((1,), (1500,), 1500, (0,), False, [(80000 * 256, 0, 1500)])])


@pytest.mark.parametrize("gcode, settings_in_order", [
    # M190 S50, M104 S195, M109 S195 ... M104 S0, M140 S0, M104 S0
    ("slicer/puzzle-cura.gcode", [("bed", 500), ("wait", 2), ("hotend", 1950), ("hotend", 1950), ("wait", 1),
                                  ("hotend", 0), ("bed", 0), ("hotend", 0)]),
    # M104 S170, M140 S60, M109 R170, M190 S60, M104 S205, M109 S205 ... M140 S50 (layer 2) ... M104 S0, M140 S0
    ("slicer/benchy-prusaslicer.gcode", [("hotend", 1700), ("bed", 600), ("hotend", 1700), ("wait", 1),
                                         ("bed", 600), ("wait", 2), ("hotend", 2050), ("hotend", 2050), ("wait", 1),
                                         ("bed", 500), ("hotend", 0), ("bed", 0)]),
])
def test_settings_of_sliced_files_become_records(tmp_path, gcode, settings_in_order):
    """A sliced file's heater settings as runtime records in program order (each M109 / M190 a target and a
    WAIT), and a dwell at each wait: the plan rests there."""
    toolpath, _ = toolpath_from_gcode(load_job(gcode_job_file(tmp_path, gcode)))
    flattener = Flattener(toolpath.start, 0.01, runtime=True)
    segments = flattener(toolpath.items)
    records = runtime_records(flattener.settings, ("hotend", "bed"))
    names = {v: k for k, v in HEATER_COMMANDS.items()} | {RT_WAIT: "wait"}
    assert [(names[int(c)], int(v)) for c, v in zip(records.command, records.value)] == settings_in_order
    waits = records.item[records.command == RT_WAIT]
    assert np.all(segments.dwell[np.searchsorted(segments.item, waits)] > 0)


def test_heats_holds_and_runs_the_host_control_laws(tmp_path, settings):
    """Hot end 25 -> 210 degC (PID), bed 25 -> 60 degC (bang-bang), both waited for, then held: the duties the
    firmware set are the host's laws' for the readings it took, period by period."""
    targets = {"hotend": 210.0, "bed": 60.0}
    img, config = image(tmp_path, settings, short_table(), "x", targets)
    run = simulate_heaters(img.hex_path, config, 170.0, plants(settings, config))
    assert run.state == "budget" and run.trip is None  # still holding
    hot, bed = heater_summary(run, "hotend", 210.0), heater_summary(run, "bed", 60.0)
    print("hotend", hot, "bed", bed)
    assert 80.0 < hot["time_to_target_s"] < 100.0
    assert hot["overshoot_c"] <= 3.0 and hot["band_c"] <= 1.0
    assert 95.0 < bed["time_to_target_s"] < 115.0
    assert bed["overshoot_c"] <= 1.5 and bed["band_c"] <= 1.5

    for h in config.heaters:
        trace = run.heaters[h.name]
        temps = np.asarray(h.table)[trace.reading]
        law = pid_reference if h.name == "hotend" else bang_bang
        want = law(h.control, temps, round(10 * targets[h.name]))
        assert len(trace.reading) >= 1690  # one reading per 0.1 s
        assert np.array_equal(trace.period_duty[:-1], want[:-1]), h.name  # the last period may not be written yet
        assert np.all(np.abs(np.diff(trace.read_s) - 0.1) < 0.002)
    # The table started once both had been within 2 degC for 3 s, and played while they held.
    settled = max(settled_at(run, h, round(10 * targets[h.name])) for h in config.heaters)
    assert len(run.steps.resumes) == 1 and settled < run.steps.resumes[0] / F_CPU < settled + 0.01
    assert len(run.steps.step_cycle) == 100


HOLDING = {"hotend": 211.0, "bed": 60.5}  # at power-up: at their targets already (the table plays after 3 s)


@pytest.mark.parametrize("fault, heater, at_s, start_c, reason, trip_s", [
    ("thermistor-open", "hotend", 5.0, {}, "sensor_open", (5.0, 5.11)),
    ("thermistor-short", "bed", 5.0, {}, "sensor_short", (5.0, 5.11)),
    ("heater-dead", "hotend", 0.0, {}, "heating_failed", (20.0, 20.2)),  # no 2 degC rise in 20 s
    ("thermistor-loose", "hotend", 10.0, HOLDING, "thermal_runaway", (50.0, 50.11)),  # 4 degC below for 40 s
    ("thermistor-loose", "bed", 10.0, HOLDING, "thermal_runaway", (30.0, 30.11)),  # 2 degC below for 20 s
    (None, "hotend", 0.0, {"hotend": 280.0}, "max_temp", (0.1, 0.14)),  # above 275 degC at the first reading
    (None, "bed", 0.0, {"bed": 2.0}, "min_temp", (0.1, 0.14)),  # below 5 degC while heating
])
def test_faults_trip_and_stop_everything(tmp_path, settings, fault, heater, at_s, start_c, reason, trip_s):
    """Each fault trips with its reason within its stated time (a period later at most, and while the table waits
    40 ms between steps, main wakes up to run a period's stages within 33 ms), while the table plays (at once, or
    after the wait for heaters already at their targets): every heater pin low, the player's timer off, the
    drivers disabled, no step after the trip."""
    holding = start_c is HOLDING
    img, config = image(tmp_path, settings, long_table(), "x", {"hotend": 210.0, "bed": 60.0}, wait=holding)
    faults = (Fault(heater, fault, at_s),) if fault else ()
    run = simulate_heaters(img.hex_path, config, 70.0, plants(settings, config, **start_c), faults=faults)
    print(fault, run.trip, run.trip_heater, run.trip_s, "stages", run.stages, "at most", run.stage_max_cycles)
    assert run.state == "done"
    assert (run.trip, run.trip_heater) == (reason, heater)
    assert trip_s[0] <= run.trip_s <= trip_s[1]
    assert run.heater_pins_low and run.steppers_stopped
    steps = run.steps.step_cycle / F_CPU  # the table was playing: a step every 40 ms up to the trip, none after
    assert len(steps) >= 2 and run.trip_s - 0.041 < steps[-1] < run.trip_s


def test_start_sequence_waits_then_moves_like_the_twin(tmp_path, settings):
    """A job (the star, corexy at 300 mm/s) behind M140 S60 / M104 S210 / M190 / M109: the table starts once
    both heaters have settled, its pulses are the twin's from there, and the heaters' stages never delay a
    step by more than the hook's check. At the end (M104 S0 / M140 S0) the heaters go off and the image halts."""
    star = tmp_path / "star.yaml"  # with its feed hold keys: main polls them beside the heaters' stages
    star.write_text((ROOT / "examples" / "star.yaml").read_text())
    job = load_job(star)
    host = host_build(job)
    img, config = image(tmp_path, settings, host.schedule, (), {"hotend": 210.0, "bed": 60.0}, end_off=True,
                        config=host.firmware_config())
    switches = simulated_switches(host)
    run = simulate_heaters(img.hex_path, config, 30.0, plants(settings, config, hotend=207.0, bed=58.5),
                           switches=switches)
    assert run.state == "done" and run.trip is None and run.heater_pins_low
    settled = max(settled_at(run, h, {"hotend": 2100, "bed": 600}[h.name]) for h in config.heaters)
    resumed = run.steps.resumes[0] / F_CPU  # the WAIT before the first block held the player until then
    print("settled", settled, "resumed", resumed)
    assert len(run.steps.resumes) == 1 and settled > 3.0 and settled < resumed < settled + 0.01
    steps = on_twin_clock(run.steps, np.array([0]), CYCLES_PER_TICK)
    verdict = compare(host, steps, switches)
    assert verdict.ok, verdict.problems

    plain = build_image(render_sources(host.schedule, host.firmware_config()), tmp_path / "plain",
                        stream_bytes(host.schedule))
    baseline = simulate_heaters(plain.hex_path, host.firmware_config(), 30.0, {}, switches=switches).steps
    delayed = ((steps.step_cycle - steps.timer_start_cycle)
               - (baseline.step_cycle - baseline.timer_start_cycle))
    print("delayed", np.unique(delayed, return_counts=True), "stages", run.stages, "at most", run.stage_max_cycles,
          "cycles; timing", verdict.timing_error_us)
    assert -2 <= delayed.min() and delayed.max() <= HOOK_CHECK_CYCLES  # +-2: main awake or asleep at a compare
    assert run.stages > 200 and run.stage_max_cycles + HOOK_CYCLES <= SLICE_CYCLES
    # Steps at up to 32 kHz (504 cycles apart) leave room for every stage: the heaters keep their period.
    t0, t1 = resumed, run.steps.step_cycle[-1] / F_CPU
    for trace in run.heaters.values():
        during = trace.read_s[(trace.read_s > t0) & (trace.read_s < t1)]
        assert len(during) >= 30 and np.all(np.abs(np.diff(during) - 0.1) < 0.002)


def test_hook_delays_a_step_by_at_most_its_check(tmp_path, settings):
    """x steps every 12 ticks (96 cycles) for 1.2 s: no stage fits between two steps (only before each block's
    first, 400 ticks later), so while a period's stages are pending the hook checks after every step interrupt,
    and a compare that comes during a check waits for it. Every pulse still lands at its tick + the player's
    constant latency + at most the check."""
    block = ((1,), (30000,), 30000, (0,), False, [(400 * 256, 0, 1), (12 * 256, 0, 29999)])
    sched = make_schedule(("x",), [block] * 6)
    img, config = image(tmp_path, settings, sched, "x", {"hotend": 210.0, "bed": 60.0}, end_off=True)
    run = simulate_heaters(img.hex_path, config, 30.0, plants(settings, config, hotend=211.0, bed=61.0))
    assert run.state == "done" and run.trip is None
    ticks = np.array([t for t, _, _ in play(sched)], dtype=np.int64)
    steps = on_twin_clock(run.steps, np.array([0]), CYCLES_PER_TICK)  # its first block waited for the heaters
    late = steps.step_cycle - steps.timer_start_cycle - CYCLES_PER_TICK * ticks
    delayed = late - late.min()
    print("step latency", late.min(), "delayed", np.count_nonzero(delayed), "by at most", delayed.max(),
          "stages", run.stages, "at most", run.stage_max_cycles)
    assert len(late) == 180000 and late.min() == 12  # the player's latency (targets/atmega2560.yaml)
    assert 0 < delayed.max() <= HOOK_CHECK_CYCLES

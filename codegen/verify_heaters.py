"""`verify` of a flash image with heaters (CLI.md): the image runs in simavr against a thermal plant per heater
(codegen/sim/avr_plant.py: DEFAULT_PLANTS with the job's `plant:` keys) from power-up, through the start
sequence's waits and homing, to the table's end; its pulses are compared with the twin's as for any image (the
table starts once the waited heaters have settled: the trace's tick 0 marks it). An image that holds its heaters
after the table never halts: its run ends HELD_AFTER_FACTOR x the table's planned duration + HELD_AFTER_S after
the table's start.

`--fault NAME[:HEATER]@SECONDS` injects a fault into a plant at a simulated time. A protection trip fails the job
with its reason, once verify has checked that the firmware stopped safely: every heater pin low, the steppers
stopped, and the pulses it made before the trip the twin's first ones.
"""

from __future__ import annotations

import argparse
import math
import re

import numpy as np

from codegen.errors import Diagnostic, JobError, SourceRef, suggest
from codegen.firmware import HeaterFirmware
from codegen.firmware.avr_heaters import SETTLE_PERIODS, SETTLE_WINDOW_DC
from codegen.firmware.avr_homing import homing_ticks_bound
from codegen.heaters.settings import heater_settings
from codegen.pipeline import HostBuild
from codegen.report import verify_json
from codegen.sim.avr import SimTrace, switch_thresholds
from codegen.sim.avr_plant import FAULTS, Fault, HeaterPlant, HeaterRun, heater_summary, simulate_heaters
from codegen.verify import MAX_TIMING_ERROR_US, compare, planned_stepping_s, simulated_switches

HEAT_LIMIT_S = 600.0  # simulated: the start sequence's waits are over by then, or the run fails
HELD_AFTER_FACTOR, HELD_AFTER_S = 1.2, 1.0  # a holding image's run ends the table's planned duration x 1.2 + 1 s
#                                            after the player started its timer (verify's budget for any table)
FAULT_FORM = f"NAME[:HEATER]@SECONDS (NAME: {', '.join(FAULTS)})"


def fault_spec(text: str) -> tuple[str, str | None, float]:
    """A --fault value: NAME[:HEATER]@SECONDS (argparse's type: a bad one is a usage error, exit 2)."""
    match = re.fullmatch(r"([a-z-]+)(?::(\w+))?@(.+)", text.strip())
    if not match:
        raise argparse.ArgumentTypeError(f"'{text}' is not {FAULT_FORM}, e.g. thermistor-open:bed@30")
    name, heater, seconds = match.groups()
    if name not in FAULTS:
        raise argparse.ArgumentTypeError(f"unknown fault '{name}'{suggest(name, FAULTS)}; faults: "
                                         f"{', '.join(FAULTS)}")
    try:
        at_s = float(seconds)
    except ValueError:
        at_s = math.nan
    if not (math.isfinite(at_s) and at_s >= 0):
        raise argparse.ArgumentTypeError(f"'{text}': the time after @ must be simulated seconds >= 0")
    return name, heater, at_s


def job_faults(specs: list[tuple[str, str | None, float]], heaters: tuple[str, ...]) -> tuple[Fault, ...]:
    """The --fault specs on the image's heaters (a spec without a heater: the hot end, or the only heater);
    JobError (exit 2) for an image without heaters or a heater it does not have."""
    def bad(message: str) -> JobError:
        return JobError([Diagnostic(SourceRef("--fault"), message)])

    if specs and not heaters:
        raise bad("the image has no heaters to inject a fault into (an AVR flash image has them when the program "
                  "sets one or the machine lists `heaters:`)")
    faults = []
    for name, heater, at_s in specs:
        heater = heater or ("hotend" if "hotend" in heaters else heaters[0])
        if heater not in heaters:
            raise bad(f"'{name}:{heater}@{at_s:g}': the image has no heater '{heater}' (it has {', '.join(heaters)})")
        faults.append(Fault(heater, name, at_s))
    return tuple(faults)


def verify_heaters(host: HostBuild, image, faults: tuple[Fault, ...]) -> tuple[dict, SimTrace]:
    """verify's result (verify_json's keys with `heaters`, `table_start_s` and `faults`; a trip's own, see
    trip_result) and the simulated trace."""
    config = host.firmware_config()
    settings = heater_settings(host.job)
    plants = {h.name: HeaterPlant(settings[h.name].plant, settings[h.name].sensor, settings[h.name].pullup_ohm)
              for h in config.heaters}
    switches = simulated_switches(host)
    tick_hz = host.target.tick_hz
    homing_s = homing_ticks_bound(config, switch_thresholds(config, switches), tick_hz) / tick_hz
    held_after_s = host.plan.total * HELD_AFTER_FACTOR + HELD_AFTER_S
    run = simulate_heaters(image.hex_path, config, HEAT_LIMIT_S + homing_s + held_after_s, plants, faults,
                           switches, held_after_s)
    tick0 = run.steps.timer_start_cycle
    table_start_s = None if tick0 is None else tick0 / run.steps.f_cpu
    if run.trip is not None:
        result = trip_result(host, run, image)
    else:
        result = verify_json(host, compare(host, run.steps, switches), image)
        if tick0 is None and run.state == "budget":
            result["problems"].insert(0, f"the heaters did not settle at their targets within {HEAT_LIMIT_S:g} s")
    result["heaters"] = {h.name: _figures(run, h, table_start_s) for h in config.heaters}
    result["table_start_s"] = None if table_start_s is None else round(table_start_s, 6)
    result["faults"] = [{"name": f.kind, "heater": f.heater, "at_s": f.at_s} for f in faults]
    return result, run.steps


def _figures(run: HeaterRun, heater: HeaterFirmware, table_start_s: float | None) -> dict:
    """heater_summary's figures with the band while the table played (from its start), and `settled_s`: when the
    firmware's wait for it was over (None: not waited for, or never); an unset heater's figures are None."""
    name, target_c = heater.name, heater.start_target_dc / 10
    if target_c == 0:
        trip = run.trip if run.trip_heater == name else None
        return {"target_c": 0.0, "time_to_target_s": None, "overshoot_c": None, "band_c": None, "trip": trip,
                "settled_s": None}
    figures = heater_summary(run, name, target_c, band_from_s=table_start_s)
    figures["settled_s"] = settled_at(run, heater) if heater.wait else None
    return {key: round(v, 3) if isinstance(v, float) and key != "target_c" else v for key, v in figures.items()}


def settled_at(run: HeaterRun, heater: HeaterFirmware) -> float | None:
    """When the firmware's wait for `heater` was over: the reading that made SETTLE_PERIODS in a row within
    SETTLE_WINDOW_DC of its target (the firmware's own test, on the readings it took)."""
    trace = run.heaters[heater.name]
    within = np.abs(np.asarray(heater.table)[trace.reading] - heater.start_target_dc) <= SETTLE_WINDOW_DC
    runs = np.convolve(within, np.ones(SETTLE_PERIODS, dtype=int), "valid")
    done = np.flatnonzero(runs == SETTLE_PERIODS)
    return float(trace.read_s[done[0] + SETTLE_PERIODS - 1]) if len(done) else None


def trip_result(host: HostBuild, run: HeaterRun, image) -> dict:
    """A run the thermal protection stopped: not a pass, with its reason; the firmware must have stopped safely
    (every heater pin low, the steppers stopped) and made only the twin's first pulses before the trip."""
    motors, problems = pulses_before_trip(host, run.steps.run_only())
    if not run.heater_pins_low:
        problems.append("after the trip a heater pin is not low")
    if not run.steppers_stopped:
        problems.append("after the trip the steppers are not stopped (Timer1 running or a driver enabled)")
    run_cycles = run.steps.run_only().step_cycle
    return {
        "pass": False, "target": host.target.target, "board": host.target.board,
        "trip": {"reason": run.trip, "heater": run.trip_heater, "time_s": round(run.trip_s, 6)},
        "heater_pins_low": run.heater_pins_low, "steppers_stopped": run.steppers_stopped,
        "duration_s": round(float(np.ptp(run_cycles)) / run.steps.f_cpu, 6) if len(run_cycles) else 0.0,
        "planned_duration_s": round(planned_stepping_s(host), 6),
        "motors": motors,
        "image": {"flash_bytes": image.flash_bytes, "ram_bytes": image.ram_bytes,
                  "table_bytes": host.schedule.table_bytes()},
        "problems": [f"heater {run.trip_heater} tripped: {run.trip} at {run.trip_s:.2f} s simulated"] + problems,
    }


def pulses_before_trip(host: HostBuild, trace) -> tuple[dict, list[str]]:
    """Per motor, the pulses made before a trip against the twin's first as many: the same directions, each
    within the timing limit of its predicted time."""
    twin, f_cpu, tick_hz = host.pulses, trace.f_cpu, host.target.tick_hz
    limit = MAX_TIMING_ERROR_US + host.target.isr_latency_us
    start = trace.timer_start_cycle or 0
    motors, problems = {}, []
    for m, name in enumerate(host.kin.motors):
        mine, theirs = trace.step_motor == m, np.flatnonzero(twin.motor == m)
        made = int(mine.sum())
        motors[name] = {"steps": made, "planned_steps": len(theirs), "max_timing_error_us": None}
        if made > len(theirs):
            problems.append(f"motor {name}: {made} steps before the trip, the twin predicted {len(theirs)} in all")
            continue
        theirs = theirs[:made]
        wrong = np.flatnonzero(trace.step_dir[mine] != twin.dir[theirs])
        if len(wrong):
            problems.append(f"motor {name}: step {wrong[0]} goes the wrong way ({len(wrong)} steps differ)")
        if not made:
            continue
        worst = float(np.abs((trace.step_cycle[mine] - start) / f_cpu - twin.tick[theirs] / tick_hz).max() * 1e6)
        motors[name]["max_timing_error_us"] = round(worst, 3)
        if worst > limit:
            problems.append(f"motor {name}: a step before the trip comes {worst:.2f} us away from its predicted "
                            f"time (limit {limit:.2f} us)")
    return motors, problems


def heater_lines(result: dict) -> list[str]:
    """verify's text lines for the heaters: one per heater, the waits' end, the faults."""
    lines = []
    for name, h in result["heaters"].items():
        if h["target_c"] == 0:
            text = "off (the program sets no target)"
        elif h["time_to_target_s"] is None:
            text = f"{h['target_c']:g} degC not reached, overshoot {h['overshoot_c']:.2f} degC"
        else:
            band = "n/a" if h["band_c"] is None else f"{h['band_c']:.2f} degC"
            settled = "" if h["settled_s"] is None else f", settled at {h['settled_s']:.1f} s"
            text = (f"{h['target_c']:g} degC reached in {h['time_to_target_s']:.1f} s{settled}, overshoot "
                    f"{h['overshoot_c']:.2f} degC, band {band} while the table played")
        lines.append(f"  heater {name}: {text}" + (f", trip: {h['trip']}" if h["trip"] else ""))
    waited = any(h["settled_s"] is not None for h in result["heaters"].values())
    if result["table_start_s"] is not None and waited:
        lines.append(f"  the table started at {result['table_start_s']:.2f} s simulated, after the waits")
    trip = result.get("trip")
    for f in result["faults"]:
        tripped = trip is not None and trip["heater"] == f["heater"]
        lines.append(f"  fault {f['name']} on {f['heater']} at {f['at_s']:g} s: "
                     + (f"tripped {trip['reason']} at {trip['time_s']:.2f} s" if tripped else "no trip"))
    return lines


def trip_lines(result: dict) -> list[str]:
    """verify's text lines for a run the protection stopped: the stop, and each motor's pulses before it."""
    trip = result["trip"]
    stopped = ("every heater pin low" if result["heater_pins_low"] else "A HEATER PIN NOT LOW") + ", " + (
        "steppers stopped" if result["steppers_stopped"] else "STEPPERS NOT STOPPED")
    lines = [f"  heater {trip['heater']} tripped: {trip['reason']} at {trip['time_s']:.2f} s simulated; {stopped}"]
    for name, m in result["motors"].items():
        timing = ("" if m["max_timing_error_us"] is None
                  else f", timing within {m['max_timing_error_us']:.2f} us of the twin's first")
        lines.append(f"  {name}: {m['steps']} of {m['planned_steps']} steps before the trip{timing}")
    return lines

"""`verify` of a flash image with heaters (CLI.md): the image runs in simavr against a thermal plant per heater
(codegen/sim/avr_plant.py: DEFAULT_PLANTS with the job's `plant:` keys) from power-up, through homing and the
table with its runtime records, to its end; the player holds at each WAIT record until its heaters have settled,
and its pulses are compared with the twin's on the twin's clock (each part after a resume from its wait's tick,
see Holds below). An image that holds its heaters after the table never halts: its run ends HELD_AFTER_FACTOR x
the table's planned duration + HELD_AFTER_S after the player's latest start (not while it holds).

Each heater's figures are its last target's (the tables' last setting of it), from when the player read it;
its band is measured once it has reached it and, if it was waited for, from the resume (else SETTLE_S after
reaching it).

Holds (a WAIT record stops the player's timer; it restarts at tick 0 once the heaters have settled): the
simulated timeline has holds that the twin's has not, so the trace is cut at each resume (the harness logs every
start of the player's timer) and each part put on the twin's clock from the tick of its wait's event (the twin
times the events after a wait from it, as the firmware does from its restart); then the pulses compare with the
twin's as for any image. Each hold is reported: when it began, how long it lasted, the heaters it waited for.

`--fault NAME[:HEATER]@SECONDS` injects a fault into a plant at a simulated time. A protection trip fails the job
with its reason, once verify has checked that the firmware stopped safely: every heater pin low, the steppers
stopped, and the pulses it made before the trip the twin's first ones.
"""

from __future__ import annotations

import argparse
import math
import re
from dataclasses import dataclass, field, replace

import numpy as np

from codegen.errors import Diagnostic, JobError, SourceRef, suggest
from codegen.firmware.avr.heaters import SETTLE_PERIODS, SETTLE_WINDOW_DC
from codegen.firmware.config import HeaterFirmware
from codegen.firmware.homing import homing_ticks_bound
from codegen.pipeline.host import HostBuild
from codegen.program.heater_settings import heater_settings
from codegen.sim.avr import SimTrace, switch_thresholds
from codegen.sim.avr_plant import FAULTS, Fault, HeaterPlant, HeaterRun, heater_summary, simulate_heaters
from codegen.tables.schedule import HEATER_COMMANDS, WAIT_MASKS
from codegen.tables.twin import event_ticks
from codegen.verify.chapters import RuntimeTimeline
from codegen.verify.compare import MAX_TIMING_ERROR_US, compare, planned_stepping_s, simulated_switches
from codegen.verify.results import verify_json

HEAT_LIMIT_S = 600.0  # simulated: the start sequence's waits are over by then, or the run fails
HELD_AFTER_FACTOR, HELD_AFTER_S = 1.2, 1.0  # a holding image's run ends the table's planned duration x 1.2 + 1 s
#                                            after the player started its timer (verify's budget for any table)
FAN_SHOWN = 8  # the fan's first changes in verify's text (a sliced print has hundreds)
FAULT_FORM = f"NAME[:HEATER]@SECONDS (NAME: {', '.join(FAULTS)})"


@dataclass
class HeatedTrace(SimTrace):
    """A run's trace with its plants' (codegen/sim/avr_plant.py HeaterTrace by heater): verify --report draws them."""

    plants: dict = field(default_factory=dict)


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


def job_plants(job, config) -> dict[str, HeaterPlant]:
    """The simulated plant behind each of the firmware's heaters: the job's (or the board's default) heater."""
    settings = heater_settings(job)
    return {h.name: HeaterPlant(settings[h.name].plant, settings[h.name].sensor, settings[h.name].pullup_ohm)
            for h in config.heaters}


def verify_heaters(host: HostBuild, image, faults: tuple[Fault, ...]) -> tuple[dict, SimTrace]:
    """verify's result (verify_json's keys with `heaters`, `table_start_s`, `holds`, `fan` and `faults`; a trip's
    own, see trip_result) and the simulated trace (on the simulated clock: the holds in it)."""
    config = host.firmware_config()
    switches = simulated_switches(host)
    tick_hz = host.target.tick_hz
    homing_s = homing_ticks_bound(config, switch_thresholds(config, switches), tick_hz) / tick_hz
    held_after_s = host.plan.total * HELD_AFTER_FACTOR + HELD_AFTER_S
    run = simulate_heaters(image.hex_path, config, HEAT_LIMIT_S + homing_s + held_after_s,
                           job_plants(host.job, config), faults, switches, held_after_s)
    return heater_result(host, run, image, faults, switches)


def heater_result(host: HostBuild, run: HeaterRun, image, faults: tuple[Fault, ...],
                  switches: dict[int, int | None], streamed: bool = False) -> tuple[dict, SimTrace]:
    """verify_heaters' result for a run with heaters (a flash image's, or with `streamed` a stream's:
    codegen/sim/avr_link.py), and its trace on the simulated clock."""
    cycles_per_tick = run.steps.f_cpu // host.target.tick_hz
    timeline = host_timeline(host)
    waits = timeline.tick[timeline.waits()]
    run_cycles = run.steps.run_only().step_cycle
    start_s = table_start_s(run.steps, int(run_cycles[0]) if len(run_cycles) else None)
    simulated = HeatedTrace(**vars(run.steps), plants=run.heaters)  # on the simulated clock, holds in it
    run.steps = on_twin_clock(run.steps, waits, cycles_per_tick)
    if run.trip is not None:
        motors, problems = pulses_before_trip(host, run.steps.run_only())
        span = float(np.ptp(run_cycles)) if len(run_cycles) else 0.0
        result = trip_result(host, run, image, motors, problems, span, planned_stepping_s(host))
    else:
        result = with_holds(verify_json(host, compare(host, run.steps, switches, streamed), image), run, waits)
    result.update(heater_figures(host, run, timeline, start_s))
    result["faults"] = [{"name": f.kind, "heater": f.heater, "at_s": f.at_s} for f in faults]
    return result, simulated


def host_timeline(host: HostBuild) -> RuntimeTimeline:
    """A host build's runtime records on the twin's clock (its tables' alone: the events' ticks are theirs)."""
    return RuntimeTimeline.of(host.schedule, event_ticks(host.schedule))


def with_holds(result: dict, run: HeaterRun, waits: np.ndarray) -> dict:
    """verify's result of a run with heaters that did not trip: the heat-up's and the holds' problems added."""
    if run.steps.timer_start_cycle is None and run.state == "budget":
        result["problems"].insert(0, f"the heaters did not settle at their targets within {HEAT_LIMIT_S:g} s")
    result["problems"] += hold_problems(run.steps, waits)
    result["pass"] = result["pass"] and not result["problems"]
    return result


def heater_figures(host: HostBuild, run: HeaterRun, timeline: RuntimeTimeline, start_s: float | None) -> dict:
    """verify's `holds`, `heaters`, `table_start_s` and `fan` of a run with heaters (its clock: the player's starts
    in run.steps; `timeline`: the tables' runtime records on the twin's clock)."""
    cycles_per_tick = run.steps.f_cpu // host.target.tick_hz
    return {"holds": holds(run.steps, timeline, cycles_per_tick),
            "heaters": {h.name: _figures(run, h, timeline, cycles_per_tick) for h in host.firmware_config().heaters},
            "table_start_s": start_s,
            "fan": [{"at_s": round(float(t), 3), "duty": round(float(d), 4)} for t, d in run.fan[1:]]}


def on_twin_clock(trace, waits: np.ndarray, cycles_per_tick: int):
    """The trace with every edge after a resume moved onto the twin's clock: the part after resume k starts at
    tick 0 + the tick of wait k (what the twin predicts there), as if the player had not held."""
    resumes = np.asarray(trace.resumes[:len(waits)], dtype=np.int64)
    if not len(resumes) or trace.timer_start_cycle is None:
        return trace
    shift = np.concatenate([[0], trace.timer_start_cycle + waits[:len(resumes)] * cycles_per_tick - resumes])

    def moved(cycles: np.ndarray) -> np.ndarray:
        return cycles + shift[np.searchsorted(resumes, cycles, side="right")]

    tool = [(int(c), v) for c, v in zip(moved(np.array([c for c, _ in trace.tool_edges], dtype=np.int64)),
                                        (v for _, v in trace.tool_edges))]
    order = np.argsort(moved(trace.step_cycle), kind="stable")
    return replace(trace, step_cycle=moved(trace.step_cycle)[order], step_motor=trace.step_motor[order],
                   step_dir=trace.step_dir[order], step_phase=trace.step_phase[order], tool_edges=tool)


def holds(trace, timeline: RuntimeTimeline, cycles_per_tick: int) -> list[dict]:
    """Each hold: when the player stopped (s, simulated from power-up), how long until its timer's tick 0 again
    (waited_s), and the heaters of its WAIT record."""
    masks, waits = timeline.value[timeline.waits()], timeline.tick[timeline.waits()]
    out, since_cycle, since_tick = [], trace.timer_start_cycle, 0
    for resume, tick, mask in zip(trace.resumes, waits, masks):
        stopped = since_cycle + (int(tick) - since_tick) * cycles_per_tick
        out.append({"at_s": round(stopped / trace.f_cpu, 6), "waited_s": round((resume - stopped) / trace.f_cpu, 6),
                    "heaters": [name for name, bit in WAIT_MASKS.items() if int(mask) & bit]})
        since_cycle, since_tick = resume, int(tick)
    return out


def hold_problems(trace, waits: np.ndarray) -> list[str]:
    """The player must have resumed once per WAIT record it reached (fewer: a run that stopped during a hold)."""
    if trace.state in ("done", "held") and len(trace.resumes) != len(waits):
        return [f"the player resumed {len(trace.resumes)} times, the tables hold it at {len(waits)} waits"]
    return []


def hold_lines(result: dict) -> list[str]:
    """verify's text lines for the holds."""
    return [f"  hold at {h['at_s']:.2f} s simulated for {h['waited_s']:.2f} s: waited for {', '.join(h['heaters'])}"
            for h in result.get("holds", [])]


def table_start_s(trace, first_step_cycle: int | None) -> float | None:
    """When the table's first step's tick 0 came (simulated s): the player's start, or the resume after the waits
    before its first step (`first_step_cycle`, as simulated; None: it made none)."""
    if trace.timer_start_cycle is None:
        return None
    starts = np.array([trace.timer_start_cycle, *trace.resumes])
    first = starts[starts <= first_step_cycle][-1] if first_step_cycle is not None else starts[0]
    return round(float(first) / trace.f_cpu, 6)


def _sim_s_of_tick(trace, waits: np.ndarray, tick: int, cycles_per_tick: int) -> float:
    """The simulated time of the twin's tick (a record's event) on the player's parts between resumes: a record at
    a wait's event comes at the stop before that hold."""
    part = int(np.searchsorted(waits[:len(trace.resumes)], tick, side="left"))
    start, since = ((trace.timer_start_cycle, 0) if part == 0
                    else (trace.resumes[part - 1], int(waits[part - 1])))
    return (start + (tick - since) * cycles_per_tick) / trace.f_cpu


def _figures(run: HeaterRun, heater: HeaterFirmware, timeline: RuntimeTimeline, cycles_per_tick: int) -> dict:
    """heater_summary's figures for the heater's last target (an off at the end aside), from when the player read
    it (an unset heater's figures are None), with `settled_s`: when the firmware's last wait for it was over
    (None: not waited for)."""
    name, trace = heater.name, run.steps
    mine = np.flatnonzero((timeline.command == HEATER_COMMANDS[name]) & (timeline.value > 0))
    target_c = float(timeline.value[mine[-1]]) / 10 if len(mine) else 0.0
    none = {"target_c": target_c, "time_to_target_s": None, "overshoot_c": None, "band_c": None,
            "trip": run.trip if run.trip_heater == name else None, "settled_s": None}
    if target_c == 0 or trace.timer_start_cycle is None:
        return none
    waits = timeline.tick[timeline.waits()]
    since_s = _sim_s_of_tick(trace, waits, int(timeline.tick[mine[-1]]), cycles_per_tick)
    samples = run.heaters[name].time_s
    if not len(samples) or since_s > samples[-1]:  # the run ended (a trip) before the player read that target
        return none
    waited = [k for k in timeline.waits() if k > mine[-1] and timeline.value[k] & WAIT_MASKS[name]]
    resume = None
    if waited:
        k = int(np.searchsorted(timeline.waits(), waited[0]))
        resume = trace.resumes[k] / trace.f_cpu if k < len(trace.resumes) else None
    figures = heater_summary(run, name, target_c, band_from_s=resume, since_s=since_s)
    figures["settled_s"] = settled_at(run, heater, round(target_c * 10), since_s) if waited else None
    return {key: round(v, 3) if isinstance(v, float) and key != "target_c" else v for key, v in figures.items()}


def settled_at(run: HeaterRun, heater: HeaterFirmware, target_dc: int, since_s: float = 0.0) -> float | None:
    """When the firmware's wait for `heater` at `target_dc` was over: the reading (from `since_s` on) that made
    SETTLE_PERIODS in a row within SETTLE_WINDOW_DC of its target (the firmware's own test, on its readings)."""
    trace = run.heaters[heater.name]
    after = trace.read_s >= since_s
    within = np.abs(np.asarray(heater.table)[trace.reading[after]] - target_dc) <= SETTLE_WINDOW_DC
    runs = np.convolve(within, np.ones(SETTLE_PERIODS, dtype=int), "valid")
    done = np.flatnonzero(runs == SETTLE_PERIODS)
    return float(trace.read_s[after][done[0] + SETTLE_PERIODS - 1]) if len(done) else None


def trip_result(host: HostBuild, run: HeaterRun, image, motors: dict, problems: list[str], span_cycles: float,
                planned_s: float) -> dict:
    """A run the thermal protection stopped: not a pass, with its reason; the firmware must have stopped safely
    (every heater pin low, the steppers stopped) and made only the twin's first pulses before the trip (`motors`
    and `problems`: pulses_before_trip's, or codegen/verify/compare.py Comparison.trip_figures'; `span_cycles`: from
    its first pulse to its last)."""
    if not run.heater_pins_low:
        problems.append("after the trip a heater pin is not low")
    if not run.steppers_stopped:
        problems.append("after the trip the steppers are not stopped (Timer1 running or a driver enabled)")
    return {
        "pass": False, "target": host.target.target, "board": host.target.board,
        "trip": {"reason": run.trip, "heater": run.trip_heater, "time_s": round(run.trip_s, 6)},
        "heater_pins_low": run.heater_pins_low, "steppers_stopped": run.steppers_stopped,
        "duration_s": round(span_cycles / run.steps.f_cpu, 6),
        "planned_duration_s": round(planned_s, 6),
        "motors": motors,
        "image": {"flash_bytes": image.flash_bytes, "ram_bytes": image.ram_bytes,
                  "table_bytes": host.totals.table_bytes},
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
        elif h["overshoot_c"] is None:
            text = f"{h['target_c']:g} degC never set (the run ended before the player read it)"
        elif h["time_to_target_s"] is None:
            text = f"{h['target_c']:g} degC not reached, overshoot {h['overshoot_c']:.2f} degC"
        else:
            band = "n/a" if h["band_c"] is None else f"{h['band_c']:.2f} degC"
            settled = "" if h["settled_s"] is None else f", settled at {h['settled_s']:.1f} s"
            text = (f"{h['target_c']:g} degC reached in {h['time_to_target_s']:.1f} s{settled}, overshoot "
                    f"{h['overshoot_c']:.2f} degC, band {band} while it held that target")
        lines.append(f"  heater {name}: {text}" + (f", trip: {h['trip']}" if h["trip"] else ""))
    lines += hold_lines(result)
    if result.get("fan"):
        fan = result["fan"]
        shown = ", ".join(f"{100 * f['duty']:.0f} % at {f['at_s']:.2f} s" for f in fan[:FAN_SHOWN])
        more = f", and {len(fan) - FAN_SHOWN} changes more (verify --json lists them)" if len(fan) > FAN_SHOWN else ""
        lines.append(f"  fan: {shown}{more}")
    start = result["table_start_s"]
    if start is not None and any(h["at_s"] < start for h in result["holds"]):
        lines.append(f"  the table's first move started at {start:.2f} s simulated, after the waits before it")
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

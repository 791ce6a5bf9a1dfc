"""Step by step against Klipper: every motor's steps of our plan (the twin's pulses) beside Klipper's on the
same G-code (issue 29: "each motor's step count equal; each motor's step times within 50 us of ours at
every step, or every difference explained").

    python benchmarks/klipper_steps.py [JOB.yaml] [--shaper mzv:50[:0.1]] [--pressure-advance 0.05[:0.04]]
                                       [--arc-resolution 1.0] [--same-limits] [--json]

Klipper's batch mode (benchmarks/klipper_ref.py) runs on the job's G-code with benchmarks/klipper/printer.cfg
plus [gcode_arcs] and, from the options, [input_shaper] and the extruder's pressure_advance (the job must say
the same for our side: `machine.input_shaper`, `machine.pressure_advance`). Its out.serial is decoded by
benchmarks/klipper_decode.py; steps queued before its last endstop_home are its G28 homing (our firmware
homes before the tables) and are left out. Both sides' times count from the first step of any motor;
positions from where homing leaves each side (Klipper: position_endstop; ours: the program's start). Steps
are paired by the half-step boundary they cross (benchmarks/klipper_compare.py), so the figures hold
although the two plans drift apart. Printed per motor: step counts, per-step time differences (global: as
they stand; local: less the drift of the two clocks), and our position minus Klipper's at each of Klipper's
steps (global, and at our time matching Klipper's by the drift).

What the differences are (Benchy: examples/printers/benchy-mini.yaml, PrusaSlicer, 12.5 M steps; small:
a few moves and two arcs, tests/benchmarks/klipper-small.gcode):
- Planning. Our plan of the Benchy lasts 2442.7 s from the first step to the last, Klipper's 2294.2 s
  (-6.1 %): the drift reaches 148 s, so the global differences say nothing of single steps. Causes: the file
  sets Marlin's classic jerk (M205 X8 Y8), which we follow and Klipper ignores (its corners come from
  square_corner_velocity); a lone `M204 P1250` / `M204 T1250` Klipper refuses, and from `M204 P1250 R1250
  T2500` on Klipper accelerates everything at min(P, T) = 1250 mm/s^2 where we travel at T = 2500; Klipper
  keeps square_corner_velocity (not the deviation) when M204 changes the acceleration; its extruder limits
  the junction speed where the extrusion ratio changes (instant_corner_velocity 1 mm/s). `--same-limits`
  drops M204/M205 from the file on both sides: then both corner by the same junction deviation at 2500 mm/s^2.
- Step times of the same motion: Klipper compresses each stepper's steps with a one-sided 25 us window
  (a step up to 25 us early, never late); our tables hold events within their own bound of the plan; so steps
  of the same plan differ by up to ~25 us plus ours.
- Homing position: ours starts the program where G28 says (0, 0, 0), Klipper at position_endstop (-2, -4, 0)
  = the low end of the job's ranges, where our own `program.home: true` starts it too; the first move's step
  count differs by 200 on x (Benchy: 17,900 of ours against 18,100) and the direction of y's first 200 steps.
- Half steps: the file writes X/Y with 3 decimals at 100 steps/mm, so a coordinate can sit on a half step
  (85.105 mm = 8510.5 steps); each side rounds it its own way, and where the path then turns back one side
  makes an extra step pair: ours has 337 more pairs on x, 676 on y, 2 on e (of 5.2 M, 4.3 M, 2.8 M steps);
  positions then differ by one step until the next move.
- Arcs: Klipper cuts G2/G3 into chords of `resolution` mm ([gcode_arcs], default 1 mm: 12.5 um off a 10 mm
  radius), ours within `tolerance` (0.002 mm): one-step position differences on arcs, and the chords' corners
  time the arc differently.
"""

from __future__ import annotations

import argparse
import configparser
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from klipper_compare import (BINS_S, Drift, Spread, Train, drift_of, nearest_pairs,  # noqa: E402
                             occurrence_pairs, position_at, trend)
from klipper_decode import decode  # noqa: E402
from klipper_ref import CONFIG, find_klipper, run_klipper  # noqa: E402

JOB = HERE.parent / "examples" / "printers" / "benchy-mini.yaml"
LIMIT_US = 50.0
SECTIONS = {"x": "stepper_x", "y": "stepper_y", "z": "stepper_z", "e": "extruder"}  # cartesian motors
SAME_LIMITS_DROPPED = ("M204", "M205")


def klipper_config(work: Path, shaper: str | None, advance: str | None, arc_resolution: float,
                   endstops: dict[str, float] | None) -> Path:
    """printer.cfg with [gcode_arcs], the options' shaper and pressure advance, and `endstops` (section ->
    position_endstop, mm) where given (Klipper merges a section given twice: the lines can follow the file)."""
    extra = [f"\n[gcode_arcs]\nresolution: {arc_resolution}\n"]
    extra += [f"\n[{section}]\nposition_endstop: {mm:g}\n" for section, mm in (endstops or {}).items()]
    if shaper:
        kind, freq, *damping = shaper.split(":")
        extra.append("\n[input_shaper]\n" + "".join(
            f"shaper_type_{a}: {kind}\nshaper_freq_{a}: {float(freq)}\n"
            + (f"damping_ratio_{a}: {float(damping[0])}\n" if damping else "") for a in "xy"))
    if advance:
        k, *smooth = advance.split(":")
        extra.append(f"\n[extruder]\npressure_advance: {float(k)}\n"
                     + (f"pressure_advance_smooth_time: {float(smooth[0])}\n" if smooth else ""))
    path = work / "printer.cfg"
    path.write_text(CONFIG.read_text() + "".join(extra))
    return path


def stepper_pins(config: Path) -> dict[str, tuple[str, bool, float]]:
    """Each stepper section: its step pin, whether its dir pin is inverted, its position_endstop (mm)."""
    parser = configparser.RawConfigParser(strict=False, inline_comment_prefixes=(";", "#"))
    parser.read(config)
    pins = {}
    for section in SECTIONS.values():
        pin = parser.get(section, "step_pin").lstrip("^~!").strip()
        inverted = parser.get(section, "dir_pin").strip().startswith("!")
        pins[section] = (pin, inverted, parser.getfloat(section, "position_endstop", fallback=0.0))
    return pins


def job_and_gcode(job_path: Path, work: Path, same_limits: bool) -> tuple[Path, Path]:
    """The job and its G-code file as both sides read them (inline G-code written out; with `same_limits`
    the M204/M205 lines become comments in both)."""
    job = yaml.safe_load(job_path.read_text())
    gcode = job["program"]["gcode"]
    text = gcode if "\n" in gcode.strip() else (job_path.parent / gcode).read_text()
    if not same_limits and "\n" not in gcode.strip():
        return job_path, job_path.parent / gcode
    if same_limits:
        text = "\n".join(";" + line if line.lstrip().upper().startswith(SAME_LIMITS_DROPPED) else line
                         for line in text.splitlines()) + "\n"
    written = work / "program.gcode"
    written.write_text(text)
    job["program"]["gcode"] = str(written)
    job.setdefault("name", job_path.stem)
    rewritten = work / job_path.name
    rewritten.write_text(yaml.safe_dump(job, sort_keys=False))
    return rewritten, written


def our_trains(job_path: Path):
    """Our steps per motor from the twin: (host, {motor: (Train, G-code line of each step)}, tick_hz)."""
    from codegen.job import load_job
    from codegen.pipeline.host import host_build

    host = host_build(load_job(job_path))
    pulses, tick_hz = host.pulses, host.target.tick_hz
    line_of_event = host.segments.line[host.event_segments()]
    origin = int(pulses.tick[0]) if len(pulses.tick) else 0
    trains = {}
    for m, motor in enumerate(host.kin.motors):
        mine = pulses.motor == m
        trains[motor] = (Train((pulses.tick[mine] - origin) / tick_hz, pulses.dir[mine].astype(np.int8),
                               int(host.start_steps[m])), line_of_event[pulses.event[mine]])
    return host, trains


def klipper_trains(serial: Path, dictionary: Path, config: Path, steps_per_mm: dict[str, float]) -> dict:
    """Klipper's program steps per motor (after its homing), from the first step of any motor."""
    pins = stepper_pins(config)
    steppers, messages = decode(serial, dictionary, {s: (pin, inv) for s, (pin, inv, _) in pins.items()})
    homing_end, _ = messages.of("endstop_home")
    after = int(homing_end[-1]) if len(homing_end) else -1
    program = {motor: steppers[section].message > after for motor, section in SECTIONS.items()}
    firsts = [steppers[SECTIONS[m]].clock[program[m]][:1] for m in SECTIONS]
    origin = int(np.concatenate(firsts).min()) if any(len(f) for f in firsts) else 0
    trains = {}
    for motor, section in SECTIONS.items():
        steps = steppers[section]
        homed = round(pins[section][2] * steps_per_mm[motor]) if motor != "e" else 0
        clock = steps.clock[program[motor]]
        trains[motor] = Train((clock - origin) / messages.dictionary.clock_hz, steps.dir[program[motor]], homed)
    return trains


def compare_motor(ours: Train, lines: np.ndarray, theirs: Train, pairs: tuple[np.ndarray, np.ndarray]) -> dict:
    mine, other = pairs
    dt = ours.time[mine] - theirs.time[other]
    smooth = trend(dt)
    spreads = {name: Spread.of(values * 1e6, LIMIT_US) for name, values in (("global", dt), ("local", dt - smooth))}
    out = {"steps": {"ours": len(ours.time), "klipper": len(theirs.time),
                     "ours_forward": int((ours.dir > 0).sum()), "klipper_forward": int((theirs.dir > 0).sum())},
           "final": {"ours": int(ours.position[-1]) if len(ours.time) else ours.start,
                     "klipper": int(theirs.position[-1]) if len(theirs.time) else theirs.start},
           "paired": len(mine), "unpaired": {"ours": len(ours.time) - len(mine),
                                             "klipper": len(theirs.time) - len(mine)}}
    for name, spread in spreads.items():
        where = {} if spread.at < 0 else {"ours_s": float(ours.time[mine[spread.at]]),
                                          "klipper_s": float(theirs.time[other[spread.at]]),
                                          "line": int(lines[mine[spread.at]])}
        out[f"time_{name}_us"] = {"max": spread.max, "p99": spread.p99, "mean": spread.mean,
                                  f"over_{LIMIT_US:g}us": spread.over, "max_at": where}
    by_klipper = np.argsort(other)  # the local offset at each of Klipper's steps, paired or not
    offset = np.interp(np.arange(len(theirs.time)), other[by_klipper], smooth[by_klipper]) if len(mine) else 0.0
    for name, at in (("global", theirs.time), ("local", theirs.time + offset)):
        gap = position_at(ours, at) - theirs.position
        spread = Spread.of(gap.astype(float), 1.0)
        where = {}
        if spread.at >= 0:
            near = min(int(np.searchsorted(ours.time, at[spread.at])), len(ours.time) - 1)
            where = {"klipper_s": float(theirs.time[spread.at]), "line": int(lines[near]) if near >= 0 else 0}
        out[f"position_{name}_steps"] = {"max": spread.max, "p99": spread.p99, "mean": spread.mean,
                                         "over_1_step": spread.over, "max_at": where}
    return out


def compare(ours: dict, theirs: dict) -> tuple[dict, Drift]:
    """Every motor compared, with the drift of the two clocks that paired their steps."""
    pairs = {motor: occurrence_pairs(train, theirs[motor]) for motor, (train, _) in ours.items()}
    for bin_s in BINS_S:
        paired_time = np.concatenate([ours[m][0].time[mine] for m, (mine, _) in pairs.items()])
        offset = np.concatenate([ours[m][0].time[mine] - theirs[m].time[other] for m, (mine, other) in pairs.items()])
        drift = drift_of(paired_time, offset, bin_s)
        pairs = {motor: nearest_pairs(train, theirs[motor], drift) for motor, (train, _) in ours.items()}
    return {motor: compare_motor(train, lines, theirs[motor], pairs[motor])
            for motor, (train, lines) in ours.items()}, drift


def print_table(result: dict) -> None:
    print(f"times from the first step of any motor on each side; ours {result['ours_duration_s']:.1f} s, "
          f"Klipper {result['klipper_duration_s']:.1f} s; drift at the end {result['drift_end_s']:+.3f} s")
    print(f"{'motor':<5} {'ours':>10} {'Klipper':>10} {'unpaired':>15} | {'local dt us: max':>16} {'p99':>7} "
          f"{'mean':>7} {'>50us':>8} {'at line':>8} | {'global max s':>12} | {'pos local: max':>14} "
          f"{'>1':>8} | {'pos global max':>14}")
    for motor, m in result["motors"].items():
        local, glob = m["time_local_us"], m["time_global_us"]
        pos_local, pos_global = m["position_local_steps"], m["position_global_steps"]
        print(f"{motor:<5} {m['steps']['ours']:>10,} {m['steps']['klipper']:>10,} "
              f"{m['unpaired']['ours']:>7,}/{m['unpaired']['klipper']:<7,} | {local['max']:>16.1f} "
              f"{local['p99']:>7.1f} {local['mean']:>+7.1f} {local['over_50us']:>8,} "
              f"{local['max_at'].get('line', 0):>8} | {glob['max'] / 1e6:>12.3f} | {pos_local['max']:>14.0f} "
              f"{pos_local['over_1_step']:>8,} | {pos_global['max']:>14.0f}")
    walls = result["wall_s"]
    print("wall: " + ", ".join(f"{k} {v:.2f} s" for k, v in walls.items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("job", type=Path, nargs="?", default=JOB)
    parser.add_argument("--shaper", help="Klipper's [input_shaper] on x and y: TYPE:FREQ[:DAMPING]")
    parser.add_argument("--pressure-advance", help="Klipper's extruder pressure_advance: K[:SMOOTH_TIME]")
    parser.add_argument("--arc-resolution", type=float, default=1.0, help="Klipper's [gcode_arcs] (mm)")
    parser.add_argument("--klipper-home", choices=("ours", "config"), default="ours",
                        help="Klipper's position_endstop: where our homing leaves the tool, or printer.cfg's")
    parser.add_argument("--same-limits", action="store_true", help="M204/M205 left out on both sides")
    parser.add_argument("--keep", type=Path, help="keep Klipper's files (printer.cfg, out.serial, log) there")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    setup = find_klipper()
    if setup is None:
        raise SystemExit("Klipper not found: see benchmarks/klipper_ref.py (KLIPPER_DIR, KLIPPER_PYTHON)")
    walls = {}
    with tempfile.TemporaryDirectory(prefix="klipper-steps-") as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        job, gcode = job_and_gcode(args.job.resolve(), work, args.same_limits)
        begin = time.perf_counter()
        host, ours = our_trains(job)
        walls["ours (host_build)"] = time.perf_counter() - begin
        endstops = None if args.klipper_home == "config" else \
            {SECTIONS[axis]: float(host.start[i]) for i, axis in enumerate("xyz") if axis in host.kin.motors}
        config = klipper_config(work, args.shaper, args.pressure_advance, args.arc_resolution, endstops)
        run = run_klipper(dataclasses.replace(setup, config=config), gcode, work / "klipper", verbose=False)
        walls["klipper"] = run.wall_s
        steps_per_mm = {m: host.job.machine.steppers[m].steps_per_mm for m in SECTIONS}
        begin = time.perf_counter()
        theirs = klipper_trains(run.serial_path, setup.dictionary, config, steps_per_mm)
        walls["decode"] = time.perf_counter() - begin
    begin = time.perf_counter()
    motors, drift = compare(ours, theirs)
    walls["compare"] = time.perf_counter() - begin
    result = {"job": str(args.job), "origin": "the first step of any motor, on each side",
              "options": {k: v for k, v in vars(args).items() if k not in ("job", "json", "keep")},
              "ours_duration_s": max(float(t.time[-1]) for t, _ in ours.values() if len(t.time)),
              "klipper_duration_s": max(float(t.time[-1]) for t in theirs.values() if len(t.time)),
              "drift_end_s": float(drift.offset[-1]) if len(drift.offset) else 0.0,
              "unknown_to_klipper": dict(run.unknown), "motors": motors, "wall_s": walls}
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print_table(result)


if __name__ == "__main__":
    main()

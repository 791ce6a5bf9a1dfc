"""Step by step against Klipper: every motor's steps of our plan (the twin's pulses) beside Klipper's on the
same G-code (issue 29: "each motor's step count equal; each motor's step times within 50 us of ours at
every step, or every difference explained").

    python benchmarks/klipper_steps.py [JOB.yaml] [--shaper mzv:50[:0.1]] [--pressure-advance 0.05[:0.04]]
        [--arc-resolution 1.0] [--same-limits] [--klipper-home ours|config] [--keep DIR] [--json]

Klipper's batch mode (benchmarks/klipper_ref.py) runs on the job's G-code (default: the Benchy of
examples/printers/benchy-mini.yaml) with benchmarks/klipper/printer.cfg plus [gcode_arcs], and [input_shaper]
and the extruder's pressure_advance as the job has them (`machine.input_shaper`, `machine.pressure_advance`,
where the job schema has them) or as the options say (the options set Klipper's only); with pressure advance
Klipper also gets M900 K / M572 S as macros calling SET_PRESSURE_ADVANCE (it answers them "Unknown command"
otherwise), so both sides follow the file's K changes (the Benchy's closing M900 K0). Its out.serial is
decoded by benchmarks/klipper_decode.py; the steps up to the end of its last homing pass are its G28 homing
(our firmware homes before the tables) and are left out. Ours are the twin's pulses (host_build). Both
sides' times count from the first step of any motor; positions from where homing leaves each side (Klipper
is given our start as position_endstop unless --klipper-home config). Steps are paired by the half-step
boundary they cross (benchmarks/klipper_compare.py), so the pairs hold although the two plans drift apart.
Printed per motor (a table, or --json): step counts, unpaired steps, per-step time differences "global"
(as they stand) and "local" (less the running median of the 17 pairs around: what is left once a smooth
planning drift is taken out), with the largest one's G-code line (ours); our position minus Klipper's at
each of Klipper's step times, "global" and "local" (at our time matching Klipper's by that running median).

What the differences are. Figures of 2026-11-29 (Klipper 84104bbbd) on two programs: the PrusaSlicer Benchy
with examples/printers/benchy-mini.yaml (12.5 M steps), and "small", benchy-mini's machine with
`G28 / G90 / M83 / G1 X20 Y10 F6000 / G1 X60 Y10 E2 F3000 / G1 X60 Y50 E2 / G2 X80 Y70 I20 J0 E1.5 F2400 /
G1 Z1 F600 / G4 P200 / G1 X20 Y20 F9000 / G3 X40 Y20 I10 J0 E2 F1800`.
- Step counts. small: equal on x and z; y 14,000 against Klipper's 13,998 with its default 1 mm arc chords
  (they cut 12.5 um inside a 10 mm radius, so Klipper's G3 stops 1 step short of y = 10 at its bottom; with
  --arc-resolution 0.1 both make 14,000); e 3,112 against 3,113: 7.5 mm is 3112.5 steps, a half step.
  Benchy: z equal (174,880); x +674, y +1,352, e +4 ours (of 5.2 M, 4.3 M, 2.8 M), final positions equal.
  The file writes X/Y with 3 decimals at 100 steps/mm, so a point can sit on a half step (85.105 mm =
  8510.5 steps): x turns back at such a point 871 times, y 926. We round such a point once (DESIGN.md,
  principle 3), Klipper steps when its float position reaches the boundary, so the two choose differently
  and where the path turns back one side makes one step out and back more. Klipper's choice depends on its
  timing: with --same-limits its x count is 72 lower, ours is the same.
- Planning (the "global" differences). Benchy: ours 2445.2 s from the first step to the last, Klipper
  2296.5 s; the drift reaches +148.6 s. By the kind of G-code line that gained it: extruding moves +167.6 s
  (the file's `M204 P800` / `M204 P1000` print accelerations, which we follow and Klipper refuses: it prints
  at 1250 from `M204 P1250 R1250 T2500`; and the file's classic jerk M205 X8 Y8, which we follow and Klipper
  ignores for its square_corner_velocity), travels -41.5 s (we travel at T = 2500 mm/s^2, Klipper at
  min(P, T) = 1250), retractions +16.4 s (R = 1250 for us, max_extrude_only_accel 5000 for Klipper), z
  +6.1 s. With --same-limits (M204/M205 left out on both sides: the same junction deviation at 2500
  mm/s^2): 2127.6 s against 2092.5 s, drift +35.1 s: extruding moves +55.0 s, z -8.9 s, retractions
  -6.4 s, travels -4.6 s. The largest gains of a single line (0.3-1.7 s) were a bug of ours, fixed since (now
  2389.1 s, drift +92.5 s): a straight move next to a short one that turned took the curvature of their vertex
  over the shorter chord (now the mean) and was capped by its centripetal limit along its whole length.
  `G28 / G1 X10 F3600 / G1 X10.001 / G1 X20 Y-1`: the last move takes us 2.26 s (x at 2.2-2.3 ms a step,
  4.4 mm/s) against Klipper's 0.187 s at 60 mm/s; without the 0.001 mm move, or with X20 instead of X20
  Y-1, both take the same. Benchy line 22648 (10.3 mm after the 0.001 mm `G1 X77.484 Y78.67 E.00006`):
  1.89 s against 0.18 s; line 10853 (14.7 mm before the 0.134 mm turn of line 10854): planned at 29.5 mm/s
  and 693 mm/s^2 instead of 80 mm/s, 0.52 s against 0.20 s. An estimate of its share: our --same-limits
  plan has 2,364 moves longer than 0.5 mm planned below 90 % of the speed their feed and length allow at
  2500 mm/s^2 with the same entry and exit speeds; they take 62 s more than that: about the +55 s.
  small: drift -20 ms: our limits are each motor's, Klipper's the toolhead's, so we accelerate
  `G1 X20 Y10 F6000` alone as if at 2795 mm/s^2 along it (each axis at 2500; first to last step 0.2562 s,
  Klipper 0.2594 s); and Klipper caps a corner where the extrusion ratio changes at instant_corner_velocity
  / change (its formula: 20 mm/s into X60 Y10 E2, where the junction deviation allows 30).
- Step times of the same motion (the "local" differences: less the running median of 17 pairs, which
  takes out a smooth planning drift). small, per G-code line, p99: 0-7 us on the straight moves for the
  motor that leads them, 70-150 us for a motor that follows (y on X20 Y20, e): our tables couple the motors
  by Bresenham, a follower steps on the leader's events, up to one leader interval from its own crossing;
  350-940 us on the arcs (Klipper's 1 mm chords against our 2 um tolerance: its chord corners slow and
  speed the axes). Our events keep within 5 % of the gap to the previous event, at most 100 us, of the plan
  (codegen/tables/compress.py), Klipper's steps within 25 us, early only: at a move's start and end, where
  steps are ms apart, this alone allows 125 us. Benchy local p99: x 297 us, y 445, z 2030, e 693 (--same-
  limits: 210, 292, 585, 468); over 50 us: 5 % of x, 10 % of y, 13 % of z, 30 % of e (a follower most of
  the time: coupling). z's 2 ms are its z-hop corners, which we take by the file's classic jerk M205 Z2
  (585 us without it). The largest local values are single steps at half-step points: x 0.655 s at line
  79154, where x rests on 93.965 mm (9396.5 steps) through a 16 mm y move, and one side steps at its start,
  the other when x moves on; y 1.41 s at line 58306 (y 83.905 mm before it), paired with the crossing of
  another pass because its own has no partner (unpaired: x 1,125 ours / 451 Klipper's, y 1,524 / 172).
- Positions (ours minus Klipper's at Klipper's step times). Global: meaningless beside a drift of 148 s
  (up to 85 mm). Local (at our time matching Klipper's by the local drift): within 1 step at 99 % of
  Klipper's steps, more than 1 step off at 4,118 x steps, 3,638 y, 4,906 z, 4,216 e (0.08 %-2.8 %), at most
  10 steps on x and 75 on y, where the drift jumps within a few steps and the running median lags it (y:
  the wipe at line 8715 after the retraction of line 8710, which Klipper makes at its 5000 mm/s^2, we at
  R = 1250). small: within 1 step everywhere.
- Homing. Klipper homes in out.serial; we leave its steps out (up to the end of its last homing pass).
  Our G28 starts the program at (0, 0, 0); printer.cfg puts Klipper's switches at position_endstop (-2, -4,
  0), the low ends of the job's ranges, where our `program.home: true` starts it too. So by default Klipper
  is given our start as position_endstop; --klipper-home config keeps printer.cfg's and shows the 200 x
  steps of `G28 / G1 X10 F3000` (ours 1,000, Klipper 1,200).
- G4 P0: Klipper (and Marlin) come to rest at it, we go on at speed (`G1 X20 F6000 / G4 P0 / G1 X40`: ours
  passes X20 at 100 mm/s, Klipper stops there: 0.29 s).
- Shaped: the i29-shaping branch of 06:59 (its job schema and planner), `machine.input_shaper` MZV 50 Hz
  on x and y, which Klipper then gets too. small (--arc-resolution 0.1): counts equal but e's half step,
  local p99 190 us x, 207 y, positions within 1 step: as unshaped. Benchy: x 5,203,970 against 5,201,720,
  y 4,325,724 against 4,322,430 (the shaped paths smooth corners; theirs and ours differ by up to a step,
  so more step pairs differ: +1,125 on x, +1,647 on y), z and e as unshaped; local p99 x 369 us, y 514,
  z 2027, e 763; positions within 1 step but at 679 x and 1,076 y steps, at most 9; 96 s in all (ours 31 s).
- Shaped and advanced (issue 29 item 4): MZV 50 Hz on x and y and K 0.05 (smooth_time 0.04) in the job, both
  sides. small (--arc-resolution 0.1): x, y, z equal; e 3,232 against 3,234: at the square corner of lines 5/6
  Klipper's extruder goes back 8 steps, ours 7: our corner is 9.17 mm/s, Klipper's 7.77 (our limits are each
  motor's), so less lead is given back; Klipper's formula on each plan (a brute-force quadrature, not our
  code) bottoms at 855.67 steps on ours, 854.66 on Klipper's, as each side steps. Local p99 x 182 us, y 206,
  z 89, e 519 (459 plain); positions within 1 step but at 2 e steps. Our e against the formula on our plan:
  within 0.79 step, as times p50 99 us, p99 587 us: chords (0.5 step) and Bresenham coupling, not the formula.
  M900 K0.02 / M572 D0 S0.08 inserted: both turn at the same positions. x-only and y-only lines: e 6,090
  against 6,096 at the reversals, where our junction is 0.95 mm/s (its direction includes e, as Marlin's),
  Klipper's 0 (x, y, z only), and we plan at 98 % of 2500 mm/s^2. Benchy, the file's limits: ours 2389.1 s,
  Klipper 2296.6 s (drift +92.5 s); x 5,204,134 against 5,201,920, y 4,325,660 against 4,322,430, z equal, e
  2,924,541 against 2,948,597 (final positions equal); unpaired x 3,126 / 912, y 4,004 / 774, e 53,677 /
  77,733. Local p99 x 393 us, y 575, z 2027, e 5,352; over 50 us 6.8 % of x, 11.7 % y, 12.7 % z, 35 % e;
  largest x 0.38 s (line 57315), y 0.19 s (27271), e 0.54 s (23537). Positions local within 1 step but at
  741 x (at most 9), 1,051 y (3), 4,919 z (3), 130,302 e steps (4.4 %, p99 7, at most 57 where the drift
  jumps). --same-limits: 2053.2 s against 2092.6 s (drift -39.4 s: per-motor limits); e 2,959,725 against
  2,966,051; local p99 x 338, y 475, z 206, e 1,598; over 1 step 711 x, 965 y, 134 z, 49,119 e (1.7 %).
  The extruder goes back wherever the lead K e' given back at a slowdown outruns the flow over the smoothing
  window, so the out-and-backs follow the corner speeds and accelerations: the file's M204/M205 (ours;
  Klipper prints at 1250 with its square_corner_velocity) make three quarters of the e difference, per-motor
  limits, e in the junction's direction and the margin the rest; where one side goes back and the other
  not, the pairing shifts (e's local milliseconds). Both advance only moves with x or y motion and e forward
  (Klipper's extruder.py; ours `can_advance`). A rule apart, unseen here: at K 0 Klipper stops smoothing,
  we keep smoothing (codegen/job/schema/advance.py); the Benchy's M900 K0 follows its last move.
- Klipper's batch mode may exit before writing its last messages (seen 1 run in 5-10 on a loaded machine:
  the last 19 % of a move, or whole moves, missing). Its copy of the program ends with M84; an output
  without the motors-off after its last step is made again ("klipper_runs" in --json).
Wall (2 cores shared with a fuzz run, Benchy): ours (host_build) 13-16 s, Klipper 7 s, decoding 1.4-1.8 s,
pairing and figures 35-37 s; 60 s and 4.6 GB peak in all. small: about 5 s in all. Shaped and advanced:
ours 21-33 s, Klipper 6-10 s, pairing 32-47 s; 63-95 s and 4.9 GB peak.
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

from klipper_compare import (BINS_S, Drift, Spread, Train, drift_of, nearest_pairs, occurrence_pairs,  # noqa: E402
                             position_at, trend)
from klipper_decode import decode, homing_end  # noqa: E402
from klipper_ref import CONFIG, find_klipper, run_klipper  # noqa: E402

JOB = HERE.parent / "examples" / "printers" / "benchy-mini.yaml"
LIMIT_US = 50.0
SECTIONS = {"x": "stepper_x", "y": "stepper_y", "z": "stepper_z", "e": "extruder"}  # cartesian motors
SAME_LIMITS_DROPPED = ("M204", "M205")
# Klipper answers M900 and M572 "Unknown command": with pressure advance it gets them as macros, so that both sides
# follow the file's K changes (ours: codegen/gcode/mcodes.py; without K or S nothing changes on either side).
ADVANCE_MACROS = """
[gcode_macro M900]
gcode:
  {% if 'K' in params %}SET_PRESSURE_ADVANCE ADVANCE={params.K}{% endif %}

[gcode_macro M572]
gcode:
  {% if 'S' in params %}SET_PRESSURE_ADVANCE ADVANCE={params.S}{% endif %}
"""


def shaping_of(machine, shaper: str | None, advance: str | None) -> tuple[dict, tuple | None]:
    """Klipper's shapers {axis: (type, freq, damping)} and pressure advance (k, smooth_time or None): the
    options' where given (TYPE:FREQ[:DAMPING] on x and y; K[:SMOOTH_TIME]), otherwise the job's
    `machine.input_shaper` and `machine.pressure_advance` (x and y: Klipper's [input_shaper] has no z)."""
    shapers = {}
    if shaper:
        kind, freq, *damping = shaper.split(":")
        shapers = {axis: (kind, float(freq), float(damping[0]) if damping else None) for axis in "xy"}
    elif getattr(machine, "input_shaper", None) is not None:
        shapers = {axis: (s.type, s.freq, s.damping) for axis, s in machine.input_shaper.axes.items() if axis in "xy"}
    if advance:
        k, *smooth = advance.split(":")
        return shapers, (float(k), float(smooth[0]) if smooth else None)
    job_advance = getattr(machine, "pressure_advance", None)
    return shapers, None if job_advance is None else (job_advance.k, job_advance.smooth_time)


def klipper_config(work: Path, shapers: dict, advance: tuple | None, arc_resolution: float,
                   endstops: dict[str, float] | None) -> Path:
    """printer.cfg with [gcode_arcs], the shapers and pressure advance (shaping_of), and `endstops` (section ->
    position_endstop, mm) where given (Klipper merges a section given twice: the lines can follow the file)."""
    extra = [f"\n[gcode_arcs]\nresolution: {arc_resolution}\n"]
    extra += [f"\n[{section}]\nposition_endstop: {mm:g}\n" for section, mm in (endstops or {}).items()]
    if shapers:
        extra.append("\n[input_shaper]\n" + "".join(
            f"shaper_type_{axis}: {kind}\nshaper_freq_{axis}: {freq:g}\n"
            + (f"damping_ratio_{axis}: {damping:g}\n" if damping is not None else "")
            for axis, (kind, freq, damping) in shapers.items()))
    if advance is not None:
        k, smooth = advance
        extra.append(f"\n[extruder]\npressure_advance: {k:g}\n"
                     + (f"pressure_advance_smooth_time: {smooth:g}\n" if smooth is not None else ""))
        extra.append(ADVANCE_MACROS)
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
    """Our job and Klipper's G-code file (inline G-code written out; with `same_limits` the M204/M205 lines
    become comments on both sides). Klipper's copy ends with M84: klipper_steps tells by it that the output
    is whole."""
    job = yaml.safe_load(job_path.read_text())
    gcode = job["program"]["gcode"]
    inline = "\n" in gcode.strip()
    text = gcode if inline else (job_path.parent / gcode).read_text()
    if same_limits:
        text = "\n".join(";" + line if line.lstrip().upper().startswith(SAME_LIMITS_DROPPED) else line
                         for line in text.splitlines()) + "\n"
    theirs = work / "klipper.gcode"
    theirs.write_text(text + ("" if text.endswith("\n") else "\n") + "M84\n")
    if not same_limits and not inline:
        return job_path, theirs
    written = work / "program.gcode"
    written.write_text(text)
    job["program"]["gcode"] = str(written)
    job.setdefault("name", job_path.stem)
    ours = work / job_path.name
    ours.write_text(yaml.safe_dump(job, sort_keys=False))
    return ours, theirs


def our_trains(job_path: Path):
    """Our steps per motor from the twin: (host, {motor: (Train, G-code line of each step)})."""
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


def klipper_steps(setup, config: Path, gcode: Path, work: Path, attempts: int = 3):
    """Klipper's run and its decoded steps: (run, steppers, messages, runs it took). Batch mode may exit before it has
    written its last messages (it seemed to on a loaded machine: the last 19 % of a move missing); the M84
    that ends Klipper's copy of the program switches the motors off after every step, so an output without
    that switch after the last step is incomplete, and Klipper runs again."""
    pins = {section: (pin, inverted) for section, (pin, inverted, _) in stepper_pins(config).items()}
    for attempt in range(1, attempts + 1):
        run = run_klipper(dataclasses.replace(setup, config=config), gcode, work, verbose=False)
        steppers, messages = decode(run.serial_path, setup.dictionary, pins)
        _, switched = messages.of("queue_digital_out")
        last_step = max((int(s.clock[-1]) for s in steppers.values() if len(s.clock)), default=0)
        if len(switched["clock"]) and (int(switched["clock"][-1]) - last_step) % 2**32 < 2**31:  # 32-bit clocks
            return run, steppers, messages, attempt
    raise SystemExit(f"Klipper's output stayed incomplete in {attempts} runs (its log: {run.log_path})")


def klipper_trains(steppers: dict, messages, config: Path, steps_per_mm: dict[str, float]) -> dict:
    """Klipper's program steps per motor (after its homing), from the first step of any motor."""
    endstops = {section: mm for section, (_, _, mm) in stepper_pins(config).items()}
    homed = homing_end(messages, steppers)
    program = {motor: steppers[section].clock > homed for motor, section in SECTIONS.items()}
    firsts = [steppers[SECTIONS[m]].clock[program[m]][:1] for m in SECTIONS]
    origin = int(np.concatenate(firsts).min()) if any(len(f) for f in firsts) else 0
    trains = {}
    for motor, section in SECTIONS.items():
        steps = steppers[section]
        start = round(endstops[section] * steps_per_mm[motor]) if motor != "e" else 0
        clock = steps.clock[program[motor]]
        trains[motor] = Train((clock - origin) / messages.dictionary.clock_hz, steps.dir[program[motor]], start)
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
    parser.add_argument("--shaper", help="Klipper's [input_shaper] on x and y: TYPE:FREQ[:DAMPING] (default: "
                                         "the job's machine.input_shaper)")
    parser.add_argument("--pressure-advance", help="Klipper's extruder pressure_advance: K[:SMOOTH_TIME] (default: "
                                                   "the job's machine.pressure_advance)")
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
        shapers, advance = shaping_of(host.job.machine, args.shaper, args.pressure_advance)
        config = klipper_config(work, shapers, advance, args.arc_resolution, endstops)
        begin = time.perf_counter()
        run, steppers, messages, klipper_runs = klipper_steps(setup, config, gcode, work / "klipper")
        walls["klipper"] = run.wall_s
        walls["decode"] = time.perf_counter() - begin - run.wall_s  # and any run made again
        steps_per_mm = {m: host.job.machine.steppers[m].steps_per_mm for m in SECTIONS}
        theirs = klipper_trains(steppers, messages, config, steps_per_mm)
    begin = time.perf_counter()
    motors, drift = compare(ours, theirs)
    walls["compare"] = time.perf_counter() - begin
    result = {"job": str(args.job), "origin": "the first step of any motor, on each side",
              "klipper_shaping": {"input_shaper": shapers, "pressure_advance": advance},
              "klipper_runs": klipper_runs,  # more than 1: an output found incomplete was made again
              "options": {k: v for k, v in vars(args).items() if k not in ("job", "json", "keep")},
              "ours_duration_s": max((float(t.time[-1]) for t, _ in ours.values() if len(t.time)), default=0.0),
              "klipper_duration_s": max((float(t.time[-1]) for t in theirs.values() if len(t.time)), default=0.0),
              "drift_end_s": float(drift.offset[-1]) if len(drift.offset) else 0.0,
              "unknown_to_klipper": dict(run.unknown), "motors": motors, "wall_s": walls}
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print_table(result)


if __name__ == "__main__":
    main()

"""`printer-codegen calibrate ringing|pressure-advance JOB.yaml [--out FILE.gcode]`: a calibration print for the
job's machine (codegen/calibrate/), written as FILE.gcode and the job file that runs it (FILE.yaml beside it: the
machine of JOB.yaml, the G-code as its program), and the table of which band has which value on stdout (`--json`:
one JSON object). Both jobs plan and verify like any other: the pressure advance job's machine has
`pressure_advance` (the machine's, else K --start with Klipper's smoothing time), which M900 needs. On a delta the
pattern must lie within the disc around the bed's middle its rods reach at the pattern's heights (Delta.reach):
else --size, --height, --end or --length is refused with the value that fits."""

from __future__ import annotations

import json
import math
from pathlib import Path

from codegen import __version__
from codegen.calibrate import Calibration, PressureAdvanceTest, RingingTest, pressure_advance_pattern, ringing_test
from codegen.calibrate.layout import number, placement
from codegen.cli.config import job_yaml
from codegen.errors import Diagnostic, JobError, SourceRef
from codegen.job import load_job
from codegen.job.schema import DEFAULT_SMOOTH_TIME, SHAPER_MAX_DAMPING
from codegen.job.schema.shaping import DEFAULT_SHAPER_DAMPING, SHAPER_HZ
from codegen.kinematics import make_kinematics
from codegen.pipeline.normalized import Section, normalized_job

DEFAULT_FOLDER = Path("build") / "calibrate"


def add_parser(verbs) -> None:
    v = verbs.add_parser("calibrate", help="write a calibration print for the job's machine: ringing (M593 F by "
                                           "height) or pressure-advance (M900 K by line)")
    tests = v.add_subparsers(dest="test", required=True)
    ringing = tests.add_parser("ringing", help="a ringing tower whose input shaper frequency (M593 F) changes every "
                                               "few mm of height (a plotted pattern without an extruder)")
    ringing.set_defaults(handler=cmd_ringing)
    _common(ringing, "ringing")
    defaults = RingingTest()
    ringing.add_argument("--start", type=float, default=defaults.start, help="Hz, the lowest band's (default 20)")
    ringing.add_argument("--end", type=float, default=defaults.end, help="Hz, the highest band's at most (default 80)")
    ringing.add_argument("--step", type=float, default=defaults.step, help="Hz from band to band (default 5)")
    ringing.add_argument("--type", choices=tuple(SHAPER_MAX_DAMPING),
                         help="the shaper (default: the machine's input_shaper type, else Marlin's zv)")
    ringing.add_argument("--axis", choices=("x", "y"), help="shape this axis alone (M593 X or Y; default both)")
    ringing.add_argument("--damping", type=float, help="the damping ratio (M593 D; default the machine's, or 0.1)")
    ringing.add_argument("--height", type=float, default=defaults.height, help="mm, the tower (default 60)")
    ringing.add_argument("--size", type=float, default=defaults.size, help="mm, its side (default 40)")
    ringing.add_argument("--layer-height", type=float, default=defaults.layer, help="mm (default 0.3)")
    ringing.add_argument("--speed", type=float, help="mm/s on the sides (default 100, at most the motors')")
    advance = tests.add_parser("pressure-advance", help="lines printed slow-fast-slow, each with its own pressure "
                                                        "advance K (M900 K)")
    advance.set_defaults(handler=cmd_pressure_advance)
    _common(advance, "pressure-advance")
    defaults = PressureAdvanceTest()
    advance.add_argument("--start", type=float, default=defaults.start, help="s, the first line's K (default 0)")
    advance.add_argument("--end", type=float, default=defaults.end, help="s, the last line's at most (default 0.1)")
    advance.add_argument("--step", type=float, default=defaults.step, help="s from line to line (default 0.005)")
    advance.add_argument("--slow", type=float, default=defaults.slow, help="mm/s, the lines' ends (default 20)")
    advance.add_argument("--fast", type=float, default=defaults.fast, help="mm/s, their middle (default 100)")
    advance.add_argument("--length", type=float, default=defaults.length, help="mm, a line (default 80)")
    advance.add_argument("--layer-height", type=float, default=defaults.layer, help="mm (default 0.2)")


def _common(v, test: str) -> None:
    v.add_argument("job", help="the job file (YAML) whose machine prints it")
    v.add_argument("--out", metavar="FILE.gcode", help=f"the G-code (default build/calibrate/<name>-{test}.gcode); "
                                                       "the job file that runs it goes beside it as FILE.yaml")
    v.add_argument("--json", action="store_true", help="print one JSON object: the files and the bands")


def _refuse(option: str, message: str) -> JobError:
    return JobError([Diagnostic(SourceRef(option), message)])


def _sweep(args, low: float, high: float, unit: str) -> None:
    """--start, --end and --step: a range within [low, high] going up."""
    for option in ("start", "end"):
        value = getattr(args, option)
        if not low <= value <= high:
            raise _refuse(f"--{option}", f"{value:g} {unit}: must be from {low:g} to {high:g}")
    if not args.start <= args.end:
        raise _refuse("--end", f"{args.end:g} {unit}: must be >= --start ({args.start:g})")
    if not args.step > 0:
        raise _refuse("--step", f"{args.step:g} {unit}: must be > 0")
    for option in ("height", "size", "layer_height", "speed", "slow", "fast", "length"):
        value = getattr(args, option, None)
        if value is not None and not value > 0:
            raise _refuse(f"--{option.replace('_', '-')}", f"{value:g}: must be > 0")


def cmd_ringing(args) -> int:
    job = load_job(Path(args.job), program_required=False)
    _sweep(args, *SHAPER_HZ, "Hz")
    machine = normalized_job(job)["machine"]
    shaper = dict(machine.get("input_shaper") or {"x": None, "y": None, "z": None, "max_smoothing": None})
    axes = [args.axis] if args.axis else ["x", "y"]
    for axis in axes:
        given = shaper.get(axis) or {}
        kind = args.type or given.get("type", "zv")
        damping = args.damping if args.damping is not None else given.get("damping", DEFAULT_SHAPER_DAMPING)
        if not 0 < damping <= SHAPER_MAX_DAMPING[kind]:
            raise _refuse("--damping", f"{damping:g}: the damping ratio of {kind} must be > 0 and <= "
                                       f"{SHAPER_MAX_DAMPING[kind]:g}")
        if args.type:  # the machine's input_shaper gives M593 its type
            shaper[axis] = {"type": kind, "freq": args.start, "damping": damping}
    machine["input_shaper"] = shaper if any(shaper.get(a) for a in ("x", "y", "z")) else None
    test = RingingTest(args.start, args.end, args.step, args.damping, args.axis, args.height, args.size,
                       args.layer_height, args.speed)
    place = _placement(job, (args.size, args.size))
    calibration = ringing_test(test, place)
    if job.machine.kinematics == "delta":
        _fit_ringing(args, make_kinematics(job.machine), place, calibration)
    return _write(args, job, machine, "ringing", calibration)


def cmd_pressure_advance(args) -> int:
    job = load_job(Path(args.job), program_required=False)
    _sweep(args, 0.0, 10.0, "s")  # K: Klipper's typical 0 to 1 s, Marlin's K up to 10
    test = PressureAdvanceTest(args.start, args.end, args.step, args.slow, args.fast, args.length,
                               layer=args.layer_height)
    try:
        calibration = pressure_advance_pattern(test, _placement(job, (args.length, args.length)))
    except ValueError as error:
        raise _refuse(str(job.path), f"calibrate pressure-advance: {error}") from None
    if job.machine.kinematics == "delta":
        _fit_lines(args, make_kinematics(job.machine), test, calibration)
    machine = normalized_job(job)["machine"]
    if machine.get("pressure_advance") is None:  # M900 K needs it (its smoothing time: Klipper's default)
        machine["pressure_advance"] = {"k": args.start, "smooth_time": DEFAULT_SMOOTH_TIME}
    return _write(args, job, machine, "pressure-advance", calibration)


def _placement(job, size: tuple[float, float]):
    start = job.program.start if job.program is not None else (0.0, 0.0)
    return placement(job.machine, start, size)


def _down(value: float) -> float:
    """`value` rounded down to 0.1 mm: a size that fits."""
    return math.floor(value * 10.0) / 10.0


def _widest(kin, z: float) -> float:
    """How far from the bed's middle the delta reaches at height `z` (refused where not even the middle)."""
    widest = kin.reach(z, z)
    if widest < 0.0:
        raise _refuse("--layer-height", f"{z:g} mm: this delta reaches z {kin.highest(0.0):.1f} mm at most")
    return widest


def _fit_ringing(args, kin, place, calibration: Calibration) -> None:
    """The tower's corners (the plotted card's at most) within the delta's reach at every height the tower has."""
    half = args.size / math.sqrt(2.0)  # from the bed's middle to a corner
    low, high = (args.layer_height, calibration.bands[-1].end) if place.printer else (place.draw_z,) * 2
    widest = _widest(kin, low)
    if half > widest:
        raise _refuse("--size", f"{args.size:g} mm: this delta reaches {widest:.1f} mm from the bed's middle at z "
                                f"{low:g} mm, a square's corners {half:.1f} mm: --size "
                                f"{_down(widest * math.sqrt(2.0)):g} at most")
    if half > kin.reach(low, high):  # its carriages would climb above their tops: a lower tower (whole bands)
        band = args.layer_height * len(calibration.bands)  # a layer more in every band
        tallest = kin.highest(half)
        fit = math.floor(tallest / band) * band
        raise _refuse("--height", f"{args.height:g} mm: a {args.size:g} mm tower reaches z {tallest:.1f} mm at most "
                                  f"on this delta: " + (f"--height {fit:g} at most" if fit > 0 else
                                                        "fewer bands (a larger --step)"))


def _fit_lines(args, kin, test, calibration: Calibration) -> None:
    """The pressure advance lines' ends within the delta's reach at the layer's height."""
    widest = _widest(kin, args.layer_height)
    across = max(abs(band.begin) for band in calibration.bands)  # the outer lines' y (the pattern is centred)
    if across > widest:
        lines = math.floor(2.0 * widest / test.spacing + 1e-9) + 1
        raise _refuse("--end", f"{args.end:g} s: {len(calibration.bands)} lines {test.spacing:g} mm apart span "
                               f"{2 * across:g} mm, this delta reaches {widest:.1f} mm from the bed's middle: "
                               f"--end {number(args.start + (lines - 1) * args.step)} at most ({lines} lines)")
    if math.hypot(args.length / 2.0, across) > widest:
        raise _refuse("--length", f"{args.length:g} mm: this delta reaches {widest:.1f} mm from the bed's middle, "
                                  f"the outer lines' ends would be {math.hypot(args.length / 2.0, across):.1f} mm: "
                                  f"--length {_down(2.0 * math.sqrt(widest ** 2 - across ** 2)):g} at most")


def _write(args, job, machine: dict, test: str, calibration: Calibration) -> int:
    """FILE.gcode and FILE.yaml, then the table (or --json)."""
    gcode = Path(args.out) if args.out else DEFAULT_FOLDER / f"{job.name}-{test}.gcode"
    job_file = gcode.with_suffix(".yaml")
    if job_file.resolve() == job.path.resolve():
        raise _refuse("--out", f"{gcode}: its job file would replace {job.path.name}: another name")
    gcode.parent.mkdir(parents=True, exist_ok=True)
    stamp = f"AUTO-GENERATED by printer-codegen {__version__} from {job.path.name} (calibrate {test}). Do not edit."
    gcode.write_text(f"; {stamp}\n{calibration.gcode}", encoding="utf-8")
    program = {"start": list(job.program.start) if job.program is not None else [0.0, 0.0],
               "home": bool(job.program is not None and job.program.home), "dialect": "marlin", "gcode": gcode.name}
    document = {"name": f"{job.name}-{test}", "target": job.target, "board": job.board, "machine": machine,
                "program": Section(program)}
    job_file.write_text(f"# {stamp}\n{job_yaml(document)}", encoding="utf-8")
    if args.json:
        print(json.dumps({"gcode": str(gcode), "job": str(job_file), "setting": calibration.setting,
                          "place": calibration.place,
                          "bands": [{"value": b.value, "begin_mm": round(b.begin, 6), "end_mm": round(b.end, 6)}
                                    for b in calibration.bands]}))
        return 0
    print(calibration.table())
    print(f"wrote {gcode} and {job_file}: printer-codegen plan {job_file}")
    return 0

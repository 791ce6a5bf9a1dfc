"""`printer-codegen tune JOB (--port PORT | --sim)`: Marlin's M303 relay test on a heater, run by the tune firmware
(codegen/firmware/avr/tune.py) on the real board or in simavr against the job's thermal plant; the host turns
the oscillation into Ziegler-Nichols gains and prints them as the job file's `heaters:` lines."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from codegen import progress
from codegen.errors import BuildError
from codegen.heaters.control import PID_PERIOD_S, fixed_gains, max_duty
from codegen.heaters.plant import heating_figures, simulate
from codegen.job import load_job
from codegen.program.heater_settings import heater_settings

if TYPE_CHECKING:  # the tune firmware (jinja2) and its host are imported by cmd_tune: the parser starts without them
    from codegen.link.tune import TuneHost

DEFAULT_TARGET_C = {"hotend": 210.0, "bed": 60.0}
MIN_ABOVE_C = 20.0  # a target this far above the heater's minimum at least: the relay must heat to cross it
CHECK_S = 300.0  # --sim: the tuned gains on the Python plant, from ambient, this long
AVRDUDE = ("avrdude", "-p", "atmega2560", "-c", "wiring", "-b", "115200", "-D")  # an Arduino Mega's bootloader


def add_parser(verbs) -> None:
    v = verbs.add_parser("tune", help="PID relay test on a heater (the real one over --port, or --sim), "
                                      "printing the gains for the job file")
    v.set_defaults(handler=cmd_tune)
    v.add_argument("job", help="the job file (YAML)")
    where = v.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", help="the board's serial port (flashed with the tune firmware), e.g. /dev/ttyACM0")
    where.add_argument("--sim", action="store_true", help="the same session in simavr with the job's thermal plant")
    v.add_argument("--heater", choices=tuple(DEFAULT_TARGET_C), default="hotend", help="default: hotend")
    v.add_argument("--target", type=float, help="degC (default: hotend 210, bed 60)")
    v.add_argument("--cycles", type=int, default=5, help="relay cycles to measure (default 5, at least 2)")
    v.add_argument("--out", help="the tune firmware's folder (default build/<name>/tune/)")
    v.add_argument("--flash", action="store_true", help="with --port: flash the tune firmware first (avrdude)")
    v.add_argument("--json", action="store_true", help="print one JSON object")
    v.add_argument("--quiet", action="store_true", help="no progress bar")


def _flash(hex_path: Path, port: str) -> None:
    cmd = [*AVRDUDE, "-P", port, "-U", f"flash:w:{hex_path}:i"]
    if shutil.which("avrdude") is None:
        raise BuildError(f"avrdude not found: install it, or flash {hex_path} yourself")
    if subprocess.run(cmd).returncode != 0:
        raise BuildError(f"flashing failed: {' '.join(cmd)}")


def _session(args, image, hex_path: Path, host: TuneHost) -> dict:
    """Run the relay; the simulated run's figures (the plant's hottest, simulated seconds) for --sim."""
    if args.sim:
        from codegen.sim.avr_plant import HeaterPlant
        from codegen.sim.avr_tune import simulate_tune

        h = image.heater
        run = simulate_tune(hex_path, image, host, HeaterPlant(h.plant, h.sensor, h.pullup_ohm))
        return {"simulated_s": round(run.seconds, 1), "plant_max_c": round(float(run.plant.temp_c.max()), 2)}
    from codegen.link.serial_port import open_port
    from codegen.link.tune import run_serial

    if args.flash:
        _flash(hex_path, args.port)
    elif not args.json:
        print(f"the board must run the tune firmware: flash {hex_path} (or add --flash)", file=sys.stderr)
    port = open_port(args.port, image.baud)
    try:
        run_serial(host, port, progress=progress.enabled() and not args.json)
    finally:
        port.close()
    return {}


def cmd_tune(args) -> int:
    from codegen.firmware.avr.tune import build_tune_image, tune_setup
    from codegen.link.tune import TuneHost, heaters_snippet

    job = load_job(Path(args.job))
    if job.target != "avr":
        raise BuildError(f"tune runs on the ATmega2560 boards only, not the {job.target} target")
    image = tune_setup(job, args.heater)
    target = DEFAULT_TARGET_C[args.heater] if args.target is None else args.target
    h = image.heater
    if args.cycles < 2 or not h.min_temp_c + MIN_ABOVE_C <= target < h.max_temp_c:
        print(f"error: --cycles must be 2 or more, and --target within {h.min_temp_c + MIN_ABOVE_C:g}.."
              f"{h.max_temp_c:g} degC (the {args.heater}'s limits)", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path("build") / job.name / "tune"
    hex_path = build_tune_image(image, out)
    host = TuneHost(args.heater, target, args.cycles, max_duty(image.heater.max_power))
    extra = _session(args, image, hex_path, host)
    result = {"heater": args.heater, "target_c": target, "outcome": host.outcome, "trip": host.trip,
              "error": host.error, "image": str(hex_path), **extra,
              "cycles": [vars(c) for c in host.relay.cycles]}
    cycle = host.result() if host.outcome == "finished" else None
    if cycle is not None:
        kp, ki, kd = cycle.gains()
        result["gains"] = {"kp": kp, "ki": ki, "kd": kd}
        controls = {name: s.control for name, s in heater_settings(job).items()}
        result["snippet"] = heaters_snippet({**controls, args.heater: {"pid": result["gains"]}})
        if args.sim:  # what the gains do on the same plant (the Python loop of codegen/heaters/plant.py)
            sim = simulate(h.plant, fixed_gains(kp, ki, kd, PID_PERIOD_S, h.max_power), CHECK_S, h.sensor, target,
                           h.pullup_ohm)
            fig = heating_figures(sim, target)
            result["check"] = {"overshoot_c": fig.overshoot_c, "band_c": fig.band_c,
                               "time_to_target_s": fig.time_to_target_s}
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print(result, host)
    return 0 if cycle is not None else 130 if host.outcome == "stopped" else 1


def _print(result: dict, host: TuneHost) -> None:
    where = f"simulated {result['simulated_s']} s" if "simulated_s" in result else "on the board"
    print(f"tune {result['heater']} at {result['target_c']:g} degC ({where}): {result['outcome']}")
    for k, c in enumerate(host.relay.cycles, 1):
        kp, ki, kd = c.gains()
        print(f"  cycle {k}: duty {c.high_duty}/{c.low_duty}, {c.t_min_c:.1f}..{c.t_max_c:.1f} degC, "
              f"period {c.period_s:.1f} s: kp {kp:.2f} ki {ki:.3f} kd {kd:.2f}")
    if result["trip"]:
        print(f"  stopped by the thermal protection: {result['trip']} (the heater is off; reset the board)")
    if result["error"]:
        print(f"  error: {result['error']}")
    if "gains" in result:
        check = result.get("check")
        if check and check["band_c"] is not None:
            print(f"  with these gains the simulated plant overshoots {check['overshoot_c']:.2f} degC and holds "
                  f"within +-{check['band_c']:.2f} degC")
        elif check:
            print(f"  with these gains the simulated plant does not reach {result['target_c']:g} degC in "
                  f"{CHECK_S:g} s")
        print("the last cycle's gains, for the job file (under machine:; keep your heaters' other keys):")
        print(result["snippet"], end="")

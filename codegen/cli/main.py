"""The command line (CLI.md): build, verify, plan, and streaming (codegen/cli/stream.py). Exit codes: 0 ok, 1 build/verification failed, 2 bad input."""

from __future__ import annotations

import argparse
import ctypes
import hashlib
import importlib
import json
import os
import sys
from pathlib import Path

from codegen import __version__, progress
from codegen.cli import batch as cli_batch
from codegen.cli import calibrate as cli_calibrate
from codegen.cli import config as cli_config
from codegen.cli import flash as cli_flash
from codegen.cli import tune as cli_tune
from codegen.cli.outputs import IMAGE_FILES, flash_dir, job_name_guess, stream_dir, whole_or_none
from codegen.errors import BuildError, JobError, render_all
from codegen.firmware.config import Image
from codegen.job import load_job
from codegen.pipeline.host import HostBuild, host_build
from codegen.report.summaries import build_report, human_plan, motion, plan_summary, write_json, write_trace
from codegen.tables.format import stream_bytes
from codegen.verify.resonance import resonance_option
from codegen.verify.results import verify_json, vibration_lines
# verify's other modules and codegen/cli/stream.py (the simulators, jinja2) are imported in the functions that use
# them: the parser and plan start without them (tests/cli/test_lazy_imports.py)

SIMULATORS = {"avr": "simavr", "mcs51": "s51"}
TARGET_MODULES = {"firmware": "codegen.firmware.{target}.image", "sim": "codegen.sim.{target}"}


def _target_module(kind: str, target: str):
    name = TARGET_MODULES[kind].format(target=target)
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as error:
        if error.name != name:
            raise
        raise BuildError(f"the {target} target has no {kind} support yet") from None


def _fingerprint(sources: dict[str, str]) -> str:
    digest = hashlib.sha256(__version__.encode())
    for name in sorted(sources):
        digest.update(name.encode() + b"\0" + sources[name].encode() + b"\0")
    return digest.hexdigest()


def _image_from_report(out_dir: Path, data: dict) -> Image:
    elf = out_dir / data["elf"] if data.get("elf") else None
    return Image(out_dir / data["hex"], elf, data["flash_bytes"], data["ram_bytes"], data["table_bytes"],
                 data["flash_capacity"], data["ram_capacity"], dict(data["sections"]), dict(data["flash_parts"]),
                 dict(data["ram_parts"]))


def _host(job, strict: bool, keep: bool | str = True, observe=None) -> HostBuild:
    """The host side of the build; the front end's warnings go to stderr."""
    host = host_build(job, strict, keep=keep, observe=observe)
    if host.warnings:
        print(render_all(host.warnings), file=sys.stderr)
    return host


def _checked_host(job, strict: bool, keep: bool | str = True) -> HostBuild:
    host = _host(job, strict, keep)
    if not host.findings.ok:
        raise BuildError(f"{job.name}: the tables do not do what the job says:\n  "
                         + "\n  ".join(host.findings.problems))
    return host


FIT_HINT = ("what helps: a larger machine.tolerance (fewer chords on curves), fewer or shorter moves, or a chip "
            "with more flash")


def _build(job, out: str | None, reuse: bool, strict: bool, keep: bool | str = True) -> tuple[HostBuild, object, Path]:
    out_dir = flash_dir(job.name, out)
    with whole_or_none(lambda: out_dir):
        host = _checked_host(job, strict, keep)
        table = stream_bytes(host.schedule)
        if table >= host.target.flash_bytes:  # refuse before compiling megabytes of table
            raise BuildError(f"job {job.name} does not fit in flash: its tables alone need {table} bytes, the "
                             f"{host.target.mcu} has {host.target.flash_bytes}; {FIT_HINT}")
        firmware = _target_module("firmware", host.target.target)
        sources = firmware.render_sources(host.schedule, host.firmware_config())
        fingerprint = _fingerprint(sources)
        report_path = out_dir / "report.json"
        if reuse and report_path.is_file() and (out_dir / "firmware.hex").is_file():
            previous = json.loads(report_path.read_text(encoding="utf-8"))
            if previous.get("fingerprint") == fingerprint:
                try:
                    return host, _image_from_report(out_dir, previous["image"]), out_dir
                except KeyError:  # a report from an older printer-codegen: build again
                    pass
        out_dir.mkdir(parents=True, exist_ok=True)
        for name in IMAGE_FILES:  # the new image replaces the old one whole or not at all
            (out_dir / name).unlink(missing_ok=True)
        try:
            image = firmware.build_image(sources, out_dir, stream_bytes(host.schedule))
        except BuildError as error:
            raise BuildError(f"job {job.name}: {error}") from None
        write_json(report_path, build_report(host, image, fingerprint, sources))
    return host, image, out_dir


def cmd_build(args) -> int:
    job_path = Path(args.job)
    folder = stream_dir if args.stream else flash_dir
    with whole_or_none(lambda: folder(job_name_guess(job_path), args.out)):  # a failed build leaves no image
        if args.stream:
            from codegen.cli import stream as cli_stream
            return cli_stream.cmd_build_stream(args)
        job = load_job(job_path, args.target)
        host, image, out_dir = _build(job, args.out, reuse=False, strict=args.strict)
    print(f"built {out_dir / image.hex_path.name}: flash {image.flash_bytes} of {image.flash_capacity} bytes "
          f"(tables {stream_bytes(host.schedule)}), RAM {image.ram_bytes} of {image.ram_capacity} bytes")
    print(human_plan(plan_summary(host)))
    return 0


def cmd_verify(args) -> int:
    from codegen.cli import stream as cli_stream
    from codegen.verify.bounded import verify_flash
    from codegen.verify.compare import compare, simulated_switches
    from codegen.verify.heaters import job_faults, verify_heaters
    from codegen.verify.hold import hold_verify, pauses

    if cli_batch.is_batch(args):  # several jobs, a folder, --jobs or --junit: codegen/cli/batch.py
        return cli_batch.cmd_verify_many(args)
    args.job = args.job[0]  # one job file: the single verify below
    if args.stream:
        host, result, trace, samples, headline = cli_stream.verify_stream(args)
        return _conclude_verify(args, host, result, trace, headline, samples)
    job = load_job(Path(args.job), args.target)
    if cli_stream.bounded(args, job.target, job):  # codegen/verify/bounded.py: a chapter at a time, on two cores
        host, image, out_dir = _build(job, args.out, reuse=True, strict=args.strict, keep="tables")
        result, compared = verify_flash(host, image, job_faults(args.fault, tuple(h.name for h in host.heaters)),
                                        args.strict, cli_stream.run_outputs(args))
        result = _shipped(host, image, result)
        return _conclude_verify(args, host, result, compared.trace, _verify_headline(host, result, out_dir),
                                compared.samples)
    # an ATmega2560's held run is compared a chapter at a time (codegen/verify/hold_bounded.py) unless --report or
    # --vcd want it whole
    tables_only = job.target == "avr" and job.machine.feed_hold is not None and not (args.report or args.vcd)
    host, image, out_dir = _build(job, args.out, reuse=True, strict=args.strict, keep="tables" if tables_only else True)
    faults = job_faults(args.fault, tuple(h.name for h in host.heaters))
    held = args.hold is not None or args.override is not None or pauses(host)
    if tables_only and not held:  # no request, no M0/M1: a chapter at a time, as an image without feed_hold
        result, compared = verify_flash(host, image, faults, args.strict, cli_stream.run_outputs(args))
        result = _shipped(host, image, result)
        return _conclude_verify(args, host, result, compared.trace, _verify_headline(host, result, out_dir),
                                compared.samples)
    if held:
        steps_csv = Path(args.trace) if tables_only and args.trace else None  # written as the run is compared
        args.trace = None if steps_csv else args.trace
        result, trace = hold_verify(host, image, args.hold, args.override, steps_csv=steps_csv)
    elif host.heaters:
        result, trace = verify_heaters(host, image, faults)
    else:
        simulator = _target_module("sim", host.target.target)
        budget = int((host.plan.total * 1.2 + 1.0) * host.target.f_cpu)
        switches = simulated_switches(host)
        trace = simulator.simulate(image.hex_path, host.firmware_config(), budget, switches=switches)
        result = verify_json(host, compare(host, trace, switches, resonance=tuple(args.resonance)), image)
    result = _shipped(host, image, result)
    return _conclude_verify(args, host, result, trace, _verify_headline(host, result, out_dir))


def _shipped(host: HostBuild, image, result: dict) -> dict:
    """verify's result, failed where the image's table is not the schedule the twin played."""
    from codegen.verify.shipped import shipped_problems

    problems = shipped_problems(image, host.target.target, host.schedule)
    if problems:
        result.update({"pass": False, "problems": problems + result["problems"]})
    return result


def _verify_headline(host: HostBuild, result: dict, out_dir: Path) -> list[str]:
    return [f"{'PASS' if result['pass'] else 'FAIL'} {host.job.name}: {out_dir / 'firmware.hex'} in "
            f"{SIMULATORS[host.target.target]}, {result['duration_s']:.4f} s simulated, "
            f"{result['planned_duration_s']:.4f} s planned"]


def _conclude_verify(args, host: HostBuild, result: dict, trace, headline: list[str], samples=None) -> int:
    """verify's output: the files not written as the run was compared, then the JSON, or `headline` and the
    verdict's lines. `samples`: what --report draws, where it was gathered as the run was compared."""
    from codegen.verify.heaters import heater_lines, trip_lines
    from codegen.verify.report_samples import whole_run_samples
    from codegen.verify.waveform import write_vcd

    if args.trace:
        write_trace(Path(args.trace), host, trace)
    if args.vcd:
        write_vcd(Path(args.vcd), host.job.name, trace)
    if args.report:  # codegen/report/html.py, with matplotlib: imported only here
        from codegen.report.html import write_verify_report
        write_verify_report(Path(args.report), host, result, trace, samples or whole_run_samples(host, trace))
    if args.json:
        print(json.dumps(result, indent=2))
        return 0 if result["pass"] else 1
    print("\n".join(headline))
    if "trip" in result:  # the thermal protection stopped the machine (codegen/verify/heaters.py)
        print("\n".join(trip_lines(result) + heater_lines(result)))
        for problem in result["problems"][1:]:
            print(f"  problem: {problem}")
        return 1
    _print_verdict(result)
    return 0 if result["pass"] else 1


def _print_verdict(result: dict) -> None:
    """verify's text lines after the first: motors, path, display, heaters, problems."""
    from codegen.verify.heaters import heater_lines
    from codegen.verify.hold import hold_lines

    for name, m in result["motors"].items():
        timing = ("timing not compared" if m["max_timing_error_us"] is None
                  else f"timing within {m['max_timing_error_us']:.2f} us of the twin")
        print(f"  {name}: {m['steps']} steps, {motion(m)}, {timing}, rate {100 * m['max_rate_ratio']:.1f} %"
              f", accel {100 * m['max_accel_ratio']:.1f} % of limit, pulse {m['min_pulse_us']:.2f} us")
    if result["max_path_error_mm"] is not None:
        print(f"  path error {result['max_path_error_mm']:.4f} mm (limit {result['path_limit_mm']:.4f} mm)")
    if "gcode_checked" in result:
        done = result["gcode_checked"]
        print(f"  G-code read again: {done['ends']} line ends, {done['feeds']} feeds, {done['arcs']} arcs and "
              f"{done['dwells']} dwells as written")
    if "pressure_advance_steps" in result:
        print(f"  pressure advance: the simulated extruder within {result['pressure_advance_steps']:.3f} steps of the "
              "formula at every pulse")
    for reason in result["not_compared"]:
        print(f"  not compared: {reason}")
    if result.get("display") is not None:
        print(f"  display at the end: |{result['display'][0]}| / |{result['display'][1]}|")
    if "heaters" in result:
        print("\n".join(heater_lines(result)))
    if "hold" in result:
        print("\n".join(hold_lines(result["hold"])))
    for line in vibration_lines(result.get("vibration", {})):
        print(line)
    if "laser" in result:
        laser = result["laser"]
        print(f"  laser: PWM {laser['pwm_hz']:g} Hz, power within {laser['max_power_error_pct']:.2f} % of full scale "
              f"of the plan at every step, {laser['cuts']} cuts, energy per mm within "
              f"{laser['max_energy_per_mm_error_pct']:.2f} %")
    for problem in result["problems"]:
        print(f"  problem: {problem}")


def cmd_plan(args) -> int:
    if args.stream:
        from codegen.cli import stream as cli_stream
        return cli_stream.cmd_plan_stream(args)
    job = load_job(Path(args.job), args.target)
    samples = None
    if args.report:  # what the report draws, gathered a window at a time (memory bounded as without it)
        from codegen.report.plan_samples import PlanSamples
        samples = PlanSamples()
    if args.tables is None:
        host = _host(job, args.strict, keep=False, observe=samples)
    else:
        host = _plan_writing_tables(job, args.strict, Path(args.tables), samples)
    summary = plan_summary(host)
    print(json.dumps(summary, indent=2) if args.json else human_plan(summary))
    if args.report:  # codegen/report/html.py, with matplotlib: imported only here
        from codegen.report.html import write_plan_report
        write_plan_report(Path(args.report), host, summary, samples)
    return 0 if summary["pass"] else 1


def _plan_writing_tables(job, strict: bool, path: Path, observe=None) -> HostBuild:
    """The plan, its table stream written to `path` as it is made; no file unless every check passes."""
    partial = path.with_name(f".{path.name}.partial")
    try:
        with open(partial, "wb") as tables:
            host = host_build(job, strict, keep=False, tables=tables, observe=observe)
        if host.warnings:
            print(render_all(host.warnings), file=sys.stderr)
        if host.findings.ok:
            partial.replace(path)
        return host
    finally:
        partial.unlink(missing_ok=True)


def cmd_stream(args) -> int:
    from codegen.cli import stream as cli_stream
    return cli_stream.cmd_stream(args)


def _fault(text: str) -> tuple[str, str | None, float]:
    """--fault's type (codegen/verify/heaters.py's fault_spec), its module imported only where verify is given one."""
    from codegen.verify.heaters import fault_spec
    return fault_spec(text)


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="printer-codegen",
        description="Plan a job (machine + shapes or G-code) on the host, build step-table firmware for an "
                    "ATmega2560 or an 8051, and verify the image pulse by pulse in a simulator.",
        epilog="Exit codes: 0 success; 1 the build failed, the job does not fit, or verification found a "
               "difference; 2 bad input (file:line:col: error: ... on stderr).")
    p.add_argument("--version", action="version", version=f"printer-codegen {__version__}")
    verbs = p.add_subparsers(dest="verb", required=True)
    for name, handler, help_text in (
        ("build", cmd_build, "plan the job and build the firmware image"),
        ("verify", cmd_verify, "build (or reuse the build), run the image in the simulator, compare with the plan"),
        ("plan", cmd_plan, "plan only: no compiler, no simulator"),
        ("stream", cmd_stream, "plan the job and stream it to a board running the streaming firmware"),
    ):
        v = verbs.add_parser(name, help=help_text)
        v.set_defaults(handler=handler)
        if name == "verify":  # several jobs or folders: codegen/cli/batch.py
            v.add_argument("job", nargs="+", help="the job file (YAML); or several, and folders (see 'several jobs')")
        else:
            v.add_argument("job", help="the job file (YAML)")
        v.add_argument("--target", choices=("avr", "mcs51"), help="override the job's target")
        v.add_argument("--strict", action="store_true", help="G-code codes skipped with a warning are errors")
        if name in ("build", "verify"):
            v.add_argument("--out", help="output folder (default build/<name>/)")
        if name in ("plan", "verify"):
            v.add_argument("--json", action="store_true", help="print one JSON object")
            v.add_argument("--report", metavar="FILE.html", help="write one self-contained HTML page of plots: the "
                           "tool path, each motor against its limits, timing, a stream's ring fill, heaters")
        if name != "stream":
            v.add_argument("--stream", action="store_true",
                           help="the machine's streaming firmware (no tables inside): the job goes over the link")
        if name != "build":
            v.add_argument("--baud", type=int, help="the link's baud rate (default machine.link.baud, or the "
                                                   "target's: AVR 250000, 8051 9600)")
        v.add_argument("--quiet", action="store_true",
                       help="no progress bars (they show on stderr where it is a terminal, for stages over 2 s)")
        if name == "stream":
            v.add_argument("--port", required=True, help="the board's serial port, e.g. /dev/ttyACM0")
        if name == "verify":
            v.add_argument("--trace", help="write every simulated step pulse to this CSV file")
            v.add_argument("--vcd", metavar="FILE.vcd",
                           help="write the simulated pins (STEP, DIR, tool, enable, endstops, ...) as a waveform for "
                                "GTKWave; timescale 1 ns: each change at cycle x 1e9 / F_CPU from reset, rounded")
            v.add_argument("--hold", type=float, metavar="SECONDS",
                           help="press the feed hold key SECONDS into the job, resume once the machine is at "
                                "rest (machine.feed_hold; a flash image)")
            v.add_argument("--override", type=int, metavar="PERCENT",
                           help="step the feed override to PERCENT (10 up to machine.feed_hold.max_override, by 10) "
                                "with the feed keys as the job starts (machine.feed_hold)")
            v.add_argument("--fault", action="append", default=[], type=_fault, metavar="NAME[:HEATER]@SECONDS",
                           help="inject a fault into a heater's simulated plant at a simulated time (repeatable): "
                                "thermistor-open, thermistor-short, heater-dead, thermistor-loose; the heater "
                                "(hotend, bed) defaults to the hot end, e.g. thermistor-open:bed@30")
            v.add_argument("--resonance", action="append", default=[], type=resonance_option, metavar="AXIS=HZ[,ZETA]",
                           help="model the toolhead on AXIS as a spring of HZ and damping ratio ZETA (default 0.1; "
                                "repeatable) driven by the simulated pulses, and report its residual vibration after "
                                "every acceleration change, shaped and unshaped; by default the job's input shaper's")
            cli_batch.add_options(v)
        if name == "plan":
            v.add_argument("--tables", help="write the table stream (codegen/tables/format.py) to this file as it is made")
    cli_tune.add_parser(verbs)
    cli_config.add_parser(verbs)
    cli_flash.add_parser(verbs)
    cli_calibrate.add_parser(verbs)
    return p


M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters


def keep_freed_memory() -> None:
    """glibc returns the large arrays a window frees to the system and the next window faults them in again
    (about 100,000 page faults on a sliced print): keep them in the heap for reuse instead (mmap only above
    32 MiB, trim only above 1 GiB). Elsewhere nothing changes."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(M_MMAP_THRESHOLD, 32 << 20)
        libc.mallopt(M_TRIM_THRESHOLD, 1 << 30)
    except (OSError, AttributeError):
        pass


def main(argv: list[str] | None = None) -> int:
    keep_freed_memory()
    args = parser().parse_args(argv)
    progress.enable(sys.stderr.isatty() and not getattr(args, "quiet", False))  # config and flash have no --quiet
    try:
        return args.handler(args)
    except JobError as error:
        print(error.render(), file=sys.stderr)
        return error.exit_code
    except BuildError as error:
        print(f"error: {error}", file=sys.stderr)
        return error.exit_code
    except KeyboardInterrupt:  # Ctrl-C before anything went to a machine (a stream's own Ctrl-C sends ABORT)
        print("error: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of our output went away (`| head`): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1

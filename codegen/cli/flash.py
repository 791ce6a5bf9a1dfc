"""`printer-codegen flash JOB [--port PORT] [--dry-run] [--out DIR] [--stream]`: write the image `build` made for the
job to the board through its serial bootloader. The ATmega2560 (Arduino Mega's bootloader) with avrdude, the
STC89C52RC (STC's ISP loader in its boot ROM) with stcgal. The AT89C52 has no bootloader at all: it is programmed
out of the board, in the ZIF socket of a TL866II+ or T48 on USB, with minipro (no --port). Nothing is flashed unless
the image matches the job as it is now: report.json's `job_fingerprint` (codegen/pipeline/normalized.py)."""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

from codegen.errors import BuildError
from codegen.job import load_job
from codegen.pipeline.normalized import job_fingerprint
from codegen.targets import target_info

INSTALL = {"avrdude": "avrdude (Debian: apt-get install avrdude)", "stcgal": "stcgal (pip install stcgal)",
           "minipro": "minipro (https://gitlab.com/DavidGriffith/minipro)"}


def add_parser(verbs) -> None:
    v = verbs.add_parser(
        "flash", help="write the built image to the board: avrdude (ATmega2560), stcgal (STC89C52RC)",
        description="Flash build/<name>/firmware.hex (what `build` made for this job; refused when missing or "
                    "built from another version of the job). ATmega2560 boards (ramps-1.4, mks-gen-l): avrdude "
                    "through the Arduino Mega's bootloader (-c wiring -b 115200). STC89C52RC: stcgal (-P stc89); "
                    "switch the board off and on when stcgal asks. AT89C52 boards (at89c52, seed-51, coil-51): no "
                    "serial bootloader; the chip goes into the ZIF socket of a TL866II+ or T48 (USB), which "
                    "minipro programs (-p AT89C52 -w firmware.hex; no --port).")
    v.set_defaults(handler=cmd_flash)
    v.add_argument("job", help="the job file (YAML)")
    v.add_argument("--port", help="the board's serial port, e.g. /dev/ttyACM0 (Mega), /dev/ttyUSB0 (STC89C52RC); "
                                  "none for an AT89C52 in minipro's programmer")
    v.add_argument("--dry-run", action="store_true", help="print the programmer's command, run nothing")
    v.add_argument("--out", help="the build's folder (default build/<name>/, with --stream build/<name>/stream/)")
    v.add_argument("--stream", action="store_true", help="the machine's streaming firmware (build --stream)")
    v.add_argument("--target", choices=("avr", "mcs51"), help="override the job's target, as given to build")


def cmd_flash(args) -> int:
    job = load_job(Path(args.job), args.target, program_required=not args.stream)
    out_dir = Path(args.out) if args.out else Path("build") / job.name / ("stream" if args.stream else "")
    hex_path = out_dir / "firmware.hex"
    _check_fresh(job, args, hex_path)
    command = flash_command(job.board, args.port, hex_path)
    if command[0] != "minipro" and not args.port:
        print(f"error: flash: {command[0]} programs board {job.board} through its serial port: give --port "
              "(e.g. /dev/ttyACM0)", file=sys.stderr)
        return 2
    if args.dry_run:
        print(shlex.join(command))
        return 0
    if shutil.which(command[0]) is None:
        raise BuildError(f"{command[0]} not found: install {INSTALL[command[0]]}, or run it yourself: "
                         f"{shlex.join(command)}")
    if command[0] == "minipro":
        print("the AT89C52 in the programmer's ZIF socket (notch to the lever), the programmer on USB",
              file=sys.stderr)
    print(shlex.join(command), file=sys.stderr)
    done = subprocess.run(command)  # its progress (and stcgal's power-cycle prompt) on the terminal
    if done.returncode != 0:
        raise BuildError(f"{command[0]} failed (exit {done.returncode}): {shlex.join(command)}")
    print(f"flashed {hex_path} to {args.port or 'the AT89C52 in minipro'}")
    return 0


def _check_fresh(job, args, hex_path: Path) -> None:
    """BuildError unless `hex_path` and its report.json exist and the report's job fingerprint is the job's."""
    from codegen.pipeline.streaming import stream_setup  # here: main.py's parser imports this module

    build = ["printer-codegen", "build", args.job, *(["--target", args.target] if args.target else []),
             *(["--stream"] if args.stream else []), *(["--out", args.out] if args.out else [])]
    rebuild = f"run `{shlex.join(build)}` first"
    report_path = hex_path.with_name("report.json")
    if not hex_path.is_file() or not report_path.is_file():
        raise BuildError(f"no firmware image at {hex_path}: {rebuild}")
    recorded = json.loads(report_path.read_text(encoding="utf-8")).get("job_fingerprint")
    if recorded is None:
        raise BuildError(f"{hex_path} was built by an older printer-codegen (its report.json has no job "
                         f"fingerprint): {rebuild}")
    stream_baud = stream_setup(job).config.baud if args.stream else None  # the link rate build --stream gives it
    if recorded != job_fingerprint(job, stream_baud):
        raise BuildError(f"{hex_path} is stale: it was built from another version of {args.job} (the job, its "
                         f"G-code, the board file, --target, --stream or printer-codegen changed since): {rebuild}")


def flash_command(board: str, port: str | None, hex_path: Path) -> list[str]:
    """The programmer's command line for the board's MCU (an AT89C52's takes no port); BuildError for a chip
    without one."""
    target = target_info(board)
    if target.mcu == "atmega2560":  # the Arduino Mega's bootloader (stk500v2): -D, it erases page by page itself
        return ["avrdude", "-p", "atmega2560", "-c", "wiring", "-P", port, "-b", "115200", "-D",
                "-U", f"flash:w:{hex_path}:i"]
    if target.mcu == "stc89c52rc":
        return ["stcgal", "-P", "stc89", "-p", port, str(hex_path)]
    if target.mcu == "at89c52":  # out of the board, in a TL866II+ / T48: minipro reads the Intel HEX file
        return ["minipro", "-p", "AT89C52", "-w", str(hex_path)]
    raise BuildError(f"flash has no programmer for the {target.mcu} (board {board})")

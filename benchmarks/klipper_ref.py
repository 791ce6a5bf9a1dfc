"""Reference: Klipper's host (klippy in batch mode) on the same G-code file as our `plan`.

    python benchmarks/klipper_ref.py [--gcode FILE] [--copies N] [--repeat 3] [--cpu N] [--quiet]

Klipper's batch mode reads a G-code file and writes, instead of sending them to a micro-controller, the
commands it would send (step runs, pin changes) to a file:
`klippy.py printer.cfg -i file.gcode -o out.serial -v -d out/klipper.dict`. This module runs it as a child
process with benchmarks/klipper/printer.cfg (the machine of examples/printers/benchy-mini.yaml on an
ATmega2560 with a RAMPS 1.4) and measures the child's wall time, its own peak resident memory (from the
rusage that os.wait4 returns for it) and the bytes of out.serial. It holds no Klipper code and builds nothing.

What must be present (when it is absent, `find_klipper()` returns None and a comparison skips Klipper):
- Klipper's source at KLIPPER_DIR (environment variable; by default the folder `klipper` beside this
  repository), with klippy/klippy.py, and the data dictionary out/klipper.dict of a Klipper micro-controller
  build for the AVR atmega2560 at 16 MHz (Klipper's own build, made in that folder as its docs/Debugging.md
  describes). Klipper's source and anything built from it stay outside this repository.
- A Python with klippy's requirements (Klipper's scripts/klippy-requirements.txt: cffi, greenlet, pyserial,
  Jinja2, MarkupSafe), given by KLIPPER_PYTHON (environment variable; by default klipper-env/bin/python
  beside this repository), and gcc, with which klippy compiles its C helper on its first start. Run klippy
  once before timing it, so that the compile is not counted.

Each run starts a fresh klippy, which reads the whole file and exits; its log (stderr) is kept as
klippy.log in the work folder. A run fails (KlipperError, with the log's tail) when klippy exits non-zero:
a config error, a shutdown, or a G-code command it refused (batch mode stops at the first one, e.g. "Move
out of range", logged as a WARNING), or when the log lacks klippy's closing "Exiting (print time ...)".
Commands Klipper does not know (M73, M201, M203, M205, M900, G29 in the PrusaSlicer Benchy) and a lone
`M204 P..` are only answered, not refused; they are counted in KlipperRun.unknown.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CONFIG = Path(__file__).resolve().parent / "klipper" / "printer.cfg"
BENCHY = REPO / "tests" / "data" / "gcode" / "slicer" / "benchy-prusaslicer.gcode"
SERIAL_NAME, LOG_NAME = "out.serial", "klippy.log"

_EXITING = re.compile(r"Exiting \(print time ([0-9.]+)s\)")
_UNKNOWN = re.compile(r'Unknown command:"([^"]*)"|Invalid (M204) command')


class KlipperError(RuntimeError):
    """klippy failed: the message ends with the tail of its log."""


@dataclass(frozen=True)
class KlipperSetup:
    klipper_dir: Path  # Klipper's source tree
    python: Path  # a Python with klippy's requirements
    dictionary: Path  # out/klipper.dict of the atmega2560 build
    config: Path = CONFIG  # our printer.cfg

    @property
    def klippy(self) -> Path:
        return self.klipper_dir / "klippy" / "klippy.py"


@dataclass
class KlipperRun:
    wall_s: float  # the child's wall time, start to exit (time.perf_counter)
    peak_rss_bytes: int  # the child's own peak resident set (ru_maxrss of os.wait4)
    serial_bytes: int  # size of out.serial: the commands for the MCU
    print_time_s: float | None  # the print time klippy reached ("Exiting (print time ...)")
    user_s: float  # the child's CPU time
    sys_s: float
    unknown: Counter = field(default_factory=Counter)  # commands only answered "Unknown"/"Invalid"
    serial_path: Path | None = None
    log_path: Path | None = None

    @property
    def peak_rss_mib(self) -> float:
        return self.peak_rss_bytes / 2**20


def find_klipper() -> KlipperSetup | None:
    """Klipper's source, its atmega2560 dictionary and a Python for klippy, or None where any is missing."""
    klipper_dir = Path(os.environ.get("KLIPPER_DIR") or REPO.parent / "klipper")
    python = Path(os.environ.get("KLIPPER_PYTHON") or REPO.parent / "klipper-env" / "bin" / "python")
    setup = KlipperSetup(klipper_dir, python, klipper_dir / "out" / "klipper.dict")
    if not (setup.klippy.is_file() and setup.dictionary.is_file() and os.access(python, os.X_OK)):
        return None
    return setup


def _tail(log: Path, lines: int = 40) -> str:
    """The log's last lines, less the G-code comments that -v echoes."""
    try:
        text = log.read_text(errors="replace").splitlines()
    except OSError:
        return "(no log)"
    return "\n".join([line for line in text if not line.startswith("DEBUG:root:;")][-lines:])


def run_klipper(setup: KlipperSetup, gcode_path: str | os.PathLike, workdir: str | os.PathLike, *,
                verbose: bool = True, cpu: int | None = None) -> KlipperRun:
    """Run klippy's batch mode on `gcode_path`; out.serial and klippy.log go to `workdir`.

    verbose: klippy's -v, as in its docs' batch command (it logs every G-code comment: about 0.2 s on the
    Benchy). cpu: pin the child to that core (os.sched_setaffinity, as `taskset -c cpu`).
    """
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    serial, log = workdir / SERIAL_NAME, workdir / LOG_NAME
    serial.unlink(missing_ok=True)
    argv = [str(setup.python), str(setup.klippy), str(setup.config), "-i", str(Path(gcode_path).resolve()),
            "-o", str(serial), "-d", str(setup.dictionary)]
    if verbose:
        argv.insert(3, "-v")
    pin = (lambda: os.sched_setaffinity(0, {cpu})) if cpu is not None else None
    with open(log, "wb") as log_file:
        begin = time.perf_counter()
        child = subprocess.Popen(argv, cwd=workdir, stdin=subprocess.DEVNULL, stdout=log_file,
                                 stderr=subprocess.STDOUT, preexec_fn=pin)
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - begin
    child.returncode = os.waitstatus_to_exitcode(status)  # reaped here: tell Popen
    text = log.read_text(errors="replace")
    refused = [line for line in text.splitlines() if line.startswith(("WARNING:", "ERROR:"))]
    exiting = _EXITING.search(text)
    if child.returncode != 0 or refused or exiting is None or not serial.is_file():
        first = f"; first refusal: {refused[0]}" if refused else ""
        raise KlipperError(f"klippy failed on {gcode_path} (exit {child.returncode}){first}; "
                           f"log {log}, its tail:\n{_tail(log)}")
    unknown = Counter(a or b for a, b in _UNKNOWN.findall(text))
    return KlipperRun(wall_s=wall, peak_rss_bytes=usage.ru_maxrss * 1024, serial_bytes=serial.stat().st_size,
                      print_time_s=float(exiting.group(1)), user_s=usage.ru_utime, sys_s=usage.ru_stime,
                      unknown=unknown, serial_path=serial, log_path=log)


def repeated_gcode(gcode_path: str | os.PathLike, copies: int, dest: str | os.PathLike) -> Path:
    """The file `copies` times over, `G92 E0` between copies, written to `dest`."""
    text = Path(gcode_path).read_text()
    if not text.endswith("\n"):
        text += "\n"
    dest = Path(dest)
    dest.write_text("G92 E0\n".join([text] * copies))
    return dest


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gcode", type=Path, default=BENCHY)
    parser.add_argument("--copies", type=int, default=1, help="the file this many times over")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--cpu", type=int, default=None, help="pin klippy to this core")
    parser.add_argument("--quiet", action="store_true", help="without klippy's -v")
    args = parser.parse_args()
    setup = find_klipper()
    if setup is None:
        raise SystemExit("Klipper not found: see this module's docstring (KLIPPER_DIR, KLIPPER_PYTHON)")
    with tempfile.TemporaryDirectory(prefix="klipper-ref-") as work:
        gcode = args.gcode if args.copies == 1 else repeated_gcode(args.gcode, args.copies, Path(work) / "in.gcode")
        print(f"Klipper batch mode on {args.gcode.name}" + (f" x{args.copies}" if args.copies > 1 else "")
              + (f", pinned to core {args.cpu}" if args.cpu is not None else ""))
        runs = []
        for i in range(args.repeat):
            run = run_klipper(setup, gcode, work, verbose=not args.quiet, cpu=args.cpu)
            runs.append(run)
            print(f"  run {i + 1}: {run.wall_s:.2f} s wall ({run.user_s:.2f} s user, {run.sys_s:.2f} s sys), "
                  f"peak RSS {run.peak_rss_mib:.1f} MiB, out.serial {run.serial_bytes:,} bytes, "
                  f"print time {run.print_time_s:.1f} s")
        best = min(runs, key=lambda r: r.wall_s)
        print(f"best of {len(runs)}: {best.wall_s:.2f} s wall, peak RSS {min(r.peak_rss_mib for r in runs):.1f} MiB")
        if best.unknown:
            print("  only answered: " + ", ".join(f"{cmd} x{n}" for cmd, n in sorted(best.unknown.items())))


if __name__ == "__main__":
    main()

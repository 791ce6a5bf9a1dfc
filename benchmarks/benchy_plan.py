"""Benchmark: `plan` of the PrusaSlicer Benchy for a Prusa MINI (examples/printers/benchy-mini.yaml), once and
three times over, against Klipper's batch mode on the same file, measured in the same run, alternating.

    python benchmarks/benchy_plan.py [--repeat 3] [--copies 1 3] [--cpu N] [--no-klipper]
        [--shaper mzv:50[:0.1]] [--pressure-advance 0.05[:0.04]]

Each of our runs is a fresh process that does what `printer-codegen plan` does (read, plan, step times, rate
runs, twin and every check; no compiler, no simulator), so its wall time includes Python's start and imports,
as Klipper's includes klippy's. Printed per run: wall time, each stage's wall time (the front end runs in a
child process beside the rest: its stages overlap the others), steps/s, peak resident memory of the main
process and of the front end's child (os.wait4 and getrusage: each process's own peak), table bytes per step
on both targets (AVR and 8051), and Klipper's wall time, peak memory and command bytes per step, with the
ratio of the best walls. Klipper runs when benchmarks/klipper_ref.py finds it (see its docstring), with the
command of the issue (`klippy.py printer.cfg -i file.gcode -o out.serial -d out/klipper.dict`); it is
skipped otherwise. `--cpu N` pins both to one core (ours then runs in one process). `--shaper` and
`--pressure-advance` give both sides the same input shaper on x and y and the same pressure advance: ours in the
job's `machine.input_shaper` and `machine.pressure_advance`, Klipper's in its printer.cfg's [input_shaper] and
[extruder] (with M900 / M572 as macros: benchmarks/klipper_steps.py `klipper_config`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))

from klipper_ref import BENCHY, find_klipper, repeated_gcode, run_klipper  # noqa: E402
from klipper_steps import klipper_config, shaping_of  # noqa: E402

JOB = REPO / "examples" / "printers" / "benchy-mini.yaml"
SLICER_ESTIMATE_S = 38 * 60 + 43
ARC_RESOLUTION_MM = 1.0  # Klipper's [gcode_arcs] default, where its printer.cfg is written (the Benchy has no arcs)


def measure_one(job_path: str, target: str | None) -> dict:
    """In the child: the plan of the job, its stage times and figures, as JSON."""
    begin = time.perf_counter()
    from codegen.cli.main import keep_freed_memory  # as `printer-codegen plan` does
    from codegen.job import load_job
    from codegen.pipeline.host import Stopwatch, host_build

    keep_freed_memory()
    watch = Stopwatch()
    host = host_build(load_job(Path(job_path), target), keep=False, watch=watch)
    totals, findings = host.totals, host.findings
    return {
        "in_process_s": time.perf_counter() - begin, "stages": watch.seconds,
        "steps": sum(findings.steps.values()), "table_bytes": totals.table_bytes, "blocks": totals.blocks,
        "runs": totals.runs, "duration_s": totals.duration_s, "pass": findings.ok, "problems": findings.problems,
        "timing_us": totals.max_timing_error_ticks / host.target.tick_hz * 1e6,
        "front_end_rss_kib": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss,
    }


def run_ours(job: Path, target: str | None, cpu: int | None) -> dict:
    argv = [sys.executable, str(Path(__file__).resolve()), "--one", str(job)]
    argv += ["--target", target] if target else []
    pin = (lambda: os.sched_setaffinity(0, {cpu})) if cpu is not None else None
    begin = time.perf_counter()
    child = subprocess.Popen(argv, stdout=subprocess.PIPE, preexec_fn=pin)
    out = child.stdout.read()
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - begin
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        raise SystemExit(f"our plan failed on {job} (exit {child.returncode})")
    result = json.loads(out)
    return {**result, "wall_s": wall, "rss_mib": usage.ru_maxrss / 1024,
            "front_mib": result["front_end_rss_kib"] / 1024}


def job_for(copies: int, work: Path, shapers: dict, advance: tuple | None) -> tuple[Path, Path]:
    """The job file and its G-code for the Benchy `copies` times over, with the shapers and pressure advance of
    `shaping_of` (benchmarks/klipper_steps.py) in its machine."""
    if copies == 1 and not shapers and advance is None:
        return JOB, BENCHY
    gcode = BENCHY if copies == 1 else repeated_gcode(BENCHY, copies, work / f"benchy-x{copies}.gcode")
    job = yaml.safe_load(JOB.read_text())
    job["name"] = f"benchy-x{copies}"
    job["program"]["gcode"] = str(gcode)
    if shapers:
        job["machine"]["input_shaper"] = {axis: {"type": kind, "freq": freq, **({} if damping is None else
                                                                                 {"damping": damping})}
                                          for axis, (kind, freq, damping) in shapers.items()}
    if advance is not None:
        k, smooth = advance
        job["machine"]["pressure_advance"] = {"k": k, **({} if smooth is None else {"smooth_time": smooth})}
    path = work / f"benchy-x{copies}.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    return path, gcode


def compare(copies: int, repeat: int, cpu: int | None, klipper, work: Path, shaping: tuple[dict, tuple | None]) -> None:
    job, gcode = job_for(copies, work, *shaping)
    ours, theirs = [], []
    for _ in range(repeat):  # alternating, so that both see the same machine
        ours.append(run_ours(job, None, cpu))
        if klipper is not None:
            theirs.append(run_klipper(klipper, gcode, work / "klipper", verbose=False, cpu=cpu))
    best = min(ours, key=lambda r: r["wall_s"])
    steps = best["steps"]
    name = "Benchy" + (f" x{copies}" if copies > 1 else "")
    print(f"\n{name}: {steps:,} steps, {best['blocks']:,} blocks, {best['runs']:,} runs; checks "
          f"{'pass' if best['pass'] else 'FAIL: ' + '; '.join(best['problems'])}; planned {best['duration_s']:.0f} s "
          f"(the slicer estimates {SLICER_ESTIMATE_S * copies} s)")
    walls = ", ".join(f"{r['wall_s']:.2f}" for r in ours)
    main_mib, front_mib = max(r["rss_mib"] for r in ours), max(r["front_mib"] for r in ours)
    print(f"  ours:    {best['wall_s']:.2f} s wall (best of {repeat}: {walls}), "
          f"{steps / best['wall_s'] / 1e6:.2f} M steps/s, peak RSS {main_mib:.0f} MiB main + {front_mib:.0f} MiB "
          f"front end")
    for stage, seconds in best["stages"].items():
        print(f"    {stage:<34} {seconds:6.3f} s")
    table = best["table_bytes"]
    print(f"  tables:  {table:,} bytes on the AVR = {table / steps:.3f} bytes/step "
          f"(timing within {best['timing_us']:.1f} us of the plan)")
    other = run_ours(job, "mcs51", cpu)
    print(f"           {other['table_bytes']:,} bytes on the 8051 = {other['table_bytes'] / steps:.3f} bytes/step "
          f"(checks {'pass' if other['pass'] else 'FAIL'})")
    if theirs:
        k = min(theirs, key=lambda r: r.wall_s)
        walls = ", ".join(f"{r.wall_s:.2f}" for r in theirs)
        print(f"  Klipper: {k.wall_s:.2f} s wall (best of {repeat}: {walls}), "
              f"peak RSS {max(r.peak_rss_mib for r in theirs):.0f} MiB, {k.serial_bytes:,} command bytes = "
              f"{k.serial_bytes / steps:.3f} bytes/step")
        print(f"  ratio (ours / Klipper, best walls): {best['wall_s'] / k.wall_s:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--copies", type=int, nargs="+", default=[1, 3])
    parser.add_argument("--cpu", type=int, default=None, help="pin ours and Klipper to this core")
    parser.add_argument("--no-klipper", action="store_true")
    parser.add_argument("--shaper", help="both sides' input shaper on x and y: TYPE:FREQ[:DAMPING]")
    parser.add_argument("--pressure-advance", help="both sides' pressure advance: K[:SMOOTH_TIME]")
    parser.add_argument("--one", help=argparse.SUPPRESS)  # a child's run
    parser.add_argument("--target", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(measure_one(args.one, args.target)))
        return
    klipper = None if args.no_klipper else find_klipper()
    where = f"at {klipper.klipper_dir}" if klipper else "not set up (benchmarks/klipper_ref.py): skipped"
    shapers, advance = shaping_of(None, args.shaper, args.pressure_advance)
    print(f"Klipper: {where}"
          + (f"; both pinned to core {args.cpu}" if args.cpu is not None else f"; {os.cpu_count()} cores")
          + f"; input shaper {shapers or 'none'}, pressure advance {advance or 'none'}")
    with tempfile.TemporaryDirectory(prefix="benchy-plan-") as tmp:
        if klipper is not None and (shapers or advance is not None):  # Klipper's printer.cfg with them
            config = klipper_config(Path(tmp), shapers, advance, ARC_RESOLUTION_MM, None)
            klipper = dataclasses.replace(klipper, config=config)
        if klipper is not None:  # klippy compiles its C helper on its first start: not in the figures
            run_klipper(klipper, BENCHY, Path(tmp) / "klipper", verbose=False)
        for copies in args.copies:
            compare(copies, args.repeat, args.cpu, klipper, Path(tmp), (shapers, advance))


if __name__ == "__main__":
    main()

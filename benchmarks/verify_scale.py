"""Benchmark: `verify --stream` of a real print at scale, in bounded memory (codegen/verify/bounded.py).

    python benchmarks/verify_scale.py [--job JOB.yaml] [--gcode FILE] [--copies N] [--both]

Runs `printer-codegen verify JOB --stream --json` (default: the PrusaSlicer Benchy on the Prusa MINI,
examples/printers/benchy-mini.yaml, heaters on) as a child process and samples every process of its tree from
/proc every 0.1 s. Prints the verdict, the wall time, the simulated seconds per wall second, the peak resident
memory (the largest process: what `/usr/bin/time -f %M` reports; and the largest sum over the tree at one
sample), and where the CPU time went: the simulator (the simavr harness) and Python (the verb's process and its
comparing process), with the rest (the compiler, the G-code reader's process).

`--gcode FILE` runs the job's machine with another program (the slicer set: ../shared/gcode/slicer, copied in
tests/data/gcode/slicer). `--copies N` verifies the job's G-code N times over (G92 E0 between copies: a print N
times as long) as well, so that the memory can be compared: it must not grow with the print. `--both` runs the job
and its copies.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
JOB = ROOT / "examples" / "printers" / "benchy-mini.yaml"
TICK_S = os.sysconf("SC_CLK_TCK")
PAGE = os.sysconf("SC_PAGE_SIZE")


def tree(root: int) -> dict[int, tuple[str, int, float]]:
    """Every process under `root` (itself included): pid -> (command, resident bytes, CPU seconds)."""
    children: dict[int, list[int]] = {}
    stats = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                command = f.read().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        pid, parent = int(entry), int(fields[1])
        children.setdefault(parent, []).append(pid)
        cpu = (int(fields[11]) + int(fields[12])) / TICK_S
        stats[pid] = (command, int(fields[21]) * PAGE, cpu)
    out, todo = {}, [root]
    while todo:
        pid = todo.pop()
        if pid in stats:
            out[pid] = stats[pid]
        todo += children.get(pid, [])
    return out


def kind(command: str) -> str:
    if "simavr-harness" in command:
        return "simulator"
    if "spawn_main" in command or " -m codegen " in command or "printer-codegen" in command:
        return "python"
    return "other"


def measure(job: Path, out: Path) -> dict:
    """verify --stream --json of `job` in a child process, sampled."""
    began = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    report = out.parent / f"{out.name}-verify.json"  # a file, not a pipe: a long run's JSON fills a pipe's 64 KiB
    with report.open("wb") as sink:
        proc = subprocess.Popen([sys.executable, "-m", "codegen", "verify", str(job), "--stream", "--json", "--quiet",
                                 "--out", str(out)], stdout=sink, stderr=subprocess.DEVNULL, cwd=ROOT)
    peak_one = peak_sum = 0
    cpu: dict[int, tuple[str, float]] = {}
    peaks: dict[str, int] = {}  # by kind of process: the verb's, the comparing one, the simulator...
    while proc.poll() is None:
        sample = tree(proc.pid)
        peak_one = max([peak_one] + [rss for _, rss, _ in sample.values()])
        for pid, (command, rss, _) in sample.items():
            role = "verb" if pid == proc.pid else "comparing" if "spawn_main" in command else kind(command)
            peaks[role] = max(peaks.get(role, 0), rss)
        peak_sum = max(peak_sum, sum(rss for _, rss, _ in sample.values()))
        cpu.update({pid: (command or cpu.get(pid, ("", 0.0))[0], seconds)  # a process that has just ended has
                    for pid, (command, _, seconds) in sample.items()})      # no command line any more
        time.sleep(0.1)
    wall = time.perf_counter() - began
    result = json.loads(report.read_text() or "{}")
    shares = {"simulator": 0.0, "python": 0.0, "other": 0.0}
    others: dict[str, float] = {}
    for command, seconds in cpu.values():
        shares[kind(command)] += seconds
        if kind(command) == "other":
            others[command.split(" ")[0]] = others.get(command.split(" ")[0], 0.0) + seconds
    return {"result": result, "wall_s": wall, "peak_one": peak_one, "peak_sum": peak_sum, "cpu": shares,
            "peaks": peaks, "others": others}


def with_gcode(job: Path, gcode: Path, folder: Path) -> Path:
    """The job's machine with another G-code file (e.g. the ArcWelder Benchy: an 11.5-hour print)."""
    text = job.read_text()
    name = f"{re.search(r'(?m)^name: (.*)$', text).group(1).strip()}-{gcode.stem}"
    other = folder / f"{name}.yaml"
    other.write_text(re.sub(r"(?m)^  gcode: .*$", f"  gcode: {gcode.resolve()}", text)
                     .replace(re.search(r"(?m)^name: .*$", text).group(0), f"name: {name}"))
    return other


def copies(job: Path, n: int, folder: Path) -> Path:
    """The job with its G-code n times over, G92 E0 between the copies."""
    text = job.read_text()
    gcode = re.search(r"(?m)^  gcode: (.*)$", text).group(1).strip()
    program = (job.parent / gcode).read_text()
    (folder / f"x{n}.gcode").write_text(("\nG92 E0\n").join([program] * n))
    name = re.search(r"(?m)^name: (.*)$", text).group(1).strip()
    copy = folder / f"{name}-x{n}.yaml"
    copy.write_text(re.sub(r"(?m)^  gcode: .*$", f"  gcode: x{n}.gcode", text)
                    .replace(f"name: {name}", f"name: {name}-x{n}"))
    return copy


def report(label: str, m: dict) -> None:
    r = m["result"]
    simulated = r.get("duration_s", 0.0)
    verdict = "PASS" if r.get("pass") else "FAIL"
    print(f"{label}: {verdict}, {simulated:.1f} s of print simulated ({r.get('planned_duration_s', 0):.1f} s "
          f"planned)")
    for problem in r.get("problems", [])[:5]:
        print(f"  problem: {problem}")
    cpu = m["cpu"]
    total = sum(cpu.values()) or 1.0
    print(f"  wall time          {m['wall_s']:8.1f} s   ({simulated / m['wall_s']:.1f} s simulated per wall s, "
          f"heat-up waits not counted in the simulated figure)")
    print(f"  peak RSS           {m['peak_one'] / 2**20:8.1f} MiB (the largest process; the tree at once: "
          f"{m['peak_sum'] / 2**20:.1f} MiB; " + ", ".join(f"{k} {v / 2**20:.0f}" for k, v in sorted(m["peaks"].items()))
          + ")")
    print(f"  CPU                {total:8.1f} s   simulator {100 * cpu['simulator'] / total:.0f} %, Python "
          f"{100 * cpu['python'] / total:.0f} %, other {100 * cpu['other'] / total:.0f} % ("
          + ", ".join(f"{Path(k).name} {v:.0f} s" for k, v in sorted(m["others"].items(), key=lambda kv: -kv[1])[:3])
          + ")")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--job", type=Path, default=JOB)
    parser.add_argument("--copies", type=int, default=3)
    parser.add_argument("--both", action="store_true", help="the job, then its copies")
    parser.add_argument("--gcode", type=Path, help="the job's machine with this G-code instead (e.g. "
                        "tests/data/gcode/slicer/benchy-arcs-arcwelder.gcode)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="verify-scale-") as tmp:
        if args.gcode:
            args.job = with_gcode(args.job, args.gcode, Path(tmp))
        once = measure(args.job, Path(tmp) / "once")
        report(args.job.name, once)
        if args.both:
            many = measure(copies(args.job, args.copies, Path(tmp)), Path(tmp) / "many")
            report(f"{args.job.name} x{args.copies}", many)
            print(f"  memory x{args.copies} / x1: {many['peak_one'] / once['peak_one']:.3f} (largest process), "
                  f"{many['peak_sum'] / once['peak_sum']:.3f} (the tree)")


if __name__ == "__main__":
    main()

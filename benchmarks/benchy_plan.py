"""Benchmark: `plan` of the PrusaSlicer Benchy (89,383 lines) for a Prusa MINI, stage by stage.

    python benchmarks/benchy_plan.py [--repeat 3]

Prints the wall time of each stage (best of the repeats), steps/s, and the planned duration against the
slicer's own estimate (38m43s). Reference: Klipper's host turns the same file into step commands in 2.2 to 2.7 s
on this kind of machine (8.45 million steps); its figure compares with "G-code to tables".
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from codegen.job import load_job
from codegen.pipeline import Stopwatch, host_build

JOB = Path(__file__).resolve().parent.parent / "examples" / "printers" / "benchy-mini.yaml"
SLICER_ESTIMATE_S = 38 * 60 + 43
TO_TABLES = ("toolpath", "segments", "plan", "step times", "rate runs")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    best: dict[str, float] = {}
    walls = []
    for _ in range(args.repeat):
        watch = Stopwatch()
        begin = time.perf_counter()
        host = host_build(load_job(JOB), watch=watch)
        walls.append(time.perf_counter() - begin)
        for stage, seconds in watch.seconds.items():
            best[stage] = min(best.get(stage, seconds), seconds)
    steps = len(host.pulses.tick)
    print(f"Benchy for a Prusa MINI: {steps:,} steps, {host.schedule.n_blocks:,} blocks, "
          f"{host.schedule.n_runs:,} runs, {host.schedule.table_bytes():,} table bytes")
    for stage, seconds in best.items():
        print(f"  {stage:<11} {seconds:6.3f} s")
    tables = sum(best[s] for s in TO_TABLES)
    print(f"G-code to tables: {tables:.2f} s = {steps / tables:,.0f} steps/s (Klipper: 2.2-2.7 s for 8.45 M steps)")
    print(f"whole plan with twin and checks: {min(walls):.2f} s wall (best of {args.repeat})")
    duration = host.plan.total
    print(f"planned duration {duration:.1f} s = {duration / 60:.1f} min; the slicer estimates {SLICER_ESTIMATE_S} s "
          f"({100 * (duration / SLICER_ESTIMATE_S - 1):+.1f} %); checks {'pass' if host.findings.ok else 'FAIL'}")


if __name__ == "__main__":
    main()

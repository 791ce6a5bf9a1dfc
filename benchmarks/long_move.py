"""Benchmark: `plan` of one long straight move against the same length as many moves (issue 28).

    python benchmarks/long_move.py [--length MM] [--steps-per-mm N] [--moves K] [--feed MM_PER_MIN]

Writes two jobs (a cartesian printer's x: `--steps-per-mm`, default 80) into a temporary folder: one `G1 X<length>`
(default 99999 mm: the largest move the reach allows, 8 M steps), and the same path as `--moves` moves (default 1000)
of equal length. Runs `python -m codegen plan JOB --json` on each under `/usr/bin/time` and prints the peak resident
memory (what `%M` reports), the wall time, the windows, the events and the plan's duration. The long move is planned
in windows of bounded steps (codegen/motion/lookahead.py WINDOW_EVENTS): its peak must not exceed the many moves'.
`--steps-per-mm 100000 --length 200` is a 20 M step move whose peak should match `--length 20`'s.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
JOB = """name: {name}
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: {spm}, max_velocity: 200, max_accel: 2500}}
    y: {{steps_per_mm: 80, max_velocity: 200, max_accel: 2500}}
program:
  gcode: |
{gcode}
"""


def job(folder: Path, name: str, spm: float, moves: list[str]) -> Path:
    path = folder / f"{name}.yaml"
    path.write_text(JOB.format(name=name, spm=spm, gcode="".join(f"    {m}\n" for m in moves)))
    return path


def run(path: Path) -> dict:
    """Peak KB and wall seconds of `plan JOB --json` (GNU time's %M and %e), with the plan's figures."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    argv = ["/usr/bin/time", "-f", "%M %e", sys.executable, "-m", "codegen", "plan", str(path), "--json"]
    done = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True)
    peak_kb, seconds = done.stderr.strip().splitlines()[-1].split()
    figures = json.loads(done.stdout)
    return {"peak_mib": int(peak_kb) / 1024, "seconds": float(seconds), "windows": figures["windows"],
            "events": figures["events"], "duration_s": figures["duration_s"], "pass": figures["pass"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--length", type=float, default=99999.0, help="mm along x (default 99999)")
    parser.add_argument("--steps-per-mm", type=float, default=80.0, help="x's steps per mm (default 80)")
    parser.add_argument("--moves", type=int, default=1000, help="moves of the same path in the second job")
    parser.add_argument("--feed", type=float, default=6000.0, help="mm/min (default 6000)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        one = job(Path(folder), "one-move", args.steps_per_mm, [f"G1 X{args.length:g} F{args.feed:g}"])
        # The same path in equal moves: junctions go straight on, the windows are the planner's own.
        ends = [args.length * (k + 1) / args.moves for k in range(args.moves)]
        many = job(Path(folder), "many-moves", args.steps_per_mm, [f"G1 X{x:.6f} F{args.feed:g}" for x in ends])
        for name, path in (("one move", one), (f"{args.moves} moves", many)):
            r = run(path)
            print(f"{name:>12}: {r['peak_mib']:7.1f} MiB peak  {r['seconds']:7.2f} s  {r['events']:>11,} steps  "
                  f"{r['windows']:>5} windows  {r['duration_s']:.3f} s of motion  pass={r['pass']}")


if __name__ == "__main__":
    main()

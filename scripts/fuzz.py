"""Fuzz `printer-codegen plan` with mutated G-code and job files (tests/fuzzing/): each input in-process in a forked
worker under a time and a memory limit, each failure reduced to a signature and shrunk to a ready-to-run job.

    python scripts/fuzz.py [--seed 28] [--count N] [--minutes M] [--jobs 2] [--out build/fuzz]
                           [--time-limit 20] [--memory-gib 3]

Prints a progress line every few seconds (inputs/s), then the table of signatures (count, smallest input's size,
its job file under OUT). Exit 1 when any failure signature was seen.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from tests.fuzzing.campaign import Settings, fuzz, table  # noqa: E402
from tests.fuzzing.outcomes import plan_input  # noqa: E402
from tests.fuzzing.pool import GiB  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seed", type=int, default=Settings.seed, help="the run's seed: the same inputs in the same order")
    p.add_argument("--count", type=int, help="stop after this many inputs")
    p.add_argument("--minutes", type=float, help="stop making inputs after this many minutes (then shrink)")
    p.add_argument("--jobs", type=int, default=Settings.jobs, help="worker processes (default 2)")
    p.add_argument("--out", type=Path, default=Settings.out, help="where the shrunk inputs go (default build/fuzz)")
    p.add_argument("--time-limit", type=float, default=Settings.time_limit, help="seconds per input (default 20)")
    p.add_argument("--memory-gib", type=float, default=3.0, help="address space per worker (default 3 GiB)")
    p.add_argument("--shrink-seconds", type=float, default=Settings.shrink_seconds,
                   help="time to shrink each signature's input (default 60)")
    args = p.parse_args(argv)
    if args.count is None and args.minutes is None:
        p.error("say how long: --count N or --minutes M")
    settings = Settings(seed=args.seed, count=args.count, minutes=args.minutes, jobs=args.jobs, out=args.out,
                        time_limit=args.time_limit, memory_bytes=int(args.memory_gib * GiB),
                        shrink_seconds=args.shrink_seconds)
    results = fuzz(settings, plan_input)
    print(f"{results.inputs} inputs in {results.seconds:.0f} s ({results.rate:.1f}/s): "
          + ", ".join(f"{kind} {n}" for kind, n in sorted(results.kinds.items())))
    if results.findings:
        print(table(results))
    return 1 if results.findings else 0


if __name__ == "__main__":
    sys.exit(main())

"""The long profile of the property tests: many random jobs per kinematics and table format, every outcome
counted, every failure written out.

    python scripts/property_run.py --examples 5000 [--kinematics delta] [--target mcs51] [--out propfind]
                                   [--seed 1] [--minutes 30]

Prints, per kinematics and target: examples run, built, refused (by message), too big, and failures; each
failure's job file goes to OUT/<kinematics>-<target>-<n>.yaml with its error in a comment, and the failures are
grouped by message (numbers blanked) so that a class shows once. Exit 1 when anything failed.
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path

from hypothesis import HealthCheck, given, seed, settings

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from tests.jobgen import TARGETS, jobs, outcome  # noqa: E402


def survey(kinematics: str, target: str, examples: int, out: Path, random_seed: int, deadline: float) -> dict:
    counts: Counter = Counter()
    classes: dict[str, list[Path]] = {}

    @seed(random_seed)
    @settings(max_examples=examples, deadline=None, database=None, derandomize=False,
              suppress_health_check=list(HealthCheck))
    @given(jobs(kinematics, target))
    def one(text):
        if time.monotonic() > deadline:
            return
        counts["run"] += 1
        with tempfile.TemporaryDirectory() as folder:
            try:
                counts[outcome(text, Path(folder))] += 1
            except Exception as err:  # noqa: BLE001 - every failure is recorded, the survey goes on
                message = f"{type(err).__name__}: {err}".splitlines()[0][:200]
                key = re.sub(r"[-+]?\d+(\.\d+)?", "#", message)
                path = out / f"{kinematics}-{target}-{counts['failed']}.yaml"
                detail = traceback.format_exc().splitlines()[-3:]
                path.write_text("".join(f"# {line}\n" for line in [message, *detail]) + text)
                classes.setdefault(key, []).append(path)
                counts["failed"] += 1

    one()
    return {"counts": counts, "classes": classes}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--examples", type=int, default=5000, help="per kinematics and target")
    p.add_argument("--kinematics", choices=["cartesian", "corexy", "delta"], action="append")
    p.add_argument("--target", choices=TARGETS, action="append")
    p.add_argument("--out", default="propfind", help="folder for the failing jobs")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--minutes", type=float, default=None, help="stop each survey after this long")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    failed = 0
    for kinematics in args.kinematics or ["cartesian", "corexy", "delta"]:
        for target in args.target or list(TARGETS):
            begin = time.monotonic()
            deadline = begin + 60 * args.minutes if args.minutes else float("inf")
            result = survey(kinematics, target, args.examples, out, args.seed, deadline)
            counts = result["counts"]
            spent = time.monotonic() - begin
            refused: Counter = Counter()
            for key, n in counts.items():
                if key.startswith("refused: "):
                    refused[re.sub(r"[-+]?\d+(\.\d+)?", "#", key[len("refused: "):])] += n
            print(f"{kinematics:9} {target:5}: {counts['run']} jobs in {spent:.0f} s, {counts['built']} built, "
                  f"{sum(refused.values())} refused, {counts['too big']} too big, {counts['invalid']} invalid, "
                  f"{counts['failed']} failed", flush=True)
            for message, n in sorted(refused.items(), key=lambda kv: -kv[1]):
                print(f"    refused {n:5}: {message}")
            for key, paths in result["classes"].items():
                print(f"    FAILED  {len(paths):5}: {key}  (e.g. {paths[0]})")
            failed += counts["failed"]
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

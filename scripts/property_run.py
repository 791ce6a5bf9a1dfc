"""The long profile of the property tests (tests/jobgen/): many random jobs per kinematics and table format,
every outcome counted, every failure class shrunk to a minimal job file.

    python scripts/property_run.py [--examples 5000] [--kinematics delta] [--target mcs51] [--out /tmp/propfind]
                                   [--seed 1] [--minutes 8] [--shrink-seconds 90]

Prints, per kinematics and target: examples run, built, refused by the build (positioned errors, counted by
message class), invalid (refused by the loader: the generator wrote a job the format does not allow), too big,
and failures by class. Each failure class (the message with its numbers blanked) is shrunk by deleting lines
and keys and rounding numbers while the same class still fails; the minimal job goes to
OUT/<kinematics>-<target>-<n>.yaml with its error in a comment. Exit 1 when anything failed.
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from hypothesis import HealthCheck, given, seed, settings

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from tests.jobgen import KINEMATICS, TARGETS, Bug, jobs, outcome  # noqa: E402

NUMBER = re.compile(r"(?<![\w.])-?\d+\.\d+|(?<![\w.])-?\d{2,}(?![\w.])")
OPTIONAL = re.compile(r", (feed|z|from|rotation|start|phase|invert_dir|range|tower_angles|direction|travel_feed|damping|"
                      r"smooth_time): (\[[^\]]*\]|[^,}\]]+)")


def _fails_with(text: str, key: str) -> bool:
    with tempfile.TemporaryDirectory() as folder:
        try:
            outcome(text, Path(folder))
        except Bug as bug:
            return key in bug.classes
        except Exception:  # noqa: BLE001 - another failure is not this class
            return False
    return False


def shrink(text: str, key: str, seconds: float) -> str:
    """The smallest job found, within `seconds`, that still fails with the class `key`: lines deleted, optional
    keys of one-line mappings deleted, numbers rounded."""
    stop = time.monotonic() + seconds
    best = text
    progress = True
    while progress and time.monotonic() < stop:
        progress = False
        lines = best.splitlines()
        for i in range(len(lines) - 1, 1, -1):  # delete one line (a shape, a G-code line, a machine key)
            if time.monotonic() > stop:
                break
            candidate = "\n".join(lines[:i] + lines[i + 1:]) + "\n"
            if _fails_with(candidate, key):
                best, lines, progress = candidate, candidate.splitlines(), True
        for match in reversed(list(OPTIONAL.finditer(best))):  # delete an optional key of a flow mapping
            if time.monotonic() > stop:
                break
            candidate = best[:match.start()] + best[match.end():]
            if _fails_with(candidate, key):
                best, progress = candidate, True
        for match in reversed(list(NUMBER.finditer(best))):  # round a number
            if time.monotonic() > stop:
                break
            value = float(match.group())
            for simpler in (f"{round(value)}", f"{round(value, 1):g}", f"{round(value, 2):g}"):
                if len(simpler) >= len(match.group()) or float(simpler) == value:
                    continue
                candidate = best[:match.start()] + simpler + best[match.end():]
                if _fails_with(candidate, key):
                    best, progress = candidate, True
                    break
    return best


def survey(kinematics: str, target: str, examples: int, random_seed: int, deadline: float) -> dict:
    counts: Counter = Counter()
    failures: dict[str, tuple[str, str]] = {}  # class -> (message, the first job that showed it)
    failures_seen: Counter = Counter()

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
            except Bug as bug:
                counts["failed"] += 1
                key = bug.classes[0] if bug.classes else "?"
                failures_seen[key] += 1
                failures.setdefault(key, (str(bug).splitlines()[0][:400], text))

    one()
    return {"counts": counts, "failures": failures, "seen": failures_seen}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--examples", type=int, default=5000, help="per kinematics and target")
    p.add_argument("--kinematics", choices=KINEMATICS, action="append")
    p.add_argument("--target", choices=TARGETS, action="append")
    p.add_argument("--out", default="/tmp/propfind", help="folder for the minimal failing jobs")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--minutes", type=float, default=None, help="stop each survey after this long")
    p.add_argument("--shrink-seconds", type=float, default=90.0, help="per failure class")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    failed = 0
    for kinematics in args.kinematics or list(KINEMATICS):
        for target in args.target or list(TARGETS):
            begin = time.monotonic()
            deadline = begin + 60 * args.minutes if args.minutes else float("inf")
            result = survey(kinematics, target, args.examples, args.seed, deadline)
            counts = result["counts"]
            spent = time.monotonic() - begin
            refused = Counter({k[len("refused: "):]: n for k, n in counts.items() if k.startswith("refused: ")})
            invalid = Counter({k[len("invalid: "):]: n for k, n in counts.items() if k.startswith("invalid: ")})
            print(f"{kinematics:9} {target:5}: {counts['run']} jobs in {spent:.0f} s: {counts['built']} built, "
                  f"{sum(refused.values())} refused, {counts['too big']} too big, {sum(invalid.values())} invalid, "
                  f"{counts['failed']} FAILED", flush=True)
            for message, n in refused.most_common():
                print(f"    refused {n:5}: {message}")
            for message, n in invalid.most_common():
                print(f"    invalid {n:5}: {message}")
            for n_class, (key, (message, text)) in enumerate(result["failures"].items()):
                minimal = shrink(text, key, args.shrink_seconds)
                path = out / f"{kinematics}-{target}-{n_class}.yaml"
                path.write_text(f"# {message}\n# class: {key}\n" + minimal)
                print(f"    FAILED  {result['seen'][key]:5}: {key}\n                   {message[:300]}\n"
                      f"                   minimal job: {path}", flush=True)
            failed += counts["failed"]
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

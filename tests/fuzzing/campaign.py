"""A fuzz run: inputs 0, 1, 2, ... of a seed through the worker pool until --count or --minutes, the outcomes
counted, each failure signature's smallest input shrunk and written to OUT/<n>-<slug>/ as a ready-to-run job,
and the table of signatures.

Shrinking keeps the signature: chunks of lines deleted (halves first, down to single lines), then words, then
characters; the G-code file first, then the job file. Candidates are tried a batch at a time (one per worker),
the first that still fails the same way is kept, and the number of tries is bounded."""

from __future__ import annotations

import re
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from itertools import count
from pathlib import Path
from typing import Callable, Iterator, TextIO

from tests.fuzzing.inputs import FuzzInput, make_input
from tests.fuzzing.outcomes import Outcome
from tests.fuzzing.pool import GiB, WorkerPool

PROGRESS_S = 5.0  # seconds between progress lines
WORD_PIECES = re.compile(rb"\s+|[^\s]+")
Reproduces = Callable[[list[FuzzInput]], int | None]  # the index of the first candidate that fails the same way


@dataclass
class Budget:
    attempts: int = 300
    seconds: float = 120.0

    def __post_init__(self):
        self.stop = time.monotonic() + self.seconds

    def take(self, n: int) -> bool:
        if self.attempts <= 0 or time.monotonic() > self.stop:
            return False
        self.attempts -= n
        return True


def _lines(data: bytes) -> list[bytes]:
    return data.splitlines(keepends=True)


def _words(data: bytes) -> list[bytes]:
    return WORD_PIECES.findall(data)


def _chars(data: bytes) -> list[bytes]:
    return [data[k:k + 1] for k in range(len(data))]


def _deletions(units: list[bytes]) -> Iterator[tuple[int, int]]:
    """(start, size) of the chunks to try deleting: halves, quarters, ... single units."""
    size = max(1, len(units) // 2)
    while True:
        for start in range(0, len(units), size):
            yield start, size
        if size == 1:
            return
        size //= 2


def _shrink_part(item: FuzzInput, part: str, split: Callable[[bytes], list[bytes]], reproduces: Reproduces,
                 batch: int, budget: Budget) -> FuzzInput:
    """The smallest `part` found by deleting chunks of `split(part)`; restarted after every success."""
    improved = True
    while improved:
        improved = False
        units = split(getattr(item, part) or b"")
        chunks = list(_deletions(units)) if units else []
        for first in range(0, len(chunks), batch):
            if not budget.take(min(batch, len(chunks) - first)):
                return item
            candidates = [item.with_part(part, b"".join(units[:s] + units[s + n:]))
                          for s, n in chunks[first:first + batch]]
            found = reproduces(candidates)
            if found is not None:
                item, improved = candidates[found], True
                break
    return item


def shrink(item: FuzzInput, reproduces: Reproduces, batch: int = 1, budget: Budget | None = None) -> FuzzInput:
    """The smallest input found that `reproduces` still accepts."""
    budget = budget or Budget()
    for part in ("gcode", "job"):
        if getattr(item, part) is None:
            continue
        for split in (_lines, _words, _chars):
            item = _shrink_part(item, part, split, reproduces, batch, budget)
    return item


@dataclass
class Settings:
    seed: int = 28
    count: int | None = None
    minutes: float | None = None
    jobs: int = 2
    time_limit: float = 20.0
    memory_bytes: int = 3 * GiB
    out: Path = Path("build/fuzz")
    shrink_attempts: int = 300
    shrink_seconds: float = 60.0


@dataclass
class Finding:
    signature: str
    outcome: Outcome
    smallest: FuzzInput
    index: int
    count: int = 0
    path: Path | None = None


@dataclass
class Results:
    inputs: int = 0
    seconds: float = 0.0
    kinds: Counter = field(default_factory=Counter)
    findings: dict[str, Finding] = field(default_factory=dict)

    @property
    def rate(self) -> float:
        return self.inputs / self.seconds if self.seconds else 0.0

    def add(self, index: int, item: FuzzInput, outcome: Outcome) -> None:
        self.inputs += 1
        self.kinds[outcome.kind] += 1
        if not outcome.failed:
            return
        finding = self.findings.setdefault(outcome.signature, Finding(outcome.signature, outcome, item, index))
        finding.count += 1
        if (item.size, index) < (finding.smallest.size, finding.index):  # the same choice whatever the order
            finding.smallest, finding.index, finding.outcome = item, index, outcome


def _inputs(settings: Settings, stop: float) -> Iterator[tuple[int, FuzzInput]]:
    for index in range(settings.count) if settings.count is not None else count():
        if time.monotonic() > stop:
            return
        yield index, make_input(settings.seed, index)


def _progress(results: Results, started: float, stream: TextIO) -> None:
    kinds = ", ".join(f"{kind} {n}" for kind, n in sorted(results.kinds.items()))
    print(f"fuzz: {results.inputs} inputs in {time.monotonic() - started:.0f} s "
          f"({results.inputs / max(time.monotonic() - started, 1e-9):.1f}/s): {kinds}; "
          f"{len(results.findings)} signatures", file=stream, flush=True)


def run_inputs(pool: WorkerPool, settings: Settings, stream: TextIO = sys.stderr) -> Results:
    """Every input of the run through the pool, counted."""
    results, started = Results(), time.monotonic()
    stop = started + settings.minutes * 60 if settings.minutes is not None else float("inf")
    made: dict[int, FuzzInput] = {}
    shown = started

    def remembered():
        for index, item in _inputs(settings, stop):
            made[index] = item
            yield index, item

    for index, outcome in pool.imap(remembered()):
        results.add(index, made.pop(index), outcome)
        if time.monotonic() - shown > PROGRESS_S:
            shown = time.monotonic()
            _progress(results, started, stream)
    results.seconds = time.monotonic() - started
    _progress(results, started, stream)
    return results


def shrink_finding(pool: WorkerPool, finding: Finding, settings: Settings) -> FuzzInput:
    def reproduces(candidates: list[FuzzInput]) -> int | None:
        outcomes = dict(pool.imap(enumerate(candidates)))
        return next((k for k in range(len(candidates)) if outcomes[k].signature == finding.signature), None)

    budget = Budget(settings.shrink_attempts, settings.shrink_seconds)
    return shrink(finding.smallest, reproduces, batch=len(pool.workers), budget=budget)


def _slug(signature: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "-", signature).strip("-")[:60]


def write_finding(finding: Finding, number: int, out: Path) -> Path:
    """The smallest input as OUT/<n>-<slug>/job.yaml (+ input.gcode), its signature and detail beside it."""
    folder = out / f"{number:02d}-{_slug(finding.signature)}"
    path = finding.smallest.write(folder)
    (folder / "signature.txt").write_text(f"{finding.signature}\nseen {finding.count} times; made from: "
                                          f"{finding.smallest.origin}\n\n{finding.outcome.detail}\n",
                                          encoding="utf-8", errors="replace")
    return path


def table(results: Results) -> str:
    rows = [("signature", "count", "size", "smallest input")]
    rows += [(f.signature, str(f.count), str(f.smallest.size), str(f.path or "")) for f in
             sorted(results.findings.values(), key=lambda f: (-f.count, f.signature))]
    widths = [max(len(row[k]) for row in rows) for k in range(3)]
    return "\n".join(f"{r[0]:<{widths[0]}}  {r[1]:>{widths[1]}}  {r[2]:>{widths[2]}}  {r[3]}" for r in rows)


def fuzz(settings: Settings, run: Callable[[FuzzInput], int], stream: TextIO = sys.stderr) -> Results:
    """The whole run: inputs, then each signature's input shrunk and written."""
    with WorkerPool(run, settings.jobs, settings.time_limit, settings.memory_bytes) as pool:
        results = run_inputs(pool, settings, stream)
        for number, finding in enumerate(sorted(results.findings.values(), key=lambda f: f.signature), 1):
            print(f"fuzz: shrinking {finding.signature} ({finding.smallest.size} bytes)", file=stream, flush=True)
            finding.smallest = shrink_finding(pool, finding, settings)
            finding.path = write_finding(finding, number, settings.out)
    return results

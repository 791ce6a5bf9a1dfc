"""Shrinking a failing input while it keeps its signature: chunks of lines deleted (halves first, down to single
lines), then words, then characters; the G-code file first, then the job file. Candidates are tried a batch at a
time (one per worker) and the first that still fails the same way is kept; the number of tries is bounded."""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from typing import Callable, Iterator

from tests.fuzzing.inputs import FuzzInput

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

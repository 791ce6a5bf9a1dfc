"""Wall time of each stage, for the benchmarks: `with watch("plan"): ...`."""

from __future__ import annotations

import time
from contextlib import contextmanager


class Stopwatch:
    def __init__(self):
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str):
        begin = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - begin

    def merge(self, seconds: dict[str, float], prefix: str = "") -> None:
        """Another watch's figures (a child process's), their stage names prefixed."""
        for stage, value in seconds.items():
            self.seconds[prefix + stage] = self.seconds.get(prefix + stage, 0.0) + value

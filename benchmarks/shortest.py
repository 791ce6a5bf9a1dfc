"""The shortest interval at which a firmware still keeps time, by bisection (the firmware benchmarks)."""

from __future__ import annotations

from typing import Callable

from codegen.errors import BuildError


def shortest(on_time: Callable[[int], bool], lo: int, hi: int, what: str) -> int:
    """The smallest interval in (lo, hi] for which `on_time` holds, assuming every longer one holds too."""
    if not on_time(hi):
        raise BuildError(f"{what}: not on time even at {hi} cycles")
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if on_time(mid):
            hi = mid
        else:
            lo = mid
    return hi

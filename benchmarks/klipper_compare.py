"""One motor's steps, ours against Klipper's, paired step by step with numpy (benchmarks/klipper_steps.py).

A step crosses a half-step boundary of its motor (position p -> p + d crosses 2p + d half steps) in a
direction. Two planners that move a motor along the same path cross the same boundaries in the same order, so
steps are paired by their crossing:

1. by occurrence: the n-th crossing of a boundary in a direction, ours with Klipper's. This holds whatever the
   two clocks do (Klipper finishes the Benchy 150 s before us), but an extra step pair on one side (a
   coordinate on a half step that one side rounds up and the other down, then turns back) shifts the count of
   that boundary for the rest of the print;
2. so the pairs of (1) only measure the drift between the two clocks (the median of ours minus Klipper's
   time in bins of 1 s of our time, `Drift`), and each of our steps is then paired with Klipper's crossing
   of the same boundary in the same direction nearest to its time less the drift; these pairs measure the
   drift again in bins of 0.1 s (an infill line crosses a boundary again a line later: the drift must be
   known closer than that), and the pairing is done once more. A Klipper step claimed twice keeps the
   nearer of ours; the rest stay unpaired (the step counts' difference, and a few more).

Times are seconds from the first step of any motor on each side. "global" differences are ours minus
Klipper's time as they stand; "local" ones less the drift at that time: what the steps do apart from the
accumulated difference of the two plans.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

BINS_S = (1.0, 0.1)  # the drift's bins: from the occurrence pairs, then from the nearest pairs it gave
DRIFT_SAMPLE = 16  # every 16th occurrence pair is enough for a bin's median
TREND_HALF = 8  # local differences: less the median of the 2 * 8 + 1 pairs around each
TICK_HZ = 16_000_000  # the common integer clock of the pairing (Klipper's MCU clock)
GROUP_SHIFT = 2**37  # ticks per boundary group in the pairing's sort key (more than a day at 16 MHz)


@dataclass
class Train:
    """One side's steps of one motor."""

    time: np.ndarray  # (S,) s from the side's origin, increasing
    dir: np.ndarray  # (S,) +1 / -1
    start: int  # the motor's position (steps) before its first step

    @cached_property
    def position(self) -> np.ndarray:
        """The position after each step."""
        return self.start + np.cumsum(self.dir, dtype=np.int64)

    @cached_property
    def crossing(self) -> np.ndarray:
        """A key per step: its half-step boundary and its direction."""
        return (2 * self.position - self.dir) * 2 + (self.dir > 0)

    @cached_property
    def by_crossing(self) -> np.ndarray:
        """The steps in order of their crossing key, in time order within a key."""
        return np.argsort(self.crossing, kind="stable")


@dataclass
class Drift:
    """Ours minus Klipper's time, as a function of our time (medians of paired steps in bins)."""

    at: np.ndarray  # bin centres, s of our time
    offset: np.ndarray  # s

    def __call__(self, ours_time: np.ndarray) -> np.ndarray:
        if not len(self.at):
            return np.zeros_like(ours_time)
        return np.interp(ours_time, self.at, self.offset)


def occurrence_pairs(ours: Train, theirs: Train) -> tuple[np.ndarray, np.ndarray]:
    """Indices (ours, theirs) of the n-th crossing of each boundary in each direction on both sides."""

    def keyed(train: Train) -> np.ndarray:
        key, order = train.crossing, train.by_crossing
        sorted_key = key[order]
        group_first = np.flatnonzero(np.r_[True, sorted_key[1:] != sorted_key[:-1]])
        rank = np.arange(len(key)) - np.repeat(group_first, np.diff(np.r_[group_first, len(key)]))
        composite = np.empty(len(key), dtype=np.int64)
        composite[order] = sorted_key * (1 << 25) + rank  # ranks < 2^25 (33 M crossings of one boundary)
        return composite

    _, mine, other = np.intersect1d(keyed(ours), keyed(theirs), assume_unique=True, return_indices=True)
    return mine, other


def drift_of(paired_ours_time: np.ndarray, paired_offset: np.ndarray, bin_s: float) -> Drift:
    """The median offset per bin of our time (pairs of every motor together)."""
    if not len(paired_ours_time):
        return Drift(np.empty(0), np.empty(0))
    paired_ours_time, paired_offset = paired_ours_time[::DRIFT_SAMPLE], paired_offset[::DRIFT_SAMPLE]
    bins = np.floor(paired_ours_time / bin_s).astype(np.int64)
    order = np.lexsort((paired_offset, bins))
    bins, offset = bins[order], paired_offset[order]
    first = np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])
    size = np.diff(np.r_[first, len(bins)])
    return Drift((bins[first] + 0.5) * bin_s, offset[first + size // 2])


def nearest_pairs(ours: Train, theirs: Train, drift: Drift) -> tuple[np.ndarray, np.ndarray]:
    """Indices (ours, theirs): each of our steps with Klipper's crossing of the same boundary in the same
    direction nearest to its time less the drift; a Klipper step claimed twice keeps the nearer."""
    if not len(ours.time) or not len(theirs.time):
        return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
    order = theirs.by_crossing
    sorted_key = theirs.crossing[order]
    group_of_k = np.cumsum(np.r_[False, sorted_key[1:] != sorted_key[:-1]])
    groups = sorted_key[np.r_[True, sorted_key[1:] != sorted_key[:-1]]]
    ticks_k = np.round(theirs.time[order] * TICK_HZ).astype(np.int64)
    sort_k = group_of_k * GROUP_SHIFT + ticks_k + GROUP_SHIFT // 2
    key_o = ours.crossing
    group_o = np.searchsorted(groups, key_o)
    known = (group_o < len(groups)) & (groups[np.minimum(group_o, len(groups) - 1)] == key_o)
    target = np.round((ours.time - drift(ours.time)) * TICK_HZ).astype(np.int64)
    sort_o = group_o * GROUP_SHIFT + target + GROUP_SHIFT // 2
    needles = np.argsort(sort_o)  # sorted needles: searchsorted walks the haystack once
    after = np.empty(len(sort_o), dtype=np.int64)
    after[needles] = np.searchsorted(sort_k, sort_o[needles])
    best = np.full(len(key_o), -1, dtype=np.int64)
    best_error = np.full(len(key_o), np.iinfo(np.int64).max)
    for candidate in (after - 1, after):  # the Klipper steps just before and after the target time
        inside = (candidate >= 0) & (candidate < len(sort_k))
        c = np.clip(candidate, 0, len(sort_k) - 1)
        same = inside & known & (group_of_k[c] == group_o)
        error = np.where(same, np.abs(sort_k[c] - sort_o), np.iinfo(np.int64).max)
        better = error < best_error
        best[better], best_error[better] = c[better], error[better]
    mine = np.flatnonzero(best >= 0)
    claimed, error = order[best[mine]], best_error[mine]
    keep = np.lexsort((error, claimed))  # the nearest claim of each Klipper step first
    first = np.r_[True, claimed[keep][1:] != claimed[keep][:-1]]
    chosen = np.sort(keep[first])
    return mine[chosen], claimed[chosen]


def trend(values: np.ndarray) -> np.ndarray:
    """The running median of 2 * TREND_HALF + 1 values around each (the ends: the nearest full window's)."""
    if len(values) <= 2 * TREND_HALF:
        return np.full(len(values), np.median(values) if len(values) else 0.0)
    medians = np.empty(len(values) - 2 * TREND_HALF)
    chunk = 1 << 18
    for first in range(0, len(medians), chunk):  # bounded memory: a chunk's windows at a time
        window = sliding_window_view(values[first:first + chunk + 2 * TREND_HALF], 2 * TREND_HALF + 1)
        medians[first:first + len(window)] = np.median(window, axis=1)
    return np.concatenate([np.full(TREND_HALF, medians[0]), medians, np.full(TREND_HALF, medians[-1])])


def position_at(train: Train, times: np.ndarray) -> np.ndarray:
    """The train's position just after `times` (steps at that very time included)."""
    if not len(train.time):
        return np.full(len(times), train.start)
    made = np.searchsorted(train.time, times, side="right")
    return np.where(made > 0, train.position[np.maximum(made - 1, 0)], train.start)


@dataclass
class Spread:
    """|differences|: largest, 99th percentile, mean (signed), count over a limit, and where the largest is."""

    max: float
    p99: float
    mean: float
    over: int
    at: int  # index of the largest

    @classmethod
    def of(cls, values: np.ndarray, limit: float) -> "Spread":
        if not len(values):
            return cls(0.0, 0.0, 0.0, 0, -1)
        size = np.abs(values)
        at = int(np.argmax(size))
        return cls(float(size[at]), float(np.percentile(size, 99)), float(values.mean()),
                   int((size > limit).sum()), at)

"""The ring buffer's fill, planned before a byte is sent: does the link keep the streaming player fed?

The player takes each record when it works out the event before the record's first (at tick 0 for the first
records), and needs `need` bytes (protocol.max_record_bytes) in the ring before it reads one. The host sends
`prefill` bytes before START, then as fast as the link carries stream bytes (`rate`: the baud rate's bytes less
the frames' overhead, with a margin) whenever the ring has room. With C(t) the bytes taken before t, what has
arrived by t is

    D(t) = min(prefill + rate t,  min over s <= t of  C(s) + usable + rate (t - s))

(the second term: the ring was as full as the host keeps it at s, `LinkBudget.usable`, then refilled at the
link's rate), and the fill when record i is read at t_i is D(t_i) - C(t_i). Both minima run over the records in
order, so the fill is known window by window in constant memory: `Ring.add` takes a window's records and says
where the fill would fall short even with the ring full at the start (`Shortfall`: slow that stretch down);
`Ring.result` gives the smallest prefill that feeds every record and the lowest fill it leaves.

The lowest fill counts the records before the last ring's worth of the stream (the fill must fall at the end,
when nothing more is to come); a job whose stream fits the ring has none.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from codegen.link import protocol
from codegen.link.host import PING_S, refill_byte_times
from codegen.tables.format import end_marker

RATE_MARGIN = 0.97  # of the link's stream bytes per second the plan counts on
PAYLOAD_SHARE = 8  # DATA frames carry at most an eighth of the ring
PREFILL_MARGIN = 2  # frames sent before START beyond what the plan needs
MIN_PAYLOAD = 8  # DATA bytes a frame carries at the least (a 64-byte ring: an eighth)
UPDATES_LOST_PING_S = 0.1  # the host's pings where the firmware sends window updates: a fallback for a lost one


@dataclass(frozen=True)
class LinkBudget:
    baud: int
    ring_bytes: int  # the firmware's ring
    need: int  # bytes the player needs in the ring before it reads a record
    payload: int  # DATA bytes per frame
    window_updates: bool = False  # the firmware ACKs unasked once its ring has room for a frame again

    @property
    def rate(self) -> float:
        """Stream bytes per second the plan counts on: 10 bits a byte, a frame's overhead, a margin."""
        return self.baud / 10 * self.payload / (self.payload + protocol.OVERHEAD_BYTES) * RATE_MARGIN

    @property
    def ping_s(self) -> float:
        """How long the host, blocked on credit, waits before it pings for a fresh ACK: with window updates only
        in case one was lost on the line (the firmware's ACK comes first), else its ordinary interval."""
        return UPDATES_LOST_PING_S if self.window_updates else PING_S

    @property
    def refill_latency_s(self) -> float:
        """From when a ring the host had filled has room for a frame again to when that frame is in it."""
        return refill_byte_times(self.payload, self.baud, self.window_updates) * 10 / self.baud

    @property
    def usable(self) -> int:
        """Ring bytes the host can count on keeping filled: the ring, less a frame that does not fit (the host
        sends whole frames, so it stops up to payload - 1 short of full), less what the link would have carried
        while the host, blocked on credit, waits to hear that a frame fits again (refill_latency_s): the player
        may take that much before the refill starts."""
        room = self.ring_bytes - (self.payload - 1) - self.rate * self.refill_latency_s
        return max(math.floor(room), self.need)


def link_budget(baud: int, ring_bytes: int, motors: int, window_updates: bool = False) -> LinkBudget:
    """`window_updates`: the firmware tells the host unasked when its ring has room for a frame again (else the
    host learns it by pinging)."""
    payload = max(MIN_PAYLOAD, min(128, ring_bytes // PAYLOAD_SHARE))
    return LinkBudget(baud, ring_bytes, protocol.max_record_bytes(motors), payload, window_updates)


@dataclass(frozen=True)
class Shortfall:
    """Records [first, last] of a window drain the ring below `need` even when it starts full."""

    first: int  # the stretch's records, in the window
    last: int
    begin_s: float  # when they are read, on the program's clock
    end_s: float
    extra_s: float  # how much longer the stretch must take


@dataclass
class Ring:
    budget: LinkBudget
    taken: int = 0  # stream bytes the player has taken
    full_low: float = math.inf  # min over records so far of C + usable - rate t (the ring full then)
    start_low: float = math.inf  # min over records so far of rate t - C (prefill aside)
    low_full: float = math.inf  # min over records so far of the fill with the ring full at some record
    windows: list[tuple[int, float, float]] = field(default_factory=list)  # (C at the end, start_low, low_full)
    last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # the last window's C, start_low, low_full by record

    def copy(self) -> "Ring":
        return replace(self, windows=list(self.windows))

    def add(self, times: np.ndarray, sizes: np.ndarray) -> list[Shortfall]:
        """A window's records: when each is read (s, on the program's clock) and its bytes; the stretches where
        the ring would run short (none: the window is fed). Nothing is kept when the window falls short (it is
        planned again and added once more)."""
        if len(times) == 0:
            return []
        b = self.budget
        before = self.taken + np.concatenate([[0], np.cumsum(sizes[:-1])])  # C just before each record
        full = np.minimum.accumulate(np.minimum(before + b.usable - b.rate * times, self.full_low))
        start = b.rate * times - before
        fill_full = np.minimum(full, b.usable) + start  # the fill, with the ring full before the first record
        if np.any(fill_full < b.need):
            return self._shortfalls(times, before, fill_full)
        self.full_low = float(full[-1])
        start_lows = np.minimum.accumulate(np.minimum(start, self.start_low))
        full_lows = np.minimum.accumulate(np.minimum(full + start, self.low_full))
        self.last = (before, start_lows, full_lows)
        self.start_low, self.low_full = float(start_lows[-1]), float(full_lows[-1])
        self.taken = int(before[-1] + sizes[-1])
        self.windows.append((self.taken, self.start_low, self.low_full))
        return []

    def _shortfalls(self, times: np.ndarray, before: np.ndarray, fill: np.ndarray) -> list[Shortfall]:
        """Each stretch that drains the ring below `need`, the first from `fill`, each next one with the ring
        full again after the one before (as if that one were slowed enough): the plan slows them all at once."""
        b = self.budget
        stretches: list[Shortfall] = []
        lo = 0
        while lo < len(times):
            short = np.flatnonzero(fill < b.need)
            if not len(short):
                break
            i = lo + int(short[0])
            k = lo + int(np.argmin(before[lo:i + 1] - b.rate * times[lo:i + 1]))  # where the ring was last full
            stretches.append(Shortfall(k, i, float(times[k]), float(times[i]),
                                       float(b.need - fill[short[0]]) / b.rate))
            lo = i + 1
            level = before[lo:] - b.rate * times[lo:]
            fill = b.usable - (level - np.minimum.accumulate(level))
        return stretches

    def result(self, stream_bytes: int) -> tuple[int, int | None]:
        """(prefill bytes, lowest fill while more than a ring's worth of the stream was still to come)."""
        b = self.budget
        prefill = b.need if math.isinf(self.start_low) else int(math.ceil(b.need - self.start_low))
        prefill = min(prefill + PREFILL_MARGIN * b.payload, b.usable, stream_bytes)  # margin: a late host
        end = stream_bytes - b.ring_bytes  # records read after the player has taken this many: the ring's drain
        counted = [(s, f) for taken, s, f in self.windows if taken <= end]
        if self.last is not None:  # the end falls in the last window: its records before it count too
            before, start_lows, full_lows = self.last
            i = int(np.searchsorted(before, end, side="right")) - 1
            if i >= 0:
                counted.append((float(start_lows[i]), float(full_lows[i])))
        if not counted:
            return prefill, None
        start_low, low_full = counted[-1]
        return prefill, int(math.floor(min(prefill + start_low, low_full)))


@dataclass(frozen=True)
class LinkPlan:
    """What `plan --stream` reports of a streamed job's link."""

    budget: LinkBudget
    stream_bytes: int  # the table stream with its tail padding
    prefill_bytes: int
    min_ring_fill_bytes: int | None
    link_slowdown_s: float

    def summary(self) -> dict:
        return {"baud": self.budget.baud, "ring_bytes": self.budget.ring_bytes, "stream_bytes": self.stream_bytes,
                "prefill_bytes": self.prefill_bytes, "min_ring_fill_bytes": self.min_ring_fill_bytes,
                "link_slowdown_s": round(self.link_slowdown_s, 6)}


def link_plan(budget: LinkBudget, ring: Ring, totals) -> LinkPlan:
    stream = totals.table_bytes + budget.need - len(end_marker(False))  # + protocol.tail_padding
    prefill, low = ring.result(stream)
    return LinkPlan(budget, stream, prefill, low, totals.link_slowdown_s)

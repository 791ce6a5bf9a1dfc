"""The ring buffer's fill, planned before a byte is sent: does the link keep the streaming player fed?

The player takes each record when it works out the event before the record's first (at tick 0 for the first
records), and needs `need` bytes (protocol.max_record_bytes) in the ring before it reads one. The host sends
`prefill` bytes before START (whole frames), then as fast as the link carries stream bytes (`rate`: the baud
rate's bytes less the frames' overhead, with a margin) whenever its credit allows. With C(t) the bytes taken
before t, what has arrived by t is at least the smaller of

    prefill - payload + rate t                                    (the line busy since the player started)
    min over g <= t of  C(g) + max(kept, usable + rate (t - g))   (the line stood idle last at some u <= t)

The first: one frame was on the line as the player started. The second: the host, blocked on credit at u, had
sent all but less than a frame of what the ACK it went by allowed, and that ACK, from g, reported the ring's fill
then: so C(g) + kept had arrived (`LinkBudget.kept`: the ring less payload - 1). The line, busy from u on, brings
a frame every frame time, and u - g is at most `refill_byte_times` less a frame (host.py): from g the arrivals
grow at `rate` after that lag and a frame, which `usable` (kept less what the line carries meanwhile) counts
from g on. Split at g = t - lag_s (where the two meet): the fill when record i is read at t_i is at least

    kept less the bytes taken in the last lag_s,  or  min over records j read by t_i - lag_s of
    C(t_j) + usable + rate (t_i - t_j) - C(t_i)

Both run over the records in order: the fill is known window by window in memory of the last lag_s's records.
`Ring.add` takes a window's records and says where the fill would fall short even with the ring full at the
start (`Shortfall`: slow that stretch down); `Ring.result` gives the smallest prefill that feeds every record and
the lowest fill it leaves.

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
    def refill_byte_times(self) -> float:
        """The longest the line stands idle behind the ACK the host went by, and a frame (host.py)."""
        return refill_byte_times(self.payload, self.baud, self.window_updates)

    @property
    def kept(self) -> int:
        """Ring bytes the host has sent, beyond those taken when the ACK it went by left, whenever it stops for
        credit: the ring less a frame that does not fit (it sends whole frames while its credit holds one)."""
        return self.ring_bytes - (self.payload - 1)

    @property
    def usable(self) -> int:
        """Where the refill counts from: `kept` less the stream bytes the line carries in refill_byte_times (in
        byte times: the line's rate whatever the baud rate's error), which the player may take before the line,
        idle behind the host's last word of the ring, has brought a frame."""
        carried = self.payload / (self.payload + protocol.OVERHEAD_BYTES) * self.refill_byte_times
        return math.floor(self.kept - carried)

    @property
    def lag_s(self) -> float:
        """Where kept and usable + rate x lag meet: the bytes taken in the last lag_s count against kept."""
        return (self.kept - self.usable) / self.rate

    @property
    def max_prefill(self) -> int:
        """Stream bytes the host can send before START: the whole frames the ring takes."""
        return self.ring_bytes // self.payload * self.payload


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


def kept_fill(budget: LinkBudget, times: np.ndarray, before: np.ndarray, lows: np.ndarray, earlier_low: float,
              first: int) -> np.ndarray:
    """The fill the host keeps (the second bound, at the top) at records first.. of `times` (when each is read, s) and
    `before` (C before each): kept less the bytes taken in the last lag_s, or the refill from a record read by
    lag_s before (`lows`: the running minimum of C + usable - rate t, `earlier_low` that of the records before)."""
    t, c = times[first:], before[first:]
    back = t - budget.lag_s
    k = np.searchsorted(times, back, side="right") - 1  # the last record read by then
    refilled = np.where(k >= 0, lows[np.maximum(k, 0)], earlier_low) + budget.rate * t - c
    taken = c - before[np.searchsorted(times, back, side="left")]  # since then
    return np.minimum(refilled, budget.kept - taken)


def _running_low(times: np.ndarray, before: np.ndarray, budget: LinkBudget, earlier_low: float) -> np.ndarray:
    return np.minimum.accumulate(np.minimum(before + budget.usable - budget.rate * times, earlier_low))


@dataclass
class Ring:
    budget: LinkBudget
    taken: int = 0  # stream bytes the player has taken
    start_low: float = math.inf  # min over records so far of rate t - C (prefill aside)
    low_kept: float = math.inf  # min over records so far of the fill the host keeps (kept_fill)
    windows: list[tuple[int, float, float]] = field(default_factory=list)  # (C at the end, start_low, low_kept)
    last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # the last window's C, start_low, low_kept by record
    # The records of the last lag_s (kept_fill looks that far back): when each is read, C before it, the running
    # minimum of C + usable - rate t; and that minimum over the records before them.
    recent: tuple[np.ndarray, np.ndarray, np.ndarray] = (np.zeros(0), np.zeros(0), np.zeros(0))
    earlier_low: float = math.inf

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
        old_t, old_c, old_low = self.recent
        all_t, all_c = np.concatenate([old_t, times]), np.concatenate([old_c, before])
        lows = np.concatenate([old_low, _running_low(times, before, b, old_low[-1] if len(old_low) else
                                                     self.earlier_low)])
        kept = kept_fill(b, all_t, all_c, lows, self.earlier_low, len(old_t))
        start = b.rate * times - before
        fill_full = np.minimum(kept, b.max_prefill - b.payload + start)  # the ring full before the first record
        if np.any(fill_full < b.need):
            return self._shortfalls(times, before, fill_full)
        start_lows = np.minimum.accumulate(np.minimum(start, self.start_low))
        kept_lows = np.minimum.accumulate(np.minimum(kept, self.low_kept))
        self.last = (before, start_lows, kept_lows)
        self.start_low, self.low_kept = float(start_lows[-1]), float(kept_lows[-1])
        self.taken = int(before[-1] + sizes[-1])
        self.windows.append((self.taken, self.start_low, self.low_kept))
        drop = int(np.searchsorted(all_t, all_t[-1] - b.lag_s, side="left"))  # records kept_fill needs no more
        self.earlier_low = float(lows[drop - 1]) if drop else self.earlier_low
        self.recent = (all_t[drop:], all_c[drop:], lows[drop:])
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
            t, c = times[lo:], before[lo:]
            fill = kept_fill(b, t, c, _running_low(t, c, b, math.inf), math.inf, 0)
        return stretches

    def result(self, stream_bytes: int) -> tuple[int, int | None]:
        """(prefill bytes, lowest fill while more than a ring's worth of the stream was still to come)."""
        b = self.budget
        prefill = b.need if math.isinf(self.start_low) else int(math.ceil(b.need - self.start_low))
        # a frame on the line as the player starts, and a margin: a late host
        prefill = min(prefill + (1 + PREFILL_MARGIN) * b.payload, b.max_prefill, stream_bytes)
        sent = min(-(-prefill // b.payload) * b.payload, stream_bytes)  # the host sends whole frames
        end = stream_bytes - b.ring_bytes  # records read after the player has taken this many: the ring's drain
        counted = [(s, f) for taken, s, f in self.windows if taken <= end]
        if self.last is not None:  # the end falls in the last window: its records before it count too
            before, start_lows, kept_lows = self.last
            i = int(np.searchsorted(before, end, side="right")) - 1
            if i >= 0:
                counted.append((float(start_lows[i]), float(kept_lows[i])))
        if not counted:
            return prefill, None
        start_low, low_kept = counted[-1]
        return prefill, int(math.floor(min(sent - b.payload + start_low, low_kept)))


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

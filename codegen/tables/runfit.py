"""Rate runs by greedy search: from each event on, the longest run `(interval, add, count)` whose every event
stays within its window, as Klipper's step compression does, in our units and with our player's limits.

Units: positions in 1/256 tick, counted from a whole tick `base` (the event before the first one stands at
position `p0`, usually 0 <= p0 < 256: small numbers for the search). An event happens at tick
base + floor(position / 256); the k-th event of a run (k = 1, 2, ...) from position p stands at
p + k * interval + add * k (k - 1) / 2.

An event's window [lo, hi] (positions) turns into a range of intervals for a given add: every event of the run
narrows it, and the run ends where it is empty. The longest run over the adds is searched by bisection: an
event that ends a run says which way the add must move (it needs a later or an earlier time than the range
allows). Two runs that both reach n events within a band of width W differ in add by at most
2 W (m + n) / (m n (n - m)) (compare them at events m = n/2 and n), so once a run reaches n events, only adds
that close to it can reach further: long runs settle in a few tries. Of the intervals the best add allows, the
one that puts the run's last event nearest the middle of its window leaves the next run the most room.

Besides its window, an event must come at least `needed` ticks after the one before (what the player needs).
First the windows' upper ends come down so that every later event can still keep its gap and its window (an
event late in a wide window, after a long gap, must not leave the next one, after a short gap, nowhere to go):
given ideal gaps of at least `needed`, every window keeps room. Then the first event of a run keeps its gap by
its window's lower end, the others by ending the run before an event that comes too soon. An event that cannot
keep both anyway (its ideal time too close to the one before) takes the earliest time the gap allows.

`fit_runs` uses the C version (codegen/native/runfit.c); `fit_runs_python` is the same search in Python, for the
tests and for machines without gcc. They try the same adds and find the same runs; the C only computes faster:
each event's interval bounds once per run for every add (one division instead of one per try), and no
clamping of the own intervals where the first event's range already keeps them.
"""

from __future__ import annotations

import ctypes

import numpy as np

from codegen.native import contiguous, library, pointer
from codegen.tables.schedule import FRAC_ONE

GUESS_STRIDE = 8  # events between the samples of the second difference that guesses each run's add


def add_guess(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """A starting add for a run at each event: the second difference of the windows' middles per event."""
    mid = (lo + hi) / 2.0
    n = len(mid)
    s = GUESS_STRIDE
    guess = np.zeros(n, dtype=np.int64)
    if n >= 2 * s + 1:
        d2 = (mid[2 * s:] - 2.0 * mid[s:-s] + mid[:-2 * s]) / (s * s)
        guess[:len(d2)] = np.round(d2)
        guess[len(d2):] = guess[len(d2) - 1]
    return guess


def leave_room(hi: np.ndarray, needed: np.ndarray) -> np.ndarray:
    """Each window's upper end, no later than every later event's upper end less the gaps in between:
    hi'[k] = min over j >= k of hi[j] - 256 * (needed[k + 1] + ... + needed[j])."""
    gaps = FRAC_ONE * np.cumsum(needed)
    return np.minimum.accumulate((hi - gaps)[::-1])[::-1] + gaps


def fit_runs(lo: np.ndarray, hi: np.ndarray, needed: np.ndarray, p0: int, base: int, max_count: int, max_add: int,
             max_interval: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Runs over the events with windows [lo, hi] (int64 positions): (count, interval, add) per run, and the
    tick of every event."""
    lo, hi, needed = contiguous(np.int64, lo, hi, needed)
    lib = library("runfit")
    if lib is None:
        room = leave_room(hi, needed)
        return fit_runs_python(lo, room, needed, add_guess(lo, room), p0, base, max_count, max_add, max_interval)
    return fit_runs_native(lib, lo, hi.copy(), needed, p0, base, max_count, max_add, max_interval)


def fit_runs_native(lib: ctypes.CDLL, lo: np.ndarray, hi: np.ndarray, needed: np.ndarray, p0: int, base: int,
                    max_count: int, max_add: int, max_interval: int):
    """`fit_runs` in C, given contiguous int64 arrays; `hi` becomes the windows' upper ends after `leave_room`."""
    n = len(lo)
    count, interval, add, tick = (np.empty(n, dtype=np.int64) for _ in range(4))
    fn = lib.fit_runs
    fn.restype = ctypes.c_int64
    i64 = ctypes.c_int64
    runs = fn(i64(n), *map(pointer, (lo, hi, needed)), i64(p0), i64(base), i64(max_count), i64(max_add),
              i64(max_interval), *map(pointer, (hi, count, interval, add, tick)))
    if runs < 0:
        raise MemoryError("rate runs: no memory for the search")
    return count[:runs], interval[:runs], add[:runs], tick


def _floor_div(a: int, b: int) -> int:
    return a // b


def _ceil_div(a: int, b: int) -> int:
    return -((-a) // b)


def _extend(add, first, lo, hi, first_lo, p0, max_count, max_interval):
    """(count, lowest interval, highest interval, widest band, which way the add must move: +1, -1, 0)."""
    events = len(lo)
    count, band, wants = 0, 0, 0
    i_lo = i_hi = None
    k = 1
    while k <= max_count and first + k - 1 < events:
        j = first + k - 1
        low = first_lo if k == 1 else lo[j]
        shift = p0 + add * (k * (k - 1) // 2)
        a, b = low - shift, hi[j] - shift
        new_lo = _ceil_div(a, k) if k == 1 or k * i_lo < a else i_lo
        new_hi = _floor_div(b, k) if k == 1 or k * i_hi > b else i_hi
        own = add * (k - 1)
        new_lo = max(new_lo, -own)
        new_hi = min(new_hi, max_interval - own)
        if new_lo > new_hi:
            wants = 0 if k == 1 else (1 if _ceil_div(a, k) > i_hi or -own > i_hi else -1)
            break
        i_lo, i_hi = new_lo, new_hi
        band = max(band, hi[j] - low)
        count = k
        k += 1
    return count, i_lo, i_hi, band, wants


def _add_spread(count: int, band: int) -> int:
    n, m = count, count // 2
    return (2 * band * (m + n)) // (m * n * (n - m)) + 1


def fit_runs_python(lo, hi, needed, guess, p0: int, base: int, max_count: int, max_add: int, max_interval: int):
    """The search of codegen/native/runfit.c, try for try (`hi`: the windows' upper ends after `leave_room`;
    `guess`: `add_guess`)."""
    lo, hi, needed, guess = (np.asarray(a, dtype=np.int64).tolist() for a in (lo, hi, needed, guess))
    events = len(lo)
    counts, intervals, adds, tick = [], [], [], [0] * events
    first, pos, last_tick = 0, int(p0), int(p0) >> 8  # ticks from base
    while first < events:
        first_lo = max(256 * (last_tick + needed[first]), lo[first])
        a_min, a_max = -max_add, max_add
        add = min(max(guess[first], a_min), a_max)
        best, best_add = (0, None, None, 0, 0), 0
        while True:
            r = _extend(add, first, lo, hi, first_lo, pos, max_count, max_interval)
            better = r[0] > best[0] or (r[0] == best[0] and r[0] > 0 and abs(add) < abs(best_add))
            if better:
                best, best_add = r, add
            if r[4] == 0:
                break
            if better and best[0] >= 2:  # (while the best stays, its spread narrows nothing more)
                spread = _add_spread(best[0], best[3])
                a_min, a_max = max(a_min, best_add - spread), min(a_max, best_add + spread)
            if r[4] > 0:
                a_min = max(a_min, add + 1)
            else:
                a_max = min(a_max, add - 1)
            if a_min > a_max:
                break
            add = a_min + (a_max - a_min) // 2
        count = best[0]
        if count == 0:
            count, best_add = 1, 0
            interval = min(first_lo - pos, max_interval)
        else:
            j = first + count - 1
            low = first_lo if count == 1 else lo[j]
            target = _floor_div(low + hi[j], 2) - pos - best_add * (count * (count - 1) // 2)
            interval = min(max(_floor_div(2 * target + count, 2 * count), best[1]), best[2])
        k, p = 1, pos
        while k <= count:
            p += interval + best_add * (k - 1)
            t = p >> 8
            if k > 1 and t - last_tick < needed[first + k - 1]:
                p -= interval + best_add * (k - 1)
                break
            tick[first + k - 1] = base + t
            last_tick = t
            k += 1
        count = k - 1
        counts.append(count)
        intervals.append(interval)
        adds.append(best_add)
        first += count
        pos = p
    as_array = lambda v: np.asarray(v, dtype=np.int64)  # noqa: E731
    return as_array(counts), as_array(intervals), as_array(adds), as_array(tick)

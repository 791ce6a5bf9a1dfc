"""The interpreter's plain G0/G1 lines in C (codegen/native/gcodelines.c): whole stretches of a file read and run
without a Python object per line or per move.

The C takes comment lines and G0/G1 lines of plain words (X Y Z E F S) as `Interpreter.line` runs them, and
stops at any other line, or at a plain line that is an error; Python's reader and interpreter take that one
and the C goes on after it. Its moves are rows of arrays, recorded among the interpreter's items as runs
(`take` makes them Lines items). Without the C helper (no gcc), Python reads every line: the items are the same.
"""

from __future__ import annotations

import ctypes

import numpy as np

from codegen.native import library
from codegen.toolpath.limits import LONGEST_MOVE_S

RUN = 3  # an item kind beside moves.py's LINE, ARC, HOME: moves made here, rows lo..hi of the arrays
REALS = ("unit", "flow", "e_shift", "feed", "draw_feed", "rapid", "speed_factor", "min_feed", "min_travel_feed",
         "accel_print", "accel_travel", "accel_retract", "s_full", "power")  # after pos and off (gcodelines.c)
FEED, POWER = 8 + REALS.index("feed"), 8 + REALS.index("power")
LIMITS = 5  # after the reals: the reach of x, y, z, e and the longest move (codegen/toolpath/limits.py)
FLAGS = ("relative", "e_relative", "has_feed", "spindle", "fixed", "mode", "s_watched")  # gcodelines.c's order
HAS_FEED, MODE = FLAGS.index("has_feed"), FLAGS.index("mode")


class NativeLines:
    """The moves one batch of G-code makes in C: `end`, `feed`, `tool`, `rapid`, `accel`, `power`, `line`, `col`
    (rows 0..made), until `clear`."""

    def __init__(self, lib: ctypes.CDLL, capacity: int):
        self.lib, self.made = lib, 0
        self.end = np.empty((capacity, 4))
        self.feed, self.accel, self.power = np.empty(capacity), np.empty(capacity), np.empty(capacity)
        self.rapid, self.line, self.col = (np.empty(capacity, dtype=np.int64) for _ in range(3))
        self.tool = np.empty(capacity, dtype=bool)
        self.dynamic = np.empty(capacity, dtype=bool)
        self.state = (ctypes.c_double * (8 + len(REALS) + LIMITS))()
        self.flags = (ctypes.c_int64 * len(FLAGS))()
        self.at, self.blocks = ctypes.c_int64(), ctypes.c_int64()
        self.rows = [a.ctypes.data_as(ctypes.c_void_p) for a in (self.end, self.feed, self.accel, self.power,
                                                                  self.rapid, self.line, self.col)]
        self.text, self.starts, self.first = b"", np.zeros(1, dtype=np.int64), 0
        self.line_starts, self.lines = self.starts.ctypes.data_as(ctypes.c_void_p), ctypes.c_int64(0)

    @classmethod
    def load(cls, capacity: int) -> "NativeLines | None":
        lib = library("gcodelines")
        if lib is None:
            return None
        lib.run_lines.restype = ctypes.c_int64
        return cls(lib, capacity)

    def read(self, lines: list[str], first: int) -> None:
        """The lines the next runs take (line `first` of the program on)."""
        self.text = "\n".join(lines).encode("utf-8", "surrogatepass")  # any other character: a line for Python
        breaks = np.flatnonzero(np.frombuffer(self.text, dtype=np.uint8) == 10)
        self.starts = np.concatenate([[0], breaks + 1, [len(self.text) + 1]]).astype(np.int64)
        self.line_starts, self.lines = self.starts.ctypes.data_as(ctypes.c_void_p), ctypes.c_int64(len(lines))
        self.first = first

    def run(self, it, at: int, budget: int) -> tuple[int, int]:
        """Lines from `at` on, for the interpreter `it`, at most `budget` of them blocks (not comments): the
        first line not taken, and the blocks taken."""
        state, flags = self.state, self.flags
        state[:] = [*it.pos, *it.off, *[getattr(it, name) or 0.0 for name in REALS],  # feed None: 0.0
                    *it.reach, LONGEST_MOVE_S]
        flags[:] = [it.relative, it.e_relative, it.feed is not None, it.spindle,
                    sum(1 << i for i in it.fixed), it.mode == "G1", it.s_watched]
        self.at.value, self.blocks.value, lo = at, budget, self.made
        moves = self.lib.run_lines(self.text, self.line_starts, self.lines, ctypes.byref(self.at),
                                   ctypes.byref(self.blocks), state, flags, ctypes.c_int64(lo),
                                   ctypes.c_int64(len(self.feed)), *self.rows)
        if self.blocks.value:
            it.mode = "G1" if flags[MODE] else "G0"
            it.feed = state[FEED] if flags[HAS_FEED] else None
            it.power = state[POWER]
        if moves:
            hi = self.made = lo + moves
            self.line[lo:hi] += it.origin.line + self.first
            self.col[lo:hi] += it.origin.col
            self.tool[lo:hi] = (self.rapid[lo:hi] == 0) & it.spindle
            self.dynamic[lo:hi] = it.dynamic  # M3 / M4 are Python's: the same for the whole run
            it.pos = state[0:4]
            start = it.add_point(it.pos)  # where Python's next move starts
            it.items.append((RUN, start, lo, hi))
        return self.at.value, self.blocks.value

    def clear(self) -> None:
        self.made = 0

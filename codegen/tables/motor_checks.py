"""Each motor's rate and acceleration checks over a pulse train that may come a window at a time.

- Rate: over any 8 consecutive steps no motor exceeds max_velocity * steps_per_mm. A window's first 7 spans
  reach back into the pulses before it: the last 7 are carried over.
- Acceleration: the velocity change between consecutive 20 ms windows (a grid from the motor's first pulse)
  stays within max_accel * 20 ms, plus the velocity jumps the junction model plans at corners inside those
  windows, plus one step of quantisation at each window edge (positions are interpolated between step times).
  An edge is measured once a pulse after it is known (the last ones when the train ends); the pulses since
  the last measured edge, the last two edge positions and the recent corners are carried over.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from codegen.motion.planner import ACCEL_WINDOW_S, RATE_WINDOW


@dataclass
class RateCheck:
    max_rate: float  # steps/s
    tail: np.ndarray = field(default_factory=lambda: np.zeros(0))  # the last RATE_WINDOW pulse times (s)
    worst: float = 0.0  # highest 8-step rate / limit so far

    def add(self, time: np.ndarray) -> np.ndarray:
        """Times (s) of this motor's new pulses; returns the index (into them) of every pulse that ends 8
        steps over the limit, with its ratio: (K,) int, (K,) float."""
        both = np.concatenate([self.tail, time])
        self.tail = both[-RATE_WINDOW:].copy()  # not a view: the window's pulses may go
        if len(both) <= RATE_WINDOW:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        ratio = RATE_WINDOW / np.maximum(both[RATE_WINDOW:] - both[:-RATE_WINDOW], 1e-12) / self.max_rate
        self.worst = max(self.worst, float(ratio.max()))
        over = np.flatnonzero(ratio > 1.0)
        return over + RATE_WINDOW - (len(both) - len(time)), ratio[over]


@dataclass
class AccelCheck:
    max_accel: float  # steps/s^2
    t0: float | None = None  # the first pulse: the grid of 20 ms windows starts there
    pulse_t: np.ndarray = field(default_factory=lambda: np.zeros(0))  # carried pulses (s) ...
    pulse_p: np.ndarray = field(default_factory=lambda: np.zeros(0))  # ... and the position after each
    position: int = 0  # net steps so far
    next_edge: int = 0  # the grid index of the next edge to measure
    edge_p: list = field(default_factory=list)  # positions at the last two measured edges
    corner_t: np.ndarray = field(default_factory=lambda: np.zeros(0))  # corners (s) not yet behind the edges
    corner_jump: np.ndarray = field(default_factory=lambda: np.zeros(0))  # this motor's jump there (steps/s)
    worst: float = 0.0

    def add(self, time: np.ndarray, direction: np.ndarray, corner_t: np.ndarray, corner_jump: np.ndarray,
            last: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """New pulses (s, +-1) and the plan's corners up to the last of them; `last`: the train ends here.
        Returns the start (s) of every pair of windows whose velocity change is over what is allowed, with
        its ratio."""
        if len(time) and self.t0 is None:
            self.t0 = float(time[0])
        self.pulse_t = np.concatenate([self.pulse_t, time])
        self.pulse_p = np.concatenate([self.pulse_p, self.position + np.cumsum(direction)])
        self.position += int(direction.sum())
        self.corner_t = np.concatenate([self.corner_t, corner_t])
        self.corner_jump = np.concatenate([self.corner_jump, corner_jump])
        if self.t0 is None or len(self.pulse_t) == 0:
            return np.zeros(0), np.zeros(0)
        t_last = float(self.pulse_t[-1])
        if last:  # the final edge is the first at or after the last pulse
            stop = int(np.ceil((t_last - self.t0) / ACCEL_WINDOW_S)) + 1
        else:  # edges strictly before the last known pulse: the pulse after each is known
            stop = int(np.ceil((t_last - self.t0) / ACCEL_WINDOW_S))
        edges = self.t0 + ACCEL_WINDOW_S * np.arange(self.next_edge, max(stop, self.next_edge))
        measured = np.interp(edges, self.pulse_t, self.pulse_p)
        p = np.concatenate([self.edge_p, measured])
        t = np.concatenate([self.t0 + ACCEL_WINDOW_S * np.arange(self.next_edge - len(self.edge_p), self.next_edge),
                            edges])
        self.next_edge += len(edges)
        begin, ratio = np.zeros(0), np.zeros(0)
        if len(p) >= 3 and len(edges):
            v = np.diff(p) / ACCEL_WINDOW_S
            dv = np.abs(np.diff(v))
            cum = np.concatenate([[0.0], np.cumsum(self.corner_jump)])
            lo = np.searchsorted(self.corner_t, t[:-2], side="left")
            hi = np.searchsorted(self.corner_t, t[2:], side="right")
            allowed = self.max_accel * ACCEL_WINDOW_S + (cum[hi] - cum[lo]) + 2.0 / ACCEL_WINDOW_S
            ratio = dv / allowed
            begin = t[:-2]
            self.worst = max(self.worst, float(ratio.max()))
        self.edge_p = list(p[-2:])
        # Keep the pulses from the last one at or before the last measured edge, and the corners after the
        # earliest edge a later pair of windows still starts at.
        since = t[-2] if len(t) >= 2 else -np.inf
        if len(t):
            keep = max(int(np.searchsorted(self.pulse_t, t[-1], side="right")) - 1, 0)
            self.pulse_t, self.pulse_p = self.pulse_t[keep:].copy(), self.pulse_p[keep:].copy()
        keep_corners = self.corner_t >= since
        self.corner_t, self.corner_jump = self.corner_t[keep_corners], self.corner_jump[keep_corners]
        over = ratio > 1.0
        return begin[over], ratio[over]

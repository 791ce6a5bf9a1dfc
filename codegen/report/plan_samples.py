"""What `plan --report` draws, gathered a window at a time as the plan goes (codegen/pipeline/windows.py hands each final
window to it), so that the report's memory does not grow with the job's steps: every window's segments and their
plan (a few numbers per segment), and every motor's position on a fine time grid (FINE_S) from the twin's pulses,
which the motion plot resamples (codegen/report/plots.py motion_of)."""

from __future__ import annotations

import numpy as np

from codegen.motion.planner import Plan
from codegen.pipeline.windows import Played
from codegen.report.plots import WINDOW_S, motion_from_grid
from codegen.toolpath.segments import Segments, concat

FINE_S = WINDOW_S / 2  # the grid the motors' positions are kept on: finer than any plot's


class PlanSamples:
    def __init__(self):
        self.windows: list[tuple[Segments, Plan]] = []
        self.chunks: list[np.ndarray] = []  # (M, K) net steps at the grid's edges, a window's worth each
        self.edges = 0  # grid edges measured so far
        self.last = np.zeros(0)  # each motor's net steps after its last pulse so far ...
        self.last_t = np.zeros(0)  # ... and that pulse's time (s)
        self.duration_s = 0.0  # the last event's time

    def __call__(self, played: Played) -> None:
        """A final window: its segments, its plan, and the motors' positions up to its last event."""
        self.windows.append((played.window.segments, played.window.plan))
        pulses = played.pulses
        if pulses is None or not len(pulses.event_tick):
            return
        if not len(self.last):
            self.last = np.zeros(pulses.event_position.shape[1])
            self.last_t = np.zeros(len(self.last))
        tick_hz = played.compressed.schedule.tick_hz
        end = float(pulses.event_tick[-1]) / tick_hz
        stop = int(np.floor(end / FINE_S)) + 1
        edges = FINE_S * np.arange(self.edges, stop)
        chunk = np.empty((len(self.last), len(edges)))
        for m in range(len(self.last)):
            tick, direction = pulses.of_motor(m)
            t = np.concatenate([[self.last_t[m]], tick / tick_hz])
            p = self.last[m] + np.concatenate([[0], np.cumsum(direction, dtype=np.int64)])
            chunk[m] = np.interp(edges, t, p)  # flat after the last pulse: the motor stands
            self.last[m], self.last_t[m] = p[-1], t[-1]
        self.chunks.append(chunk)
        self.edges, self.duration_s = stop, end

    def segments(self) -> Segments | None:
        return concat(*(s for s, _ in self.windows)) if self.windows else None

    def plan(self) -> Plan | None:
        return Plan.join([p for _, p in self.windows]) if self.windows else None

    def motion(self, steps_per_mm: np.ndarray):
        """plots.motor_motion's series over the whole job."""
        fine = np.concatenate(self.chunks + [self.last[:, None]], axis=1)  # and the final positions at the end
        fine_edges = np.append(FINE_S * np.arange(fine.shape[1] - 1), self.duration_s)
        return motion_from_grid(fine_edges, fine, self.duration_s, steps_per_mm)

"""What `verify --report` draws, gathered a chapter at a time as the run is compared (codegen/verify/bounded.py), in a
size that does not grow with the run: the planned path on a time grid fixed by the plan's length, the simulated
tool's positions at every `stride`-th pulse (the stride doubles whenever the samples would pass MAX_POINTS), each
motor's position on a time grid that coarsens the same way, and per motor a histogram of its pulses' timing against
the twin in whole units of 1 / lcm(F_CPU, tick_hz) s (a cycle on the ATmega2560: exact; coarsened only if a run's
errors take more than MAX_DISTINCT values).
codegen/report/plots.py draws them; a run kept whole is gathered the same way, as one chapter (whole_run_samples).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from codegen.sim.avr_edges import Steps
from codegen.tables.laser import planned_speed
from codegen.verify.chapters import Chapter, RuntimeTimeline, whole_chapter
from codegen.verify.heaters import host_timeline, on_twin_clock

MAX_POINTS = 20_000  # per curve
GRID_S = 0.005  # the motors' positions are kept on this grid at first: finer than any plot's
MAX_DISTINCT = 4096  # timing errors kept per motor as (value, count) pairs, at most


@dataclass
class PathSamples:
    """A tool path as a polyline: (N, 3) mm, and per piece between neighbouring points its colour value (speed in
    mm/s, or laser power in % of full scale) and whether it works: the tool on, or a printer's extruder pushing
    (else a travel move)."""

    axes: np.ndarray
    value: np.ndarray  # (N - 1,)
    working: np.ndarray  # (N - 1,) bool


def _segment_at(plan, t: np.ndarray) -> np.ndarray:
    return np.clip(np.searchsorted(plan.t_start, t, side="right") - 1, 0, len(plan.t_start) - 1)


def _planned_power(segments, k: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """The ideal laser power (0..1) on segments `k` at `speed`: S over s_max, M4's times speed over feed
    (codegen/tables/laser.py event_power)."""
    feed = segments.feed[k]
    ratio = np.divide(speed, feed, out=np.ones_like(speed), where=np.isfinite(feed) & (feed > 0))
    return segments.power[k] * np.where(segments.dynamic[k], np.minimum(ratio, 1.0), 1.0)


def _planned_points(plan, segments, t: np.ndarray) -> np.ndarray:
    """Where the plan's trapezoids put the tool at times `t` (N, 3)."""
    k = _segment_at(plan, t)
    tau, accel, peak = t - plan.t_start[k], plan.accel[k], plan.v_peak[k]
    t_dec = np.maximum(plan.duration[k] - plan.t_acc[k] - plan.t_cruise[k] - segments.dwell[k], 0.0)
    ta = np.minimum(tau, plan.t_acc[k])
    tc = np.clip(tau - plan.t_acc[k], 0.0, plan.t_cruise[k])
    td = np.clip(tau - plan.t_acc[k] - plan.t_cruise[k], 0.0, t_dec)
    s = plan.v_entry[k] * ta + 0.5 * accel * ta ** 2 + peak * (tc + td) - 0.5 * accel * td ** 2
    share = np.clip(np.divide(s, plan.length[k], out=np.zeros_like(s), where=plan.length[k] > 0), 0.0, 1.0)
    return segments.start[k, :3] + share[:, None] * (segments.end[k, :3] - segments.start[k, :3])


def _planned_pieces(plan, segments, middle: np.ndarray, power: bool) -> tuple[np.ndarray, np.ndarray]:
    """The colour value and the working flag of the pieces whose middles are at `middle`."""
    k = _segment_at(plan, middle)
    speed = planned_speed(plan, k, middle)
    value = 100 * _planned_power(segments, k, speed) if power else speed
    extruding = segments.end[k, 3] > segments.start[k, 3]
    return value, (segments.tool[k] | extruding) & (segments.dwell[k] <= 0)


class PlannedPath:
    """The job's path as planned, its parts (plan and segments, in order) added as they come: the trapezoids sampled
    on a time grid over the whole plan (`total_s`) and at a share of the `segments` segments' starts, each piece
    coloured by the planned speed or the ideal laser power at its middle."""

    def __init__(self, total_s: float, segments: int, power: bool):
        self.grid = np.linspace(0.0, total_s, MAX_POINTS // 2)
        self.every = np.linspace(0, segments - 1, min(segments, MAX_POINTS // 2)).astype(np.int64)
        self.power = power
        self.taken = self.seen = 0  # grid points and segments so far
        self.parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.last_t: float | None = None  # the last point so far, on `previous`'s plan
        self.previous = None

    def add(self, plan, segments, last: bool) -> None:
        if not len(segments):
            return
        starts = self.every[(self.every >= self.seen) & (self.every < self.seen + len(segments))] - self.seen
        stop = len(self.grid) if last else int(np.searchsorted(self.grid, plan.total, side="left"))
        t = np.union1d(self.grid[self.taken:stop], plan.t_start[starts])
        self.taken, self.seen = max(self.taken, stop), self.seen + len(segments)
        if len(t):
            middle = 0.5 * (t[1:] + t[:-1])
            value, working = _planned_pieces(plan, segments, middle, self.power)
            if self.last_t is not None:  # the piece from the part before: on the plan its middle is in
                joint = np.array([0.5 * (self.last_t + t[0])])
                part = (plan, segments) if joint[0] >= plan.t_start[0] else self.previous
                value, working = (np.concatenate([a, b]) for a, b in zip(_planned_pieces(*part, joint, self.power),
                                                                          (value, working)))
            self.parts.append((_planned_points(plan, segments, t), value, working))
            self.last_t = float(t[-1])
        self.previous = (plan, segments)

    def result(self) -> PathSamples:
        if not self.parts:
            return PathSamples(np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=bool))
        return PathSamples(*(np.concatenate([p[k] for p in self.parts]) for k in range(3)))


class RunSamples:
    """`add` each chapter's simulated pulses (in time order) with the twin's they pair with, then `extra` the pulses
    after the twin's last; `timeline`: the runtime records on the twin's clock, once known (the heaters' targets)."""

    def __init__(self, host, f_cpu: int):
        motors = len(host.kin.motors)
        self.names, self.f_cpu = host.kin.motors, f_cpu
        common = math.gcd(f_cpu, host.target.tick_hz)  # an error is (cycles x per_cycle - ticks x per_tick) units
        self.per_cycle, self.per_tick = host.target.tick_hz // common, f_cpu // common
        self.planned = PlannedPath(host.totals.duration_s, host.totals.segments, host.laser is not None)
        self.start: int | None = None  # the cycle of time 0: the player's tick 0
        self.count, self.stride = 0, 1  # run pulses so far; one of every `stride` is sampled
        self.cycle = np.zeros(0, dtype=np.int64)  # (K,) the sampled pulses' cycles ...
        self.steps = np.zeros((0, motors), dtype=np.int64)  # (K, M) ... and every motor's net steps after each
        self.net = np.zeros(motors, dtype=np.int64)  # after the last pulse so far
        self.last_cycle = 0
        self.grid_s = GRID_S
        self.grid = np.zeros((motors, 0))  # (M, G) net steps at grid_s x 0, 1, ...
        self.last_s = np.zeros(motors)  # each motor's last pulse so far (s)
        self.duration_s = 0.0  # the last run pulse's time
        self.quantum = 1  # units per timing histogram bin
        self.errors: list[tuple[np.ndarray, np.ndarray] | None] = [(np.zeros(0, np.int64),) * 2] * motors
        self.timeline: RuntimeTimeline | None = None

    def add(self, chapter: Chapter | None, sim: Steps, clock: np.ndarray, start: int | None) -> None:
        """`clock`: the pulses' cycles on the twin's clock; `start`: the player's tick 0 (cycle), if known."""
        if chapter is not None:
            self.planned.add(chapter.plan, chapter.segments, chapter.last)
        if not len(sim.cycle):
            return
        self.start = self.start if self.start is not None else (start if start is not None else int(sim.cycle[0]))
        seconds = (sim.cycle - self.start) / self.f_cpu
        index = self.count + np.arange(len(sim.cycle))
        pick = np.flatnonzero(index % self.stride == 0)
        stop = int(np.floor(seconds[-1] / self.grid_s)) + 1
        edges = self.grid_s * np.arange(self.grid.shape[1], stop)
        picked = np.empty((len(pick), len(self.net)), dtype=np.int64)
        grid = np.empty((len(self.net), len(edges)))
        for m in range(len(self.net)):
            mine = np.flatnonzero(sim.motor == m)
            net = self.net[m] + np.concatenate([[0], np.cumsum(sim.dir[mine], dtype=np.int64)])
            picked[:, m] = net[np.searchsorted(mine, pick, side="right")]
            grid[m] = np.interp(edges, np.concatenate([[self.last_s[m]], seconds[mine]]), net)  # flat between
            self.net[m], self.last_s[m] = net[-1], seconds[mine[-1]] if len(mine) else self.last_s[m]
            if chapter is not None:
                self._timing(m, clock[mine], chapter.pulses.tick[chapter.pulses.motor == m])
            elif len(mine):
                self.errors[m] = None  # pulses the twin did not predict: this motor's cannot be paired
        self.cycle, self.steps = np.concatenate([self.cycle, sim.cycle[pick]]), np.concatenate([self.steps, picked])
        self.grid = np.concatenate([self.grid, grid], axis=1)
        self.count += len(sim.cycle)
        self.last_cycle, self.duration_s = int(sim.cycle[-1]), float(seconds[-1])
        while len(self.cycle) > MAX_POINTS:  # keep the samples at even multiples of the stride
            self.cycle, self.steps, self.stride = self.cycle[::2], self.steps[::2], 2 * self.stride
        while self.grid.shape[1] > 2 * MAX_POINTS:
            self.grid, self.grid_s = self.grid[:, ::2], 2 * self.grid_s

    def extra(self, sim: Steps) -> None:
        self.add(None, sim, sim.cycle, None)

    def _timing(self, m: int, clock: np.ndarray, tick: np.ndarray) -> None:
        """Motor m's pulses against the twin's in order, into its histogram; none once a chapter's counts differ."""
        if self.errors[m] is None or len(clock) != len(tick):
            self.errors[m] = None
            return
        values, counts = self.errors[m]
        error = ((clock - self.start) * self.per_cycle - tick * self.per_tick) // self.quantum * self.quantum
        self.errors[m] = _merged(np.concatenate([values, error]), np.concatenate([counts, np.ones_like(error)]))
        while len(self.errors[m][0]) > MAX_DISTINCT:
            self.quantum *= 2
            self.errors = [None if e is None else _merged(e[0] // self.quantum * self.quantum, e[1])
                           for e in self.errors]

    def simulated(self) -> tuple[np.ndarray, np.ndarray]:
        """The sampled pulses' cycles and net steps (K, M), the run's last pulse the last of them."""
        if self.count and (self.count - 1) % self.stride:
            return np.append(self.cycle, self.last_cycle), np.concatenate([self.steps, self.net[None]])
        return self.cycle, self.steps

    def positions(self) -> tuple[np.ndarray, np.ndarray]:
        """Each motor's net steps (M, G + 1) on the time grid and at the run's end, and the grid's times (s)."""
        return (np.append(self.grid_s * np.arange(self.grid.shape[1]), self.duration_s),
                np.concatenate([self.grid, self.net[:, None]], axis=1))

    def timing_us(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Per motor whose pulses all paired with the twin's: its timing errors (us) and how many pulses had each."""
        return {name: (e[0] * 1e6 / (self.f_cpu * self.per_cycle), e[1]) for name, e in zip(self.names, self.errors)
                if e is not None and len(e[0])}


def _merged(values: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    distinct, at = np.unique(values, return_inverse=True)
    return distinct, np.bincount(at, weights=counts, minlength=len(distinct)).astype(np.int64)


def whole_run_samples(host, trace) -> RunSamples:
    """RunSamples of a run kept whole (a kept host build's twin; `trace`: the run, on the simulated clock, with the
    heaters' holds in it), as one chapter."""
    samples = RunSamples(host, trace.f_cpu)
    run = trace.run_only()
    order = np.argsort(run.step_cycle, kind="stable")
    sim = Steps(run.step_cycle[order], run.step_motor[order], run.step_dir[order])
    samples.timeline = timeline = host_timeline(host)
    clock = on_twin_clock(run, timeline.tick[timeline.waits()], trace.f_cpu // host.target.tick_hz).step_cycle
    samples.add(whole_chapter(host), sim, clock, run.timer_start_cycle)
    return samples

"""The stages after the planner, one lookahead window at a time: step times, curve timing, rate runs, the twin
and its checks.

A window hands the next one what the player carries across: its clock (the last event's time, to 1/256
tick: the next window's runs count from there) and the motors' positions; and what the checks need of the
pulses before (codegen/tables/motor_checks.py). Windows end at corners, so curve timing never joins two windows'
blocks; rate runs start afresh at every window (one run more per window than a run over the whole program
might need). The path check measures a window's first and last steps against the neighbouring windows'
segments too.

With input shaping or pressure advance a window is played as the blocks of its shaped motion (its extruder
advanced: codegen/pipeline/shaping.py), and the plan before shaping is what a retry slows. Each era of the
program's shapers (between M593s: windows end there, codegen/motion/lookahead.py) has its own, the job's pressure
advance in each; an era's last window plays its shaped motion to rest (the plan rests there long enough), and the
next era's first starts afresh.

Where the twin's pulses break a motor's limit (a coarse motor's 8 steps across the Bresenham phases of
several blocks, a delta carriage between cut points), the window is planned again with the segments under
that stretch slowed (codegen/pipeline/slowing.py; its entry speed stays: the window before is final), and the
next window starts no faster than it now ends.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, replace
from typing import BinaryIO, Callable

import numpy as np

from codegen.errors import BuildError
from codegen.kinematics.base import Kinematics
from codegen.link.ring import LinkBudget, Ring
from codegen.motion.advance import AdvanceReference
from codegen.motion.blocks import Events
from codegen.motion.lookahead import Lookahead, Window, merge
from codegen.motion.planner import PlannerLimits, finish, jitter_rate, passes, profile
from codegen.motion.shaped_motion import ShapingSettings
from codegen.motion.stepgen import generate
from codegen.pipeline.shaping import ShapingTail, shaped_window
from codegen.pipeline.slowing import link_slow_down, reaches_back, slow_down
from codegen.stopwatch import Stopwatch
from codegen.tables.checks import Checker, MotorTrain, corners_after
from codegen.tables.compress import Compressed, compress
from codegen.tables.format import encode, end_marker, record_events, stream_bytes
from codegen.tables.headroom import with_ceilings
from codegen.tables.hold import HoldPlan
from codegen.tables.laser import LaserPwm, event_counts, power_error_of, with_power
from codegen.tables.runtime import RuntimeRecords, block_extra_ticks, runtime_cycles, window_runtime
from codegen.tables.schedule import Schedule
from codegen.tables.twin import Pulses, predict
from codegen.targets import TargetInfo
from codegen.toolpath.segments import Segments, concat

RATE_ROUNDS = 8  # plans of a window at most: a stretch over a motor's rate or acceleration slows it
LINK_ROUNDS = 16  # and where the ring runs short: slowing one stretch may move a shortfall on to the next


@dataclass
class Played:
    """One window's results, on the program's clock: event times in s, ticks and positions absolute."""

    window: Window
    compressed: Compressed  # ideal and emitted ticks on the program's clock
    origin_fx: int  # 1/256 tick: the player's clock when the window begins
    events_count: int
    timing_error_ticks: float  # the largest distance of an emitted event from its planned time
    events: Events | None  # these two only when the stages keep them
    pulses: Pulses | None  # ticks absolute, event_position counted from the program's start
    prior_item: int = -1  # the item of the last block before the window (its runtime records come after it)
    power_error: float = 0.0  # a laser's: the largest distance of an event's power from the ideal (of full scale)
    ceiling_bytes: int = 0  # what the feed override's ceiling records add to the tables (their runs' splits too)
    table_schedule: Schedule | None = None  # as the table stream carries it (runtime records in place): for `observe`
    planned: Window | None = None  # a shaped window's plan before shaping (`window` holds its blocks); None: unshaped
    advance: AdvanceReference | None = None  # an advanced extruder's formula over the window (motion/advance.py)


@dataclass
class Totals:
    """What `plan` reports of the whole program, summed over its windows."""

    duration_s: float = 0.0
    windows: int = 0
    segments: int = 0
    blocks: int = 0
    runs: int = 0
    events: int = 0
    table_bytes: int = 0  # the end marker included
    max_timing_error_ticks: float = 0.0  # the largest distance of an emitted event from its planned time
    link_slowdown_s: float = 0.0  # time the link's bandwidth added to the plan (streaming)
    max_power_error: float = 0.0  # a laser's: the largest distance of an event's power from the ideal
    power_records: int = 0
    ceiling_records: int = 0  # the feed override's headroom (codegen/tables/headroom.py)
    ceiling_bytes: int = 0  # theirs and their runs' splits
    advance_slowed: int = 0  # plans of windows slowed where the advanced extruder broke its limits
    advance_slowed_line: int = 0  # the G-code line of the first such place (0: none, or not G-code)
    # era -> s (shaped clock): its advanced extruder smoothed from there on (-inf: from its start; inf: nowhere)
    smoothed_from: dict = field(default_factory=dict)

    def add(self, played: Played) -> None:
        sched = played.compressed.schedule
        end = len(end_marker(False))  # counted once for the whole program
        self.duration_s = played.window.plan.total if len(played.window.plan.duration) else self.duration_s
        self.windows += 1
        self.segments += len(played.window.segments)
        self.blocks += sched.n_blocks
        self.runs += sched.n_runs
        self.events += played.events_count
        self.table_bytes += stream_bytes(sched) - (end if self.table_bytes else 0)
        self.max_timing_error_ticks = max(self.max_timing_error_ticks, played.timing_error_ticks)
        self.max_power_error = max(self.max_power_error, played.power_error)
        self.power_records += sched.n_power
        self.ceiling_records += sched.n_ceiling
        self.ceiling_bytes += played.ceiling_bytes
        if played.advance is not None and len(played.window.segments):
            era, smooth = int(played.window.segments.shaping[0]), played.advance.half > 0
            if era not in self.smoothed_from:  # its first window
                self.smoothed_from[era] = -np.inf if smooth else np.inf
            elif smooth and self.smoothed_from[era] == np.inf:
                self.smoothed_from[era] = played.advance.begin


@dataclass(frozen=True)
class StageSettings:
    """What the stages after the planner need of the machine: the checks' tolerance, the player's pulse timing."""

    tolerance_mm: float  # machine.tolerance: how far from the path the checks let a step put the tool
    step_pulse_us: float  # STEP high time
    dir_setup_us: float  # DIR before STEP
    shaping: ShapingSettings | None = None  # the machine's input shapers (codegen/pipeline/shaping.py); None: unshaped


@dataclass
class _Carried:
    """What a window hands the next: the checks' state, the player's clock and positions, its last segment."""

    checker: Checker
    origin_fx: int  # 1/256 tick: the last event's time
    position: np.ndarray  # (M,) steps after the last event, from the program's start
    before: Segments | None  # the last segment
    ring: Ring | None = None  # the streaming player's ring fill (codegen/link/ring.py)
    block_item: int = -1  # the item of the last block's segment (runtime records after it come before the next)
    laser_counts: int = 0  # the laser's PWM counts after the last event
    shaping_tail: ShapingTail | None = None  # a shaped window's plan tail and end point (codegen/pipeline/shaping.py)


class Stages:
    """`play` each window of the lookahead in order; each call hands out the windows that are final (a window
    stays open until the next one has passed its checks: a stretch over a limit that begins in it slows both)."""

    def __init__(self, settings: StageSettings, kin: Kinematics, target: TargetInfo, limits: PlannerLimits,
                 start_steps: np.ndarray, lookahead: Lookahead, keep: bool, watch: Stopwatch | None = None,
                 tables: BinaryIO | None = None, link: LinkBudget | None = None,
                 runtime: Callable[[], RuntimeRecords] | None = None, laser: LaserPwm | None = None,
                 hold: HoldPlan | None = None, observe: Callable[[Played], None] | None = None,
                 eras: Callable[[int], ShapingSettings | None] | None = None):
        """`settings`: the machine's tolerance and pulse timing; `keep`: the windows handed out keep their events
        and pulses (for `join`); `watch` times the stages; `tables` gets each final window's table records as it
        is made (a window ends at a block and a run start, so they join into the whole program's stream;
        `finish` adds the end marker); `link`: the stream's link, whose ring must never run dry (a stretch that
        needs more bytes than it carries slows); `runtime`: the program's runtime records so far
        (codegen/tables/runtime.py), whose cost the blocks after them get; `laser`: the laser's PWM, whose power
        records the runs get (codegen/tables/laser.py); `hold`: the feed hold, whose ceiling records they get where
        its override goes above 100 % (codegen/tables/headroom.py); `observe` gets each final window with its
        pulses (which it drops after unless `keep`); `eras` gives the shapers of each era of the program's
        (a segment's `shaping`; None: the machine's throughout)."""
        self.kin, self.target, self.limits, self.lookahead = kin, target, limits, lookahead
        self.max_rate = jitter_rate(kin.limits.max_rate, limits.pulse_jitter_s)  # what the pulses may use
        self.keep, self.watch, self.tables = keep, watch or Stopwatch(), tables
        self.shaping_of = eras or (lambda era: settings.shaping)
        max_smoothing = None if settings.shaping is None else settings.shaping.max_smoothing
        self.carried = _Carried(Checker(kin, start_steps, settings.tolerance_mm, max_smoothing), 0,
                                np.zeros(len(kin.motors), dtype=np.int64), None, None if link is None else Ring(link))
        self.open: tuple[Played, _Carried] | None = None  # the last window played, and what came before it
        self.totals = Totals()
        self.runtime, self.laser, self.hold, self.observe = runtime, laser, hold, observe
        motors, pulse_us = len(kin.motors), settings.step_pulse_us
        self.gaps = (target.run_gap_ticks(motors, pulse_us),
                     target.block_gap_ticks(pulse_us, settings.dir_setup_us))

    @property
    def checker(self) -> Checker:
        return self.carried.checker

    def play(self, window: Window, after: Segments | None, last: bool) -> list[Played]:
        """Window `window`, followed by segment `after` (None at the program's end; `last` then)."""
        before = self.carried
        out = []
        played, carried, scale = self._attempt(window, after, last, before)
        w_exit, rounds = None, 0
        while scale is not None:
            # Play the open window and this one again where a stretch reaches back into it (not across the rest
            # between two eras of the shapers): a slowed window keeps its entry speed, which the one before set.
            if (scale[3] and self.open is not None
                    and self.open[0].window.segments.shaping[-1] == window.segments.shaping[0]):
                open_window = self.open[0].window if self.open[0].planned is None else self.open[0].planned
                window, before = merge(open_window, window), self.open[1]
                self.open = None
                played, carried, scale = self._attempt(window, after, last, before)
                continue
            if rounds >= (RATE_ROUNDS if scale[2] is None else LINK_ROUNDS) - 1:
                break
            rounds += 1
            was = window.plan.total
            # A stretch still over after a few rounds is slowed harder (each round's share squared, cubed ...):
            # where the shaper mixes the plan's times, slowing by the overshoot alone can leave it a few % over.
            harder = 1 + rounds // 3
            window, w_exit = self._plan_again(window, scale[0] ** harder, scale[1] ** harder)
            if scale[2] is not None:
                self.totals.link_slowdown_s += window.plan.total - was
            played, carried, scale = self._attempt(window, after, last, before)
        if scale is not None and scale[2] is not None:
            budget, short = carried.ring.budget, scale[2]
            raise BuildError(f"the link at {budget.baud} baud cannot keep the streaming player's ring of "
                             f"{budget.ring_bytes} bytes (the host keeps {budget.kept} of them filled, "
                             f"{budget.usable} after the refill's lag) fed between {short.begin_s:.3f} and "
                             f"{short.end_s:.3f} s into the job, even slowed {rounds} times: a board with a larger "
                             f"ring (XRAM), a faster link (machine.link.baud), or a larger machine.tolerance")
        if w_exit is not None:
            self.lookahead.resume(w_exit, window.plan.total)
            self.lookahead.slow_straight_on(float(window.segments.feed[-1]))
        if self.open is not None:
            out.append(self.open[0])
        self.open, self.carried = (played, before), carried
        if last:
            out.append(played)
            self.open = None
        for p in out:
            self.totals.add(p)
            if self.observe is None and self.tables is None:
                continue
            p.table_schedule = self._with_runtime(p, last and p is out[-1])
            if self.observe is not None:
                self.observe(p)
                p.pulses = p.pulses if self.keep else None
                p.events = p.events if self.keep else None
            if self.tables is not None:
                self.tables.write(encode(p.table_schedule).data[:-len(end_marker(False))])
            p.table_schedule = None
        return out

    def _with_runtime(self, played: Played, last: bool):
        """A final window's schedule with its runtime records, for the table stream."""
        schedule = played.compressed.schedule
        if self.runtime is None:
            return schedule
        return window_runtime(schedule, self.runtime(), played.window.segments.item, played.prior_item, last)

    def finish(self) -> None:
        if self.tables is not None:
            self.tables.write(end_marker(False))

    def _attempt(self, window: Window, after: Segments | None, last: bool, before: _Carried):
        """Play the window from what came before: its results, what it hands on, and how to slow it down where
        the checks found a motor over its limits or the ring runs short: each segment's share of its speed and
        of its acceleration, the ring's first Shortfall (None for a motor's limits), and whether the window before
        is to be played again with it (a shortfall: always); None: nowhere."""
        kin, target, watch = self.kin, self.target, self.watch
        planned, shaped = window, None
        era = int(window.segments.shaping[0]) if len(window.segments) else 0
        shaping = self.shaping_of(era)
        # An era's last window: its shaped motion settles in the rest it ends with, and the next era starts afresh.
        era_ends = after is not None and int(after.shaping[0]) != era
        if shaping is not None and len(window.plan.duration):  # from here on the window is its shaped blocks
            with watch("input shaping"):
                shaped = shaped_window(window, kin, shaping, target.max_gap_s, before.shaping_tail, last, era_ends)
            window = shaped.window
        with watch("step times"):
            events = shaped.events if shaped is not None else generate(
                window.segments, window.plan, kin, window.steps, max_gap=target.max_gap_s, curves=True,
                max_rate=self.max_rate)
        block_item = window.segments.item[events.block_segment]
        extra = None if self.runtime is None else block_extra_ticks(
            self.runtime(), block_item, before.block_item, runtime_cycles(target), target.tick_hz, target.f_cpu)
        with watch("rate runs"):
            prior = [np.round(rate.tail * target.tick_hz) for rate in before.checker.rates]  # the last steps played
            compressed = compress(events, kin.motors, target.tick_hz, *self.gaps, max_rate=self.max_rate,
                                  origin_fx=before.origin_fx, block_extra_ticks=extra, prior_ticks=prior)
        laser_counts, power_error = before.laser_counts, 0.0
        if self.laser is not None and len(events.time):
            with watch("laser power"):
                counts, ideal = event_counts(events, window.plan, window.segments, self.laser)
                compressed.schedule = with_power(compressed.schedule, counts, before.laser_counts)
                power_error = power_error_of(counts, ideal, self.laser.top)
                laser_counts = int(counts[-1])
        with watch("twin"):
            pulses = predict(compressed.schedule, before.origin_fx, before.position)
        ceiling_bytes = 0
        if self.hold is not None and len(events.time):
            with watch("feed ceilings"):  # they change no pulse
                was = stream_bytes(compressed.schedule)
                compressed.schedule = with_ceilings(compressed.schedule, self.hold, pulses, before.position,
                                                    self.max_rate, kin.limits.max_accel * kin.limits.steps_per_mm)
                ceiling_bytes = stream_bytes(compressed.schedule) - was
        error = float(np.max(np.abs(pulses.event_tick - events.time * target.tick_hz), initial=0.0))
        played = Played(window, compressed, before.origin_fx, len(events.time), error,
                        events if self.keep or self.observe else None, pulses if self.keep or self.observe else None,
                        before.block_item, power_error, ceiling_bytes, planned=None if shaped is None else planned,
                        advance=None if shaped is None else shaped.advance)
        # The checks see the neighbouring windows' segments around this one's (a shaped window's next are not yet).
        parts = [p for p in (before.before, window.segments, after if shaped is None else None) if p is not None]
        around = concat(*parts)
        shift = 0 if before.before is None else 1
        event_segment = np.repeat(events.block_segment, np.diff(events.block_first)) + shift
        trains = [MotorTrain(tick / target.tick_hz, direction)
                  for tick, direction in map(pulses.of_motor, range(len(kin.motors)))]
        with watch("checks"):
            if shaped is None:
                corners_t, jumps = corners_after(window.plan, window.segments, before.before, self.kin)
            else:
                corners_t, jumps = shaped.corners_t, shaped.jumps
            checker = copy.deepcopy(before.checker)
            if shaped is not None and shaping.shaped:
                checker.add_smoothing(shaped.smoothing_mm, shaped.smoothing_at, shaped.smoothing_line)
            if shaped is not None and shaped.advance is not None:
                checker.add_advance(*self._advance_worst(shaped, pulses, before.position))
            checker.add_tool(compressed.schedule.block_tool, window.segments.tool[events.block_segment])
            hits = checker.add(trains, pulses.event_position, event_segment, around, corners_t, jumps, last)
            if shaped is not None and shaped.tail.smooth:  # a nominal extruder's limits are the plan's
                self._note_extruder_limits(hits, pulses, planned, shaping.shift)
        n = len(window.segments)
        position = pulses.event_position[-1] if len(pulses.event_position) else before.position
        ring = None if before.ring is None else before.ring.copy()
        carried = _Carried(checker, _end_fx(played), position,
                           window.segments.take(np.arange(n - 1, n)) if n else before.before, ring,
                           int(block_item[-1]) if len(block_item) else before.block_item, laser_counts,
                           None if shaped is None or era_ends else shaped.tail)
        # Limits are kept by slowing the plan's segments: a shaped piece's are the one under it.
        planned_segment = event_segment - shift if shaped is None else shaped.origin[event_segment - shift]
        reach = None if shaped is None else shaping.spread
        scale = slow_down(planned.plan, planned_segment, pulses, hits, target.tick_hz, reach)
        if ring is not None:
            with watch("link"):
                reads, sizes, record_event = _record_reads(compressed.schedule, pulses, before.origin_fx,
                                                           target.tick_hz)
                shortfalls = ring.add(reads, sizes)
            if scale is None and shortfalls:
                record_segment = planned_segment[np.minimum(record_event, len(event_segment) - 1)]
                return played, carried, (*link_slow_down(planned.plan, shortfalls, record_segment, sizes,
                                                               ring.budget.rate), shortfalls[0], True)
        back = scale is not None and reaches_back(hits, planned.plan.t_start[0], pulses, target.tick_hz, reach)
        return played, carried, None if scale is None else (*scale, None, back)

    def _note_extruder_limits(self, hits: list, pulses: Pulses, planned: Window, shift: float) -> None:
        """Where the advanced extruder breaks its rate or acceleration (the window is then planned again, slower):
        counted, and the first place's G-code line kept for a note; `shift`: s the era's shaped clock runs behind
        the plan's."""
        e = self.kin.motors.index("e")
        (rate_end, _), (accel_begin, _) = hits[e]
        if not len(rate_end) and not len(accel_begin):
            return
        tick, _ = pulses.of_motor(e)
        times = np.concatenate([tick[rate_end] / self.target.tick_hz, accel_begin]) - shift
        segment = np.clip(np.searchsorted(planned.plan.t_start, times.min(), side="right") - 1, 0,
                          len(planned.segments) - 1)
        self.totals.advance_slowed += 1
        if not self.totals.advance_slowed_line:
            self.totals.advance_slowed_line = int(planned.segments.line[segment])

    def _advance_worst(self, shaped, pulses: Pulses, position: np.ndarray) -> tuple[float, float, int]:
        """The advanced extruder's pulses against the pressure advance formula (`AdvanceReference.worst`), each at
        its event's planned time: a slow block load makes a pulse late, which the timing check allows for."""
        e = self.kin.motors.index("e")
        tick, direction = pulses.of_motor(e)
        event = np.searchsorted(pulses.event_tick, tick)  # a pulse's event: events come at distinct ticks
        after = self.checker.start_steps[e] + position[e] + np.cumsum(direction)
        return shaped.advance.worst(shaped.events.time[event], direction, after, self.kin.limits.steps_per_mm[e])

    def _plan_again(self, window: Window, speed: np.ndarray, accel: np.ndarray) -> tuple[Window, float]:
        """The window with its segments slowed: the same entry speed, an exit no faster than before (v^2)."""
        plan, segments = window.plan, window.segments
        entry = plan.v_entry[0]
        cap = np.maximum(plan.v_peak * speed, np.where(np.arange(len(speed)) == 0, entry, 0.0))
        slowed = replace(segments, feed=np.minimum(segments.feed, cap),
                         accel=np.minimum(segments.accel, plan.accel * accel))
        prof = profile(slowed, self.kin, window.steps, self.limits)
        w_last = min(plan.v_exit[-1] ** 2, prof.w_nominal[-1])
        w = passes(prof, entry ** 2, w_last)
        again = finish(prof, w, plan.t_start[0])
        again.corner[0], again.corner[-1] = plan.corner[0], plan.corner[-1]
        return replace(window, segments=slowed, plan=again), float(w[-1])


def _record_reads(schedule, pulses: Pulses, origin_fx: int, tick_hz: int):
    """When the player reads each record of a window (s, on the program's clock): at the event before the one
    it starts (the window's first records at the last event before it); the records' bytes and events."""
    event, size = record_events(schedule)
    before = np.concatenate([[origin_fx >> 8], pulses.event_tick])
    return before[event] / tick_hz, size, event


def _end_fx(played: Played) -> int:
    """1/256 tick: when the window's last event happens, as the player counts."""
    sched = played.compressed.schedule
    n, interval, add = sched.run_count, sched.run_interval, sched.run_add
    return played.origin_fx + int(np.sum(interval * n + add * (n * (n - 1) // 2)))

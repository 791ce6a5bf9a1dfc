"""Feed hold, resume and feed override by time dilation, the host's half: the constants the AVR player uses and
the model of its integer arithmetic (the twin of a held or overridden run).

The player plays the tables on a dilated clock. F (0..F_MAX) is the feed factor in 1/128 (F_ONE: 100 %): every
event's tick delta becomes (delta x D[F]) >> 8 with D[F] = 32768 / F (8.8 fixed point; F_ONE gives delta itself),
at most CLAMP (a long wait's first tick; long waits themselves are not dilated). So the path is unchanged and every
motor's velocity scales with F / F_ONE (its acceleration with the square, plus the factor's own change).

Above 100 % the factor goes only as far as the ceiling records let it (codegen/tables/headroom.py): the target it ramps
towards is the lower of the override and the ceiling in force, which the host sets from every motor's headroom on
the stretch being played and lowers early enough for the ramp to come back down before the headroom ends.

F ramps towards a target (0 for a hold, the override for resume) on the real clock: after each dilated delta of
t ticks, F.frac16 moves by t x K. K keeps every motor's extra acceleration v x dF/dt within RAMP_SHARE of its
limit at its highest velocity. Where the plan itself accelerates at the limit, the two must not add up: above
F_FREE (f^2 + RAMP_SHARE <= 1) the factor falls only while the pending event's rate run does not brake (its add
<= 0) and rises only while it does not accelerate (add >= 0); at or below F_FREE it moves freely. On curves the
planner leaves a share of 1 - centripetal_share (RAMP_SHARE) of every motor's acceleration for this. A delta's
motors speed up and slow down along a straight line (its blocks' ratios change), which the master's add cannot
tell (a gated ramp let random deltas break the limits by 9 to 12 %): a delta's plan keeps RAMP_SHARE of every
motor's acceleration instead (planner_limits' accel_share), and its factor moves freely (no gate).

At F 0 the player parks before the pending event (its timer's interrupt off); resume re-arms it RESUME_TICKS
after main reads the timer, at F 1, and the ramp goes on up. An M0/M1 pause (a runtime record RT_PAUSE) sets F 0
where the plan rests; its resume goes on at F_ONE. Once F and the target are both F_ONE the player leaves the
dilated path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from codegen.errors import BuildError
from codegen.kinematics.base import StepperLimits
from codegen.tables.schedule import FRAC_BITS, RT_PAUSE, Schedule

F_ONE = 128  # the feed factor 1 (100 %)
F_MAX = 255  # the highest factor (199 %): the override's 200 % step
RAMP_SHARE = 0.2  # of each motor's acceleration that the factor's change may take (the planner's curves leave it)
F_FREE = int(math.floor(F_ONE * math.sqrt(1.0 - RAMP_SHARE)))  # at or below: f^2 a_max + RAMP_SHARE a_max <= a_max
CLAMP = 0xFEFFFF  # the longest dilated delta, 1/256 tick: just under a long wait (0xFF00 ticks)
LONG = 0xFF00 << FRAC_BITS  # an undilated delta this long goes the long-wait way, undilated
RESUME_TICKS = 0xFEFF  # from main's read of the timer at resume to the pending event: at least its own interval
# (a parked event is never a long wait), so no step comes sooner after the one before than the plan's
PLAYER_MAX_OVERRIDE = {"avr": ("ATmega2560", 200), "mcs51": ("8051", 100)}  # % each player's override goes up to
# (the 8051's has no ceiling records)
FRAC16 = 1 << 16
PARKED = -1  # Dilation.factor after the event the player parked behind
STRETCH = 1 << 16  # events of a steady stretch dilated at once


def dilation_table(f_top: int = F_ONE) -> np.ndarray:
    """D[F] for F = 0..f_top (8.8 fixed point, D[F_ONE] = 256; D[0] is never used: F 0 parks)."""
    f = np.arange(f_top + 1, dtype=np.int64)
    return np.where(f > 0, (F_ONE * 256 + f // 2) // np.maximum(f, 1), 0)


def override_target(step: int) -> int:
    """The target F of the override keys' step 1..20 (10 % each): step x 12.8, rounded (the player's
    (step x 205 + 8) >> 4), at most F_MAX."""
    return min((step * 205 + 8) >> 4, F_MAX)


@dataclass(frozen=True)
class HoldPlan:
    """What the firmware's feed hold needs: the ramp's K (F.frac16 per tick) and the board's keys."""

    ramp_k: int  # F.frac16 per dilated tick
    gate_above: int  # above this F the ramp waits for the plan's add (F_FREE); F_MAX: never (a delta's)
    keys: dict  # function (hold, resume, feed+, feed-) -> board pin name (PL2) or (row, column) of a key matrix
    table: tuple[int, ...]  # dilation_table() up to the highest target
    max_step: int = 10  # the override's highest step (machine.feed_hold.max_override / 10)

    @property
    def gated(self) -> bool:
        return self.gate_above < F_MAX

    @property
    def top(self) -> int:
        """The highest factor the override can ask for."""
        return override_target(self.max_step)

    def ramp_per_second(self, tick_hz: int) -> float:
        """F per second while the factor ramps."""
        return self.ramp_k * tick_hz / FRAC16

    def ramp_seconds(self, tick_hz: int) -> float:
        """From F_ONE to 0 at the ramp's rate (where nothing freezes it)."""
        return F_ONE * FRAC16 / self.ramp_k / tick_hz


@dataclass(frozen=True)
class HoldSettings:
    """`machine.feed_hold` and what its ramp needs of the machine."""

    override: int  # % the job starts with
    max_override: int | None  # % the override keys go up to; None: the player's most
    steppers: tuple[StepperLimits, ...]  # every stepper's limits
    ramp_share: bool  # the plan keeps RAMP_SHARE of every motor's acceleration (plans_ramp_share): no gate


def hold_plan(hold: HoldSettings, tick_hz: int, board_name: str, board: dict, streamed: bool = False) -> HoldPlan:
    """`machine.feed_hold` on `board`: the ramp from the machine's limits, the keys from `hold_keys:` (none for the
    8051's streaming firmware, `streamed`: the link's request frames are its only way in)."""
    keys = board.get("hold_keys") or {}
    if not keys and not (streamed and board.get("target") == "mcs51"):
        raise BuildError(f"machine.feed_hold: board {board_name} has no hold_keys (targets/{board_name}.yaml)")
    player, top = PLAYER_MAX_OVERRIDE[board.get("target", "avr")]
    for name, percent in (("max_override", hold.max_override), ("override", hold.override)):
        if percent is not None and percent > top:
            raise BuildError(f"machine.feed_hold.{name}: the {player}'s player goes up to {top} % (has {percent} %)")
    per_second = min(s.max_accel / s.max_velocity for s in hold.steppers)  # of f, for the fastest motor at its limit
    ramp_k = int(RAMP_SHARE * per_second * F_ONE * FRAC16 / tick_hz)
    if not 1 <= ramp_k < FRAC16:
        raise BuildError(f"machine.feed_hold: the feed ramp ({RAMP_SHARE * per_second:.4g} /s) does not fit the "
                         f"player's 16-bit step per tick ({ramp_k})")
    gate_above = F_MAX if hold.ramp_share else F_FREE
    max_step = (hold.max_override or top) // 10
    return HoldPlan(ramp_k, gate_above, {str(k): _key_place(v) for k, v in keys.items()},
                    tuple(int(d) for d in dilation_table(override_target(max_step))), max_step)


def _key_place(value) -> str | tuple[int, ...]:
    """A hold key's place on its board: a pin name (PL2), or (row, column) on the board's key matrix."""
    return tuple(int(v) for v in value) if isinstance(value, (list, tuple)) else str(value)


def plans_ramp_share(feed_hold: bool, kinematics: str, target: str) -> bool:
    """The plan keeps RAMP_SHARE of every motor's acceleration for the ramp: a delta's with feed_hold, and every
    8051 image's (its player's ramp has no gate)."""
    return feed_hold and (kinematics == "delta" or target == "mcs51")


def event_runs(schedule: Schedule) -> np.ndarray:
    """(E,) int32: the rate run every event belongs to (a quarter of an int64 per event: dilate keeps it whole)."""
    return np.repeat(np.arange(len(schedule.run_count), dtype=np.int32), schedule.run_count)


def run_deltas(schedule: Schedule, run: np.ndarray, first: int = 0) -> np.ndarray:
    """The undilated tick delta (1/256 tick) of every event from `first` on, from its run (`run`: event_runs, or a
    stretch of it), built in place."""
    delta = np.arange(first, first + len(run), dtype=np.int64)
    delta -= (np.cumsum(schedule.run_count) - schedule.run_count)[run]  # k: the event's place in its run
    delta *= schedule.run_add[run]
    delta += schedule.run_interval[run]
    return delta


def event_deltas(schedule: Schedule) -> tuple[np.ndarray, np.ndarray]:
    """Every event's undilated tick delta (1/256 tick) and the add of its rate run."""
    run = event_runs(schedule)
    return run_deltas(schedule, run), schedule.run_add[run]


@dataclass
class Dilation:
    """A held, paused or overridden run as the player plays it: every event's tick (-1: never played), the feed
    factor its interrupt leaves (what a laser's M4 power follows until the next event; PARKED where the player
    parked after it, the laser dark), and where it parked: (the pending event, the tick of the event played last,
    whether an M0/M1 pause parked it)."""

    tick: np.ndarray  # (E,) int64
    factor: np.ndarray  # (E,) int16, 0..F_MAX or PARKED
    parks: list[tuple[int, int, bool]]

    def window(self, first: int, end: int) -> Dilation:
        """Events first..end - 1 (as Dilator.window)."""
        return Dilation(self.tick[first:end], self.factor[first:end], self.parks)


def _ramp(ffx: int, target: int, ticks: int, add: int, k: int, gate_above: int) -> int:
    """F.frac16 after a dilated delta of `ticks`, moving towards `target` where the gate lets it."""
    f = ffx >> 16
    if f == target:
        return ffx
    down = f > target
    if f > gate_above and ((add > 0) if down else (add < 0)):
        return ffx  # the plan brakes (a hold) or accelerates (a resume): the factor waits
    step = ticks * k
    goal = target << 16
    return max(ffx - step, goal) if down else min(ffx + step, goal)


def pause_events(schedule: Schedule) -> list[int]:
    """The events an M0/M1 pause parks before: the first of the block its record precedes (none at the end)."""
    first = np.concatenate([[0], np.cumsum(schedule.block_events)])
    blocks = schedule.runtime_block[(schedule.runtime_command == RT_PAUSE) &
                                    (schedule.runtime_block < schedule.n_blocks)]
    return [int(first[b]) for b in blocks]


def run_ceilings(schedule: Schedule) -> np.ndarray:
    """(R,) the factor's ceiling in force over every rate run (F_ONE before the first record)."""
    if not schedule.n_ceiling:
        return np.full(len(schedule.run_count), F_ONE, dtype=np.int64)
    has = schedule.run_ceiling >= 0
    last = np.maximum.accumulate(np.where(has, np.arange(len(has)), -1))
    return np.where(last >= 0, schedule.run_ceiling[np.maximum(last, 0)], F_ONE)


def event_ceilings(schedule: Schedule) -> np.ndarray:
    """(E,) the factor's ceiling in force at every event's interrupt (F_ONE before the first record), from the
    schedule's ceiling records."""
    return run_ceilings(schedule)[event_runs(schedule)]


class Dilator:
    """The player's dilated clock over the events in order, a piece of STRETCH events at a time, in memory that does
    not grow with the run: the events' ticks and factors as `dilate` gives them (Dilation), asked for in order
    (`window`), and the parks as they come. `changes`: (event, target F) in order, each seen first by the interrupt
    that computes that event's delta; after each park the player goes on at the next of `resumes` (the simulator's
    tick of the parked event: main re-armed the timer there) towards `resume_target`, at F 1 after a hold and at
    F_ONE after a pause; without one the rest never plays. A target above F_ONE is capped by the ceiling records. A
    per-event loop only where the factor ramps: elsewhere the deltas are summed (scaled where the factor is steady)."""

    def __init__(self, schedule: Schedule, plan: HoldPlan, changes: list[tuple[int, int]], resumes: list[int] = (),
                 resume_target: int = F_ONE):
        self.schedule, self.plan, self.resume_target = schedule, plan, resume_target
        self.events = int(schedule.run_count.sum())
        self.run_end = np.cumsum(schedule.run_count)
        self.pending, self.pauses, self.resumes = list(changes), pause_events(schedule), list(resumes)
        marks = sorted([e for e, _ in self.pending] + self.pauses)
        self.free_until = marks[0] if marks else self.events  # undilated (and no factor moves) before the first mark
        run_first = self.run_end - schedule.run_count
        self.ceiling_marks = run_first[schedule.run_ceiling >= 0] if schedule.n_ceiling else np.zeros(0, np.int64)
        self.adds, self.ceilings = schedule.run_add.tolist(), run_ceilings(schedule).tolist()
        self.e, self.here = 0, 0  # the next event to play; the tick (24.8) of the one played last
        self.ffx, self.target, self.paused, self.stopped = F_ONE << 16, F_ONE, False, False
        self.parks: list[tuple[int, int, bool]] = []
        self.pieces: list[tuple[int, np.ndarray, np.ndarray]] = []  # (first event, tick, factor) not yet let go

    def window(self, first: int, end: int) -> Dilation:
        """Events first..end - 1 (`first` never below an earlier window's): their ticks and factors, and the parks
        so far. An event's factor is final once the event after it has played."""
        self.play(min(end + 1, self.events))
        self.pieces = [p for p in self.pieces if p[0] + len(p[1]) > first or p is self.pieces[-1]]
        parts = [(max(first - p0, 0), min(end - p0, len(tick)), tick, factor) for p0, tick, factor in self.pieces]
        parts = [(a, b, tick, factor) for a, b, tick, factor in parts if b > a]
        tick = np.concatenate([t[a:b] for a, b, t, _ in parts] or [np.zeros(0, np.int64)])
        factor = np.concatenate([f[a:b] for a, b, _, f in parts] or [np.zeros(0, np.int16)])
        return Dilation(tick, factor, list(self.parks))

    def ticks_at(self, events: np.ndarray) -> np.ndarray:
        """The ticks of `events` (sorted, none before an earlier call's), playing on as far as the last; the pieces
        read are let go (a Dilator asked this is asked for no window)."""
        out = np.empty(len(events), dtype=np.int64)
        i = 0
        while i < len(events):
            while self.e <= events[i]:
                self.pieces = self.pieces[-1:]  # read: let go (the last stays for its last factor)
                self._piece()
            first, tick, _ = next(p for p in self.pieces if events[i] < p[0] + len(p[1]))
            j = int(np.searchsorted(events, first + len(tick)))
            out[i:j] = tick[events[i:j] - first]
            i = j
        self.pieces = self.pieces[-1:]
        return out

    def first_from(self, tick: int) -> int:
        """The first event whose tick is at least `tick`, or that never plays (self.events if none), from where the
        last such question left off."""
        while True:
            for first, ticks, _ in self.pieces:
                hit = np.flatnonzero((ticks >= tick) | (ticks < 0))
                if len(hit):
                    return first + int(hit[0])
            if self.e >= self.events:
                return self.events
            self.pieces = []
            self._piece()

    def park(self, k: int) -> tuple[int, int, bool] | None:
        """The k-th park (from 0), playing on until it comes; None where the run ends before."""
        while len(self.parks) <= k and self.e < self.events and not self.stopped:
            self.pieces = self.pieces[-1:]
            self._piece()
        return self.parks[k] if len(self.parks) > k else None

    def play(self, end: int) -> None:
        """Play on until every event before `end` has played (a piece at a time)."""
        while self.e < end:
            self._piece()

    def _set_factor(self, event: int, value: int, start: int, factor: np.ndarray) -> None:
        """factor[event] = value in the piece from `start`, or the piece before's last."""
        if event >= start:
            factor[event - start] = value
        elif len(self.pieces) > 1:
            self.pieces[-2][2][-1] = value

    def _piece(self) -> None:
        start = self.e
        end = min(self.events, start + STRETCH)
        run = np.searchsorted(self.run_end, np.arange(start, end), side="right").astype(np.int32)
        delta = run_deltas(self.schedule, run, start)
        tick = np.empty(end - start, dtype=np.int64)
        factor = np.full(end - start, F_ONE, dtype=np.int16)  # event e's delta and ramp come in e - 1's interrupt
        self.pieces.append((start, tick, factor))
        self.e = end
        if self.stopped:  # parked without a resume: the rest never plays
            tick[:], factor[:] = -1, PARKED
            return
        e, here = start, self.here
        if e < self.free_until:
            free = min(end, self.free_until) - start
            steps = np.cumsum(delta[:free])
            steps += here
            here = int(steps[-1])
            np.right_shift(steps, FRAC_BITS, out=tick[:free])
            e += free
        table, k, gate = self.plan.table, self.plan.ramp_k, self.plan.gate_above
        # the loop's scalars, fast, without a Python int per event: a view of the deltas, the runs' adds and ceilings
        deltas, runs, adds, ceilings = memoryview(delta), memoryview(run), self.adds, self.ceilings
        pending, pauses, resumes = self.pending, self.pauses, self.resumes
        ffx, target, paused = self.ffx, self.target, self.paused
        while e < end:
            while pending and pending[0][0] <= e:
                target = pending.pop(0)[1]
            if pauses and pauses[0] <= e:  # the record comes with this event's block: F 0
                pauses.pop(0)
                ffx, paused = ffx & 0xFFFF, True
            i, f = e - start, ffx >> 16
            d, goal = deltas[i], min(target, ceilings[runs[i]])
            steady = e
            if f == goal and f:  # a steady factor up to the next change (F_ONE: undilated)
                steady = min([pending[0][0] if pending else end, end] + pauses[:1])
                if target > F_ONE:  # the goal may change at the next ceiling record
                    nxt = int(np.searchsorted(self.ceiling_marks, e, side="right"))
                    steady = min(steady, int(self.ceiling_marks[nxt]) if nxt < len(self.ceiling_marks) else steady)
            if steady > e:
                d = delta[i:steady - start]
                step = np.where(d >= LONG, d, np.minimum((d * table[f]) >> 8, CLAMP))
                np.cumsum(step, out=step)
                step += here
                here = int(step[-1])
                np.right_shift(step, FRAC_BITS, out=tick[i:steady - start])
                if e:
                    self._set_factor(e - 1, f, start, factor)
                factor[i:steady - start - 1] = f
                e = steady
                continue
            if d >= LONG:
                here += d  # a long wait: undilated, and no ramp
            elif f == 0:
                self.parks.append((e, here >> FRAC_BITS, paused))
                self._set_factor(max(e - 1, 0), PARKED, start, factor)
                if not resumes:
                    tick[i:], factor[i:] = -1, PARKED
                    self.stopped = True
                    break
                here = resumes.pop(0) << FRAC_BITS | here & 0xFF  # main re-arms the compare; the fraction stays
                ffx, target, paused = (F_ONE if paused else 1) << 16, self.resume_target, False
            else:
                d = min((d * table[f]) >> 8, CLAMP)
                here += d
                ffx = _ramp(ffx, goal, d >> FRAC_BITS, adds[runs[i]], k, gate)
            if e and f:
                self._set_factor(e - 1, ffx >> 16, start, factor)
            tick[i] = here >> FRAC_BITS
            e += 1
        self.here, self.ffx, self.target, self.paused = here, ffx, target, paused


def dilate(schedule: Schedule, plan: HoldPlan, changes: list[tuple[int, int]], resumes: list[int] = (),
           resume_target: int = F_ONE) -> Dilation:
    """Every event's tick and factor under `changes` and the schedule's pauses, and the parks (Dilator, whole)."""
    dilator = Dilator(schedule, plan, changes, resumes, resume_target)
    return dilator.window(0, dilator.events)

"""Laser power: G-code S over the job's s_max, M3 constant and M4 dynamic (Grbl's laser mode), as power records
in the table stream (codegen/tables/format.py) that set the board's PWM at the step where the power changes.

The host knows the planned speed at every event, so M4's power follows it at every event, not once per
segment as in Grbl: an event's ideal power is S / s_max while the tool is on (M3), times the planned speed
over the programmed feed (M4, never above 1); 0 while the tool is off (G0 and M5 are dark). M4's power moves in
steps of POWER_STEP of full scale, so that the power the PWM plays is within half a step (+ half a PWM count)
of the ideal at every event; M3's is S itself. A power record comes before the rate run that starts at the
event where the power changes: `with_power` splits a run there (exactly: the run's interval at that event,
the same add), which changes no event's time. The player latches the record when it loads the run and writes
the PWM's compare register right after that event's STEP edge (templates/avr/player_isr.S.j2); the PWM takes
the new duty at its next period (phase-correct PWM: its compare register is double-buffered).

With feed_hold (codegen/tables/hold.py) M4's power must follow the feed factor F as well: its records carry DYNAMIC_FLAG
(bit 15; TOP stays below it), and while the clock is dilated the player writes counts x G >> 8 with
G = 2 F below F_ONE (`follow`: 0 at F 0; F_ONE and above, the override's headroom, keep the record's counts: M4
never burns more than its S, as Grbl's), at the event and again whenever F changes; at rest the laser is dark
whatever the mode.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from codegen.errors import BuildError
from codegen.motion.blocks import Events
from codegen.motion.planner import Plan
from codegen.tables.hold import F_ONE
from codegen.tables.schedule import Schedule, in_force, split_runs
from codegen.toolpath.segments import Segments

POWER_STEP = 0.01  # of full scale: M4's power steps
PWM_PRESCALERS = (1, 8, 64, 256, 1024)  # Timer5's
DYNAMIC_FLAG = 0x8000  # a power record's M4 mark, where the power follows the feed factor (feed_hold)
COUNTS = 0x7FFF  # a record's counts under the flag


@dataclass(frozen=True)
class LaserPwm:
    """The laser's PWM on the board: its pin (targets/<board>.yaml `laser_pwm`), Timer5's prescaler and TOP
    (phase-correct PWM: f = F_CPU / (2 x prescaler x TOP), 0 counts always low, TOP always high)."""

    pin: str
    pwm_hz: float  # what the job asked for
    prescaler: int
    top: int  # counts of full power
    f_cpu: int
    follows_feed: bool = False  # M4's records carry DYNAMIC_FLAG (a machine with feed_hold)

    @property
    def dynamic_flag(self) -> int:
        return DYNAMIC_FLAG if self.follows_feed else 0

    @property
    def actual_hz(self) -> float:
        return self.f_cpu / (2.0 * self.prescaler * self.top)


@dataclass(frozen=True)
class LaserSettings:
    """`machine.laser`, and whether M4's power follows the feed factor."""

    pwm_hz: float  # machine.laser.pwm_hz
    follows_feed: bool  # the machine has feed_hold


def laser_pwm(laser: LaserSettings | None, board_name: str, board: dict, f_cpu: int) -> LaserPwm | None:
    """The laser's PWM on board `board_name` (None without machine.laser); BuildError where the board has none."""
    if laser is None:
        return None
    pin = board.get("laser_pwm")
    if pin is None or board.get("target") != "avr":
        raise BuildError(f"machine.laser: board {board_name} has no laser PWM output (`laser_pwm` in its file); "
                         f"only the tool pin's on and off")
    for prescaler in PWM_PRESCALERS:
        top = round(f_cpu / (2.0 * prescaler * laser.pwm_hz))
        if top <= (COUNTS if laser.follows_feed else 0xFFFF):
            return LaserPwm(str(pin), float(laser.pwm_hz), prescaler, top, f_cpu, laser.follows_feed)
    raise BuildError(f"machine.laser.pwm_hz {laser.pwm_hz:g} is below what Timer5 makes")


def planned_speed(plan: Plan, segment: np.ndarray, time: np.ndarray) -> np.ndarray:
    """The plan's path speed (mm/s) at `time` (s) in `segment`: the trapezoid's ramp, cruise and ramp."""
    tau = np.maximum(time - plan.t_start[segment], 0.0)
    accel, t_acc, t_cruise = plan.accel[segment], plan.t_acc[segment], plan.t_cruise[segment]
    rising = plan.v_entry[segment] + accel * tau
    falling = plan.v_peak[segment] - accel * (tau - t_acc - t_cruise)
    speed = np.where(tau < t_acc, rising, np.where(tau < t_acc + t_cruise, plan.v_peak[segment], falling))
    return np.clip(speed, 0.0, plan.v_peak[segment])


def _event_segments(events: Events) -> np.ndarray:
    return np.repeat(events.block_segment, np.diff(events.block_first))


def event_power(events: Events, plan: Plan, segments: Segments, segment: np.ndarray | None = None) -> np.ndarray:
    """(E,) every event's ideal power, 0..1 of full scale (`segment`: each event's, when known)."""
    segment = _event_segments(events) if segment is None else segment
    on = np.repeat(events.block_tool, np.diff(events.block_first)).astype(bool) & (segments.dwell[segment] <= 0)
    power = np.where(on, segments.power[segment], 0.0)
    dynamic = on & segments.dynamic[segment]
    if dynamic.any():
        feed = segments.feed[segment[dynamic]]
        speed = planned_speed(plan, segment[dynamic], events.time[dynamic])
        ratio = np.divide(speed, feed, out=np.ones_like(speed), where=np.isfinite(feed) & (feed > 0))
        power[dynamic] *= np.minimum(ratio, 1.0)
    return power


def event_counts(events: Events, plan: Plan, segments: Segments, laser: LaserPwm) -> tuple[np.ndarray, np.ndarray]:
    """(E,) the power records' values at every event: the PWM counts (M4's power in POWER_STEP steps, M3's as
    it is), M4's with the laser's dynamic_flag; and (E,) every event's ideal power (0..1)."""
    segment = _event_segments(events)
    power = event_power(events, plan, segments, segment)
    dynamic = segments.dynamic[segment]
    stepped = np.where(dynamic, np.round(power / POWER_STEP) * POWER_STEP, power)
    counts = np.round(np.clip(stepped, 0.0, 1.0) * laser.top).astype(np.int64)
    return np.where(dynamic & (counts > 0), counts | laser.dynamic_flag, counts), power


def follow(records: np.ndarray, factor: np.ndarray | int) -> np.ndarray:
    """The counts the player writes for power records (DYNAMIC_FLAG: M4's) at feed factor F (codegen/tables/hold.py
    Dilation.factor): M4's times G = 2 F over 256 below F_ONE (all of it at F_ONE and above: M4 never burns
    more than its S, as Grbl's), the rest as they are; none where the player parked (a negative factor)."""
    counts = records & COUNTS
    f = np.maximum(np.asarray(factor, dtype=np.int64), 0)
    scaled = np.where(((records & DYNAMIC_FLAG) > 0) & (f < F_ONE), (counts * (2 * f)) >> 8, counts)
    return np.where(np.asarray(factor) < 0, 0, scaled)


def with_power(schedule: Schedule, counts: np.ndarray, before: int) -> Schedule:
    """The schedule with a power record wherever `counts` (per event) changes, `before` being the count in force
    before its first event: each such event starts a run (a run split there)."""
    previous = np.concatenate([[before], counts[:-1]])
    change = np.flatnonzero(counts != previous)
    if not len(change):
        return schedule
    out, run = split_runs(schedule, change)
    power = np.full(out.n_runs, -1, dtype=np.int64) if not len(out.run_power) else out.run_power.copy()
    power[run] = counts[change]
    return replace(out, run_power=power)


def played_counts(schedule: Schedule, before: int = 0) -> np.ndarray:
    """(E,) the PWM counts the player has set at every event, from the schedule's power records."""
    return in_force(schedule, schedule.run_power, before)


def power_error_of(counts: np.ndarray, ideal: np.ndarray, top: int) -> float:
    """The largest distance (of full scale) of the played power (records' counts) from the ideal, over the
    events."""
    return float(np.max(np.abs((counts & COUNTS) / top - ideal), initial=0.0))

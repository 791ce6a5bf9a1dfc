"""The plan and the twin against rules written down here, apart from the code that made them.

The other checks take some of their allowances from the plan and the tables themselves: the acceleration check
allows at a corner the velocity jump the plan says it makes there, and the simulator is compared with a twin made
from the same tables. A planner that corners too fast, or a compressor that lets events wander from their planned
times, raises its own allowance and passes them. These two rules are stated here, as the specification they check:

- Corner speeds, Grbl's junction deviation: where the path turns, theta the angle between the reversed incoming
  direction and the outgoing one (180 degrees going straight on), the speed is at most
  sqrt(a * jd * sin(theta/2) / (1 - sin(theta/2))): `a` the largest acceleration along the corner's normal that
  every motor can give (its max_accel, through the machine's kinematics at the corner), `jd` the program's junction
  deviation (M205 J) or the machine's. Where the program set Marlin's classic jerk (M205 X Y Z E) the jerk rule
  holds instead: no axis changes its speed by more than its jerk. A full reversal stops. The planner's other caps
  (feed, motor rates, curvature, stops) only lower a corner's speed, so this is an upper bound at every junction;
  a curve's vertices turn a little and get a large bound.
- Timing window, the rate runs (codegen/tables/compress.py): every event the twin plays (its tick, which the
  simulator is matched against) comes within TIMING_SHARE of its gap to the event before it, or TIMING_MIN_TICKS,
  of its planned time, plus TIMING_ROUNDING_TICKS; the gap from the earlier of that event's planned and played
  ticks (a window's runs start from the tick the one before played). A block's first event may come later: where
  the plan leaves less time before it than the player needs to load the block (and the runtime records before
  it), the compressor puts it back that far, and that time is the player's (the simulator's against the twin).
  The events after it in its block catch up (at no more than the motors' rates: a block at their limit takes a
  while): none comes later than the block's first did, over both their windows, and the block's last comes within
  its window (the planner leaves every block the time to make up its load: codegen/motion/planner.py catch_up_time).
  A shaped build's blocks are chords of the shaped motion, not the plan's segments, so that time is not theirs:
  there a block's last event may still lag (as much as its first), and the next block's load adds to that lag.

Both run a chapter at a time (codegen/verify/chapters.py), in numpy, carrying a few numbers from chapter to chapter.
"""

from __future__ import annotations

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.planner import Plan, segment_lengths
from codegen.pipeline.host import HostBuild
from codegen.toolpath.segments import Segments
from codegen.verify.chapters import Chapter

STRAIGHT_SIN_HALF = 1.0 - 1e-9  # sin(theta/2) from here on: going straight on, no junction bound
REVERSAL_COS = -1.0 + 1e-9  # cos(turn) below this: a full reversal, which stops
SPEED_SLACK = 1e-6  # relative, and in mm/s: a corner's speed over its bound by less is rounding
TIMING_SHARE = 0.05  # of an event's planned gap to the event before it: how far the rate runs may move it
TIMING_MIN_TICKS = 2.0  # the window never tighter than this (the timer rounds down to whole ticks)
TIMING_ROUNDING_TICKS = 1.0  # an event's tick is whole, its planned time is not


def corner_bounds(plan: Plan, segments: Segments, before: Segments | None, kin: Kinematics,
                  machine_deviation: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every junction of a stretch of the plan between two moving segments (the one with the stretch before it, whose
    last segment is `before`, included): its index (junction j is before segment j), the largest speed the rules
    allow there (mm/s), and whether that is the jerk rule's (else the junction deviation's)."""
    u = plan.direction if before is None else np.concatenate([segment_lengths(before)[1], plan.direction])
    shift = 0 if before is None else 1
    u_in, u_out = u[:-1], u[1:]
    moving = np.any(u_in != 0, axis=1) & np.any(u_out != 0, axis=1)
    j = np.flatnonzero(moving) + 1 - shift
    u_in, u_out = u_in[moving], u_out[moving]
    cos_turn = np.clip(np.sum(u_in * u_out, axis=1), -1.0, 1.0)
    sin_half = np.sqrt(0.5 * (1.0 + cos_turn))
    change = u_out - u_in
    norm = np.linalg.norm(change, axis=1, keepdims=True)
    normal = np.divide(change, norm, out=np.zeros_like(change), where=norm > 0)
    factors = kin.motor_factors(normal, segments.start[j])
    accel = kin.limits.max_accel[None, :]
    a_normal = np.min(np.divide(accel, factors, out=np.full_like(factors, np.inf), where=factors > 0), axis=1)
    deviation = segments.junction_deviation[j]
    deviation = np.where(np.isnan(deviation), machine_deviation, deviation)
    with np.errstate(divide="ignore", invalid="ignore"):
        v_deviation = np.sqrt(np.where(sin_half < STRAIGHT_SIN_HALF, a_normal * deviation * sin_half / (1 - sin_half),
                                       np.inf))
        jerk = segments.jerk[j]
        v_jerk = np.min(np.where((np.abs(change) > 1e-12) & ~np.isnan(jerk), jerk / np.abs(change), np.inf), axis=1)
    by_jerk = np.any(~np.isnan(jerk), axis=1)
    bound = np.where(by_jerk, v_jerk, v_deviation)
    return j, np.where(cos_turn < REVERSAL_COS, 0.0, bound), by_jerk


class PlanChecks:
    """The corner and timing rules over the chapters of `host`'s run, in order (`add`); `timing`: the chapters' pulses
    are the twin's as the tables play them (a held run's dilated twin is on another clock: not compared)."""

    def __init__(self, host: HostBuild, timing: bool = True):
        self.kin, self.tick_hz, self.timing = host.kin, host.target.tick_hz, timing
        self.machine_deviation = float(host.job.machine.junction_deviation)
        self.segments, self.events = 0, 0  # the chapters' so far
        self.last_planned_tick, self.last_played_tick = 0.0, 0  # the last event's before the chapter (from tick 0)
        self.worst_corner = 0.0  # the highest planned corner speed so far, over its bound
        self.worst_timing = 0.0  # the farthest an event came from its planned time, over its window
        self.reported: set[str] = set()
        # A shaped job's corners are its plan's before shaping (its blocks are chords of the shaped curve), checked
        # whole with the first chapter (a build that did not keep that plan has none to check).
        self.shaped, self.planned = host.shaped, host.planned

    @property
    def not_compared(self) -> list[str]:
        return [] if self.timing else ["timing window: a held run's twin is dilated by its holds, off the plan's clock"]

    def add(self, chapter: Chapter) -> list[str]:
        """The chapter's problems: its fastest corner over its bound, its event farthest outside its window (each
        kind once in a run)."""
        problems = self._corners(chapter)
        if self.timing:
            problems += self._timing(chapter)
        self.segments += len(chapter.segments)
        self.events += len(chapter.events.time)
        return problems

    def _corners(self, chapter: Chapter) -> list[str]:
        plan, segments, before = chapter.plan, chapter.segments, chapter.before
        if self.shaped:
            if self.segments or self.planned is None:
                return []
            (segments, plan), before = self.planned, None
        if not len(segments):
            return []
        j, bound, by_jerk = corner_bounds(plan, segments, before, self.kin, self.machine_deviation)
        speed = plan.v_entry[j]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(speed > 0, speed / bound, 0.0)
        self.worst_corner = max(self.worst_corner, float(ratio.max(initial=0.0)))
        over = speed > bound * (1 + SPEED_SLACK) + SPEED_SLACK
        if not np.any(over) or "corner" in self.reported:
            return []
        self.reported.add("corner")
        k = int(np.argmax(np.where(over, ratio, 0.0)))
        at = int(j[k])
        if by_jerk[k]:
            rule = "the jerk set there allows"
        else:
            deviation = segments.junction_deviation[at]
            rule = (f"the junction deviation {self.machine_deviation if np.isnan(deviation) else deviation:g} mm "
                    "allows")
        count = int(np.count_nonzero(over))
        line = int(segments.line[at])
        where = (f"segment {(0 if self.shaped else self.segments) + at}"
                 + (f", where G-code line {line} begins" if line else ""))
        return [f"corner at {plan.t_start[at]:.3f} s ({where}): planned {speed[k]:.1f} mm/s where {rule} "
                f"{bound[k]:.1f} mm/s" + (f" ({count} corners over their bound)" if count > 1 else "")]

    def _timing(self, chapter: Chapter) -> list[str]:
        planned, played = chapter.events.time * self.tick_hz, chapter.pulses.event_tick
        if not len(planned):
            return []
        before = np.minimum(np.concatenate([[self.last_planned_tick], planned[:-1]]),
                            np.concatenate([[self.last_played_tick], played[:-1]]))
        self.last_planned_tick, self.last_played_tick = float(planned[-1]), int(played[-1])
        window = np.maximum(TIMING_SHARE * (planned - before), TIMING_MIN_TICKS) + TIMING_ROUNDING_TICKS
        ratio = np.abs(played - planned) / window
        first, last = chapter.events.block_first[:-1], chapter.events.block_first[1:] - 1
        late = played[first] - planned[first]  # a block's load, and its block's events catching up after it
        load = np.repeat(np.where(late > window[first], late + window[first], 0.0), last - first + 1)
        if not self.shaped:  # the planner left the block the time to catch up (a shaped one's are not its segments)
            load[last] = 0.0
        catching_up = (load > 0) & (played > planned)
        ratio[catching_up] = np.maximum(played - planned - load, 0.0)[catching_up] / window[catching_up]
        ratio[first[late > 0]] = 0.0
        k = int(np.argmax(ratio))
        self.worst_timing = max(self.worst_timing, float(ratio[k]))
        if ratio[k] <= 1.0 or "timing" in self.reported:
            return []
        self.reported.add("timing")
        over = int(np.count_nonzero(ratio > 1.0))
        return [f"timing: the twin plays event {self.events + k} {abs(played[k] - planned[k]):.0f} ticks from its "
                f"planned time (the rate runs' window lets an event move {100 * TIMING_SHARE:g} % of its gap, at least "
                f"{TIMING_MIN_TICKS:g} ticks, plus {TIMING_ROUNDING_TICKS:g} of rounding: here {window[k]:.0f} ticks; "
                f"{over} events outside)"]

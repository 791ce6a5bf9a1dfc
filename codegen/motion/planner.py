"""Lookahead planner: constant-acceleration trapezoids over the whole program, vectorised.

Speeds are limited per segment by the feed, every motor's velocity (projected on the motor, with Bresenham's
step quantisation taken into account), the player's event rate and block load time (and the time a block's events
need to make up a load at the compressor's catch-up pace), and on curves by the centripetal acceleration each
motor can take (v^2 * curvature). Junction speeds follow Grbl's junction deviation at corners. The
backward and forward passes are exact recurrences on v^2 written as running minima (numpy, no Python loop).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.toolpath.segments import Segments

SMOOTH_TURN = 0.5  # rad: junctions turning less than this are part of a curve, not corners
RATE_WINDOW = 7  # step intervals over which motor rates are held (8 consecutive steps)
ACCEL_WINDOW_S = 0.020  # s over which motor accelerations are held (velocity change between two windows)
# Of a motor's rate the compressor's pushed events catch up at (codegen/tables/compress.py; the planner keeps 2 %).
CATCH_UP_SHARE = 0.985


@dataclass(frozen=True)
class PlannerLimits:
    junction_deviation: float  # mm
    max_event_rate: float = np.inf  # events/s the player sustains
    block_overhead: float = 0.0  # s a block start costs the player beyond an ordinary event
    block_load: float = 0.0  # s the player needs between a block's first event and the one before, with headroom
    margin: float = 0.02  # headroom kept below every motor limit, for step and tick quantisation
    pulse_jitter_s: float = 0.0  # how much closer than planned the player may put 8 steps (TargetInfo)
    tool_stops: bool = True  # the tool switching on or off is a stop (a pen); a laser's power follows at its step
    centripetal_share: float = 0.8  # largest share of a motor's acceleration a curve may use sideways
    accel_share: float = 1.0  # share of every motor's acceleration the plan may use (the rest: a feed hold's ramp)


@dataclass
class Plan:
    length: np.ndarray  # (n,) mm of path
    direction: np.ndarray  # (n, 4) unit vectors (zero for dwells)
    v_entry: np.ndarray
    v_peak: np.ndarray
    v_exit: np.ndarray
    accel: np.ndarray  # mm/s^2 along the path
    s_acc: np.ndarray  # mm accelerating
    s_cruise: np.ndarray  # mm at v_peak
    t_acc: np.ndarray
    t_cruise: np.ndarray
    t_start: np.ndarray  # s
    duration: np.ndarray  # s, dwell included
    corner: np.ndarray  # (n + 1,) bool: junction j (before segment j) is a corner, not a curve

    @staticmethod
    def join(plans: list["Plan"]) -> "Plan":
        """Consecutive plans as one: each one's last junction is the next one's first."""
        fields = {name: np.concatenate([getattr(p, name) for p in plans])
                  for name in Plan.__dataclass_fields__ if name != "corner"}
        return Plan(**fields, corner=np.concatenate([p.corner[:-1] for p in plans] + [plans[-1].corner[-1:]]))

    @property
    def total(self) -> float:
        return float(self.t_start[-1] + self.duration[-1]) if len(self.duration) else 0.0

    def time_at(self, seg: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Time (s since the start) when the tool is `s` mm into segment `seg` (arrays)."""
        v0, vp, a = self.v_entry[seg], self.v_peak[seg], self.accel[seg]
        s_acc, s_cr = self.s_acc[seg], self.s_cruise[seg]
        in_acc = np.minimum(s, s_acc)
        t = 2.0 * in_acc / np.maximum(v0 + np.sqrt(v0 * v0 + 2.0 * a * in_acc), 1e-300)
        in_cruise = np.clip(s - s_acc, 0.0, s_cr)
        t = t + np.where(in_cruise > 0, in_cruise / np.maximum(vp, 1e-300), 0.0)
        in_dec = np.maximum(s - s_acc - s_cr, 0.0)
        root = np.sqrt(np.maximum(vp * vp - 2.0 * a * in_dec, 0.0))
        t = t + 2.0 * in_dec / np.maximum(vp + root, 1e-300)
        return self.t_start[seg] + t


def segment_lengths(segments: Segments) -> tuple[np.ndarray, np.ndarray]:
    """Path length (xyz, or |e| for extruder-only moves) and unit direction of every segment."""
    delta = segments.end - segments.start
    length = np.linalg.norm(delta[:, :3], axis=1)
    length = np.where(length > 0, length, np.abs(delta[:, 3]))
    direction = np.divide(delta, length[:, None], out=np.zeros_like(delta), where=length[:, None] > 0)
    return length, direction


def jitter_rate(max_rate: np.ndarray, jitter_s: float) -> np.ndarray:
    """The rate (steps/s) to plan for so that 8 steps still keep `max_rate` when the player puts them
    `jitter_s` closer: their RATE_WINDOW intervals must span RATE_WINDOW / max_rate + jitter_s."""
    return max_rate / (1.0 + jitter_s * max_rate / RATE_WINDOW)


def quantisation_factor(steps: np.ndarray) -> np.ndarray:
    """Per motor, how far below its limit a Bresenham slave must run so that any 8 consecutive steps stay
    within the limit: slaves step on master events, so 7 of their intervals can span floor(7 N / d) events."""
    d = np.abs(steps).astype(float)
    n = d.max(axis=1, keepdims=True)
    ratio = np.divide(RATE_WINDOW * n, d, out=np.ones_like(d), where=d > 0)
    return np.where((d > 0) & (d < n), np.floor(ratio) / np.maximum(ratio, 1e-300), 1.0)


def catch_up_time(steps: np.ndarray, max_rate: np.ndarray, limits: PlannerLimits) -> np.ndarray:
    """Per segment (one block), the least time its events take where the block load delays its first event (the
    load is longer than an event's gap at CATCH_UP_SHARE of the motors' rates): the rest come at no more than
    that share (the compressor's `rate_gaps`), so they make up the delay only in what the block leaves them;
    a block at its motors' full rate never would, and the player would fall further behind at every block load.
    0 where the load is shorter (no delay), or no motor steps."""
    d = np.abs(steps).astype(float)
    rate = CATCH_UP_SHARE * jitter_rate(max_rate, limits.pulse_jitter_s)[None, :] * quantisation_factor(steps)
    at_rate = np.max(d / rate, axis=1, initial=0.0)  # every event at the catch-up pace
    gap = np.divide(at_rate, d.max(axis=1, initial=0.0), out=np.zeros_like(at_rate), where=at_rate > 0)
    return np.where((limits.block_load > gap) & (at_rate > 0), at_rate - gap + limits.block_load, 0.0)


def bresenham_factors(factors: np.ndarray, steps: np.ndarray, steps_per_mm: np.ndarray) -> np.ndarray:
    """Motor mm per path mm as the player moves the slaves: a slave makes |d| / N steps per master event,
    with d and N rounded, where the exact ratio may be smaller (a short block of a coarse motor: 10 steps
    against 12 for 12.5 exact ones goes 4 % faster than the line)."""
    d = np.abs(steps).astype(float)
    n = d.max(axis=1, keepdims=True)
    master = np.argmax(d, axis=1)
    events_per_mm = np.take_along_axis(factors, master[:, None], axis=1) * steps_per_mm[master][:, None]
    return np.divide(events_per_mm * d, n * steps_per_mm[None, :], out=np.zeros_like(factors), where=n > 0)


def _axis_cap(per_axis: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The largest path rate (velocity or acceleration) whose share on every axis stays within `per_axis`."""
    share = np.abs(u)
    return np.min(np.divide(per_axis, share, out=np.full_like(share, np.inf), where=share > 0), axis=1)


def _bend_cap(budget: np.ndarray, sideways: np.ndarray, lumped: np.ndarray) -> np.ndarray:
    """(n,) the largest v with v^2 * sideways + v * lumped <= budget for every motor (the quadratic's positive
    root, written without cancellation; inf where neither term grows with v)."""
    grows = lumped + np.sqrt(lumped * lumped + 4.0 * sideways * budget[None, :])
    return np.min(np.divide(2.0 * budget[None, :], grows, out=np.full_like(grows, np.inf), where=grows > 0),
                  axis=1)


@dataclass
class Profile:
    """The speed limits of a stretch of segments, before the passes: per segment and per junction (junction j
    is before segment j; 0 and n are the stretch's ends)."""

    length: np.ndarray  # (n,) mm
    direction: np.ndarray  # (n, 4)
    moving: np.ndarray  # (n,) bool
    dwell: np.ndarray  # (n,) s
    w_nominal: np.ndarray  # (n,) (mm/s)^2: the segment's own speed limit, squared
    accel: np.ndarray  # (n,) mm/s^2
    w_max: np.ndarray  # (n + 1,) (mm/s)^2: the junction's limit; 0 at stops and at the stretch's ends
    smooth: np.ndarray  # (n + 1,) bool: the junction is part of a curve (False at the ends)
    jump: np.ndarray  # (n + 1, M): each motor's velocity jump at the junction per mm/s of entry speed
    jump_limit: np.ndarray  # (M,) the largest jump a curve's vertex may make (half a window's acceleration)

    def __len__(self) -> int:
        return len(self.length)

    @property
    def gain(self) -> np.ndarray:
        """v^2 gained over each segment at full acceleration."""
        return 2.0 * self.accel * self.length

    def part(self, lo: int, hi: int) -> "Profile":
        """Segments lo..hi-1 with their junctions lo..hi (the ends keep their limits)."""
        return Profile(self.length[lo:hi], self.direction[lo:hi], self.moving[lo:hi], self.dwell[lo:hi],
                       self.w_nominal[lo:hi], self.accel[lo:hi], self.w_max[lo:hi + 1], self.smooth[lo:hi + 1],
                       self.jump[lo:hi + 1], self.jump_limit)


@np.errstate(over="ignore")  # a motor's share of a move can be ~1e-300: its cap overflows to inf, no cap
def profile(segments: Segments, kin: Kinematics, steps: np.ndarray, limits: PlannerLimits) -> Profile:
    """`steps` (n, M): signed motor steps of every segment (from positions rounded once)."""
    n = len(segments)
    length, u = segment_lengths(segments)
    moving = length > 0
    motor = kin.limits
    keep = 1.0 - limits.margin
    vmax = motor.max_velocity * keep * jitter_rate(motor.max_rate, limits.pulse_jitter_s) / motor.max_rate
    amax = motor.max_accel * keep * limits.accel_share
    # (n, M) motor mm per path mm: the larger of the two ends (they differ where the kinematics is not linear)
    factors = np.maximum(kin.motor_factors(u, segments.start), kin.motor_factors(u, segments.end))
    factors = np.maximum(factors, bresenham_factors(factors, steps, motor.steps_per_mm))
    q = quantisation_factor(steps)
    v_motor = np.min(np.divide(vmax * q, factors, out=np.full_like(factors, np.inf), where=factors > 0), axis=1)
    master = np.abs(steps).max(axis=1) if steps.size else np.zeros(n)
    # Every segment is one block: its events at the sustained rate, plus the block load at its start.
    least_time = master / limits.max_event_rate + limits.block_overhead
    v_events = np.divide(keep * length, least_time, out=np.full(n, np.inf), where=least_time > 0)
    catch_up = catch_up_time(steps, motor.max_rate, limits)
    v_events = np.minimum(v_events, np.divide(length, catch_up, out=np.full(n, np.inf), where=catch_up > 0))

    # Junctions j = 1 .. n-1 between segment j-1 and j.
    u_prev, u_next = u[:-1], u[1:]
    cos_turn = np.clip(np.sum(u_prev * u_next, axis=1), -1.0, 1.0)
    turn = np.arccos(cos_turn)
    normal = u_next - u_prev
    norm = np.linalg.norm(normal, axis=1)
    normal = np.divide(normal, norm[:, None], out=np.zeros_like(normal), where=norm[:, None] > 0)
    normal_factors = kin.motor_factors(normal, segments.start[1:])  # (n-1, M)
    a_normal = np.min(np.divide(amax, normal_factors, out=np.full_like(normal_factors, np.inf),
                                where=normal_factors > 0), axis=1)
    sin_half = np.sqrt(0.5 * (1.0 + cos_turn))  # Grbl's sin(theta/2), theta = angle to the reversed incoming
    deviation = np.where(np.isnan(segments.junction_deviation[1:]), limits.junction_deviation,
                         segments.junction_deviation[1:])
    with np.errstate(divide="ignore", invalid="ignore"):
        w_jd = np.where(sin_half < 1.0 - 1e-9, a_normal * deviation * sin_half / (1.0 - sin_half), np.inf)
    # Where the program set Marlin's classic jerk, no axis may change its speed by more than its jerk.
    jerk = segments.jerk[1:]
    change = np.abs(u_next - u_prev)
    with np.errstate(divide="ignore", invalid="ignore"):
        v_jerk = np.min(np.where((change > 1e-12) & ~np.isnan(jerk), jerk / change, np.inf), axis=1)
    w_jd = np.where(np.any(~np.isnan(jerk), axis=1), v_jerk ** 2, w_jd)
    w_jd = np.where(cos_turn < -1.0 + 1e-9, 0.0, w_jd)  # a full reversal stops
    smooth = (turn < SMOOTH_TURN) & moving[:-1] & moving[1:]
    # The turn over the mean of the two chords: exactly 1 / R for chords of any lengths on a circle of radius R,
    # and a blip of a chord beside a long one bends the long one little (as a corner, by junction deviation).
    mean_chord = 0.5 * (length[:-1] + length[1:])
    curvature = np.where(smooth, np.divide(2.0 * np.sin(0.5 * turn), mean_chord, out=np.zeros(n - 1),
                                           where=mean_chord > 0), 0.0)
    with np.errstate(divide="ignore"):
        w_curve_j = np.where(curvature > 0, limits.centripetal_share * a_normal / curvature, np.inf)

    # Each segment takes the larger curvature of its two ends (smooth ends only).
    kappa = np.zeros(n)
    side = np.zeros((n, len(motor.names)))
    kappa[:-1] = np.maximum(kappa[:-1], curvature)
    kappa[1:] = np.maximum(kappa[1:], curvature)
    curved_normals = normal_factors * (curvature > 0)[:, None]
    side[:-1] = np.maximum(side[:-1], curved_normals)
    side[1:] = np.maximum(side[1:], curved_normals)
    # Motor acceleration per (mm/s)^2: centripetal on curves, and a non-linear machine's motors speed up and
    # slow down along straight lines too.
    bend = np.maximum(kin.motor_bend(u, segments.start), kin.motor_bend(u, segments.end))
    sideways = kappa[:, None] * side + bend
    # Where motors move linearly along each piece (a delta's carriages), that bend comes at the pieces' ends as a
    # velocity step of v * kink: within one acceleration window, v * kink / ACCEL_WINDOW_S more per mm/s.
    kinks = kin.chord_kinks(segments.start, segments.end)
    kink = np.zeros((n, len(motor.names)))
    kink[:-1], kink[1:] = np.maximum(kink[:-1], kinks), np.maximum(kink[1:], kinks)
    lumped = kink / ACCEL_WINDOW_S
    v_curve = _bend_cap(limits.centripetal_share * amax, sideways, lumped)
    v_program = _axis_cap(segments.axis_velocity, u)
    v_nominal = np.minimum.reduce([segments.feed, v_motor, v_events, v_curve, v_program])
    v_nominal = np.where(moving, v_nominal, 0.0)
    if np.any(~np.isfinite(v_nominal)):
        raise ValueError("a segment moves no motor: its speed is unbounded")
    spare = amax[None, :] - v_nominal[:, None] ** 2 * sideways - v_nominal[:, None] * lumped
    accel = np.min(np.divide(spare, factors, out=np.full_like(factors, np.inf), where=factors > 0), axis=1)
    accel = np.minimum.reduce([accel, segments.accel, _axis_cap(segments.axis_accel, u)])
    accel = np.where(moving, accel, 1.0)

    # Largest v^2 at each junction; 0 at the ends, around dwells and where the tool switches (unless it need not).
    w_nom = v_nominal ** 2
    w_max = np.zeros(n + 1)
    inner = np.minimum.reduce([w_nom[:-1], w_nom[1:], w_jd, w_curve_j])
    stops = (~moving[:-1]) | (~moving[1:]) | (limits.tool_stops & (segments.tool[:-1] != segments.tool[1:]))
    w_max[1:-1] = np.where(stops, 0.0, inner)
    smooth_at = np.zeros(n + 1, dtype=bool)
    smooth_at[1:-1] = smooth
    jump = np.zeros((n + 1, len(motor.names)))
    jump[1:-1] = kin.motor_factors(u_next - u_prev, segments.start[1:])
    return Profile(length, u, moving, segments.dwell, w_nom, accel, w_max, smooth_at, jump,
                   0.5 * amax / keep * ACCEL_WINDOW_S)



def passes(prof: Profile, w_first: float = 0.0, w_last: float = 0.0) -> np.ndarray:
    """v^2 at every junction: as fast as every limit allows, starting at `w_first` and ending at `w_last`."""
    w_max = prof.w_max.copy()
    w_max[0], w_max[-1] = w_first, w_last
    gain = prof.gain
    # Backward pass: w[j] = min(w_max[j], w[j+1] + gain[j])  <=>  w[j] - D[j] = min_{k>=j} (w_max[k] - D[k]).
    suffix = np.concatenate([np.cumsum(gain[::-1])[::-1], [0.0]])
    w_back = np.minimum.accumulate((w_max - suffix)[::-1])[::-1] + suffix
    # Forward pass: w[j] = min(w_back[j], w[j-1] + gain[j-1]).
    prefix = np.concatenate([[0.0], np.cumsum(gain)])
    w = np.minimum.accumulate(w_back - prefix) + prefix
    w = np.clip(np.minimum(w, w_back), 0.0, None)
    w[0], w[-1] = w_first, min(w[-1], w_last)
    return w


def settled(prof: Profile) -> np.ndarray:
    """The junctions whose backward-pass speed no continuation of the stretch can change: the rest of the
    stretch gains at least their own limit, so a stop at its end never reaches back to them."""
    suffix = np.concatenate([np.cumsum(prof.gain[::-1])[::-1], [0.0]])
    return suffix >= prof.w_max


def finish(prof: Profile, w: np.ndarray, t0: float = 0.0) -> Plan:
    """The trapezoids through junction speeds `w` (v^2), starting at time `t0`."""
    n = len(prof)
    moving, accel, length, gain = prof.moving, prof.accel, prof.length, prof.gain
    w0, w1 = w[:-1], w[1:]
    w_peak = np.minimum(prof.w_nominal, 0.5 * (gain + w0 + w1))
    w_peak = np.maximum(w_peak, np.maximum(w0, w1))
    s_acc = np.where(moving, (w_peak - w0) / (2.0 * accel), 0.0)
    s_dec = np.where(moving, (w_peak - w1) / (2.0 * accel), 0.0)
    s_cruise = np.maximum(length - s_acc - s_dec, 0.0)
    v0, vp, v1 = np.sqrt(w0), np.sqrt(w_peak), np.sqrt(w1)
    t_acc = np.where(moving, (vp - v0) / accel, 0.0)
    t_dec = np.where(moving, (vp - v1) / accel, 0.0)
    t_cruise = np.divide(s_cruise, vp, out=np.zeros(n), where=vp > 0)
    duration = t_acc + t_cruise + t_dec + prof.dwell
    t_start = t0 + np.concatenate([[0.0], np.cumsum(duration)[:-1]])
    # A vertex of a curve where some motor's velocity jumps by more than half what its acceleration gives it in
    # one window is a corner (its jump bounded by the junction deviation), not a bend spread over the curve.
    spread = np.all(np.sqrt(w)[:, None] * prof.jump <= prof.jump_limit[None, :], axis=1)
    corner = ~(prof.smooth & spread)
    return Plan(length, prof.direction, v0, vp, v1, accel, s_acc, s_cruise, t_acc, t_cruise, t_start, duration,
                corner)


def plan(segments: Segments, kin: Kinematics, steps: np.ndarray, limits: PlannerLimits) -> Plan:
    """The whole program at once, from rest to rest."""
    if len(segments) == 0:
        empty = np.zeros(0)
        return Plan(empty, np.zeros((0, 4)), empty, empty, empty, empty, empty, empty, empty, empty, empty,
                    empty, np.ones(1, dtype=bool))
    prof = profile(segments, kin, steps, limits)
    return finish(prof, passes(prof))

"""The planned motion as exact piecewise quadratics in time, and that motion convolved with the input shapers.

A plan moves the tool along straight segments with constant-acceleration phases, so every axis is a quadratic in
time between the phases' ends. Shaping replaces each axis x(t) by sum A_i x(t - tau_i) (codegen/motion/shapers.py,
tau_i the impulse times less their mean, as Klipper's kin_shaper.c centres them) before the motors' transform, as
Klipper does: the shaped motion is again piecewise quadratic, with breaks at every phase end shifted by every
impulse time. `shape` computes those pieces exactly (numpy over the pieces, a loop over the few impulses).

The shaped clock runs `shift` later than the plan's (the largest mean impulse time), so that the earliest impulse
of any axis starts at the plan's start: no event comes before the program's.

With pressure advance the extruder axis is Klipper's advanced and smoothed extruder (codegen/motion/advance.py,
`advanced`) on the same clock, which then runs at least half the smoothing time behind the plan; x, y and z stay
as shaped (unshaped where an axis has no shaper).
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass

import numpy as np

from codegen.motion.advance import AdvanceSettings, advanced_extruder
from codegen.motion.planner import Plan
from codegen.motion.shapers import Shaper, make_shaper
from codegen.native import contiguous, library, pointer
from codegen.toolpath.segments import Segments

AXES = 4  # x, y, z, e: the extruder is never shaped (Klipper's neither), only advanced
SAME_PIECE = 1e-9  # relative: neighbouring pieces whose quadratics agree this closely are one


@dataclass(frozen=True)
class ShapingSettings:
    """The shaper of each axis (None: unshaped), the smoothing allowed (mm; None: no limit), and the extruder's
    pressure advance (None: none)."""

    shapers: tuple[Shaper | None, ...]  # x, y, z
    max_smoothing: float | None = None
    advance: AdvanceSettings | None = None

    @property
    def shaped(self) -> bool:
        """Some axis has a shaper (else only the extruder is advanced)."""
        return any(s is not None for s in self.shapers)

    @property
    def shift(self) -> float:
        """s the shaped clock runs behind the plan's: the largest mean impulse time, and the advance's half
        smoothing time (it reads the plan that far ahead)."""
        return max([s.mean_time for s in self.shapers if s is not None]
                   + ([self.advance.half] if self.advance is not None else []), default=0.0)

    def offsets(self, axis: int) -> tuple[np.ndarray, np.ndarray]:
        """An axis's impulse amplitudes and times relative to their mean (one impulse at 0 when unshaped)."""
        shaper = self.shapers[axis] if axis < len(self.shapers) else None
        if shaper is None:
            return np.ones(1), np.zeros(1)
        return shaper.amplitudes, shaper.times - shaper.mean_time

    @property
    def spread(self) -> float:
        """s the shaped motion lasts longer than the plan (the advanced extruder reads half a smoothing time on)."""
        late = [float(self.offsets(a)[1][-1]) for a in range(AXES)] + ([self.advance.half] if self.advance else [])
        return max(late) + self.shift


def shaping_of(specs: tuple, max_smoothing: float | None = None,
               advance: AdvanceSettings | None = None) -> ShapingSettings | None:
    """The settings of the shapers given as (type, freq, damping) for x, y, z (None: unshaped) with the extruder's
    pressure advance (None: none); None when they shape no axis and advance no extruder (with pressure advance,
    unshaped axes still take the shaped motion's path: its extruder is advanced)."""
    if all(spec is None for spec in specs) and advance is None:
        return None
    return ShapingSettings(tuple(None if spec is None else make_shaper(*spec) for spec in specs), max_smoothing,
                           advance)


def settle_time(change, smooth_time: float = 0.0) -> float:
    """s the motion shaped before an M593 (an InputShaping item) goes on after the plan's: its shapers' spread,
    with pressure advance's smoothing (`smooth_time`, s; 0: none) in it."""
    advance = AdvanceSettings(smooth_time, 0.0) if smooth_time > 0 else None
    before = shaping_of(change.before, advance=advance)
    return 0.0 if before is None else before.spread


@dataclass
class Motion:
    """Every axis as quadratics between breaks: on piece k, from breaks[k] for dt, position + velocity dt +
    accel dt^2 / 2. Before the first break the tool rests at the first piece's position, after the last at the end.
    `origin` (K,): the plan's segment each piece belongs to (for a shaped piece, the one under its middle)."""

    breaks: np.ndarray  # (K + 1,) s
    position: np.ndarray  # (K, 4) mm
    velocity: np.ndarray  # (K, 4) mm/s
    accel: np.ndarray  # (K, 4) mm/s^2
    origin: np.ndarray  # (K,) int

    def __len__(self) -> int:
        return len(self.position)

    @property
    def end(self) -> np.ndarray:
        return self.at_piece(len(self) - 1, self.breaks[-1:] - self.breaks[-2:-1])[0]

    def at_piece(self, piece, dt) -> np.ndarray:
        """(N, 4) positions at dt (N,) s into pieces (N,)."""
        dt = np.asarray(dt, dtype=float)[:, None]
        return self.position[piece] + self.velocity[piece] * dt + 0.5 * self.accel[piece] * dt * dt

    def piece_of(self, t: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self.breaks, t, side="right") - 1, 0, len(self) - 1)

    def at(self, t) -> np.ndarray:
        """(N, 4) the tool at times t (N,), resting before the first piece and after the last."""
        t = np.clip(np.asarray(t, dtype=float), self.breaks[0], self.breaks[-1])
        piece = self.piece_of(t)
        return self.at_piece(piece, t - self.breaks[piece])


def cut(motion: Motion, times: np.ndarray) -> Motion:
    """The same motion with breaks at `times` too (those inside it)."""
    times = np.unique(times[(times > motion.breaks[0]) & (times < motion.breaks[-1])])
    at = np.searchsorted(motion.breaks, times)  # the break each goes before
    fresh = motion.breaks[at] != times
    times, at = times[fresh], at[fresh]
    if not len(times):
        return motion
    breaks = np.insert(motion.breaks, at, times)
    begin = breaks[:-1]
    parent = np.repeat(np.arange(len(motion)), 1 + np.bincount(at - 1, minlength=len(motion)))
    dt = begin - motion.breaks[parent]
    inner = np.flatnonzero(dt != 0)  # the second parts of cut pieces; the rest begin where they did
    position, velocity = motion.position[parent], motion.velocity[parent]
    position[inner] = motion.at_piece(parent[inner], dt[inner])
    velocity[inner] += motion.accel[parent[inner]] * dt[inner, None]
    return Motion(breaks, position, velocity, motion.accel[parent], motion.origin[parent])


def between(motion: Motion, begin: float, end: float) -> Motion:
    """The motion from `begin` to `end` (s), within its own."""
    whole = cut(motion, np.array([begin, end]))
    first, last = np.searchsorted(whole.breaks, [max(begin, whole.breaks[0]), min(end, whole.breaks[-1])])
    return Motion(whole.breaks[first:last + 1], whole.position[first:last], whole.velocity[first:last],
                  whole.accel[first:last], whole.origin[first:last])


def planned_motion(segments: Segments, plan: Plan) -> Motion:
    """The plan's motion: per segment its acceleration, cruise, deceleration and dwell, those that last."""
    n = len(plan.duration)
    t_dec = np.maximum(plan.duration - plan.t_acc - plan.t_cruise - segments.dwell, 0.0)
    lasts = np.stack([plan.t_acc, plan.t_cruise, t_dec, segments.dwell], axis=1)  # (n, 4 phases)
    begins = plan.t_start[:, None] + np.concatenate([np.zeros((n, 1)), np.cumsum(lasts, axis=1)[:, :-1]], axis=1)
    s0 = np.stack([np.zeros(n), plan.s_acc, plan.s_acc + plan.s_cruise, plan.length], axis=1)
    speed = np.stack([plan.v_entry, plan.v_peak, plan.v_peak, np.zeros(n)], axis=1)
    accel = np.stack([plan.accel, np.zeros(n), -plan.accel, np.zeros(n)], axis=1)
    keep = (lasts > 0).ravel()
    seg = np.repeat(np.arange(n), 4)[keep]
    u = plan.direction[seg]
    breaks = np.append(begins.ravel()[keep], plan.total)
    return Motion(breaks, segments.start[seg] + u * s0.ravel()[keep, None], u * speed.ravel()[keep, None],
                  u * accel.ravel()[keep, None], seg)


def shape(motion: Motion, settings: ShapingSettings) -> Motion:
    """The motion convolved with each axis's shaper, on the shaped clock (`settings.shift` later), in pieces."""
    impulses = [settings.offsets(axis) for axis in range(AXES)]
    shifts = np.unique(np.concatenate([times for _, times in impulses])) + settings.shift
    breaks = np.unique((motion.breaks[None, :] + shifts[:, None]).ravel())
    begin, length = breaks[:-1], np.diff(breaks)
    middle = begin + 0.5 * length
    position, velocity, accel = (np.zeros((len(begin), AXES)) for _ in range(3))
    reads = {}  # impulse time -> where the plan is read: the axes of one shaper read it alike
    end = motion.end
    for axis, (amplitudes, times) in enumerate(impulses):
        for amplitude, tau in zip(amplitudes, times):
            if float(tau) not in reads:
                source = middle - settings.shift - tau  # the plan's time this impulse reads
                piece = motion.piece_of(source)
                inside = (source >= motion.breaks[0]) & (source <= motion.breaks[-1])
                dt = np.where(inside, begin - settings.shift - tau - motion.breaks[piece], 0.0)
                reads[float(tau)] = piece, inside, dt, source > motion.breaks[-1]  # past the end: it rests there
            piece, inside, dt, last = reads[float(tau)]
            held = np.where(last, end[axis], motion.position[piece, axis])
            v, a = np.where(inside, motion.velocity[piece, axis], 0.0), np.where(inside, motion.accel[piece, axis], 0.0)
            p = np.where(inside, motion.position[piece, axis] + motion.velocity[piece, axis] * dt + 0.5 * a * dt * dt,
                         held)
            position[:, axis] += amplitude * p
            velocity[:, axis] += amplitude * (v + a * dt)
            accel[:, axis] += amplitude * a
    origin = motion.origin[motion.piece_of(middle - settings.shift)]
    return _merged(Motion(breaks, position, velocity, accel, origin))


def advanced(shaped: Motion, planned: Motion, segments: Segments, settings: ShapingSettings, smooth: bool) -> Motion:
    """The shaped motion with its extruder axis advanced (codegen/motion/advance.py) from the plan's (`planned`,
    whose pieces' origins index `segments`; `smooth`: smoothed, else nominal), on the shaped clock; both go on
    resting beyond their ends."""
    extruder = advanced_extruder(planned.breaks, planned.position[:, 3], planned.velocity[:, 3],
                                 planned.accel[:, 3], planned.origin, segments, settings.advance, smooth)
    e_breaks = extruder.breaks + settings.shift
    first, last = min(shaped.breaks[0], e_breaks[0]), max(shaped.breaks[-1], e_breaks[-1])
    whole = cut(_rest_beyond(shaped, first, last), e_breaks)
    begin = whole.breaks[:-1]
    k = extruder.piece_of(begin + 0.5 * np.diff(whole.breaks) - settings.shift)
    dt = np.clip(begin - settings.shift, extruder.breaks[0], extruder.breaks[-1]) - extruder.breaks[k]
    outside = (begin < e_breaks[0]) | (begin >= e_breaks[-1])  # the extruder rests there
    inside = extruder.position[k] + extruder.velocity[k] * dt + 0.5 * extruder.accel[k] * dt * dt
    whole.position[:, 3] = np.where(begin >= e_breaks[-1], extruder.end, inside)
    whole.velocity[:, 3] = np.where(outside, 0.0, extruder.velocity[k] + extruder.accel[k] * dt)
    whole.accel[:, 3] = np.where(outside, 0.0, extruder.accel[k])
    return _merged(whole)


def _rest_beyond(motion: Motion, first: float, last: float) -> Motion:
    """The motion from `first` to `last` (s), resting before its first break and after its last."""
    before, after = first < motion.breaks[0], last > motion.breaks[-1]
    still = np.zeros((1, AXES))
    parts = ([(motion.position[:1], motion.origin[:1])] if before else []) + [(motion.position, motion.origin)] + (
        [(motion.end[None, :], motion.origin[-1:])] if after else [])
    breaks = np.concatenate([[first] if before else [], motion.breaks, [last] if after else []])
    position = np.concatenate([p for p, _ in parts])
    pad = lambda x: np.concatenate(([still] if before else []) + [x] + ([still] if after else []))  # noqa: E731
    return Motion(breaks, position, pad(motion.velocity), pad(motion.accel), np.concatenate([o for _, o in parts]))


def _merged(motion: Motion) -> Motion:
    """Neighbouring pieces that continue one quadratic (a cruise across collinear segments) as one, and no
    piece of zero length."""
    length = np.diff(motion.breaks)
    keep = length > 0
    if not np.all(keep):
        breaks = np.append(motion.breaks[:-1][keep], motion.breaks[-1])
        motion = Motion(breaks, motion.position[keep], motion.velocity[keep], motion.accel[keep], motion.origin[keep])
        length = np.diff(motion.breaks)
    if len(motion) < 2:
        return motion
    h = length[:-1, None]
    p, v, a = motion.position, motion.velocity, motion.accel
    scale = 1.0 + np.abs(p[1:]) + np.abs(v[1:]) + np.abs(a[1:])
    continues = np.all((np.abs(p[:-1] + v[:-1] * h + 0.5 * a[:-1] * h * h - p[1:]) <= SAME_PIECE * scale)
                       & (np.abs(v[:-1] + a[:-1] * h - v[1:]) <= SAME_PIECE * scale)
                       & (np.abs(a[:-1] - a[1:]) <= SAME_PIECE * scale), axis=1)
    continues &= motion.origin[:-1] == motion.origin[1:]  # a piece's tool, feed and item are its segment's
    first = np.flatnonzero(np.concatenate([[True], ~continues]))
    breaks = np.append(motion.breaks[first], motion.breaks[-1])
    return Motion(breaks, p[first], v[first], a[first], motion.origin[first])


def smoothing(shaped: Motion, planned: Motion, settings: ShapingSettings,
              samples: int = 4) -> tuple[float, np.ndarray, int]:
    """How far (mm, xyz) the shaped tool gets from where the plan puts it at the same moment, at its largest: the
    distance, the plan's point there, and the plan's segment. It bounds how far the shaped path strays from the
    programmed one and how much of a corner it cuts; on a reversal at constant acceleration it is Klipper's
    smoothing (codegen/motion/shapers.py `smoothing`). Sampled `samples` + 1 times along every shaped piece; in C
    where it could be built (codegen/native/smoothing.c, the same bits)."""
    share = np.linspace(0.0, 1.0, samples + 1)
    lib = library("smoothing")
    if lib is None:
        t = (shaped.breaks[:-1, None] + np.diff(shaped.breaks)[:, None] * share[None, :]).ravel()
        piece = np.repeat(np.arange(len(shaped)), len(share))
        here = shaped.at_piece(piece, t - shaped.breaks[piece])
        distance = np.linalg.norm(here[:, :3] - planned.at(t - settings.shift)[:, :3], axis=1)
        worst = int(np.argmax(distance))
        distance, t = float(distance[worst]), t[worst:worst + 1]
    else:
        arrays = contiguous(np.float64, shaped.breaks, shaped.position, shaped.velocity, shaped.accel, planned.breaks,
                            planned.position, planned.velocity, planned.accel, share)
        far = np.zeros(1)
        worst = lib.shaped_smoothing(ctypes.c_int64(len(shaped)), *map(pointer, arrays[:4]),
                                     ctypes.c_int64(len(planned)), *map(pointer, arrays[4:8]),
                                     ctypes.c_int64(len(share)), pointer(arrays[8]),
                                     ctypes.c_double(settings.shift), pointer(far))
        piece, sample = divmod(worst, len(share))
        t = shaped.breaks[piece:piece + 1] + np.diff(shaped.breaks[piece:piece + 2]) * share[sample]
        distance = float(far[0])
    there = planned.at(t - settings.shift)[0]
    return distance, there[:3], int(planned.origin[planned.piece_of(t - settings.shift)][0])

"""Segments: the toolpath flattened into straight pieces (and dwells), as arrays: the planner's input.

Arcs become equal chords within the machine's tolerance; curves arrive as chords already. Each piece keeps
what the checks need to measure against the exact path (arc centre and radius, or samples of the true curve)
and the limits the program set for it (G-code M201/M203/M204/M205). An arc's radius is given at the angle of
its piece's start, with how it grows per radian (a spiral's: a G-code end off the circle): a piece cut later
(codegen/motion/staircase.py, the delta's cuts) keeps its chord's reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from codegen.toolpath.items import FINE_STEPS, Arc, Curve, Dwell, InputShaping, Limits, Line, Lines, Output, Toolpath

REF_LINE, REF_ARC, REF_CURVE = 0, 1, 2
AXIS = {"x": 0, "y": 1, "z": 2, "e": 3}
RUNTIME_OUTPUTS = ("hotend", "bed", "fan", "pause")  # the settings a player with a runtime plays at their place
WAIT_REST_S = 0.001  # a temperature wait, G4 P0: the plan rests there, in a dwell this long


@dataclass
class Segments:
    start: np.ndarray  # (n, 4) mm
    end: np.ndarray  # (n, 4) mm
    feed: np.ndarray  # (n,) mm/s, inf = unlimited
    tool: np.ndarray  # (n,) bool
    power: np.ndarray  # (n,) the tool's power while it is on, 0..1 (G-code S over the job's s_max)
    dynamic: np.ndarray  # (n,) bool: M4, the power follows the actual speed over the programmed one
    dwell: np.ndarray  # (n,) s; > 0 marks a dwell (start == end)
    item: np.ndarray  # (n,) index of the toolpath item the piece comes from
    line: np.ndarray  # (n,) the G-code line the item is written on (0: not written in the G-code)
    accel: np.ndarray  # (n,) mm/s^2, the program's cap on the path acceleration (inf: none)
    axis_velocity: np.ndarray  # (n, 4) mm/s per axis the program allows (inf: no limit of its own)
    axis_accel: np.ndarray  # (n, 4) mm/s^2 per axis the program allows
    jerk: np.ndarray  # (n, 4) mm/s per axis, Marlin's classic jerk at the piece's start (nan: not set)
    junction_deviation: np.ndarray  # (n,) mm the program set (nan: the machine's)
    advance: np.ndarray  # (n,) s, the pressure advance K in force (codegen/motion/advance.py; 0: none)
    shaping: np.ndarray  # (n,) int: the input shapers' era, the M593s before the piece (0: the machine's shapers)
    ref_kind: np.ndarray  # (n,) REF_LINE | REF_ARC | REF_CURVE
    ref_center: np.ndarray  # (n, 2) arc centre in its plane
    ref_radius: np.ndarray  # (n,) mm, the arc's radius at ref_angle
    ref_angle: np.ndarray  # (n,) rad, the arc's angle at its chord's start
    ref_growth: np.ndarray  # (n,) mm per rad the arc's radius grows with the angle (0: a circle)
    ref_plane: np.ndarray  # (n, 2) int axes of the arc plane
    ref_fine: np.ndarray  # (n,) row of `fine` holding the true curve along the chord, -1 for none
    fine: np.ndarray  # (k, FINE_STEPS + 1, 3) true-curve samples

    def __len__(self) -> int:
        return len(self.feed)

    def take(self, index: np.ndarray, **replace) -> "Segments":
        """The segments at `index` (the shared `fine` samples stay as they are), with fields replaced."""
        fields = {name: getattr(self, name)[index] for name in self.__dataclass_fields__ if name != "fine"}
        fields.update(fine=self.fine, **replace)
        return Segments(**fields)

    def compact(self) -> "Segments":
        """The same segments with only the curve samples they use."""
        used = self.ref_fine >= 0
        ref_fine = np.full(len(self), -1, dtype=np.int64)
        ref_fine[used] = np.arange(int(used.sum()))
        fields = {name: getattr(self, name) for name in self.__dataclass_fields__}
        return Segments(**{**fields, "ref_fine": ref_fine, "fine": self.fine[self.ref_fine[used]]})


def concat(*parts: Segments) -> Segments:
    """The parts one after the other (at least one)."""
    fields = {name: np.concatenate([getattr(p, name) for p in parts])
              for name in parts[0].__dataclass_fields__ if name not in ("fine", "ref_fine")}
    if all(p.fine is parts[0].fine for p in parts):
        return Segments(**fields, fine=parts[0].fine, ref_fine=np.concatenate([p.ref_fine for p in parts]))
    base = np.cumsum([0] + [len(p.fine) for p in parts[:-1]])
    ref_fine = np.concatenate([np.where(p.ref_fine >= 0, p.ref_fine + b, -1) for p, b in zip(parts, base)])
    return Segments(**fields, fine=np.concatenate([p.fine for p in parts]), ref_fine=ref_fine)


def arc_chord_count(radius: float, sweep: float, tolerance: float) -> int:
    """Fewest equal chords whose sagitta stays within `tolerance` (`radius`: a spiral's larger)."""
    if radius <= tolerance:
        return max(1, math.ceil(abs(sweep) / (math.pi / 2)))
    max_angle = 2.0 * math.acos(1.0 - tolerance / radius)
    return max(1, math.ceil(abs(sweep) / max_angle - 1e-9))


class _LimitState:
    """The program's limits (and pressure advance K) as they stand, snapshotted once per change."""

    def __init__(self, advance: float = 0.0):
        self.rows = [(np.full(4, np.inf), np.full(4, np.inf), np.full(4, np.nan), np.nan, advance)]

    def apply(self, item: Limits) -> None:
        velocity, accel, jerk, jd, advance = (np.array(a, copy=True) if isinstance(a, np.ndarray) else a
                                              for a in self.rows[-1])
        for target, values in ((velocity, item.max_velocity), (accel, item.max_accel), (jerk, item.jerk)):
            for axis, value in (values or {}).items():
                target[AXIS[axis]] = value
        if item.junction_deviation is not None:
            jd = item.junction_deviation
        if item.advance is not None:
            advance = item.advance
        self.rows.append((velocity, accel, jerk, jd, advance))

    def arrays(self, index: np.ndarray) -> tuple[np.ndarray, ...]:
        velocity, accel, jerk = (np.array([r[k] for r in self.rows])[index] for k in range(3))
        return (velocity, accel, jerk, np.array([r[3] for r in self.rows])[index],
                np.array([r[4] for r in self.rows], dtype=float)[index])


def flatten(toolpath: Toolpath, tolerance: float) -> Segments:
    """Every motion item as straight pieces, in order; Limits items apply to the pieces after them."""
    return Flattener(toolpath.start, tolerance)(toolpath.items)


class Flattener:
    """`flatten` a batch of items at a time: the limits in force and the position carry over, and each piece's
    `item` counts the items of every batch before (a Lines item counts as its moves). With `runtime` (a player
    that plays heater and fan settings at their place), `settings` gathers them with their item index, and a
    temperature wait becomes a dwell of WAIT_REST_S at its index: the plan comes to rest there. An InputShaping
    item (M593) rests the plan too, for as long as `settle` says the motion shaped before needs to come to rest,
    and begins a new era of shapers (`shapings` gathers the items, taken by the caller)."""

    def __init__(self, start: np.ndarray, tolerance: float, runtime: bool = False, gcode_file: str | None = None,
                 settle: Callable[[InputShaping], float] | None = None, advance: float = 0.0):
        """`gcode_file`: the pieces of items written there keep their line (verify reads the G-code again);
        `settle`: s the motion shaped before an InputShaping item takes to rest (None: WAIT_REST_S); `advance`: the
        pressure advance K the program starts with (the job's)."""
        self.tolerance, self.gcode_file, self.settle = tolerance, gcode_file, settle
        self.limits = _LimitState(advance)
        self.position = np.asarray(start, dtype=float)
        self.items = 0
        self.runtime = runtime
        self.settings: list[tuple[int, Output]] = []  # (item index, setting), taken by the caller
        self.era = 0
        self.shapings: list[InputShaping] = []  # the era changes, taken by the caller

    def __call__(self, batch: list) -> Segments:
        limits = self.limits
        limits.rows = limits.rows[-1:]  # the limits in force; earlier ones are gone with their batches
        groups, single = [], _Single()  # the pieces and their items' columns, in order; items one at a time
        index, fines = self.items, []
        for item in batch:
            if isinstance(item, Lines):
                groups += single.take()
                groups.append(_lines_group(item, index, len(limits.rows) - 1, item.file == self.gcode_file, self.era))
                self.position = item.end
                index += len(item)
                continue
            if isinstance(item, Limits):
                limits.apply(item)
            elif isinstance(item, Output) and self.runtime and item.name in RUNTIME_OUTPUTS:
                self.settings.append((index, item))
                if item.wait and (item.value > 0 or item.name == "pause"):
                    single.add(self._pieces(Dwell(WAIT_REST_S, item.source), fines), index, len(limits.rows) - 1,
                               self._line(item), self.era)
            elif isinstance(item, InputShaping):  # the last piece of its era: a rest
                seconds = WAIT_REST_S if self.settle is None else max(WAIT_REST_S, self.settle(item))
                single.add(self._pieces(Dwell(seconds, item.source), fines), index, len(limits.rows) - 1,
                           self._line(item), self.era)
                self.era += 1
                self.shapings.append(item)
            elif isinstance(item, (Line, Arc, Curve, Dwell)):  # not Output, Home: nothing to move along
                single.add(self._pieces(item, fines), index, len(limits.rows) - 1, self._line(item), self.era)
            index += 1
        groups += single.take()
        self.items = index
        return _segments(groups, limits, fines)

    def _line(self, item) -> int:
        return item.source.line if item.source.file == self.gcode_file else 0

    def _pieces(self, item, fines: list) -> tuple:
        """The item's points and what its pieces share (a curve's samples go to `fines`)."""
        ref = (REF_LINE, (0.0, 0.0), 0.0, (0, 1), 0.0, 0.0, 0.0)
        if isinstance(item, Line):
            pts = (item.start, item.end)
        elif isinstance(item, Arc):
            n = arc_chord_count(max(item.radius, item.radius + item.radius_change), item.sweep, self.tolerance)
            pts = item.points(item.start_angle + item.sweep * np.arange(n + 1) / n)
            pts[0], pts[-1] = item.start, item.end
            ref = (REF_ARC, item.center, item.radius, item.plane, item.start_angle, item.sweep, item.radius_change)
        elif isinstance(item, Curve):
            pts = item.points
            ref = (REF_CURVE, (0.0, 0.0), 0.0, (0, 1), 0.0, 0.0, 0.0)
            fines.append(item.fine)
        else:  # a dwell
            pts = (self.position, self.position)
            return pts, math.inf, False, math.inf, 0.0, False, item.seconds, ref
        self.position = pts[-1]
        return (pts, item.feed, item.tool, getattr(item, "accel", math.inf), getattr(item, "power", 1.0),
                getattr(item, "dynamic", False), 0.0, ref)


# An item's columns (each piece of it repeats them): name, type, shape.
COLUMNS = (("pieces", np.int64, ()), ("item", np.int64, ()), ("feed", float, ()), ("tool", bool, ()),
           ("accel", float, ()), ("power", float, ()), ("dynamic", bool, ()), ("dwell", float, ()),
           ("kind", np.int64, ()), ("center", float, (2,)),
           ("radius", float, ()), ("plane", np.int64, (2,)), ("angle", float, ()), ("sweep", float, ()),
           ("change", float, ()), ("limits", np.int64, ()), ("fine", np.int64, ()), ("line", np.int64, ()),
           ("shaping", np.int64, ()))


class _Single:
    """Items gathered one at a time, taken as one group: their pieces' starts and ends, then their COLUMNS."""

    def __init__(self):
        self.points, self.rows, self.fine_count = [], [], 0

    def add(self, pieces: tuple, index: int, state: int, line: int, era: int) -> None:
        pts, feed, tool, accel, power, dynamic, dwell, (kind, center, radius, plane, angle, sweep, change) = pieces
        count = len(pts) - 1
        self.points.append(pts)
        self.rows.append((count, index, feed, tool, accel, power, dynamic, dwell, kind, center, radius, plane, angle,
                          sweep, change, state, self.fine_count if kind == REF_CURVE else -1, line, era))
        self.fine_count += count if kind == REF_CURVE else 0

    def take(self) -> list[tuple]:
        if not self.rows:
            return []
        stacked = [np.asarray(p, dtype=float).reshape(-1, 4) for p in self.points]
        columns = [np.asarray(c, dtype=t) for c, (_, t, _) in zip(zip(*self.rows), COLUMNS)]
        self.points, self.rows = [], []
        return [(np.concatenate([p[:-1] for p in stacked]), np.concatenate([p[1:] for p in stacked]), *columns)]


def _lines_group(lines: Lines, index: int, state: int, in_gcode: bool, era: int) -> tuple:
    """The group of a Lines item: a piece per move (their lines kept `in_gcode`)."""
    n = len(lines)
    return (lines.points[:-1], lines.points[1:], np.ones(n, dtype=np.int64), np.arange(index, index + n),
            lines.feed, lines.tool, lines.accel, lines.power, lines.dynamic, np.zeros(n), np.full(n, REF_LINE),
            np.zeros((n, 2)), np.zeros(n),
            np.tile(np.array([0, 1]), (n, 1)), np.zeros(n), np.zeros(n), np.zeros(n), np.full(n, state),
            np.full(n, -1),
            lines.line if in_gcode else np.zeros(n, dtype=np.int64), np.full(n, era))


def _segments(groups: list[tuple], limits: _LimitState, fines: list) -> Segments:
    """The groups' pieces as Segments: the items' columns repeated over their pieces."""
    if not groups:
        groups = [(np.zeros((0, 4)), np.zeros((0, 4)), *(np.zeros((0, *shape), dtype=t) for _, t, shape in COLUMNS))]
    (starts, ends, counts, owners, feed, tool, accel, power, dynamic, dwell, kind, center, radius, plane, angle, sweep,
     change, state, fine_rows, line, era) = (np.concatenate(c) for c in zip(*groups))
    each = lambda values: np.repeat(values, counts, axis=0)  # noqa: E731
    rank = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    along = rank / each(counts)  # of the item, where each piece starts
    growth = np.divide(change, sweep, out=np.zeros(len(sweep)), where=sweep != 0.0)
    first_fine = each(fine_rows)
    velocity, axis_accel, jerk, jd, advance = limits.arrays(each(state))
    jerk = np.where((rank > 0)[:, None], np.nan, jerk)  # only where a move starts: chords carry on smoothly
    return Segments(
        start=starts, end=ends, feed=each(feed), tool=each(tool), power=each(power), dynamic=each(dynamic),
        dwell=each(dwell), item=each(owners), line=each(line),
        accel=each(accel), axis_velocity=velocity.reshape(-1, 4), axis_accel=axis_accel.reshape(-1, 4),
        jerk=jerk.reshape(-1, 4), junction_deviation=jd, advance=advance, shaping=each(era), ref_kind=each(kind),
        ref_center=each(center).reshape(-1, 2),
        ref_radius=each(radius) + each(change) * along, ref_angle=each(angle) + each(sweep) * along,
        ref_growth=each(growth), ref_plane=each(plane).reshape(-1, 2),
        ref_fine=np.where(first_fine >= 0, first_fine + rank, -1),
        fine=np.concatenate(fines) if fines else np.zeros((0, FINE_STEPS + 1, 3)),
    )

"""Segments: the toolpath flattened into straight pieces (and dwells), as arrays: the planner's input.

Arcs become equal chords within the machine's tolerance; curves arrive as chords already. Each piece keeps
what the checks need to measure against the exact path (arc centre and radius, or samples of the true curve)
and the limits the program set for it (G-code M201/M203/M204/M205).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from codegen.toolpath import FINE_STEPS, Arc, Curve, Dwell, Limits, Line, Toolpath

REF_LINE, REF_ARC, REF_CURVE = 0, 1, 2
AXIS = {"x": 0, "y": 1, "z": 2, "e": 3}


@dataclass
class Segments:
    start: np.ndarray  # (n, 4) mm
    end: np.ndarray  # (n, 4) mm
    feed: np.ndarray  # (n,) mm/s, inf = unlimited
    tool: np.ndarray  # (n,) bool
    dwell: np.ndarray  # (n,) s; > 0 marks a dwell (start == end)
    item: np.ndarray  # (n,) index of the toolpath item the piece comes from
    accel: np.ndarray  # (n,) mm/s^2, the program's cap on the path acceleration (inf: none)
    axis_velocity: np.ndarray  # (n, 4) mm/s per axis the program allows (inf: no limit of its own)
    axis_accel: np.ndarray  # (n, 4) mm/s^2 per axis the program allows
    jerk: np.ndarray  # (n, 4) mm/s per axis, Marlin's classic jerk at the piece's start (nan: not set)
    junction_deviation: np.ndarray  # (n,) mm the program set (nan: the machine's)
    ref_kind: np.ndarray  # (n,) REF_LINE | REF_ARC | REF_CURVE
    ref_center: np.ndarray  # (n, 2) arc centre in its plane
    ref_radius: np.ndarray  # (n,)
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
    """Fewest equal chords whose sagitta stays within `tolerance`."""
    if radius <= tolerance:
        return max(1, math.ceil(abs(sweep) / (math.pi / 2)))
    max_angle = 2.0 * math.acos(1.0 - tolerance / radius)
    return max(1, math.ceil(abs(sweep) / max_angle - 1e-9))


class _LimitState:
    """The program's limits as they stand, snapshotted once per change."""

    def __init__(self):
        self.rows = [(np.full(4, np.inf), np.full(4, np.inf), np.full(4, np.nan), np.nan)]

    def apply(self, item: Limits) -> None:
        velocity, accel, jerk, jd = (np.array(a, copy=True) if isinstance(a, np.ndarray) else a
                                     for a in self.rows[-1])
        for target, values in ((velocity, item.max_velocity), (accel, item.max_accel), (jerk, item.jerk)):
            for axis, value in (values or {}).items():
                target[AXIS[axis]] = value
        if item.junction_deviation is not None:
            jd = item.junction_deviation
        self.rows.append((velocity, accel, jerk, jd))

    def arrays(self, index: np.ndarray) -> tuple[np.ndarray, ...]:
        velocity, accel, jerk = (np.array([r[k] for r in self.rows])[index] for k in range(3))
        return velocity, accel, jerk, np.array([r[3] for r in self.rows])[index]


def flatten(toolpath: Toolpath, tolerance: float) -> Segments:
    """Every motion item as straight pieces, in order; Limits items apply to the pieces after them."""
    return Flattener(toolpath.start, tolerance)(toolpath.items)


class Flattener:
    """`flatten` a batch of items at a time: the limits in force and the position carry over, and each piece's
    `item` counts the items of every batch before."""

    def __init__(self, start: np.ndarray, tolerance: float):
        self.tolerance = tolerance
        self.limits = _LimitState()
        self.position = np.asarray(start, dtype=float)
        self.items = 0

    def __call__(self, batch: list) -> Segments:
        points, counts, owners = [], [], []
        feed, tool, accel, dwell, kind, center, radius, plane, state, fine_rows, fines = ([] for _ in range(11))
        limits = self.limits
        limits.rows = limits.rows[-1:]  # the limits in force; earlier ones are gone with their batches
        position, tolerance, first = self.position, self.tolerance, self.items
        fine_count = 0
        for index, item in enumerate(batch, first):
            if isinstance(item, Limits):
                limits.apply(item)
                continue
            if isinstance(item, Line):
                pts = (item.start, item.end)
                ref = (REF_LINE, (0.0, 0.0), 0.0, (0, 1))
            elif isinstance(item, Arc):
                n = arc_chord_count(item.radius, item.sweep, tolerance)
                pts = item.points(item.start_angle + item.sweep * np.arange(n + 1) / n)
                pts[0], pts[-1] = item.start, item.end
                ref = (REF_ARC, item.center, item.radius, item.plane)
            elif isinstance(item, Curve):
                pts = item.points
                ref = (REF_CURVE, (0.0, 0.0), 0.0, (0, 1))
                fines.append(item.fine)
            elif isinstance(item, Dwell):
                pts = (position, position)
                ref = (REF_LINE, (0.0, 0.0), 0.0, (0, 1))
            else:
                continue  # Output, Home: nothing to move along
            pieces = len(pts) - 1
            points.append(pts)
            counts.append(pieces)
            owners.append(index)
            moving = not isinstance(item, Dwell)
            feed.append(item.feed if moving else math.inf)
            tool.append(item.tool if moving else False)
            accel.append(getattr(item, "accel", math.inf))
            dwell.append(0.0 if moving else item.seconds)
            kind.append(ref[0]), center.append(ref[1]), radius.append(ref[2]), plane.append(ref[3])
            state.append(len(limits.rows) - 1)
            fine_rows.append(fine_count if ref[0] == REF_CURVE else -1)
            fine_count += pieces if ref[0] == REF_CURVE else 0
            position = pts[-1]
        self.position, self.items = position, first + len(batch)
        counts_a = np.asarray(counts, dtype=np.int64)
        each = lambda values, dtype=float: np.repeat(np.asarray(values, dtype=dtype), counts_a, axis=0)  # noqa: E731
        stacked = [np.asarray(p, dtype=float).reshape(-1, 4) for p in points]
        starts = np.concatenate([p[:-1] for p in stacked]) if stacked else np.zeros((0, 4))
        ends = np.concatenate([p[1:] for p in stacked]) if stacked else np.zeros((0, 4))
        rank = np.arange(int(counts_a.sum())) - np.repeat(np.cumsum(counts_a) - counts_a, counts_a)
        first_fine = each(fine_rows, np.int64)
        velocity, axis_accel, jerk, jd = limits.arrays(each(state, np.int64))
        jerk = np.where((rank > 0)[:, None], np.nan, jerk)  # only where a move starts: chords carry on smoothly
        return Segments(
            start=starts, end=ends, feed=each(feed), tool=each(tool, bool), dwell=each(dwell),
            item=each(owners, np.int64), accel=each(accel), axis_velocity=velocity.reshape(-1, 4),
            axis_accel=axis_accel.reshape(-1, 4), jerk=jerk.reshape(-1, 4), junction_deviation=jd,
            ref_kind=each(kind, np.int64), ref_center=each(center).reshape(-1, 2), ref_radius=each(radius),
            ref_plane=each(plane, np.int64).reshape(-1, 2),
            ref_fine=np.where(first_fine >= 0, first_fine + rank, -1),
            fine=np.concatenate(fines) if fines else np.zeros((0, FINE_STEPS + 1, 3)),
        )

"""Toolpath: ordered primitives in machine millimetres, and their flattening into straight segments.

Coordinates are 4-vectors of axis positions [x, y, z, e] in mm. Feeds are mm/s (math.inf: as fast as the
machine allows). Curves keep their exact geometry here; `flatten` turns them into chords within the machine's
tolerance and remembers, per chord, the exact reference the checks measure against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from codegen.errors import SourceRef

AXES = ("x", "y", "z", "e")

REF_LINE, REF_ARC, REF_CURVE = 0, 1, 2
FINE_STEPS = 16  # samples of the true curve per chord, for measuring the distance to it


@dataclass(frozen=True)
class Line:
    start: np.ndarray
    end: np.ndarray
    feed: float
    tool: bool
    source: SourceRef
    label: str = "line"


@dataclass(frozen=True)
class Arc:
    """A circular arc in the plane of axes (u, v) (0=x, 1=y, 2=z), optionally helical along the other axes."""

    start: np.ndarray
    end: np.ndarray
    center: tuple[float, float]
    radius: float
    start_angle: float  # radians, in the (u, v) plane
    sweep: float  # radians, positive counter-clockwise
    feed: float
    tool: bool
    source: SourceRef
    plane: tuple[int, int] = (0, 1)
    label: str = "arc"

    def points(self, angles: np.ndarray) -> np.ndarray:
        """Points at the given angles; the axes outside the plane move linearly with the angle."""
        u, v = self.plane
        frac = (angles - self.start_angle) / self.sweep if self.sweep else np.zeros_like(angles)
        pts = self.start[None, :] + frac[:, None] * (self.end - self.start)[None, :]
        pts[:, u] = self.center[0] + self.radius * np.cos(angles)
        pts[:, v] = self.center[1] + self.radius * np.sin(angles)
        return pts


@dataclass(frozen=True)
class Curve:
    """A smooth curve already cut into chords whose deviation from the curve is at most `deviation` mm.

    `fine` holds the true curve sampled FINE_STEPS + 1 times along every chord's parameter interval: the
    checks measure the tool's distance to the curve on it, not on the chords."""

    points: np.ndarray  # (n, 4), n >= 2
    deviation: float
    feed: float
    tool: bool
    source: SourceRef
    fine: np.ndarray  # (n - 1, FINE_STEPS + 1, 3)
    label: str = "curve"

    @property
    def start(self) -> np.ndarray:
        return self.points[0]

    @property
    def end(self) -> np.ndarray:
        return self.points[-1]


@dataclass(frozen=True)
class Dwell:
    seconds: float
    source: SourceRef
    label: str = "dwell"


Move = Line | Arc | Curve
Item = Line | Arc | Curve | Dwell


@dataclass
class Toolpath:
    start: np.ndarray  # where the tool is when the program starts
    items: list[Item] = field(default_factory=list)

    def end(self) -> np.ndarray:
        for item in reversed(self.items):
            if not isinstance(item, Dwell):
                return item.end
        return self.start


@dataclass
class Segments:
    """Straight pieces (or dwells) in program order, as arrays; the planner's and the checks' input."""

    start: np.ndarray  # (n, 4) mm
    end: np.ndarray  # (n, 4) mm
    feed: np.ndarray  # (n,) mm/s, inf = unlimited
    tool: np.ndarray  # (n,) bool
    dwell: np.ndarray  # (n,) s; > 0 marks a dwell (start == end)
    item: np.ndarray  # (n,) index of the toolpath item the piece comes from
    ref_kind: np.ndarray  # (n,) REF_LINE | REF_ARC | REF_CURVE
    ref_center: np.ndarray  # (n, 2) arc centre in its plane
    ref_radius: np.ndarray  # (n,)
    ref_plane: np.ndarray  # (n, 2) int axes of the arc plane
    ref_deviation: np.ndarray  # (n,) mm, largest chord deviation from the true curve (REF_CURVE)
    ref_fine: np.ndarray  # (n,) row of `fine` holding the true curve along the chord, -1 for none
    fine: np.ndarray  # (k, FINE_STEPS + 1, 3) true-curve samples

    def __len__(self) -> int:
        return len(self.feed)

    def take(self, index: np.ndarray, **replace) -> "Segments":
        """The segments at `index` (the shared `fine` samples stay as they are), with fields replaced."""
        fields = {name: getattr(self, name)[index] for name in self.__dataclass_fields__ if name != "fine"}
        fields.update(fine=self.fine, **replace)
        return Segments(**fields)


def arc_chord_count(radius: float, sweep: float, tolerance: float) -> int:
    """Fewest equal chords whose sagitta stays within `tolerance`."""
    if radius <= tolerance:
        return max(1, math.ceil(abs(sweep) / (math.pi / 2)))
    max_angle = 2.0 * math.acos(1.0 - tolerance / radius)
    return max(1, math.ceil(abs(sweep) / max_angle - 1e-9))


def flatten(toolpath: Toolpath, tolerance: float) -> Segments:
    starts, ends, feeds, tools, dwells, items = [], [], [], [], [], []
    kinds, centers, radii, planes, devs, fine_rows, fines = [], [], [], [], [], [], []
    fine_count = 0
    position = np.asarray(toolpath.start, dtype=float)
    for index, item in enumerate(toolpath.items):
        if isinstance(item, Dwell):
            starts.append(position[None, :])
            ends.append(position[None, :])
            pieces = 1
            feeds.append([math.inf])
            tools.append([False])
            dwells.append([item.seconds])
            fine_rows.append([-1])
            kind, center, radius, plane, dev = REF_LINE, (0.0, 0.0), 0.0, (0, 1), 0.0
        else:
            if isinstance(item, Line):
                pts = np.stack([item.start, item.end])
                kind, center, radius, plane, dev = REF_LINE, (0.0, 0.0), 0.0, (0, 1), 0.0
            elif isinstance(item, Arc):
                n = arc_chord_count(item.radius, item.sweep, tolerance)
                angles = item.start_angle + item.sweep * np.arange(n + 1) / n
                pts = item.points(angles)
                pts[0], pts[-1] = item.start, item.end
                kind, center, radius, plane, dev = REF_ARC, item.center, item.radius, item.plane, 0.0
            else:
                pts = item.points
                kind, center, radius, plane, dev = REF_CURVE, (0.0, 0.0), 0.0, (0, 1), item.deviation
            pieces = len(pts) - 1
            if kind == REF_CURVE:
                fines.append(item.fine)
                fine_rows.append(fine_count + np.arange(pieces))
                fine_count += pieces
            else:
                fine_rows.append(np.full(pieces, -1))
            starts.append(pts[:-1])
            ends.append(pts[1:])
            feeds.append(np.full(pieces, item.feed))
            tools.append(np.full(pieces, item.tool))
            dwells.append(np.zeros(pieces))
            position = item.end
        items.append(np.full(pieces, index))
        kinds.append(np.full(pieces, kind))
        centers.append(np.tile(np.asarray(center, float), (pieces, 1)))
        radii.append(np.full(pieces, radius))
        planes.append(np.tile(np.asarray(plane, int), (pieces, 1)))
        devs.append(np.full(pieces, dev))
    if not starts:
        empty = np.zeros((0, 4))
        return Segments(empty, empty, np.zeros(0), np.zeros(0, bool), np.zeros(0), np.zeros(0, int),
                        np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2), int), np.zeros(0),
                        np.zeros(0, int), np.zeros((0, FINE_STEPS + 1, 3)))
    return Segments(
        start=np.concatenate(starts).astype(float),
        end=np.concatenate(ends).astype(float),
        feed=np.concatenate(feeds).astype(float),
        tool=np.concatenate(tools).astype(bool),
        dwell=np.concatenate(dwells).astype(float),
        item=np.concatenate(items).astype(int),
        ref_kind=np.concatenate(kinds).astype(int),
        ref_center=np.concatenate(centers).astype(float),
        ref_radius=np.concatenate(radii).astype(float),
        ref_plane=np.concatenate(planes).astype(int),
        ref_deviation=np.concatenate(devs).astype(float),
        ref_fine=np.concatenate(fine_rows).astype(int),
        fine=np.concatenate(fines) if fines else np.zeros((0, FINE_STEPS + 1, 3)),
    )

"""Toolpath: ordered primitives in machine millimetres (the front ends' output: shapes, G-code).

Coordinates are 4-vectors of axis positions [x, y, z, e] in mm. Feeds are mm/s (math.inf: as fast as the
machine allows). Curves keep their exact geometry here; codegen/toolpath/segments.py cuts them into chords.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from codegen.errors import SourceRef

AXES = ("x", "y", "z", "e")

FINE_STEPS = 16  # samples of the true curve per chord, for measuring the distance to it


@dataclass(frozen=True)
class Line:
    start: np.ndarray
    end: np.ndarray
    feed: float
    tool: bool
    source: SourceRef
    label: str = "line"
    accel: float = math.inf  # mm/s^2: the program's own cap on this move's acceleration (G-code M204)
    power: float = 1.0  # tool power while the tool is on, 0..1 (G-code S over its full scale)
    dynamic: bool = False  # M4: the power scales with the actual speed over the programmed one (Grbl's laser mode)


@dataclass(frozen=True, eq=False)
class Lines:
    """Straight moves one after another, as arrays (G-code's G0/G1 lines): move k goes from points[k] to
    points[k + 1]. It stands for the Line items `lines()` gives and counts as that many items."""

    points: np.ndarray  # (n + 1, 4), read-only
    feed: np.ndarray  # (n,)
    tool: np.ndarray  # (n,) bool
    rapid: np.ndarray  # (n,) bool: G0 (else G1, the moves' label)
    accel: np.ndarray  # (n,)
    power: np.ndarray  # (n,)
    dynamic: np.ndarray  # (n,) bool
    file: str
    line: np.ndarray  # (n,) where each move is written
    col: np.ndarray  # (n,)

    def __len__(self) -> int:
        return len(self.feed)

    @property
    def start(self) -> np.ndarray:
        return self.points[0]

    @property
    def end(self) -> np.ndarray:
        return self.points[-1]

    def source(self, k: int) -> SourceRef:
        return SourceRef(self.file, int(self.line[k]), int(self.col[k]))

    def lines(self) -> list[Line]:
        rows, columns = list(self.points), (self.feed, self.tool, self.rapid, self.accel, self.power, self.dynamic,
                                            self.line, self.col)
        return [Line(rows[k], rows[k + 1], feed, tool, SourceRef(self.file, line, col), "G0" if rapid else "G1",
                     accel, power, dynamic)
                for k, (feed, tool, rapid, accel, power, dynamic, line, col)
                in enumerate(zip(*(c.tolist() for c in columns)))]

    def split_first(self) -> list:
        """The first move as a Line, then the others (if any)."""
        return self._part(0, 1).lines() + ([self._part(1, len(self))] if len(self) > 1 else [])

    def _part(self, lo: int, hi: int) -> "Lines":
        return replace(self, points=self.points[lo:hi + 1], **{name: getattr(self, name)[lo:hi] for name in _PER_MOVE})


_PER_MOVE = ("feed", "tool", "rapid", "accel", "power", "dynamic", "line", "col")


def expanded(items: list) -> list:
    """The items with every Lines as its Line items."""
    return [one for item in items for one in (item.lines() if isinstance(item, Lines) else (item,))]


@dataclass(frozen=True)
class Arc:
    """A circular arc in the plane of axes (u, v) (0=x, 1=y, 2=z), optionally helical along the other axes.

    A G-code arc whose end is a little off the circle of its start (within Grbl's limits, codegen/gcode/arcs.py)
    is a spiral: its radius goes evenly with the angle from `radius` at the start to `radius + radius_change` at
    the end, so the path reaches the program's end without a jog (LinuxCNC's reading)."""

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
    accel: float = math.inf
    power: float = 1.0
    dynamic: bool = False
    radius_change: float = 0.0  # mm, the end's radius less the start's

    def points(self, angles: np.ndarray) -> np.ndarray:
        """Points at the given angles; the radius and the axes outside the plane move linearly with the angle."""
        u, v = self.plane
        frac = (angles - self.start_angle) / self.sweep if self.sweep else np.zeros_like(angles)
        pts = self.start[None, :] + frac[:, None] * (self.end - self.start)[None, :]
        radius = self.radius + self.radius_change * frac
        pts[:, u] = self.center[0] + radius * np.cos(angles)
        pts[:, v] = self.center[1] + radius * np.sin(angles)
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


@dataclass(frozen=True)
class Limits:
    """Machine limits the program sets from here on (G-code M201/M203/M205); the planner keeps the smaller
    of these and the machine's own. Axis names x, y, z, e; None: unchanged. And the extruder's pressure advance K
    from here on (M900, M572: codegen/motion/advance.py)."""

    source: SourceRef
    max_velocity: dict[str, float] | None = None  # mm/s per axis (M203)
    max_accel: dict[str, float] | None = None  # mm/s^2 per axis (M201)
    jerk: dict[str, float] | None = None  # mm/s per axis, Marlin's classic jerk (M205 X Y Z E)
    junction_deviation: float | None = None  # mm (M205 J)
    advance: float | None = None  # s, pressure advance K (M900 K, M572 S)


@dataclass(frozen=True)
class Home:
    """The named axes go to their home position (G28); the motion is the firmware's homing."""

    axes: tuple[str, ...]
    position: np.ndarray  # where the tool is afterwards (4-vector)
    source: SourceRef


@dataclass(frozen=True)
class Output:
    """A setting of an auxiliary output: fan speed 0..1 (M106/M107), or a heater's target in degrees C
    (M104/M109 hot end, M140/M190 bed; `wait`: the program waits until it is reached); or a program pause
    (M0/M1: `pause`, the program waits for the resume key)."""

    name: str  # fan | hotend | bed | pause
    value: float
    wait: bool
    source: SourceRef


ShaperSpec = tuple[str, float, float]  # an axis's shaper: Klipper's type name, frequency (Hz), damping ratio


@dataclass(frozen=True)
class InputShaping:
    """The axes' input shapers from here on (G-code M593), each x, y, z a ShaperSpec or None (unshaped), and the
    ones before. The machine comes to rest first, and the motion shaped before settles there
    (codegen/toolpath/segments.py)."""

    shapers: tuple[ShaperSpec | None, ...]  # x, y, z
    before: tuple[ShaperSpec | None, ...]
    source: SourceRef


Move = Line | Lines | Arc | Curve
Item = Line | Lines | Arc | Curve | Dwell | Limits | Home | Output | InputShaping


@dataclass
class Toolpath:
    start: np.ndarray  # where the tool is when the program starts
    items: list[Item] = field(default_factory=list)

    def end(self) -> np.ndarray:
        for item in reversed(self.items):
            if isinstance(item, (Line, Lines, Arc, Curve)):
                return item.end
        return self.start

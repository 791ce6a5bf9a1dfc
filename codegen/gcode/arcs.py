"""G2/G3 geometry: the centre from I/J/K offsets or from R, with Grbl's checks, and the signed sweep.

Everything here is in the arc plane's own coordinates (u, v): G17 (x, y), G18 (z, x), G19 (y, z), so
"counter-clockwise" is the plane's positive orientation and G3 sweeps are positive, G2 sweeps negative.
Grbl's rules (gcode.c, motion_control.c):
- I/J/K form: the centre is the start plus the offsets. The end must lie on the same circle: a difference
  of the two radii over 0.005 mm is an error when it is also over 0.5 mm or over 0.1 % of the radius.
  An end equal to the start is a full circle (sweep +-2 pi). An end off the circle by less is drawn as a
  spiral, the radius going evenly with the angle from the start's to the end's (LinuxCNC's reading): Grbl and
  Marlin keep the start's radius and close the gap on their last segment, a jog of up to 0.5 mm where the
  program draws none.
- R form: the centre is on the side that makes the arc shorter than half a turn for R > 0, longer for
  R < 0. An R smaller than half the chord is an error, and so is an end equal to the start. Unlike Grbl,
  an R short of half the chord by no more than the radius slack (0.005 mm, numbers rounded by the program's
  writer) is taken as the half circle on the chord, as Marlin does for any R.
- Length: at most LONGEST_ARC_MM (codegen/toolpath/limits.py), whatever the radius: R < 0 on a huge circle is
  the long way round it.
- Sweep: atan2 of the start and end directions, taken the long way round when its sign disagrees with the
  direction (within 5e-7 rad, so an end at the start is a whole turn).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from codegen.toolpath.limits import arc_error

RADIUS_SLACK = 0.005  # mm: radii differing by no more than this always pass
RADIUS_ERROR = 0.5  # mm
RADIUS_SHARE = 0.001  # of the radius (0.1 %)
LARGEST_RADIUS_MM = 1e5  # 100 m: beyond any machine (ArcWelder writes 9,999 mm at most)
ANGLE_EPSILON = 5e-7  # rad, Grbl's ARC_ANGULAR_TRAVEL_EPSILON


class ArcError(Exception):
    """A G2/G3 that defines no arc; `letter` names the word the message is about."""

    def __init__(self, message: str, letter: str):
        super().__init__(message)
        self.message = message
        self.letter = letter


class Circle(NamedTuple):
    center: tuple[float, float]  # (u, v)
    radius: float  # mm, from the centre to the start
    start_angle: float  # rad, from the centre to the start
    sweep: float  # rad, > 0 counter-clockwise (G3), < 0 clockwise (G2)
    radius_change: float = 0.0  # mm, from the centre to the end less `radius`: a spiral


def mm(value: float) -> str:
    """A length for messages: up to 4 decimals, no trailing zeros."""
    text = f"{value:.4f}".rstrip("0").rstrip(".")
    return "0" if text == "-0" else text


def sweep_between(center: tuple[float, float], start: tuple[float, float], end: tuple[float, float],
                  clockwise: bool) -> float:
    su, sv = start[0] - center[0], start[1] - center[1]
    eu, ev = end[0] - center[0], end[1] - center[1]
    angle = math.atan2(su * ev - sv * eu, su * eu + sv * ev)
    if clockwise:
        if angle >= -ANGLE_EPSILON:
            angle -= 2.0 * math.pi
    elif angle <= ANGLE_EPSILON:
        angle += 2.0 * math.pi
    return angle


def _within_largest(radius: float, letter: str) -> None:
    if not radius <= LARGEST_RADIUS_MM:
        raise ArcError(f"arc radius {radius:.6g} mm is beyond the largest an arc may have, {LARGEST_RADIUS_MM:g} mm "
                       f"(so large an arc is a straight line to the planner's precision: write G1)", letter)


def too_long(circle: Circle, length: float, long_way: bool) -> str | None:
    """Why an arc of `length` mm (its helix's) is longer than a move may draw, or None."""
    message = arc_error(length)
    if message is None or not long_way:
        return message
    return f"{message} (R < 0 goes the long way round a circle of {mm(circle.radius)} mm radius)"


def from_offsets(start: tuple[float, float], end: tuple[float, float], offset: tuple[float, float],
                 clockwise: bool, letters: tuple[str, str]) -> Circle:
    """I/J/K form: `offset` is the centre relative to the start (in mm); `letters` the offset words."""
    center = (start[0] + offset[0], start[1] + offset[1])
    r_start = math.hypot(offset[0], offset[1])
    r_end = math.hypot(end[0] - center[0], end[1] - center[1])
    if r_start == 0.0:
        raise ArcError(f"arc radius is 0: {letters[0]} and {letters[1]} put the centre at the start", letters[0])
    _within_largest(r_start, letters[0])
    delta = abs(r_end - r_start)
    if delta > RADIUS_SLACK and (delta > RADIUS_ERROR or delta > RADIUS_SHARE * r_start):
        raise ArcError(f"arc end is not on the circle: radius {mm(r_start)} mm at the start, {mm(r_end)} mm "
                       f"at the end (a difference of {mm(delta)} mm; at most 0.005 mm, or 0.5 mm and 0.1 % "
                       f"of the radius)", letters[0])
    start_angle = math.atan2(start[1] - center[1], start[0] - center[0])
    return Circle(center, r_start, start_angle, sweep_between(center, start, end, clockwise), r_end - r_start)


def from_radius(start: tuple[float, float], end: tuple[float, float], r: float, clockwise: bool) -> Circle:
    """R form (r in mm, negative for the long way round)."""
    x, y = end[0] - start[0], end[1] - start[1]
    if x == 0.0 and y == 0.0:
        raise ArcError("an R arc cannot end where it starts; give the centre with I/J/K for a full circle", "R")
    chord = math.hypot(x, y)
    _within_largest(abs(r), "R")
    h_x2_div_d = 4.0 * r * r - x * x - y * y
    if h_x2_div_d < 0.0:
        if chord / 2.0 - abs(r) > RADIUS_SLACK:
            raise ArcError(f"arc radius {mm(abs(r))} mm is too small for the chord of {mm(chord)} mm "
                           f"(at least {mm(chord / 2.0)} mm)", "R")
        h_x2_div_d = 0.0  # short by no more than the slack (rounded numbers): the half circle on the chord
    h_x2_div_d = -math.sqrt(h_x2_div_d) / chord
    if not clockwise:
        h_x2_div_d = -h_x2_div_d
    if r < 0.0:
        h_x2_div_d = -h_x2_div_d
    center = (start[0] + 0.5 * (x - y * h_x2_div_d), start[1] + 0.5 * (y + x * h_x2_div_d))
    radius = math.hypot(start[0] - center[0], start[1] - center[1])
    start_angle = math.atan2(start[1] - center[1], start[0] - center[0])
    return Circle(center, radius, start_angle, sweep_between(center, start, end, clockwise))

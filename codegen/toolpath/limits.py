"""The numbers a toolpath may hold: how far from the origin a point may be, how long a move, a dwell or an arc.

A number beyond these would overflow what the later stages hold (the firmware's int32 positions in steps, the
tables' rate runs) or make the host's work grow with the number instead of the job's real steps: the front
ends (codegen/gcode/, codegen/shapes/) refuse such a number where it is written, naming the limit.
"""

from __future__ import annotations

import math

import numpy as np

from codegen.job.schema.fields import REACH_MM

POSITION_STEPS = 2**31 - 1  # the firmware's positions in steps are int32
LONGEST_MOVE_S = 86_400.0  # a day: no real move is slower; the host plans (and the twin plays) every event of it
LONGEST_DWELL_S = 86_400.0  # a day: a dwell is planned as events of the longest interval, so its length costs
LONGEST_ARC_MM = 1e5  # 100 m of arc: no further than across the reach (R < 0 on a huge circle goes the long way)
_UNITS = (("year", 365.25 * 86_400.0), ("day", 86_400.0), ("hour", 3_600.0), ("minute", 60.0))


def duration(seconds: float) -> str:
    """A time for messages in the largest unit it reaches: '13.4 years', '1 day', '12 s'."""
    if not math.isfinite(seconds):
        return "forever"
    for name, size in _UNITS:
        if seconds >= size:
            count = f"{seconds / size:.3g}"
            return f"{count} {name}" if count == "1" else f"{count} {name}s"
    return f"{seconds:.3g} s"


def axis_reach(machine) -> list[float]:
    """How far (mm) each axis [x, y, z, e] may go from the origin: REACH_MM, and no further than an int32 count of
    its motor's steps (corexy's a and b add x and y, a delta's carriages follow z plus a rod at most)."""
    steppers, kinematics = machine.steppers, machine.kinematics
    fine = {name: POSITION_STEPS / float(s.steps_per_mm) for name, s in steppers.items()}
    if kinematics == "cartesian":
        xyz = [fine.get(name, REACH_MM) for name in "xyz"]
    elif kinematics == "corexy":
        shared = min(fine["a"], fine["b"]) / 2.0
        xyz = [shared, shared, fine.get("z", REACH_MM)]
    else:
        carriage = min(fine["a"], fine["b"], fine["c"]) - float(machine.delta.diagonal_rod)
        xyz = [max(carriage, 0.0)] * 3
    return [min(REACH_MM, r) for r in xyz] + [fine.get("e", math.inf)]


def reach_error(axis: int, value: float, reach: list[float]) -> str | None:
    """Why the position `value` (mm) of axis `axis` (0..3: x, y, z, e) is out of reach, or None."""
    if abs(value) <= reach[axis]:  # False for nan too
        return None
    why = "from the origin" if reach[axis] == REACH_MM else "(its motor counts its position in int32 steps)"
    return f"{'xyze'[axis]} = {value:.6g} mm is beyond the reach of {reach[axis]:.6g} mm {why}"


def move_error(length: float, speed: float) -> str | None:
    """Why a move of `length` (mm) at `speed` (mm/s) is too long, or None (before the machine's limits)."""
    seconds = length / speed
    if seconds <= LONGEST_MOVE_S:
        return None
    return (f"makes this move last {duration(seconds)}; the slowest move the tables hold lasts "
            f"{duration(LONGEST_MOVE_S)} (here at least {length / LONGEST_MOVE_S * 60.0:.3g} mm/min)")


def dwell_error(seconds: float) -> str | None:
    if seconds <= LONGEST_DWELL_S:
        return None
    return f"a dwell of {duration(seconds)}; the longest dwell the tables hold is {duration(LONGEST_DWELL_S)}"


def arc_error(length: float) -> str | None:
    if length <= LONGEST_ARC_MM:
        return None
    return f"this arc is {length:.6g} mm long; the longest arc a move may draw is {LONGEST_ARC_MM:g} mm"


def items_errors(items: list, reach: list[float]) -> list[str]:
    """Why a shape's items (Line, Arc, Curve) go beyond these limits: each reason once, in the items' order."""
    found: dict[str, None] = {}
    for item in items:
        points = item.points if hasattr(item, "fine") else np.array([item.start, item.end])
        extent = np.abs(points).max(axis=0)
        if hasattr(item, "radius"):  # an arc's bulge: as far as its centre and radius go
            for axis, centre in zip(item.plane, item.center):
                extent[axis] = max(extent[axis], abs(centre) + item.radius)
        beyond = [message for axis in range(4) if (message := reach_error(axis, float(extent[axis]), reach))]
        found.update(dict.fromkeys(beyond))
        if beyond:  # its length and duration are then beside the point
            continue
        if hasattr(item, "radius"):
            length = math.hypot(item.radius * abs(item.sweep), float(np.linalg.norm(item.end - item.start)))
            if (message := arc_error(length)) is not None:
                found[message] = None
        else:
            length = float(np.linalg.norm(np.diff(points[:, :3], axis=0), axis=1).sum())
        if (message := move_error(length, item.feed)) is not None:
            found[f"the feed of {item.feed * 60.0:.6g} mm/min {message}"] = None
    return list(found)

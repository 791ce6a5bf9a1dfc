"""Circular shapes: `arc` and `circle`, kept as exact `Arc` primitives in the XY plane."""

from __future__ import annotations

import math

import numpy as np

from codegen.shapes.context import Pen, within_a_turn
from codegen.toolpath.items import Arc, Item


def arc(shape, pen: Pen) -> list[Item]:
    """From center + radius*(cos start, sin start), turning `sweep` degrees (positive: counter-clockwise)."""
    return _arc(shape, pen, shape.start, shape.sweep)


def circle(shape, pen: Pen) -> list[Item]:
    """A whole turn from `start`, counter-clockwise unless `direction` is cw."""
    return _arc(shape, pen, shape.start, -360.0 if shape.direction == "cw" else 360.0)


def _arc(shape, pen: Pen, start_deg: float, sweep_deg: float) -> list[Item]:
    start_deg = within_a_turn(start_deg)
    cx, cy = float(shape.center[0]), float(shape.center[1])
    r = float(shape.radius)
    z = pen.z(shape)
    a0, sweep = math.radians(start_deg), math.radians(sweep_deg)
    start = np.array([cx + r * math.cos(a0), cy + r * math.sin(a0), z, 0.0])
    if abs(sweep_deg) >= 360.0:
        end = start.copy()  # a whole turn closes exactly
    else:
        a1 = math.radians(start_deg + sweep_deg)
        end = np.array([cx + r * math.cos(a1), cy + r * math.sin(a1), z, 0.0])
    items: list[Item] = pen.travel(shape, start)
    if sweep != 0.0:
        items.append(Arc(start, end, (cx, cy), r, a0, sweep, pen.feed(shape), True, shape.source,
                         label=shape.kind))
    return items

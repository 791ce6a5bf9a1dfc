"""Straight shapes: `line`, `polyline`, `points` (the same: drawn through in order) and `travel` (tool off)."""

from __future__ import annotations

from codegen.shapes.context import Pen
from codegen.toolpath.items import Item


def line(shape, pen: Pen) -> list[Item]:
    """From `from` (travelling there first) or the current point, to `to`."""
    if shape.from_ is None:
        start = pen.position.copy()
        start[2] = pen.z(shape)
    else:
        start = pen.point(shape, shape.from_)
    return pen.travel(shape, start) + pen.line(shape, start, _next_point(pen, shape, shape.to, start))


def polyline(shape, pen: Pen) -> list[Item]:
    """`polyline` and `points`: travel to the first point, then draw through the others in order."""
    first = pen.point(shape, shape.points[0])
    items: list[Item] = pen.travel(shape, first)
    here = first
    for p in shape.points[1:]:
        there = _next_point(pen, shape, p, here)
        items += pen.line(shape, here, there)
        here = there
    return items


def travel(shape, pen: Pen) -> list[Item]:
    """A straight tool-off move at the shape's own feed, else the program's travel feed."""
    target = _next_point(pen, shape, shape.to, pen.position)
    return pen.travel(shape, target, None if shape.feed is None else shape.feed / 60.0)


def _next_point(pen: Pen, shape, p, previous):
    """A point after `previous`: with two numbers it keeps the shape's `z`, else the height it is at."""
    return pen.point(shape, p, previous[2] if shape.z is None else None)

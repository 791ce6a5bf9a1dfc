"""Random shapes for the property tests: every kind of JOB-FORMAT.md (line, polyline, points, arc, circle, ellipse,
sine, function with a random expression of the expression language, travel), 3-D points and `z:` on 3-axis
machines, per-shape feeds; and the points in a machine's box the G-code generator uses too."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from tests.jobgen.machines import Box, mixed, num, point


@st.composite
def points(draw, box: Box, n=1, full=False):
    """n points in the box; on a 3-axis machine some with their height, with `full` all of them."""
    out = []
    for _ in range(n):
        p = [box.coord(draw, 0), box.coord(draw, 1)]
        if full or (box.three and draw(st.booleans())):
            p.append(box.coord(draw, 2))
        out.append(p)
    return out


UNARY = ("sin", "cos", "tan", "asin", "acos", "atan", "sqrt", "exp", "log", "abs")


@st.composite
def expressions(draw, depth=3):
    """A random expression of the `function` language (JOB-FORMAT.md): numbers, x, pi, e, + - * / **, unary
    minus, parentheses and the ten functions."""
    if depth == 0 or draw(st.integers(0, 3)) == 0:
        leaf = draw(st.sampled_from(["x", "x", "x", "n", "pi", "e", "xs"]))
        if leaf == "n":
            return num(draw(st.floats(0.1, 10)), 3)
        if leaf == "xs":
            return f"x / {num(draw(st.floats(2, 40)), 3)}"
        return leaf
    form = draw(st.sampled_from(["fn", "fn", "bin", "bin", "neg", "pow", "par"]))
    if form == "fn":
        return f"{draw(st.sampled_from(UNARY))}({draw(expressions(depth - 1))})"
    if form == "neg":
        return f"-{draw(expressions(depth - 1))}"
    if form == "pow":
        return f"({draw(expressions(depth - 1))}) ** {draw(st.sampled_from(['2', '3', '0.5', '-1', '1.5']))}"
    if form == "par":
        return f"({draw(expressions(depth - 1))})"
    op = draw(st.sampled_from(["+", "-", "*", "/"]))
    return f"{draw(expressions(depth - 1))} {op} {draw(expressions(depth - 1))}"


def _scaled(expression: str, span: float, height: float) -> str:
    """The expression, scaled down when it would leave the box by far (the scale is part of the language)."""
    from codegen.job.expr import parse

    try:
        y = parse(expression).evaluate(np.linspace(0.0, span, 257))
    except Exception:  # noqa: BLE001 - a text the parser refuses is the loader's to report
        return expression
    finite = np.abs(y[np.isfinite(y)])
    peak = float(finite.max()) if finite.size else 0.0
    if peak > height and peak < 1e12:
        return f"{num(height / peak, 3)} * ({expression})"
    return expression


KINDS = ("line", "polyline", "points", "arc", "circle", "ellipse", "sine", "function", "travel")


@st.composite
def shape(draw, box: Box):
    kind = draw(st.sampled_from(KINDS))
    # A delta homes: a 2-D shape is drawn at the current height (the home height at first, where it cannot move
    # sideways), so a delta's shapes mostly carry their height.
    full = box.delta and draw(st.integers(0, 7)) > 0
    z = f", z: {num(box.coord(draw, 2))}" if (full or (box.three and draw(st.booleans()))) else ""
    feed = f", feed: {num(draw(mixed([60, 600, 1500, 6000, 30000], 30, 30000)))}" if draw(st.booleans()) else ""
    if kind in ("line", "travel"):
        (a,) = draw(points(box, full=full))
        start = ""
        if kind == "line" and draw(st.booleans()):
            start = f"from: {point(draw(points(box, full=full))[0])}, "
        return f"- {kind}: {{{start}to: {point(a)}{feed}}}"
    if kind in ("polyline", "points"):
        pts = draw(points(box, n=draw(st.integers(1 if kind == "points" else 2, 5)), full=full))
        if kind == "points":
            return "- points: [" + ", ".join(point(p) for p in pts) + "]"
        return f"- polyline: {{points: [{', '.join(point(p) for p in pts)}]{feed}}}"
    centre = [box.coord(draw, 0), box.coord(draw, 1)]
    room = box.room(centre)
    r = draw(st.floats(0.3, max(0.31, room))) if draw(st.integers(0, 5)) else draw(st.floats(0.01, 0.3))
    if kind == "arc":
        sweep = draw(st.one_of(st.sampled_from([360.0, -360.0, 90.0, -180.0]),
                               st.floats(-360, 360).filter(lambda s: abs(s) > 0.01)))
        return (f"- arc: {{center: {point(centre)}, radius: {num(r)}, start: {num(draw(st.floats(-360, 360)))}, "
                f"sweep: {num(sweep)}{z}{feed}}}")
    if kind == "circle":
        start = f", start: {num(draw(st.floats(-180, 180)))}" if draw(st.booleans()) else ""
        direction = draw(st.sampled_from(["ccw", "cw"]))
        return f"- circle: {{center: {point(centre)}, radius: {num(r)}{start}, direction: {direction}{z}{feed}}}"
    if kind == "ellipse":
        b = max(0.01, draw(st.floats(0.05, 1.0)) * r)
        a, b = (r, b) if draw(st.booleans()) else (b, r)
        rotation, start = draw(st.floats(-180, 180)), draw(st.floats(-180, 180))
        sweep = draw(st.floats(-360, 360).filter(lambda s: abs(s) > 0.5))
        return (f"- ellipse: {{center: {point(centre)}, a: {num(a)}, b: {num(b)}, rotation: {num(rotation)}, "
                f"start: {num(start)}, sweep: {num(sweep)}{z}{feed}}}")
    width = box.hi[0] - box.lo[0]
    height = box.hi[1] - box.lo[1]
    if kind == "sine":
        amplitude = draw(st.floats(-0.4, 0.4)) * height
        length = draw(st.floats(0.5, 0.8 * width)) * draw(st.sampled_from([1, -1]))
        x0 = box.lo[0] + 0.1 * width if length > 0 else box.hi[0] - 0.1 * width
        y0 = 0.5 * (box.lo[1] + box.hi[1])
        omega = draw(mixed([0.1, 0.25, 1.0], 0.01, 3.0)) * draw(st.sampled_from([1, 1, -1]))
        return (f"- sine: {{origin: {point([x0, y0])}, amplitude: {num(amplitude)}, "
                f"omega: {num(omega)}, phase: {num(draw(st.floats(-360, 360)))}, "
                f"length: {num(length)}{z}{feed}}}")
    # function: a random expression, scaled to fit the box's height; x from `a` to `b` (either way round)
    span = draw(st.floats(0.5, 0.7 * width))
    expression = _scaled(draw(expressions()), span, 0.4 * height)
    if draw(st.integers(0, 9)) == 0:
        expression = num(draw(st.floats(-5, 5)))  # `y: 2` is a constant function
    x = [0.0, span] if draw(st.booleans()) else [span, 0.0]
    origin = [box.lo[0] + 0.15 * width, 0.5 * (box.lo[1] + box.hi[1])]
    return f"- function: {{y: \"{expression}\", x: {point(x)}, origin: {point(origin)}{z}{feed}}}"


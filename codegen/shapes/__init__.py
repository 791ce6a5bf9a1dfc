"""Shapes -> Toolpath: each shape of the program becomes exact primitives in machine millimetres.

Lines and arcs stay exact (`Line`, `Arc`); ellipses, sines and functions become `Curve` chords whose distance
from the true curve is proven to be within the machine's tolerance. Before a shape that does not start where
the tool is, a tool-off travel move is inserted. Every shape's errors are reported, each at its source.
"""

from __future__ import annotations

import math

import numpy as np

from codegen.errors import Diagnostic, JobError
from codegen.shapes import arcs, lines
from codegen.shapes.context import Pen
from codegen.shapes.ellipse import ellipse
from codegen.shapes.function import function
from codegen.shapes.sine import sine
from codegen.toolpath.items import Toolpath
from codegen.toolpath.limits import axis_reach, items_errors

BUILDERS = {
    "line": lines.line,
    "polyline": lines.polyline,
    "points": lines.polyline,
    "travel": lines.travel,
    "arc": arcs.arc,
    "circle": arcs.circle,
    "ellipse": ellipse,
    "sine": sine,
    "function": function,
}

__all__ = ["build_toolpath", "BUILDERS"]


def build_toolpath(job) -> Toolpath:
    """The job's shape program as a Toolpath; raises JobError with every shape's diagnostics."""
    machine, program = job.machine, job.program
    start = np.zeros(4)
    start[: len(program.start)] = [float(v) for v in program.start]
    pen = Pen(
        position=start.copy(),
        tolerance=float(machine.tolerance),
        draw_feed=float(program.feed) / 60.0,
        travel_feed=math.inf if program.travel_feed is None else float(program.travel_feed) / 60.0,
        motors=tuple(machine.motor_names),
        has_z="z" in machine.motor_names or machine.kinematics == "delta",
    )
    toolpath = Toolpath(start=start)
    reach = axis_reach(machine)
    problems: list[Diagnostic] = []
    for shape in program.shapes:
        builder = BUILDERS.get(shape.kind)
        if builder is None:
            problems.append(Diagnostic(shape.source, f"unknown shape `{shape.kind}`"))
            continue
        try:
            items = builder(shape, pen)
        except JobError as err:  # the shape is skipped; the shapes after it are still checked
            problems.extend(err.diagnostics)
            continue
        beyond = items_errors(items, reach)
        if beyond:  # the shape is refused, like a shape in error: the next one starts where the tool is
            problems.extend(Diagnostic(shape.source, message) for message in beyond)
            continue
        toolpath.items.extend(items)
        if items:
            pen.position = items[-1].end.copy()
    if problems:
        raise JobError(problems)
    return toolpath

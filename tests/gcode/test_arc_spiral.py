"""An I/J arc whose end is off its start's circle, within Grbl's limits (fuzz finding: G3 X100 Y85.352 I24 J127
from X93 Y86.42 ends 0.0564 mm inside its start's circle of 129.2478 mm): the front end makes it a spiral from the
start's radius to the end's, the chords follow the spiral, and the path check measures against the spiral, not
the start's circle (which the chords left by the whole 0.0564 mm on the last one: the tool strayed 0.060 mm)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from codegen.gcode import arcs
from codegen.tables.checks import path_errors, path_errors_numpy
from codegen.toolpath.items import Toolpath
from codegen.toolpath.segments import REF_ARC, flatten
from tests.gcode.helpers import items

PROGRAM = "X93.Y86.42\nG3X100Y85.352I24J127\n"  # no G word: the modal G0 at the start; "93." is 93
CENTRE = (93 + 24, 86.42 + 127)
START_RADIUS = math.hypot(24, 127)
END_RADIUS = math.hypot(100 - CENTRE[0], 85.352 - CENTRE[1])
START_ANGLE = math.atan2(-127, -24)
SWEEP = math.atan2(85.352 - CENTRE[1], 100 - CENTRE[0]) - START_ANGLE  # a short turn counter-clockwise
TOLERANCE = 0.002
CHORDS = 5  # a sweep of 0.0548 rad over chords of at most 2 acos(1 - 0.002 / 129.2478) = 0.01113 rad


def spiral(fractions: np.ndarray) -> np.ndarray:
    """Points (x, y, z) of the program's spiral at fractions of its sweep."""
    angle = START_ANGLE + SWEEP * fractions
    radius = START_RADIUS + (END_RADIUS - START_RADIUS) * fractions
    return np.column_stack([CENTRE[0] + radius * np.cos(angle), CENTRE[1] + radius * np.sin(angle),
                            np.zeros(len(fractions))])


def the_arc():
    travel, arc = items(PROGRAM)
    assert (travel.label, travel.end.tolist()) == ("G0", [93, 86.42, 0, 0])
    return travel, arc


def test_the_arc_is_a_spiral_from_the_starts_radius_to_the_ends():
    _, arc = the_arc()
    assert END_RADIUS - START_RADIUS == pytest.approx(-0.0564441, abs=1e-7)  # Grbl allows 0.1 %: 0.129 mm
    assert SWEEP == pytest.approx(math.radians(3.14), abs=1e-8)
    assert (arc.label, arc.start.tolist(), arc.end.tolist()) == ("G3", [93, 86.42, 0, 0], [100, 85.352, 0, 0])
    assert arc.center == pytest.approx(CENTRE) and arc.radius == pytest.approx(START_RADIUS)
    assert arc.radius_change == pytest.approx(END_RADIUS - START_RADIUS)
    assert (arc.start_angle, arc.sweep) == (pytest.approx(START_ANGLE), pytest.approx(SWEEP))
    fractions = np.array([0.0, 0.25, 0.5, 1.0])
    drawn = arc.points(arc.start_angle + arc.sweep * fractions)
    assert drawn[:, :3] == pytest.approx(spiral(fractions), abs=1e-9)
    assert drawn[-1, :2] == pytest.approx([100, 85.352], abs=1e-9)  # the program's end, no jog
    assert arcs.from_offsets((0, 0), (10, 0), (5, 0), True, "IJ").radius_change == 0.0  # on the circle


def test_the_chords_end_on_the_spiral_and_keep_its_radius_and_angle():
    travel, arc = the_arc()
    segments = flatten(Toolpath(travel.start, [travel, arc]), TOLERANCE)
    pieces = np.flatnonzero(segments.ref_kind == REF_ARC)
    assert len(pieces) == CHORDS
    k = np.arange(CHORDS) / CHORDS
    assert segments.end[pieces, :3] == pytest.approx(spiral(k + 1 / CHORDS), abs=1e-9)
    assert segments.ref_radius[pieces] == pytest.approx(START_RADIUS + (END_RADIUS - START_RADIUS) * k)
    assert segments.ref_angle[pieces] == pytest.approx(START_ANGLE + SWEEP * k)
    assert segments.ref_growth[pieces] == pytest.approx(np.full(CHORDS, (END_RADIUS - START_RADIUS) / SWEEP))
    assert segments.ref_growth[0] == 0.0  # the travel


@pytest.mark.parametrize("measure", [path_errors, path_errors_numpy], ids=["c", "numpy"])
def test_the_path_check_measures_against_the_spiral(measure):
    travel, arc = the_arc()
    segments = flatten(Toolpath(travel.start, [travel, arc]), TOLERANCE)
    fractions = np.linspace(0.0, 1.0, 41)
    seg = 1 + np.minimum((fractions * CHORDS).astype(np.int64), CHORDS - 1)  # each point's own chord
    on_spiral = np.column_stack([spiral(fractions), np.zeros(len(fractions))])
    assert measure(on_spiral, seg, segments, math.inf).max() == pytest.approx(0.0, abs=1e-9)
    on_start_circle = on_spiral[-1:].copy()  # where the start's circle reaches the end's angle
    on_start_circle[0, :2] = np.array(CENTRE) + START_RADIUS * np.array([math.cos(START_ANGLE + SWEEP),
                                                                         math.sin(START_ANGLE + SWEEP)])
    assert measure(on_start_circle, seg[-1:], segments, math.inf)[0] == pytest.approx(START_RADIUS - END_RADIUS)
    last = CHORDS  # the last chord cut in two (the staircase's and the delta's cuts): each half keeps the spiral
    middle = 0.5 * (segments.start[last] + segments.end[last])
    halves = segments.take(np.array([last, last]), start=np.array([segments.start[last], middle]),
                           end=np.array([middle, segments.end[last]]))
    late = on_spiral[fractions >= 0.9]
    assert measure(late, np.ones(len(late), dtype=np.int64), halves, math.inf).max() == pytest.approx(0.0, abs=1e-9)

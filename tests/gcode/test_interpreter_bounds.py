"""The G-code interpreter's bounds (issue 28): numbers beyond what the tables hold (a reach, a day's move or
dwell, an arc's size) refused at the word that sets them, at once, without the minutes and memory they took."""

from __future__ import annotations

import time

from tests.gcode.helpers import errors, items


def test_an_arc_larger_than_any_machine_is_refused_at_its_word():
    """Issue 28: a radius of 1e150 divided by zero in the chord count; R1e6 on a 0.2 mm chord ran for minutes."""
    message = ("arc radius {} mm is beyond the largest an arc may have, 100000 mm (so large an arc is a straight line "
               "to the planner's precision: write G1)")
    assert errors("G2 X5 Y0 I1" + "0" * 150 + " J0\nG1 X2 Y7\nG2 X2.2 Y6.9 R1000000\n") == [
        (8, 14, message.format("1e+150")), (10, 18, message.format("1e+06"))]
    assert len(items("G1 X2 Y7\nG2 X2.2 Y6.9 R99999\n")) == 2  # within the limit: an arc


SLOWEST = "the slowest move the tables hold lasts 1 day"


def test_a_position_beyond_reach_is_refused_at_each_axis_word_at_once():
    """Issue 28: X1e10 allocated 745 MiB, X1e20 overflowed int64 steps; E beyond the int32 steps of its motor."""
    started = time.monotonic()
    assert errors("G1 X10000000000 Z-100000000000000000000\nG1 X5 E30000000\nG91 G1 Y99999\nG1 Y2\n") == [
        (8, 8, "x = 1e+10 mm is beyond the reach of 100000 mm from the origin"),
        (8, 21, "z = -1e+20 mm is beyond the reach of 100000 mm from the origin"),
        (9, 11, "e = 3e+07 mm is beyond the reach of 2.68435e+07 mm (its motor counts its position in int32 steps)"),
        (11, 8, "y = 100001 mm is beyond the reach of 100000 mm from the origin")]
    assert time.monotonic() - started < 2.0
    assert len(items("G1 X100000 Y-100000 E26000000\n")) == 1  # at the reach: a move


def test_a_move_slower_than_a_day_is_refused_at_its_feed():
    """Issue 28: F0.000001 planned 13 years; a Z move at F0.000000001 failed the build with its rate 635 % over."""
    assert errors("G1 X5 Y5 F0.000001\nG1 X6\nG1 X7 F600\nG0 X8\n") == [
        (8, 14, f"'F0.000001' makes this move last 13.4 years; {SLOWEST} (here at least 0.00491 mm/min)"),
        (9, 5, f"the feed of 1e-06 mm/min makes this move last 11.4 years; {SLOWEST} (here at least 0.00417 mm/min)")]
    assert errors("G0 X20\n", travel_feed=1e-3) == [
        (8, 5, f"the feed of 0.001 mm/min makes this move last 13.9 days; {SLOWEST} (here at least 0.0139 mm/min)")]
    assert len(items("G1 X14.4 F0.01\n")) == 1  # 1440 minutes: a day


def test_a_dwell_longer_than_a_day_is_refused_at_its_word():
    """Issue 28: G4 P1000000000000 split into 119 M dwell entries (909 MiB)."""
    assert errors("G1 X1\nG4 P1000000000000\nG4 S86401\nG1 X2\n") == [
        (9, 8, "'P1000000000000': a dwell of 31.7 years; the longest dwell the tables hold is 1 day"),
        (10, 8, "'S86401': a dwell of 1 day; the longest dwell the tables hold is 1 day")]
    assert [type(it).__name__ for it in items("G4 S86400\n")] == ["Dwell"]


def test_an_arc_longer_than_the_reach_is_refused_at_its_radius():
    """Issue 28: R-99999 went the long way round a 100 m circle: 628 km of arc, 345 MiB after 11 s."""
    assert errors("G1 X5 Y5\nG2 X10 Y5 R-99999\nG3 X5 Y5 I16000 J0\n") == [
        (9, 15, "this arc is 628307 mm long; the longest arc a move may draw is 100000 mm (R < 0 goes the long way "
                "round a circle of 99999 mm radius)"),
        (10, 14, "this arc is 100531 mm long; the longest arc a move may draw is 100000 mm")]
    assert len(items("G1 X5 Y5\nG2 X10 Y5 R99999\n")) == 2  # the short way: an arc

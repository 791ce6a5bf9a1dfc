"""Grbl 1.1's codes that a plan can hold: work coordinate systems, G53, stored positions, G92.1, G93, G43.1,
coolant, tool changes, and the refusal of probing."""

import math

import pytest

from codegen.toolpath.items import Line, Output
from tests.gcode.helpers import MILL, errors, items, run


def ends(gcode: str, **kw):
    return [i.end[:3].tolist() for i in items(gcode, motors=MILL, **kw) if isinstance(i, Line)]


def test_work_systems_and_g10():
    # G10 L2 sets G55's offset; G55 then reads coordinates from it (Z, not named, stays); G54 (all zero) again.
    assert ends("G10 L2 P2 X10 Y20 Z1\nG55\nG0 X1 Y1\nG0 Z0\nG54\nG0 X1 Y1\n") == [
        [11, 21, 0], [11, 21, 1], [1, 1, 1]]
    # L20: the current position becomes the given coordinates in that system (P0: the current one).
    assert ends("G0 X5 Y5\nG10 L20 P0 X0 Y0\nG0 X1 Y2\n") == [[5, 5, 0], [6, 7, 0]]
    # G92 comes on top of the work system; G92.1 drops it and keeps the system.
    assert ends("G10 L2 P1 X100\nG0 X0\nG92 X50\nG0 X60\nG92.1\nG0 X0\n") == [[100, 0, 0], [110, 0, 0],
                                                                              [100, 0, 0]]


def test_g53_moves_in_machine_coordinates_for_its_line_only():
    assert ends("G10 L2 P1 X10 Z5\nG0 X0 Z0\nG53 G0 X1 Z2\nG0 X0\nG91\nG53 G1 X3 F600\n") == [
        [10, 0, 5], [1, 0, 2], [10, 0, 2], [3, 0, 2]]
    assert errors("G53 G2 X1 I1\n", motors=MILL) == [(8, 5, "G53 (machine coordinates) moves only with G0 or G1")]


def test_stored_positions_g28_g30():
    # G28.1 stores the machine position; G28 X5 goes by X5 (program coordinates), then X to the stored one.
    assert ends("G0 X7 Y8 Z3\nG28.1\nG0 X0 Y0 Z0\nG28 X5\nG28\n") == [
        [7, 8, 3], [0, 0, 0], [5, 0, 0], [7, 0, 0], [7, 8, 3]]
    # G30 without G30.1: the home position; with it, the stored one.
    assert ends("G0 X4 Y4\nG30\nG0 X2\nG30.1\nG0 X9 Y9\nG30 Y1\n") == [
        [4, 4, 0], [0, 0, 0], [2, 0, 0], [9, 9, 0], [9, 1, 0], [9, 0, 0]]


def test_inverse_time_feed():
    lines = [i for i in items("G93\nG1 X30 F2\nG2 X0 Y0 I-15 F4\nG94\nG1 X1 F60\n", motors=MILL)]
    assert lines[0].feed == pytest.approx(30 * 2 / 60)  # 30 mm in half a minute
    assert lines[1].feed == pytest.approx(math.pi * 15 * 4 / 60)  # a half circle in a quarter minute
    assert lines[2].feed == pytest.approx(1.0)
    assert errors("G93\nG1 X30\n", motors=MILL) == [
        (9, 5, "in inverse time mode (G93) every G1, G2 and G3 needs F (1/minutes)")]


def test_tool_length_offset():
    assert ends("G43.1 Z2.5\nG0 Z1\nG49\nG0 Z1\n") == [[0, 0, 3.5], [0, 0, 1]]
    assert errors("G43.1\n", motors=MILL) == [(8, 5, "G43.1 needs Z, the tool length offset")]


def test_coolant_tool_change_probe_and_blending():
    toolpath, warnings = run("M8\nM7\nM9\nT1 M6\nG64\nG0 X1\n", motors=MILL)
    outputs = [(o.name, o.value) for o in toolpath.items if isinstance(o, Output)]
    assert outputs == [("flood", 1.0), ("mist", 1.0), ("mist", 0.0), ("flood", 0.0)]
    assert [w.message for w in warnings] == [  # T1 is M6's tool number: one warning, as Marlin
        "'M6' ignored (tool change; the machine has one tool)",
        "'G64' ignored (path blending; corners always blend by the junction deviation)"]
    assert errors("T1 M6\n", strict=True, motors=MILL)[0][2] == \
        "'M6' is not accepted with --strict (tool change; the machine has one tool)"
    assert [w.message for w in run("T2\n", motors=MILL)[1]] == ["'T2' ignored (tool select; the machine has one tool)"]
    assert errors("G38.2 Z-10 F100\n", motors=MILL) == [(8, 5, "'G38.2' probes: the move stops where a contact "
                                                               "closes, a measurement taken while the machine "
                                                               "runs, which a plan computed beforehand cannot know")]


def test_g92_1_keeps_the_extruders_flow_scaled_position():
    # M221 S50: E 10 is 5 mm of machine E; G92.1 leaves E alone, so E 12 is 1 mm further (6), not 8.5.
    ends = [i.end.tolist() for i in items("M221 S50\nG1 X1 E10\nG92.1\nG1 X2 E12\n") if isinstance(i, Line)]
    assert ends == [[1, 0, 0, 5], [2, 0, 0, 6]]


def test_back_from_inverse_time_the_feed_is_undefined_until_an_f():
    # Grbl: after G93 -> G94 the feed rate is undefined; here, as before any F, the job's feed (1200 mm/min).
    feeds = [i.feed for i in items("G1 X1 F600\nG93 G1 X2 F60\nG94\nG1 X3\nG1 X4 F300\n", motors=MILL)]
    assert feeds == [10.0, 1.0, 20.0, 5.0]


def test_g10_errors():
    assert errors("G10 L2 P1\nG10 L20 P7 X0\nG10 P1 X0\n", motors=MILL) == [
        (8, 5, "G10 needs the axis words to set (X, Y, Z)"),
        (9, 13, "G10 needs P0 (the current system) to P6 (G59)"),
        (10, 5, "G10 needs L2 or L20 (work coordinate offsets)")]

"""The G-code interpreter: small programs -> the exact Toolpath items, and every error with its place."""

from __future__ import annotations

import math

import numpy as np
import pytest

from codegen.errors import JobError, SourceRef
from codegen.gcode import toolpath_from_gcode
from codegen.toolpath.items import Arc, Dwell, Limits, Line, Output
from tests.gcode.helpers import MILL, PLOTTER, errors, items, make_job, run

INF = math.inf
PI = math.pi


def moves(gcode: str, **kw):
    """(label, start, end, feed, tool) of every Line."""
    return [(i.label, i.start.tolist(), i.end.tolist(), i.feed, i.tool) for i in items(gcode, **kw)]


def arc(item: Arc):
    return (item.label, item.start.tolist(), item.end.tolist(), item.center, item.radius, item.start_angle,
            item.sweep, item.plane)


# ---- lines, feeds, modes ----

def test_lines_feeds_and_rapids():
    assert moves("G1 X10\nG1 Y5 F600\nG0 X0 F3000\nG1 Y0\n") == [
        ("G1", [0, 0, 0, 0], [10, 0, 0, 0], 20.0, False),  # no F yet: program.feed 1200 mm/min
        ("G1", [10, 0, 0, 0], [10, 5, 0, 0], 10.0, False),
        ("G0", [10, 5, 0, 0], [0, 5, 0, 0], INF, False),  # rapid: as fast as the machine allows
        ("G1", [0, 5, 0, 0], [0, 0, 0, 0], 50.0, False),  # F is modal, G0 lines set it too
    ]
    assert moves("G0 X1\n", travel_feed=6000) == [("G0", [0, 0, 0, 0], [1, 0, 0, 0], 100.0, False)]


def test_axis_only_lines_use_the_motion_mode():
    assert [m[0] for m in moves("X1\nG1 X2 F60\nY3\nG0 X3\nZ1\n")] == ["G0", "G1", "G1", "G0", "G0"]


def test_start_position_and_sources():
    toolpath, _ = run("G1 X5\n\n  G1 Y5\n", start=(1, 2, 3))
    assert toolpath.start.tolist() == [1, 2, 3, 0]
    a, b = toolpath.items
    assert a.start.tolist() == [1, 2, 3, 0] and b.end.tolist() == [5, 5, 3, 0]
    assert (a.source, b.source) == (SourceRef("job.yaml", 8, 5), SourceRef("job.yaml", 10, 7))


def test_points_are_shared_read_only_rows():
    a, b = items("G1 X1\nG1 X2\n")
    assert np.shares_memory(a.end, b.start) and not a.end.flags.writeable


def test_no_motion_and_zero_length_produce_nothing():
    got = moves("G90\nF100\nG1 X0 Y0\nG1\nG21\nS10\nG1 X5\nG1 X5\nG91 G1 X0\nM5\n", laser=True, s_max=255)
    assert got == [("G1", [0, 0, 0, 0], [5, 0, 0, 0], 100 / 60, False)]


def test_g91_g92_g20_combinations():
    got = moves("G21 G90 G92 X10 Y10\nG1 X20 Y10 F60\nG91 G1 X-5 Y5\nG20 G1 X1\nG90 G1 X0 Y0\nG21 G92 X0\n"
                "G1 X1\n")
    assert got == [
        ("G1", [0, 0, 0, 0], [10, 0, 0, 0], 1.0, False),  # machine = program + offset (-10, -10)
        ("G1", [10, 0, 0, 0], [5, 5, 0, 0], 1.0, False),  # G91: relative
        ("G1", [5, 5, 0, 0], [30.4, 5, 0, 0], 1.0, False),  # G20: 1 inch; F stays what it was in mm/s
        ("G1", [30.4, 5, 0, 0], [-10, -10, 0, 0], 1.0, False),  # G90 X0 Y0 in program coordinates
        ("G1", [-10, -10, 0, 0], [-9, -10, 0, 0], 1.0, False),  # G92 X0 at machine x = -10
    ]
    assert moves("G20 G1 X1 F10\n") == [("G1", [0, 0, 0, 0], [25.4, 0, 0, 0], pytest.approx(25.4 / 6), False)]


def test_extruder_modes():
    got = moves("M83\nG1 X1 E1 F60\nG1 X2 E1\nG92 E0\nM82\nG1 X3 E5\nG1 E4\nG91\nG1 E1\nG90\nG1 E0\n"
                "G20 M83 G1 E1\n")
    assert [m[2][3] for m in got] == [1, 2, 7, 6, 7, 2, 27.4]
    assert [m[2][0] for m in got] == [1, 2, 3, 3, 3, 3, 3]
    assert items("G90 M83 G1 E1\nG1 E1\n")[1].end[3] == 2  # M83 after G90 on one line: E relative


def test_feed_applies_to_the_move_as_given():
    (move, retract) = items("M83\nG1 X3 Y4 E2 F600\nG1 E-1 F1200\n")
    assert (move.feed, retract.feed) == (10.0, 20.0)  # the planner reads it along xyz, or |E| alone


def test_tool_and_power():
    got = items("G1 X1 F60\nM3 S127.5\nG1 X2\nG0 X3\nS255\nG2 X5 I1\nS510\nG1 X6\nM5\nG1 X7\nM4 S0\nG1 X8\n"
                "G1 X9 S51\n", laser=True, dialect="marlin")
    assert [(i.label, i.tool, i.power) for i in got] == [
        ("G1", False, 1.0), ("G1", True, 0.5), ("G0", False, 0.5), ("G2", True, 1.0), ("G1", True, 1.0),
        ("G1", False, 1.0), ("G1", True, 0.0), ("G1", True, 0.2)]
    assert items("M3 S500\nG1 X1\n", s_max=1000, laser=True)[0].power == 0.5  # the job's full scale


def test_outputs():
    got = items("M106\nM106 S127.5\nM107\nM104 S200\nM109 R170\nM109 S215\nM140 S60\nM190 S60\nM104 S0 T0\n")
    assert [(o.name, o.value, o.wait, o.source.line) for o in got] == [
        ("fan", 1.0, False, 8), ("fan", 0.5, False, 9), ("fan", 0.0, False, 10), ("hotend", 200.0, False, 11),
        ("hotend", 170.0, True, 12), ("hotend", 215.0, True, 13), ("bed", 60.0, False, 14),
        ("bed", 60.0, True, 15), ("hotend", 0.0, False, 16)]
    assert all(isinstance(o, Output) for o in got)


def test_limits_and_accelerations():
    got = items("M201 X2500 Y2500 Z400 E5000\nM203 X180 E80\nM205 X8 Y8.5 J0.02\nM205 J0.05\n"
                "M204 P1000 T2000 R500\nG1 X1 E1\nG1 X2\nG1 E-1\nM204 S300\nG1 X3 E1\nG1 X4\nG1 E2\n")
    limits = got[:4]
    assert all(isinstance(x, Limits) for x in limits)
    assert [(x.max_accel, x.max_velocity, x.jerk, x.junction_deviation) for x in limits] == [
        ({"x": 2500, "y": 2500, "z": 400, "e": 5000}, None, None, None),
        (None, {"x": 180, "e": 80}, None, None),
        (None, None, {"x": 8, "y": 8.5}, 0.02),
        (None, None, None, 0.05)]
    assert [i.accel for i in got[4:]] == [1000, 2000, 500, 300, 300, 500]
    assert items("G1 X1\n")[0].accel == INF


def test_dwell():
    got = items("G4 P400\nG4 S1.5\nG4\nG4 P100 S2\n", dialect="marlin")
    assert [(type(d), d.seconds) for d in got] == [(Dwell, 0.4), (Dwell, 1.5), (Dwell, 2.0)]


def test_home():
    got = items("G92 X10 Y10\nG1 X20 F60\nG28 X\nG1 X5 Y20\nG28 X0 Y0\nG1 Z1\nG28\n", start=(1, 2, 3))
    assert [(type(i).__name__, i.end.tolist() if isinstance(i, Line) else i.position.tolist(),
             getattr(i, "axes", None)) for i in got] == [
        ("Line", [11, 2, 3, 0], None),  # offset x = 1 - 10
        ("Home", [0, 2, 3, 0], ("x",)),  # homing clears x's offset
        ("Line", [5, 12, 3, 0], None),  # y keeps its offset 2 - 10
        ("Home", [0, 0, 3, 0], ("x", "y")),  # values are ignored (Marlin)
        ("Line", [0, 0, 1, 0], None),
        ("Home", [0, 0, 0, 0], ("x", "y", "z")),  # G28 alone: every axis
    ]
    assert items("G28\n", motors=PLOTTER)[0].axes == ("x", "y")
    delta = items("G28 X\n", motors=("a", "b", "c", "e"), kinematics="delta")[0]
    assert (delta.axes, delta.position.tolist()) == (("x", "y", "z"), [0, 0, 250, 0])
    corexy = items("G28 Y\n", motors=("a", "b", "z", "e"), kinematics="corexy", start=(3, 4, 5))[0]
    assert (corexy.axes, corexy.position.tolist()) == (("y",), [3, 0, 5, 0])


def test_program_end():
    toolpath, warnings = run("G1 X1\nM2\nG1 X2\nthis is not G-code\n")
    assert len(toolpath.items) == 1 and warnings == []
    assert len(items("G1 X1\nM30\nM600\n")) == 1


# ---- arcs ----

def test_quarter_arcs_both_directions():
    a, b = items("G0 X-5 Y0\nG2 X0 Y5 I5 J0 F600\nG3 X5 Y0 I0 J-5\n")[1:]
    assert arc(a) == ("G2", [-5, 0, 0, 0], [0, 5, 0, 0], (0, 0), 5, PI, pytest.approx(-PI / 2), (0, 1))
    assert arc(b) == ("G3", [0, 5, 0, 0], [5, 0, 0, 0], (0, 0), 5, PI / 2, pytest.approx(3 * PI / 2), (0, 1))
    assert (a.feed, a.tool, a.accel) == (10.0, False, INF)


def test_full_circles():
    cw, ccw = items("G0 X5\nG2 X5 Y0 I-5\nG3 I-5 J0\n")[1:]
    assert (cw.sweep, ccw.sweep) == (-2 * PI, 2 * PI)
    assert cw.end.tolist() == cw.start.tolist() == [5, 0, 0, 0] and cw.center == (0, 0) and cw.radius == 5


def test_r_form_both_signs():
    got = items("G2 X10 Y0 R10\nG0 X0\nG2 X10 R-10\nG0 X0\nG3 X10 R10\nG0 X0\nG3 X10 R-10\nG0 X0\nG2 X10 R5\n")
    arcs = [i for i in got if isinstance(i, Arc)]
    h = 5 * math.sqrt(3)
    assert [(a.center, a.radius, a.start_angle, a.sweep) for a in arcs] == [
        ((5, pytest.approx(-h)), pytest.approx(10), pytest.approx(2 * PI / 3), pytest.approx(-PI / 3)),
        ((5, pytest.approx(h)), pytest.approx(10), pytest.approx(-2 * PI / 3), pytest.approx(-5 * PI / 3)),
        ((5, pytest.approx(h)), pytest.approx(10), pytest.approx(-2 * PI / 3), pytest.approx(PI / 3)),
        ((5, pytest.approx(-h)), pytest.approx(10), pytest.approx(2 * PI / 3), pytest.approx(5 * PI / 3)),
        ((5, 0), 5, PI, pytest.approx(-PI)),  # R = half the chord: the half circle
    ]


def test_arc_in_g91_is_relative_and_offsets_are_from_the_start():
    (a,) = items("G91 G2 X10 Y0 I5 J0\n", start=(1, 1))
    assert arc(a) == ("G2", [1, 1, 0, 0], [11, 1, 0, 0], (6, 1), 5, PI, pytest.approx(-PI), (0, 1))


def test_helical_arc_moves_z_and_e_along():
    (a,) = items("G0 X10\nM83\nG3 X0 Y10 Z5 E2 I-10 J0\n")[1:]
    assert arc(a) == ("G3", [10, 0, 0, 0], [0, 10, 5, 2], (0, 0), 10, 0, pytest.approx(PI / 2), (0, 1))
    middle = a.points(np.array([PI / 4]))[0]
    assert middle.tolist() == pytest.approx([10 / math.sqrt(2), 10 / math.sqrt(2), 2.5, 1.0])
    assert a.accel == INF


def test_arcs_in_the_other_planes():
    zx, yz = items("G18 G2 X10 Z0 I5 K0\nG0 X0\nG19 G3 Y10 Z0 J5 K0\n")[0::2]
    assert arc(zx) == ("G2", [0, 0, 0, 0], [10, 0, 0, 0], (0, 5), 5, -PI / 2, pytest.approx(-PI), (2, 0))
    assert zx.points(np.array([-PI]))[0].tolist() == pytest.approx([5, 0, -5, 0])  # u = z, v = x
    assert arc(yz) == ("G3", [0, 0, 0, 0], [0, 10, 0, 0], (5, 0), 5, PI, pytest.approx(PI), (1, 2))
    assert yz.points(np.array([1.5 * PI]))[0].tolist() == pytest.approx([0, 5, -5, 0])


def test_grbl_radius_checks():
    assert len(items("G2 X10 I5.002\n")) == 1  # 0.004 mm apart: within 0.005 mm
    assert len(items("G2 X2000 I1000.003\n")) == 1  # 0.006 mm: over 0.005 mm but within 0.1 % and 0.5 mm
    assert errors("G2 X10 I5.003\nG2 X2000 I1000.3\n") == [
        (8, 12, "arc end is not on the circle: radius 5.003 mm at the start, 4.997 mm at the end (a difference "
               "of 0.006 mm; at most 0.005 mm, or 0.5 mm and 0.1 % of the radius)"),
        (9, 14, "arc end is not on the circle: radius 1000.3 mm at the start, 999.7 mm at the end (a "
                "difference of 0.6 mm; at most 0.005 mm, or 0.5 mm and 0.1 % of the radius)"),
    ]


def test_r_form_checks():
    (a,) = items("G2 X10 R4.996\n")  # short of half the chord by 0.004 mm (rounded numbers): the half circle
    assert (a.center, a.radius, a.sweep) == ((5, 0), 5, pytest.approx(-PI))
    assert errors("G2 X10 R4.9\nG2 X0 Y0 R5\nG3 X1 Y0 R-0.4\n") == [
        (8, 12, "arc radius 4.9 mm is too small for the chord of 10 mm (at least 5 mm)"),
        (9, 14, "an R arc cannot end where it starts; give the centre with I/J/K for a full circle"),
        (10, 14, "arc radius 0.4 mm is too small for the chord of 1 mm (at least 0.5 mm)"),
    ]


def test_arc_word_errors():
    assert errors("G2 X10\nG2 X10 K5\nG2 X10 R5 I5\nG2 X0 Y0 I0 J0\nG18 G3 X1 J1\nG1 X5 I3\n") == [
        (8, 5, "G2 needs the centre: I/J offsets (XY plane) or R"),
        (9, 12, "'K' is not an offset in the XY plane; use I and J"),
        (10, 12, "give either R or I/J, not both"),
        (11, 14, "arc radius is 0: I and J put the centre at the start"),
        (12, 15, "'J' is not an offset in the ZX plane; use K and I"),
        (13, 11, "'I3' is not a parameter of G1"),
    ]
    assert errors("G18 G2 X10 I5\n", motors=PLOTTER) == [
        (8, 9, "an arc in the ZX plane moves z, but the machine has no z motor (motors: x, y)")]


# ---- the machine's axes ----

def test_axes_the_machine_cannot_move():
    assert errors("G1 Z0.2\nG1 X1 E0.5\n", motors=PLOTTER) == [
        (8, 8, "'Z0.2' moves z, but the machine has no z motor (motors: x, y)"),
        (9, 11, "'E0.5' moves e, but the machine has no e motor (motors: x, y)"),
    ]
    assert errors("G1 X1 E.5\n", motors=MILL) == [(8, 11, "'E.5' moves e, but the machine has no e motor "
                                                         "(motors: x, y, z)")]
    assert len(items("G1 Z0 E0\nG92 Z5 E3\nG1 X1 Z5 E3\nM82\n", motors=PLOTTER)) == 1  # they stay where they are


# ---- messages ----

def test_unsupported_and_tool_errors():
    assert errors("G38.2 Z-5\nM600\nG10 L3 P1 X0\nG1 Q5\nP5\nG1 F0 X1\nM3 S-1\nM220 S0\nG92\nM106 P1\nM104 S200 T1\n") == [
        (8, 5, "'G38.2' probes: the move stops where a contact closes, a measurement taken while the machine "
               "runs, which a plan computed beforehand cannot know"),
        (9, 5, "unsupported G-code 'M600'"),
        (10, 9, "G10 needs L2 or L20 (work coordinate offsets)"),
        (11, 8, "'Q5' is not a parameter of G1"),
        (12, 5, "'P5' needs a code that takes it"),
        (13, 8, "feed rate 'F0' must be > 0"),
        (14, 8, "power 'S-1' must be >= 0"),
        (15, 10, "'S0' must be > 0"),
        (16, 5, "G92 needs the axis words to set (X, Y, Z, E)"),
        (17, 10, "'P1': the machine has one fan (P0)"),
        (18, 15, "'T1': the machine has one hot end (T0)"),
    ]
    assert errors("G1 G92 X0\n") == [(8, 8, "'G1' and 'G92' on one line: both take the axis words")]


def test_errors_point_into_a_gcode_file(tmp_path):
    (tmp_path / "part.gcode").write_text("G1 X1\n  G1 X2 Q1\n")
    job = make_job("part.gcode", path=tmp_path / "job.yaml")
    with pytest.raises(JobError) as caught:
        toolpath_from_gcode(job)
    (d,) = caught.value.diagnostics
    assert (d.where, d.message) == (SourceRef(str(tmp_path / "part.gcode"), 2, 9), "'Q1' is not a parameter of G1")
    assert caught.value.render().endswith("  G1 X2 Q1\n        ^")


def test_too_many_errors():
    found = errors("".join(f"G1 X{i} Q1\n" for i in range(30)))
    assert len(found) == 21
    assert found[19] == (27, 12, "'Q1' is not a parameter of G1")
    assert found[20] == (28, 12, "too many errors (20 reported), stopping here")


def test_warnings_one_per_code():
    toolpath, warnings = run("M73 P0\nG1 X1\nM73 P50\nT0\nM84\nM205 S0 T0 B20000\nM220 S100\nG29\n"
                             "M862.3 P \"MINI\"\nM117 Hello\nM73 P100\n")
    assert len(toolpath.items) == 1
    assert [(w.severity, w.where.line, w.where.col, w.message) for w in warnings] == [
        ("warning", 8, 5, "'M73' ignored (print progress); 3 times"),
        ("warning", 11, 5, "'T0' ignored (tool select; the machine has one tool)"),
        ("warning", 12, 5, "'M84' ignored (motors off)"),
        ("warning", 13, 16, "'M205 B' ignored (minimum segment time; Marlin applies it only while its move "
                            "queue runs low)"),
        ("warning", 15, 5, "'G29' ignored (bed levelling; there is no probe)"),
        ("warning", 16, 5, "'M862.3' ignored (printer check)"),
        ("warning", 17, 5, "'M117' ignored (display message)"),
    ]


def test_strict_makes_skipped_codes_errors():
    assert errors("M73 P0\nG1 X1\nM73 P50\nM205 S0 B1\n", strict=True) == [
        (8, 5, "'M73' is not accepted with --strict (print progress)"),
        (10, 5, "'M73' is not accepted with --strict (print progress)"),
        (11, 13, "'M205 B' is not accepted with --strict (minimum segment time; Marlin applies it only while its "
                 "move queue runs low)"),
    ]


def test_error_lines_do_nothing_but_the_rest_is_checked():
    assert errors("G1 X1 Q1\nG1 X2 E1\nG1 Z1\n", motors=PLOTTER) == [
        (8, 11, "'Q1' is not a parameter of G1"),
        (9, 11, "'E1' moves e, but the machine has no e motor (motors: x, y)"),
        (10, 8, "'Z1' moves z, but the machine has no z motor (motors: x, y)"),
    ]


@pytest.mark.parametrize("mode", ["M82", "M83"])
def test_m221_scales_the_extruders_moves_from_its_place(mode):
    """Marlin and Klipper: M221 S<percent> scales every E distance after it; absolute E stays the program's."""
    absolute = mode == "M82"
    program = ["G1 X1 E2", "M221 S50", "G1 X2 E4" if absolute else "G1 X2 E2", "G92 E0", "G1 X3 E2",
             "M221 S100", "G1 X4 E4" if absolute else "G1 X4 E2"]
    ends = [item.end[3] for item in items("\n".join([mode] + program)) if isinstance(item, Line)]
    assert ends == [2.0, 3.0, 4.0, 6.0]  # 2, then 2 at 50 %, 2 at 50 % after G92, then 2 at 100 %


def test_m220_scales_every_moves_feed_from_its_place():
    """Marlin and Klipper: M220 S<percent> multiplies the feed rate of every move after it (G0 included, G2/G3
    too); B saves the factor and R restores it (Marlin)."""
    found = [(i.label, i.feed) for i in items(
        "G1 X10 F600\nM220 S50\nG1 X20\nG0 X0\nG2 X10 I5\nM220 B S200\nG1 X20 F60\nM220 R\nG1 X30\n",
        travel_feed=3000)]
    assert found == [("G1", 10.0), ("G1", 5.0), ("G0", 25.0), ("G2", 5.0), ("G1", 2.0), ("G1", 0.5)]
    assert errors("M220 S-5\nM220 Q1\n") == [(8, 10, "'S-5' must be > 0"), (9, 10, "'Q1' is not a parameter of M220")]


def test_m220_r_after_an_arc_restores_the_feed_and_is_no_arc():
    """The modal G2/G3 takes a bare I/J/K/R as an arc word only where no code on the line takes it."""
    found = [(i.label, i.feed) for i in items("G1 X10 F600\nM220 B S50\nG3 X0 Y10 R10\nM220 R\nG1 X0 Y0\n")]
    assert found == [("G1", 10.0), ("G3", 5.0), ("G1", 10.0)]


def test_lines_of_vertical_tab_or_form_feed_only_are_blank():
    assert [i.end[0] for i in items("G1 X10 F600\n\v\nG1 X0\n\f\n \v \n")] == [10.0, 0.0]


def test_m205_least_feed_rates():
    """Marlin's M205 S (moves that extrude) and T (the others): a slower move runs at that speed (mm/s)."""
    found = [i.feed for i in items("M205 S5 T20\nG1 X1 E1 F60\nG1 X2 F60\nG1 X3 E2 F600\nM205 S0 T0\n"
                                   "G1 X4 F60\n")]
    assert found == [5.0, 20.0, 10.0, 1.0]


def test_pressure_advance_only_off():
    """Without machine.pressure_advance, M900 K0 / M572 S0 change nothing and are skipped; a non-zero advance would
    move the extruder off the plan (tests/gcode/test_advance_codes.py: with it)."""
    assert [w.message for w in run("M900 K0\nM572 S0\n")[1]] == [
        "'M900' ignored (linear advance off (K0), as without it)",
        "'M572' ignored (pressure advance off (S0), as without it)"]
    assert errors("M900 K0.05\nM572 S0.04\n") == [
        (8, 10, "'M900 K0.05': pressure (linear) advance needs machine.pressure_advance in the job; without it only "
                "K0 (off)"),
        (9, 10, "'M572 S0.04': pressure (linear) advance needs machine.pressure_advance in the job; without it only "
                "S0 (off)")]

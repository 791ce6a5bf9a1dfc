"""Real G-code files (tests/data/gcode, see its ATTRIBUTION.md): every one interprets, with facts checked
per file; and the job loader's G-code (a file next to the job, or inline) reaches the interpreter."""

from __future__ import annotations

import math
import re
import textwrap
from collections import Counter
from types import SimpleNamespace as NS

import pytest

from codegen.errors import JobError, SourceRef
from codegen.gcode import toolpath_from_gcode
from codegen.job import load_job
from codegen.toolpath.items import Arc, Dwell, Home, Limits, Line, Output
from tests.helpers import DATA, machine

DATA = DATA / "gcode"
PRINTER = ("x", "y", "z", "e")
MILL = ("x", "y", "z")
PLOTTER = ("x", "y")

FILES = {  # file -> the machine it is for
    "parser/circle.gcode": MILL,
    "parser/circle-inch.gcode": MILL,
    "parser/spaces.gcode": MILL,
    "plotter/circular_interpolation.gcode": PLOTTER,
    "plotter/smooth_curves_circular_interpolation.gcode": PLOTTER,
    "plotter/shapes.gcode": PLOTTER,
    "laser/hiking.gcode": PLOTTER,
    "slicer/benchy-prusaslicer.gcode": PRINTER,
    "slicer/benchy-arcs-arcwelder.gcode": PRINTER,
    "slicer/puzzle-cura.gcode": PRINTER,
}


def job_for(name: str, motors) -> NS:
    path = DATA / name
    return NS(machine=machine(motors=motors), path=path.parent / "job.yaml",
              program=NS(start=(0, 0), feed=1200, travel_feed=None, gcode=path.name,
                         gcode_source=SourceRef(str(path.parent / "job.yaml"), 9, 10)))


_cache: dict[str, tuple] = {}


def interpret(name: str):
    if name not in _cache:
        _cache[name] = toolpath_from_gcode(job_for(name, FILES[name]))
    return _cache[name]


def kinds(items) -> dict[str, int]:
    return dict(Counter(type(i).__name__ for i in items))


def final(items) -> list[float]:
    last = [i for i in items if isinstance(i, (Line, Arc, Home))][-1]
    return (last.position if isinstance(last, Home) else last.end).tolist()


def messages(warnings) -> list[str]:
    return [w.message for w in warnings]


def e_by_hand(name: str, relative: bool) -> float:
    """The extruder's machine position at the end, worked out from the file's E, G92 and M221 words alone:
    every E distance times the flow in force (M221 S, percent)."""
    e = program = 0.0  # machine position, and the program's E there
    flow = 1.0
    for line in (DATA / name).read_text().splitlines():
        code = line.split(";")[0]
        m = re.match(r"\s*(G[0-3]|G92)\s(.*)", code)
        word = re.search(r"E\s*([-+]?[\d.]+)", m.group(2)) if m else None
        percent = re.match(r"\s*M221\s+S([\d.]+)", code)
        if percent:
            flow = float(percent.group(1)) / 100.0
        elif word:
            value = float(word.group(1))
            if m.group(1) == "G92":
                program = value
            else:
                target = program + value if relative else value
                e, program = e + flow * (target - program), target
    return e


@pytest.mark.parametrize("name", sorted(FILES))
def test_every_file_interprets(name):
    toolpath, warnings = interpret(name)
    assert toolpath.items and {w.severity for w in warnings} <= {"warning", "note"}
    for a, b in zip(toolpath.items, toolpath.items[1:]):  # moves chain: each starts where the last ended
        if isinstance(a, (Line, Arc)) and isinstance(b, (Line, Arc)):
            assert b.start is a.end or (b.start == a.end).all()


def test_special_fields_has_exactly_its_checksum_error():
    with pytest.raises(JobError) as caught:
        toolpath_from_gcode(job_for("parser/special-fields.gcode", PRINTER))
    assert [(d.where.file, d.where.line, d.where.col, d.message) for d in caught.value.diagnostics] == [
        (str(DATA / "parser" / "special-fields.gcode"), 8, 16,
         "checksum mismatch: the line says *30, its checksum is 33")]


def test_circle():
    toolpath, warnings = interpret("parser/circle.gcode")
    arcs = [i for i in toolpath.items if isinstance(i, Arc)]
    assert kinds(toolpath.items) == {"Line": 3, "Arc": 4} and warnings == []
    assert [(a.center, a.radius, a.sweep) for a in arcs] == [((0, 0), 5, pytest.approx(-math.pi / 2))] * 4
    assert sum(a.sweep for a in arcs) == pytest.approx(-2 * math.pi)
    assert final(toolpath.items) == [0, 0, 5, 0] and arcs[0].feed == pytest.approx(200 / 60)


def test_circle_in_inches():
    toolpath, warnings = interpret("parser/circle-inch.gcode")
    arcs = [i for i in toolpath.items if isinstance(i, Arc)]
    assert kinds(toolpath.items) == {"Line": 6, "Arc": 4}
    assert [a.radius for a in arcs] == [pytest.approx(12.7)] * 4 and arcs[0].start.tolist() == [-12.7, 0, 0, 0]
    assert arcs[0].feed == pytest.approx(2.5 * 25.4 / 60)
    assert final(toolpath.items) == pytest.approx([0, 0, 6.35, 0])
    assert warnings == []  # G54 is the work coordinate system it selects


def test_spaces():
    toolpath, _ = interpret("parser/spaces.gcode")
    (move,) = toolpath.items  # the three lines say the same; the second and third do not move
    assert (move.end.tolist(), move.feed) == ([-5, 0, 0, 0], math.inf)


def test_svg2gcode_arcs():
    toolpath, warnings = interpret("plotter/circular_interpolation.gcode")
    arcs = [i for i in toolpath.items if isinstance(i, Arc)]
    assert kinds(toolpath.items) == {"Line": 20, "Arc": 59} and warnings == []
    assert (sum(a.sweep < 0 for a in arcs), sum(a.sweep > 0 for a in arcs)) == (11, 48)
    assert all(abs(a.sweep) < math.pi for a in arcs)  # R > 0: every arc the short way
    assert final(toolpath.items) == [7, 2, 0, 0]
    smooth, _ = interpret("plotter/smooth_curves_circular_interpolation.gcode")
    arcs = [i for i in smooth.items if isinstance(i, Arc)]
    assert kinds(smooth.items) == {"Line": 925, "Arc": 770}
    assert (sum(a.sweep < 0 for a in arcs), sum(a.sweep > 0 for a in arcs)) == (295, 475)
    assert final(smooth.items) == [59.288, 10.298, 0, 0] and {a.feed for a in arcs} == {5.0}


def test_svg2gcode_lines():
    toolpath, _ = interpret("plotter/shapes.gcode")
    assert kinds(toolpath.items) == {"Line": 944} and final(toolpath.items) == [105.925, 108.499, 0, 0]
    assert sum(i.feed == math.inf for i in toolpath.items) == 7  # the G0 moves


def test_laser():
    toolpath, warnings = interpret("laser/hiking.gcode")
    assert kinds(toolpath.items) == {"Output": 100, "Dwell": 49, "Line": 2874}
    assert [(w.severity, w.where.line, w.where.col, w.message) for w in warnings] == [
        ("note", 4, 4, "G4 P in milliseconds: G-code dialect marlin, guessed from line 8 ('M106' is Marlin's); "
                       "program.dialect sets it"),
        ("warning", 9, 4, "'S' ignored (the machine has no `laser:`, so M3/M4 switch the tool pin on and off only; "
                          "`machine.laser: {pwm_hz: 1000}` (a PWM laser) gives power control over S)")]
    lines = [i for i in toolpath.items if isinstance(i, Line)]
    assert sum(i.tool for i in lines) == 2825 and {i.power for i in lines if i.tool} == {1.0}
    assert {i.seconds for i in toolpath.items if isinstance(i, Dwell)} == {0.4}
    assert final(toolpath.items) == [448.66124, 288.35741, 0, 0]


def test_prusaslicer_benchy():
    toolpath, warnings = interpret("slicer/benchy-prusaslicer.gcode")
    items = toolpath.items
    assert kinds(items) == {"Limits": 3, "Output": 357, "Home": 1, "Line": 60360}
    assert final(items)[:3] == [178, 178, 78]
    assert final(items)[3] == pytest.approx(e_by_hand("slicer/benchy-prusaslicer.gcode", True), abs=1e-6)
    # M221 S95 after the 18 mm intro line, to the end: 5 % less filament than the file's E (4279.56152)
    assert final(items)[3] == pytest.approx(18 + 0.95 * (4279.56152 - 18), abs=1e-5)
    lines = [i for i in items if isinstance(i, Line)]
    # M204: P for moves that extrude, T for travel, R for E alone (counted by hand from the file, the same way)
    assert Counter(i.accel for i in lines) == {800: 39784, 1000: 14766, 2500: 3947, 1250: 1863}
    limits = [i for i in items if isinstance(i, Limits)]
    assert limits[0].max_accel == {"x": 2500, "y": 2500, "z": 400, "e": 5000}
    assert limits[1].max_velocity == {"x": 180, "y": 180, "z": 12, "e": 80}
    assert limits[2].jerk == {"x": 8, "y": 8, "z": 2, "e": 10}
    outputs = [(o.name, o.value, o.wait) for o in items if isinstance(o, Output) and o.name != "fan"]
    assert outputs == [("hotend", 170, False), ("bed", 60, False), ("hotend", 170, True), ("bed", 60, True),
                       ("hotend", 205, False), ("hotend", 205, True), ("bed", 50, False), ("hotend", 0, False),
                       ("bed", 0, False)]
    assert messages(warnings) == [
        "'M73' ignored (print progress); 139 times",
        "'G29' ignored (bed levelling; there is no probe)",
        "'M900' ignored (linear advance off (K0), as without it)",
        "'M84' ignored (motors off)",
    ]


def test_arcwelder_benchy():
    toolpath, warnings = interpret("slicer/benchy-arcs-arcwelder.gcode")
    items = toolpath.items
    arcs = [i for i in items if isinstance(i, Arc)]
    assert kinds(items) == {"Output": 147, "Home": 2, "Line": 22181, "Arc": 3772}
    assert (sum(a.sweep < 0 for a in arcs), sum(a.sweep > 0 for a in arcs)) == (1529, 2243)
    assert sum(a.end[3] > a.start[3] for a in arcs) == 3765  # all but 7 extrude
    assert sum(a.accel == math.inf for a in arcs) == 3772  # the file has no M204
    assert final(items) == pytest.approx([0, 0, 48, e_by_hand("slicer/benchy-arcs-arcwelder.gcode", False)])
    assert final(items)[3] == pytest.approx(4911.43746, abs=1e-6)
    assert messages(warnings) == ["'M84' ignored (motors off)"]


def test_cura_puzzle():
    toolpath, warnings = interpret("slicer/puzzle-cura.gcode")
    items = toolpath.items
    assert kinds(items) == {"Output": 10, "Home": 3, "Line": 32205}
    homes = [i for i in items if isinstance(i, Home)]
    assert [h.axes for h in homes] == [("x", "y"), ("z",), ("x", "y")]
    last = [i for i in items if isinstance(i, Line)][-1]  # the end code's G91 move: `G1 Z+0.5 E-5 X-20 Y-20`
    assert (last.end - last.start).tolist() == pytest.approx([-20, -20, 0.5, -5])
    # the last absolute E is 3196.98752, after the E3 primed before `G92 E0`; then G91 E-1 and E-5
    assert final(items) == pytest.approx([0, 0, 24.3, 3 + 3196.98752 - 1 - 5])
    assert messages(warnings) == ["'M117' ignored (display message)", "'M84' ignored (motors off)"]


# ---- through the job loader ----

MACHINE = """\
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
    y: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
    z: {steps_per_mm: 400, max_velocity: 10, max_accel: 200}
"""


def test_loaded_job_with_a_gcode_file():
    job = load_job(DATA / "circle-job.yaml")
    toolpath, warnings = toolpath_from_gcode(job)
    assert kinds(toolpath.items) == {"Line": 3, "Arc": 4} and warnings == []
    assert toolpath.start.tolist() == [0, 0, 0, 0] and toolpath.items[1].source.file == str(DATA / "parser" /
                                                                                             "circle.gcode")


def test_loaded_job_with_inline_gcode_points_into_the_job_file(tmp_path):
    path = tmp_path / "inline.yaml"
    path.write_text(MACHINE + textwrap.dedent("""\
        program:
          start: [1, 2]
          gcode: |
            G1 X10 F600
              G1 Y10 Q2
            G1 Z1 E1
        """))
    job = load_job(path)
    with pytest.raises(JobError) as caught:
        toolpath_from_gcode(job)
    assert [(d.where.line, d.where.col, d.message) for d in caught.value.diagnostics] == [
        (11, 14, "'Q2' is not a parameter of G1"),
        (12, 11, "'E1' moves e, but the machine has no e motor (motors: x, y, z)"),
    ]
    assert caught.value.render().splitlines()[1:3] == ["      G1 Y10 Q2", " " * 13 + "^"]
    toolpath, _ = toolpath_from_gcode(job_ok(tmp_path))
    assert [i.end.tolist() for i in toolpath.items] == [[10, 2, 0, 0], [10, 10, 0, 0]]


def job_ok(tmp_path):
    path = tmp_path / "ok.yaml"
    path.write_text(MACHINE + "program:\n  start: [1, 2]\n  gcode: |\n    G1 X10 F600\n    G1 Y10\n")
    return load_job(path)

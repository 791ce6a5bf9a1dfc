"""Random job files for the property tests (hypothesis): machines of every kinematics and programs of every
shape kind and of G-code, written as YAML text so that the real loader reads them.

Machines: cartesian, corexy, delta; 2 or 3 axes, sometimes an extruder; steps/mm 5 to 400; max velocity 5 to 500
mm/s and max acceleration 50 to 10,000 mm/s^2 (log-uniform, two orders of magnitude); junction deviation 0.001
to 0.2 mm; tolerance 1 um to 0.05 mm; per motor no `range`, a range that contains the program's box, or a tight
one that may cut it (the job is then refused at the shape or G-code line); sometimes inverted DIR pins, `start`,
`home: true`, `travel_feed`.

Programs: 1 to 3 shapes of every kind of JOB-FORMAT.md (line, polyline, points, arc, circle, ellipse, sine,
function with a random expression of the expression language, travel; 3-D points and `z:` on 3-axis machines;
per-shape feeds), or G-code: G0/G1 with feeds, G2/G3 in G17/G18/G19 with IJK or R (R < 0 beyond 180 degrees),
full circles, helical arcs, G90/G91, G20/G21, G92 offsets, G4, M3/M5, E words (M82/M83), and a little of Grbl
(G10 L20, G54/G55, G53, G28.1 + G28, G92.1).

The invariant (`outcome`): a job the loader accepts either builds with every check passing (findings.ok,
final == expected_final, and verify's second reading of its G-code finds the tables doing what it says), or is
refused with a positioned error (JobError, exit 2: every diagnostic has file:line:col) or a size error (exit 1:
the tables do not fit the chip, as `build` refuses them). Anything else (a failed check, a BuildError not about
size, any other exception) raises `Bug`.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

from codegen.errors import BuildError, JobError
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.tables.format import stream_bytes
from codegen.verify.chapters import whole_chapter
from codegen.verify.program_check import ProgramCheck

TARGETS = ("avr", "mcs51")
KINEMATICS = ("cartesian", "corexy", "delta")


# ---- numbers as YAML / G-code text (never an exponent: PyYAML reads `1e+04` as a string) ----

def _num(x: float, sig: int = 4) -> str:
    x = float(x)
    if x == 0 or not math.isfinite(x):
        return "0"
    digits = min(6, max(0, sig - 1 - math.floor(math.log10(abs(x)))))
    text = f"{x:.{digits}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _point(p) -> str:
    return "[" + ", ".join(_num(v) for v in p) + "]"


def _log_uniform(lo: float, hi: float, sig: int = 3):
    """Floats from lo to hi, log-uniform, rounded to `sig` significant digits (as people write them)."""
    return st.floats(math.log10(lo), math.log10(hi)).map(lambda e: float(_num(10 ** e, sig)))


def _mixed(common, lo, hi, sig=3):
    """The values people use, or any value of the span."""
    return st.one_of(st.sampled_from(common), _log_uniform(lo, hi, sig))


# ---- machines ----

class Box:
    """The coordinate box (mm) a program stays in; `three`: the machine has a z motor."""

    def __init__(self, lo, hi, three, delta=False):
        self.lo, self.hi, self.three, self.delta = list(lo), list(hi), three, delta

    def coord(self, draw, axis):
        lo, hi = self.lo[axis], self.hi[axis]
        return draw(st.floats(lo, hi, allow_nan=False)) if hi > lo else lo

    def room(self, centre, floor=0.3):
        return min(centre[0] - self.lo[0], self.hi[0] - centre[0], centre[1] - self.lo[1], self.hi[1] - centre[1],
                   40.0)


def _range(draw, lo: float, hi: float) -> str:
    """'' (no range), a range around [lo, hi], or a tight one that may cut it."""
    mode = draw(st.sampled_from(["none", "none", "none", "contains", "contains", "tight"]))
    if mode == "none":
        return ""
    if mode == "contains":
        a, b = lo - draw(st.floats(0.5, 20)), hi + draw(st.floats(0.5, 20))
    else:
        span = hi - lo
        a, b = lo + draw(st.floats(0, 0.45)) * span, hi - draw(st.floats(0, 0.45)) * span
    return f", range: [{_num(a, 5)}, {_num(b, 5)}]"


@st.composite
def machines(draw, kinematics: str):
    """(the machine's YAML text, the Box its programs stay in, whether it has an extruder)."""
    three = kinematics == "delta" or draw(st.booleans())
    extruder = draw(st.integers(0, 4)) == 0
    names = {"cartesian": ("x", "y", "z"), "corexy": ("a", "b", "z"), "delta": ("a", "b", "c")}[kinematics]
    names = names if three else names[:2]
    text = ["machine:", f"  kinematics: {kinematics}"]
    if kinematics == "delta":
        radius = draw(_mixed([60.0, 90.0, 105.2, 140.0], 40, 200))
        rod = float(_num(radius * draw(st.floats(1.7, 2.6)), 5))
        height = draw(_mixed([150.0, 250.0, 400.0], 100, 600))
        reach = 0.5 * radius
        box = Box((-reach, -reach, 0.0), (reach, reach, min(60.0, 0.5 * height)), True, delta=True)
        top = height + math.sqrt(rod * rod - radius * radius)  # every carriage at home
        motor_span = {n: (0.0, top) for n in names}
        angles = ""
        if draw(st.integers(0, 3)) == 0:
            angles = f", tower_angles: [{', '.join(_num(a + draw(st.floats(-4, 4))) for a in (210, 330, 90))}]"
        delta = f"  delta: {{radius: {_num(radius, 5)}, diagonal_rod: {_num(rod, 5)}, height: {_num(height, 5)}{angles}}}"
    else:
        width = draw(st.sampled_from([10.0, 40.0, 80.0]))
        box = Box((0.0, 0.0, 0.0), (width, width, 20.0 if three else 0.0), three)
        if kinematics == "cartesian":
            motor_span = {"x": (0.0, width), "y": (0.0, width), "z": (0.0, 20.0)}
        else:  # A = X + Y, B = X - Y
            motor_span = {"a": (0.0, 2 * width), "b": (-width, width), "z": (0.0, 20.0)}
        delta = ""
    text.append("  steppers:")
    for name in names + (("e",) if extruder else ()):
        spm = draw(_mixed([5, 6.25, 12.732, 40, 80, 100, 157.5, 200, 400], 5, 400, 4))
        vmax = draw(_mixed([5, 20, 60, 150, 300, 500], 5, 500))
        amax = draw(_mixed([50, 200, 800, 3000, 10000], 50, 10000))
        extra = _range(draw, *motor_span[name]) if name != "e" else ""
        if draw(st.integers(0, 5)) == 0:
            extra += ", invert_dir: true"
        text.append(f"    {name}: {{steps_per_mm: {_num(spm, 5)}, max_velocity: {_num(vmax)}, "
                    f"max_accel: {_num(amax)}{extra}}}")
    if draw(st.integers(0, 5)):
        text.append(f"  junction_deviation: {_num(draw(_mixed([0.002, 0.01, 0.05, 0.1], 0.001, 0.2)))}")
    if draw(st.integers(0, 5)):
        text.append(f"  tolerance: {_num(draw(_mixed([0.001, 0.002, 0.005, 0.01, 0.02, 0.05], 0.001, 0.05)))}")
    if delta:
        text.append(delta)
    return "\n".join(text), box, extruder


# ---- shapes ----

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
            return _num(draw(st.floats(0.1, 10)), 3)
        if leaf == "xs":
            return f"x / {_num(draw(st.floats(2, 40)), 3)}"
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
        return f"{_num(height / peak, 3)} * ({expression})"
    return expression


KINDS = ("line", "polyline", "points", "arc", "circle", "ellipse", "sine", "function", "travel")


@st.composite
def shape(draw, box: Box):
    kind = draw(st.sampled_from(KINDS))
    # A delta homes: a 2-D shape is drawn at the current height (the home height at first, where it cannot move
    # sideways), so a delta's shapes mostly carry their height.
    full = box.delta and draw(st.integers(0, 7)) > 0
    z = f", z: {_num(box.coord(draw, 2))}" if (full or (box.three and draw(st.booleans()))) else ""
    feed = f", feed: {_num(draw(_mixed([60, 600, 1500, 6000, 30000], 30, 30000)))}" if draw(st.booleans()) else ""
    if kind in ("line", "travel"):
        (a,) = draw(points(box, full=full))
        start = ""
        if kind == "line" and draw(st.booleans()):
            start = f"from: {_point(draw(points(box, full=full))[0])}, "
        return f"- {kind}: {{{start}to: {_point(a)}{feed}}}"
    if kind in ("polyline", "points"):
        pts = draw(points(box, n=draw(st.integers(1 if kind == "points" else 2, 5)), full=full))
        if kind == "points":
            return "- points: [" + ", ".join(_point(p) for p in pts) + "]"
        return f"- polyline: {{points: [{', '.join(_point(p) for p in pts)}]{feed}}}"
    centre = [box.coord(draw, 0), box.coord(draw, 1)]
    room = box.room(centre)
    r = draw(st.floats(0.3, max(0.31, room))) if draw(st.integers(0, 5)) else draw(st.floats(0.01, 0.3))
    if kind == "arc":
        sweep = draw(st.one_of(st.sampled_from([360.0, -360.0, 90.0, -180.0]),
                               st.floats(-360, 360).filter(lambda s: abs(s) > 0.01)))
        return (f"- arc: {{center: {_point(centre)}, radius: {_num(r)}, start: {_num(draw(st.floats(-360, 360)))}, "
                f"sweep: {_num(sweep)}{z}{feed}}}")
    if kind == "circle":
        start = f", start: {_num(draw(st.floats(-180, 180)))}" if draw(st.booleans()) else ""
        direction = draw(st.sampled_from(["ccw", "cw"]))
        return f"- circle: {{center: {_point(centre)}, radius: {_num(r)}{start}, direction: {direction}{z}{feed}}}"
    if kind == "ellipse":
        b = max(0.01, draw(st.floats(0.05, 1.0)) * r)
        a, b = (r, b) if draw(st.booleans()) else (b, r)
        return (f"- ellipse: {{center: {_point(centre)}, a: {_num(a)}, b: {_num(b)}, "
                f"rotation: {_num(draw(st.floats(-180, 180)))}, start: {_num(draw(st.floats(-180, 180)))}, "
                f"sweep: {_num(draw(st.floats(-360, 360).filter(lambda s: abs(s) > 0.5)))}{z}{feed}}}")
    width = box.hi[0] - box.lo[0]
    height = box.hi[1] - box.lo[1]
    if kind == "sine":
        amplitude = draw(st.floats(-0.4, 0.4)) * height
        length = draw(st.floats(0.5, 0.8 * width)) * draw(st.sampled_from([1, -1]))
        x0 = box.lo[0] + 0.1 * width if length > 0 else box.hi[0] - 0.1 * width
        y0 = 0.5 * (box.lo[1] + box.hi[1])
        omega = draw(_mixed([0.1, 0.25, 1.0], 0.01, 3.0)) * draw(st.sampled_from([1, 1, -1]))
        return (f"- sine: {{origin: {_point([x0, y0])}, amplitude: {_num(amplitude)}, "
                f"omega: {_num(omega)}, phase: {_num(draw(st.floats(-360, 360)))}, "
                f"length: {_num(length)}{z}{feed}}}")
    # function: a random expression, scaled to fit the box's height; x from `a` to `b` (either way round)
    span = draw(st.floats(0.5, 0.7 * width))
    expression = _scaled(draw(expressions()), span, 0.4 * height)
    if draw(st.integers(0, 9)) == 0:
        expression = _num(draw(st.floats(-5, 5)))  # `y: 2` is a constant function
    x = [0.0, span] if draw(st.booleans()) else [span, 0.0]
    origin = [box.lo[0] + 0.15 * width, 0.5 * (box.lo[1] + box.hi[1])]
    return f"- function: {{y: \"{expression}\", x: {_point(x)}, origin: {_point(origin)}{z}{feed}}}"


# ---- G-code ----

class _GState:
    """What the generated G-code has said so far: the tool in machine mm, units, distance mode, offsets."""

    def __init__(self, here):
        self.here = list(here)  # machine coordinates, mm (x, y, z)
        self.inches = False
        self.relative = False
        self.off = [0.0, 0.0, 0.0]  # machine = program + off (G92 and work systems together)
        self.e = 0.0

    @property
    def scale(self):
        return 25.4 if self.inches else 1.0

    def word(self, axis: int, value_mm: float, letter: str | None = None) -> str:
        """The axis word for a target in machine mm; updates nothing."""
        letter = letter or "XYZ"[axis]
        base = self.here[axis] if self.relative else self.off[axis]
        digits = 5 if self.inches else 4
        return f"{letter}{(value_mm - base) / self.scale:.{digits}f}"

    def parsed(self, axis: int, word: str) -> float:
        """The machine coordinate the interpreter reads from a word this state wrote."""
        base = self.here[axis] if self.relative else self.off[axis]
        return base + float(word[1:]) * self.scale


@st.composite
def gcode(draw, box: Box, extruder: bool):
    """A G-code program: see the module's docstring."""
    lines = [draw(st.sampled_from(["G21", "G21 G90", "G90"]))]
    if extruder:
        lines.append(draw(st.sampled_from(["M82", "M83"])))
    first = draw(points(box, full=box.three))[0]
    g = _GState(first + [box.lo[2]] * (3 - len(first)))
    if box.delta:  # from the top of a homed delta: down first, then across
        lines += [f"G0 Z{first[2]:.3f}", f"G0 X{first[0]:.3f} Y{first[1]:.3f}"]
    else:
        lines.append(f"G0 X{first[0]:.3f} Y{first[1]:.3f}" + (f" Z{first[2]:.3f}" if box.three else ""))
    lines.append(f"G1 F{_num(draw(_mixed([120, 900, 3000, 12000], 30, 30000)))}")
    absolute_e = "M82" in lines

    def feed():
        if draw(st.integers(0, 3)):
            return ""
        f = draw(_mixed([120, 900, 3000, 12000], 30, 30000)) / g.scale
        return f" F{_num(f)}"

    def e_word(length):
        if not extruder or draw(st.booleans()):
            return ""
        de = length * draw(st.floats(0.0, 0.1))
        g.e += de
        return f" E{(g.e if absolute_e else de) / g.scale:.5f}"

    def move(code, target):
        words = [g.word(a, target[a]) for a in range(3) if a < 2 or box.three]
        words = [w for a, w in enumerate(words) if a < 2 or draw(st.booleans())]  # Z not always written
        new = list(g.here)
        for w in words:
            a = "XYZ".index(w[0])
            new[a] = g.parsed(a, w)
        length = math.dist(new, g.here)
        text = f"{code} {' '.join(words)}{feed() if code == 'G1' else ''}{e_word(length) if code == 'G1' else ''}"
        g.here = new
        return text

    for _ in range(draw(st.integers(1, 7))):
        kind = draw(st.sampled_from(["G0", "G1", "G1", "arc", "arc", "arc", "G91", "G20", "G92", "misc", "grbl"]))
        if kind in ("G0", "G1"):
            p = draw(points(box, full=box.three))[0]
            lines.append(move(kind, p + g.here[len(p):]))
        elif kind == "arc":
            planes = ["G17"] + (["G18", "G19"] if box.three else [])
            plane = draw(st.sampled_from(planes))
            u, v, w = {"G17": (0, 1, 2), "G18": (2, 0, 1), "G19": (1, 2, 0)}[plane]
            angle = draw(st.floats(0, 2 * math.pi))
            r = draw(st.floats(0.3, 10.0))
            centre = (g.here[u] + r * math.cos(angle), g.here[v] + r * math.sin(angle))
            full_circle = draw(st.integers(0, 5)) == 0
            sweep = 2 * math.pi if full_circle else draw(st.floats(0.05, 2 * math.pi - 0.05))
            code = draw(st.sampled_from(["G2", "G3"]))
            start = math.atan2(g.here[v] - centre[1], g.here[u] - centre[0])
            end = start + (-sweep if code == "G2" else sweep)
            target = list(g.here)
            target[u] = centre[0] + r * math.cos(end)
            target[v] = centre[1] + r * math.sin(end)
            helix = box.three and draw(st.integers(0, 3)) == 0
            if helix:
                target[w] = box.coord(draw, w) if w == 2 else target[w] + draw(st.floats(-3, 3))
            words = [g.word(u, target[u]), g.word(v, target[v])] + ([g.word(w, target[w])] if helix else [])
            if full_circle and draw(st.booleans()):
                words = words[2:]  # a full circle: no end point at all
            if not full_circle and draw(st.integers(0, 2)) == 0:  # R form: negative beyond 180 degrees
                radius = (-r if sweep > math.pi else r) / g.scale
                centre_words = f"R{radius:.{5 if g.inches else 4}f}"
            else:
                letters = "IJK"
                digits = 5 if g.inches else 4
                centre_words = (f"{letters[u]}{(centre[0] - g.here[u]) / g.scale:.{digits}f} "
                                f"{letters[v]}{(centre[1] - g.here[v]) / g.scale:.{digits}f}")
            lines.append(plane) if plane != "G17" or draw(st.booleans()) else None
            lines.append(f"{code} {' '.join(words)} {centre_words}{feed()}")
            new = list(g.here)
            for wd in words:
                a = "XYZ".index(wd[0])
                new[a] = g.parsed(a, wd)
            g.here = new
            if plane != "G17":
                lines.append("G17")
        elif kind == "G91":
            g.relative = not g.relative
            lines.append("G91" if g.relative else "G90")
        elif kind == "G20":
            g.inches = not g.inches
            lines.append("G20" if g.inches else "G21")
        elif kind == "G92":
            if draw(st.integers(0, 3)) == 0:
                lines.append("G92.1" if draw(st.booleans()) else "G92 X0 Y0" + (" Z0" if box.three else ""))
                g.off = [0.0, 0.0, 0.0] if lines[-1] == "G92.1" else [g.here[0], g.here[1],
                                                                      g.here[2] if box.three else g.off[2]]
            else:
                p = [draw(st.floats(-50, 50)), draw(st.floats(-50, 50))]
                lines.append(f"G92 X{p[0] / g.scale:.3f} Y{p[1] / g.scale:.3f}")
                g.off[0] = g.here[0] - float(f"{p[0] / g.scale:.3f}") * g.scale
                g.off[1] = g.here[1] - float(f"{p[1] / g.scale:.3f}") * g.scale
        elif kind == "misc":
            lines.append(draw(st.sampled_from(["G4 P0.05", "M3 S1000", "M5", "M4 S200", "G94", "G64", "M107"])))
        else:  # grbl: work systems, machine coordinates, a stored position
            what = draw(st.sampled_from(["G10", "G53", "G28"]))
            if what == "G10" and not g.relative:
                p = [draw(st.floats(-20, 20)), draw(st.floats(-20, 20))]
                system = draw(st.sampled_from(["G54", "G55"]))
                lines += [f"G10 L20 P{1 + (system == 'G55')} X{p[0] / g.scale:.3f} Y{p[1] / g.scale:.3f}", system]
                # L20 sets the system so that the tool is at p; G92's offset stays on top of it
                g.off[0] = g.here[0] - float(f"{p[0] / g.scale:.3f}") * g.scale
                g.off[1] = g.here[1] - float(f"{p[1] / g.scale:.3f}") * g.scale
            elif what == "G53" and not g.relative:
                p = draw(points(box))[0]
                lines.append(f"G53 G0 X{p[0] / g.scale:.4f} Y{p[1] / g.scale:.4f}")
                g.here[0], g.here[1] = (float(f"{c / g.scale:.4f}") * g.scale for c in p[:2])
            elif what == "G28":
                lines.append("G28.1")
                stored = list(g.here)
                p = draw(points(box))[0]
                lines.append(move("G1", p + g.here[2:]))
                lines.append("G28")
                g.here = stored
    if draw(st.integers(0, 4)) == 0:
        lines.append(draw(st.sampled_from(["M2", "M30", "M5"])))
    return "\n".join(lines)


# ---- jobs ----

@st.composite
def jobs(draw, kinematics: str, target: str):
    """A whole job file's text."""
    machine, box, extruder = draw(machines(kinematics))
    program = ["program:"]
    if draw(st.integers(0, 3)) == 0:
        start = draw(points(box, full=box.delta))[0]
        program.append(f"  start: {_point(start)}")
    if kinematics != "delta" and draw(st.integers(0, 9)) == 4:
        program.append("  home: true")
    if draw(st.booleans()):
        program.append(f"  feed: {_num(draw(_mixed([120, 600, 1500, 6000, 30000], 30, 30000)))}")
    if draw(st.integers(0, 3)) == 0:
        program.append(f"  travel_feed: {_num(draw(_mixed([600, 3000, 12000], 60, 60000)))}")
    if draw(st.integers(0, 2)) == 0:
        program.append("  gcode: |")
        program += ["    " + line for line in draw(gcode(box, extruder)).splitlines()]
    else:
        program.append("  shapes:")
        program += ["    " + draw(shape(box)) for _ in range(draw(st.integers(1, 3)))]
    return "\n".join(["name: prop", f"target: {target}", machine, *program]) + "\n"


# ---- the invariant ----

class Bug(AssertionError):
    """A job the loader accepted that neither built with every check passing nor was refused cleanly.
    `classes`: the failure's message classes (numbers blanked), one per problem."""

    def __init__(self, message: str, classes: list[str]):
        super().__init__(message)
        self.classes = classes


def message_class(text: str) -> str:
    """A message with its numbers, quoted names and file names blanked: one class per kind of message."""
    text = re.sub(r"/\S+\.yaml", "FILE", text)
    text = re.sub(r" \(y = .*", "", text)  # the function's expression
    text = re.sub(r"\b(motor|carriage|axis) \w\b", r"\1 M", text)
    text = re.sub(r"[-+]?\d+(\.\d+)?(e[-+]?\d+)?", "#", text)
    return re.sub(r"\s+", " ", text).strip()[:160]


def _positioned(err: JobError) -> bool:
    return bool(err.diagnostics) and all(d.where.file and d.where.line > 0 and d.where.col > 0
                                         for d in err.diagnostics)


def outcome(text: str, folder: Path) -> str:
    """Run one job through the loader and the host build (as `printer-codegen build` does, without compiling).
    Returns 'built', 'invalid: <class>' (the loader refused it), 'refused: <class>' (a positioned error from the
    build) or 'too big'; raises Bug for anything else."""
    path = folder / "job.yaml"
    path.write_text(text)
    try:
        job = load_job(path)
    except JobError as err:
        if not _positioned(err):
            raise Bug(f"loader error without file:line:col: {err.diagnostics}",
                      ["unpositioned loader error: " + message_class(d.message) for d in err.diagnostics])
        return "invalid: " + message_class(err.diagnostics[0].message)
    try:
        host = host_build(job)
    except JobError as err:
        if not _positioned(err):
            raise Bug(f"error without file:line:col: {err.diagnostics}",
                      ["unpositioned error: " + message_class(d.message) for d in err.diagnostics])
        return "refused: " + message_class(err.diagnostics[0].message)
    except BuildError as err:
        if "fit" in str(err):
            return "too big"
        raise Bug(f"BuildError not about size: {err}", ["BuildError: " + message_class(str(err))])
    except Exception as err:  # noqa: BLE001 - any other exception is a bug
        import traceback

        frame = traceback.extract_tb(err.__traceback__)[-1]
        where = f"{Path(frame.filename).name}:{frame.name}"
        raise Bug(f"{type(err).__name__} in {where}: {err}",
                  [f"{type(err).__name__} in {where}: " + message_class(str(err))]) from err
    f = host.findings
    if not f.ok:
        raise Bug("a check failed: " + "; ".join(f.problems), [message_class(p) for p in f.problems])
    if f.final != f.expected_final:
        raise Bug(f"final {f.final} != expected {f.expected_final}", ["final != expected_final"])
    against = ProgramCheck(host)  # the tables against verify's own reading of the G-code
    against.add(whole_chapter(host))
    problems = against.finish()
    if problems:
        raise Bug("the tables against the G-code: " + "; ".join(problems[:3]), [message_class(p) for p in problems])
    if stream_bytes(host.schedule) >= host.target.flash_bytes:  # build refuses it before compiling
        return "too big"
    return "built"

"""Random job files for the property tests (hypothesis): machines of every kinematics and programs of every
shape kind and of G-code, written as YAML text so that the real loader reads them.

The invariant (`outcome`): a job the loader accepts either builds with every check passing, or is refused with a
positioned error (exit 2) or a size error (exit 1). Anything else is a bug of ours.
"""

from __future__ import annotations

import math
from pathlib import Path

from hypothesis import strategies as st

from codegen.errors import BuildError, JobError
from codegen.job import load_job
from codegen.pipeline import host_build

TARGETS = ("avr", "mcs51")


def _num(x: float) -> str:
    return f"{x:.4g}"


def _point(p) -> str:
    return "[" + ", ".join(_num(v) for v in p) + "]"


@st.composite
def machines(draw, kinematics: str):
    """A machine dict (YAML-ready text pieces) and the box its programs stay in: ((lo, hi) per axis)."""
    three = kinematics == "delta" or draw(st.booleans())
    names = {"cartesian": ("x", "y", "z"), "corexy": ("a", "b", "z"), "delta": ("a", "b", "c")}[kinematics]
    names = names if three else names[:2]
    steppers = []
    for name in names:
        spm = draw(st.sampled_from([5, 6.25, 12.732, 40, 80, 100, 157.5, 200, 400]))
        vmax = draw(st.sampled_from([5, 20, 60, 150, 300, 500]))
        amax = draw(st.sampled_from([50, 200, 800, 3000, 10000]))
        steppers.append(f"    {name}: {{steps_per_mm: {spm}, max_velocity: {vmax}, max_accel: {amax}}}")
    tolerance = draw(st.sampled_from([0.001, 0.002, 0.005, 0.0125, 0.02, 0.05]))
    jd = draw(st.sampled_from([0.002, 0.01, 0.05, 0.1]))
    text = ["machine:", f"  kinematics: {kinematics}", "  steppers:", *steppers,
            f"  junction_deviation: {jd}", f"  tolerance: {tolerance}"]
    if kinematics == "delta":
        radius = draw(st.sampled_from([60.0, 90.0, 105.2, 140.0]))
        rod = round(radius * draw(st.sampled_from([1.8, 2.0, 2.4])), 1)
        height = draw(st.sampled_from([150.0, 250.0, 400.0]))
        text.append(f"  delta: {{radius: {radius}, diagonal_rod: {rod}, height: {height}}}")
        reach = 0.5 * radius
        box = ((-reach, reach), (-reach, reach), (0.0, min(60.0, 0.5 * height)))
    else:
        box = ((0.0, 80.0), (0.0, 80.0), (0.0, 20.0) if three else (0.0, 0.0))
    return "\n".join(text), box, three


def _coord(draw, box, axis):
    lo, hi = box[axis]
    return draw(st.floats(lo, hi, allow_nan=False, allow_infinity=False)) if hi > lo else lo


@st.composite
def points(draw, box, three, n=1, full=False):
    """Points in the box; with `full` always with their height."""
    out = []
    for _ in range(n):
        p = [_coord(draw, box, 0), _coord(draw, box, 1)]
        if full or (three and draw(st.booleans())):
            p.append(_coord(draw, box, 2))
        out.append(p)
    return out


def _radius(draw, box, centre, floor=0.5):
    room = min(centre[0] - box[0][0], box[0][1] - centre[0], centre[1] - box[1][0], box[1][1] - centre[1])
    return draw(st.floats(floor, max(floor, room), allow_nan=False)) if room > floor else floor


EXPRESSIONS = ["sin(x)", "x**2 / 40", "3 * cos(x / 5)", "sqrt(x + 1)", "exp(x / 30)", "abs(x - 10) / 3",
               "2 * sin(x) * cos(x / 3)", "log(x + 2)", "atan(x / 4) * 5", "-x / 2 + 1", "tan(x / 40)"]


@st.composite
def shape(draw, box, three, delta=False):
    kind = draw(st.sampled_from(["line", "polyline", "points", "arc", "circle", "ellipse", "sine", "function",
                                 "travel"]))
    # A delta homes: its 2-D shapes would be drawn at the home height, where it cannot move sideways.
    given = delta or (three and box[2][1] > 0 and draw(st.booleans()))
    z = f", z: {_num(_coord(draw, box, 2))}" if given else ""
    feed = f", feed: {draw(st.sampled_from([60, 600, 1500, 6000, 30000]))}" if draw(st.booleans()) else ""
    if kind == "line":
        (a,) = draw(points(box, three, full=delta))
        start = f"from: {_point(draw(points(box, three, full=delta))[0])}, " if draw(st.booleans()) else ""
        return f"- line: {{{start}to: {_point(a)}{feed}}}"
    if kind in ("polyline", "points"):
        pts = draw(points(box, three, n=draw(st.integers(2, 5)), full=delta))
        if kind == "points":
            return "- points: [" + ", ".join(_point(p) for p in pts) + "]"
        return f"- polyline: {{points: [{', '.join(_point(p) for p in pts)}]{feed}}}"
    if kind == "travel":
        return f"- travel: {{to: {_point(draw(points(box, three, full=delta))[0])}}}"
    centre = [_coord(draw, box, 0), _coord(draw, box, 1)]
    r = _radius(draw, box, centre)
    if kind == "arc":
        sweep = draw(st.floats(-360, 360, allow_nan=False).filter(lambda s: abs(s) > 0.5))
        return (f"- arc: {{center: {_point(centre)}, radius: {_num(r)}, start: {_num(draw(st.floats(-180, 180)))}, "
                f"sweep: {_num(sweep)}{z}{feed}}}")
    if kind == "circle":
        direction = draw(st.sampled_from(["ccw", "cw"]))
        return f"- circle: {{center: {_point(centre)}, radius: {_num(r)}, direction: {direction}{z}{feed}}}"
    if kind == "ellipse":
        b = draw(st.floats(0.3, 1.0)) * r
        return (f"- ellipse: {{center: {_point(centre)}, a: {_num(r)}, b: {_num(b)}, "
                f"rotation: {_num(draw(st.floats(-90, 90)))}, sweep: {_num(draw(st.floats(10, 360)))}{z}{feed}}}")
    width = box[0][1] - box[0][0]
    if kind == "sine":
        amplitude = min(r, 0.2 * width)
        length = draw(st.floats(2, 0.6 * width)) * draw(st.sampled_from([1, -1]))
        x0 = box[0][0] + 0.2 * width if length > 0 else box[0][1] - 0.2 * width
        return (f"- sine: {{origin: {_point([x0, centre[1]])}, amplitude: {_num(amplitude)}, "
                f"omega: {_num(draw(st.floats(0.02, 2.0)))}, phase: {_num(draw(st.floats(0, 360)))}, "
                f"length: {_num(length)}{z}{feed}}}")
    expression = draw(st.sampled_from(EXPRESSIONS))
    span = draw(st.floats(1, 0.5 * width))
    origin = [box[0][0] + 0.25 * width, 0.5 * (box[1][0] + box[1][1])]
    return f"- function: {{y: \"{expression}\", x: [0, {_num(span)}], origin: {_point(origin)}{z}{feed}}}"


@st.composite
def gcode(draw, box, three):
    """G-code lines: G0-G3 (arcs in the planes the machine has), G91 stretches, G20 inches, G92 offsets."""
    lines = ["G21", "G90"]
    here = [0.5 * (box[0][0] + box[0][1]), 0.5 * (box[1][0] + box[1][1]), box[2][0]]
    lines.append(f"G0 X{here[0]:.3f} Y{here[1]:.3f}" + (f" Z{here[2]:.3f}" if three else ""))
    lines.append(f"G1 F{draw(st.sampled_from([120, 900, 3000, 12000]))}")
    for _ in range(draw(st.integers(1, 6))):
        kind = draw(st.sampled_from(["G0", "G1", "G2", "G3", "G91", "G20", "G92"]))
        if kind in ("G0", "G1"):
            (p,) = draw(points(box, three))
            z = f" Z{p[2]:.3f}" if len(p) > 2 else ""
            lines.append(f"{kind} X{p[0]:.3f} Y{p[1]:.3f}{z}")
            here = [p[0], p[1], p[2] if len(p) > 2 else here[2]]
        elif kind in ("G2", "G3"):
            planes = ["G17"] + (["G18", "G19"] if three else [])
            plane = draw(st.sampled_from(planes))
            u, v = {"G17": (0, 1), "G18": (2, 0), "G19": (1, 2)}[plane]
            letters = {0: "I", 1: "J", 2: "K"}
            angle = draw(st.floats(0, 2 * math.pi))
            r = draw(st.floats(0.5, 8.0))
            off = (r * math.cos(angle), r * math.sin(angle))
            sweep = draw(st.floats(0.2, 2 * math.pi - 0.2))
            centre = (here[u] + off[0], here[v] + off[1])
            start = math.atan2(-off[1], -off[0])
            end = start + (-sweep if kind == "G2" else sweep)
            target = here[:]
            target[u] = centre[0] + r * math.cos(end)
            target[v] = centre[1] + r * math.sin(end)
            axes = "XYZ"
            words = f"{axes[u]}{target[u]:.4f} {axes[v]}{target[v]:.4f}"
            lines += [plane, f"{kind} {words} {letters[u]}{off[0]:.4f} {letters[v]}{off[1]:.4f}", "G17"]
            here = target
        elif kind == "G91":
            dx, dy = draw(st.floats(-5, 5)), draw(st.floats(-5, 5))
            lines += ["G91", f"G1 X{dx:.3f} Y{dy:.3f}", "G90"]
            here = [here[0] + round(dx, 3), here[1] + round(dy, 3), here[2]]
        elif kind == "G20":
            dx = draw(st.floats(-0.2, 0.2))
            lines += ["G20", "G91", f"G1 X{dx:.4f}", "G90", "G21"]
            here = [here[0] + round(dx, 4) * 25.4, here[1], here[2]]
        else:  # G92: the program's coordinates shift; the next moves are written in them
            lines += [f"G92 X0 Y0", f"G1 X{draw(st.floats(-3, 3)):.3f} Y{draw(st.floats(-3, 3)):.3f}",
                      f"G92 X{here[0]:.3f} Y{here[1]:.3f}"]
    return "\n".join(lines)


@st.composite
def jobs(draw, kinematics: str, target: str):
    machine, box, three = draw(machines(kinematics))
    program = ["program:"]
    if draw(st.booleans()):
        program.append(f"  feed: {draw(st.sampled_from([120, 600, 1500, 6000, 30000]))}")
    if draw(st.integers(0, 3)) == 0:
        text = draw(gcode(box, three))
        program.append("  gcode: |")
        program += ["    " + line for line in text.splitlines()]
    else:
        program.append("  shapes:")
        delta = kinematics == "delta"
        program += ["    " + draw(shape(box, three, delta)) for _ in range(draw(st.integers(1, 3)))]
    return "\n".join([f"name: prop", f"target: {target}", machine, *program]) + "\n"


def outcome(text: str, folder: Path) -> str:
    """Run one job through the loader and the host build. Returns 'built', 'refused: ...' or 'too big'; raises
    AssertionError for a bug (a failed check, an unpositioned refusal, any other exception)."""
    path = folder / "job.yaml"
    path.write_text(text)
    try:
        job = load_job(path)
    except JobError as err:
        assert all(d.where.line for d in err.diagnostics), err.diagnostics
        return "invalid"
    try:
        host = host_build(job)
    except JobError as err:
        assert all(d.where.line and d.where.col for d in err.diagnostics), err.diagnostics
        return "refused: " + err.diagnostics[0].message.split(":")[0][:60]
    except BuildError as err:
        assert "fit" in str(err), f"build error that is not about size: {err}"
        return "too big"
    f = host.findings
    assert f.ok, f.problems
    assert f.final == f.expected_final
    return "built"

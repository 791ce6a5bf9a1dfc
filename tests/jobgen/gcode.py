"""Random G-code for the property tests: G0/G1 with feeds, G2/G3 in G17/G18/G19 with IJK or R (R < 0 beyond 180
degrees), full circles, helical arcs, G90/G91, G20/G21, G92 offsets, G4, M3/M5, E words (M82/M83), a little of
Grbl (G10 L20, G54/G55, G53, G28.1 + G28), and issue 29's codes: M593 [X|Y] F<Hz> D<zeta> (F0: off) and M900 K /
M572 D0 S (pressure advance's K, changed mid-print, K0 too). Now and then one of those has a value the job must
refuse at its word (an F off 1 to 1000 Hz, a damping beyond the shaper's, a K below 0 or without the machine's
pressure_advance, an extruder other than D0): the job is then refused with its position."""

from __future__ import annotations

import math

from hypothesis import strategies as st

from codegen.job.schema.shaping import SHAPER_MAX_DAMPING
from tests.jobgen.machines import Drawn, mixed, num, shaper_damping, shaper_hz
from tests.jobgen.shapes import points


@st.composite
def m593(draw, machine: Drawn):
    """M593 with the axes it names (none: x and y), a frequency (0: off) and a damping ratio, each maybe absent;
    one in eight a value the job refuses. Valid frequencies keep above `machine.lowest_hz` (its max_smoothing)."""
    axes = draw(st.sampled_from(["", "", " X", " Y", " X Y"]))
    named = [a.lower() for a in axes.split()] or ["x", "y"]
    types = [machine.shaper_types[a] for a in named]
    words = [f"M593{axes}"]
    bad = draw(st.sampled_from(["", "F", "D"]) if draw(st.integers(0, 7)) == 7 else st.just(""))
    if bad == "F":
        words.append(f"F{num(draw(st.sampled_from([0.5, -10.0, 1500.0, 0.01])))}")
    elif draw(st.integers(0, 4)):
        freq = draw(st.one_of(st.just(0.0), shaper_hz()))
        if machine.lowest_hz is not None and freq:
            freq = max(freq, machine.lowest_hz)
        words.append(f"F{num(freq)}")
    largest = min(SHAPER_MAX_DAMPING[t] for t in types)
    if bad == "D":
        words.append(f"D{num(draw(st.sampled_from([0.0, -0.1, largest + 0.05, 1.0, 2.0])))}")
    elif draw(st.booleans()):
        words.append(f"D{num(shaper_damping(draw, min(types, key=SHAPER_MAX_DAMPING.get)), 3)}")
    return " ".join(words)


@st.composite
def advance(draw, machine: Drawn):
    """M900 K<k> or M572 [D0] S<k>: with the machine's pressure_advance any K from 0 to 0.5 (one in eight: a K
    below 0 or M572 D1, refused); without it K0 (harmless), one in eight another K (refused at its word)."""
    bad = draw(st.integers(0, 7)) == 7
    k = draw(st.one_of(st.sampled_from([0.0, 0.02, 0.1]), st.floats(0, 0.5).map(lambda v: float(num(v, 2)))))
    if not machine.advance:
        k = k if bad else 0.0
    elif bad and draw(st.booleans()):
        k = -draw(st.sampled_from([0.01, 0.5]))
    if draw(st.booleans()):
        return f"M900 K{num(k, 3)}"
    extruder = "D1 " if bad and machine.advance and k >= 0 else draw(st.sampled_from(["D0 ", ""]))
    return f"M572 {extruder}S{num(k, 3)}"


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
def gcode(draw, machine: Drawn, issue29: bool = True):
    """A G-code program: see the module's docstring (`issue29`: with M593, M900 and M572)."""
    box, extruder = machine.box, machine.extruder
    lines = [draw(st.sampled_from(["G21", "G21 G90", "G90"]))]
    if extruder:
        lines.append(draw(st.sampled_from(["M82", "M83"])))
    first = draw(points(box, full=box.three))[0]
    g = _GState(first + [box.lo[2]] * (3 - len(first)))
    if box.delta:  # from the top of a homed delta: down first, then across
        lines += [f"G0 Z{first[2]:.3f}", f"G0 X{first[0]:.3f} Y{first[1]:.3f}"]
    else:
        lines.append(f"G0 X{first[0]:.3f} Y{first[1]:.3f}" + (f" Z{first[2]:.3f}" if box.three else ""))
    lines.append(f"G1 F{num(draw(mixed([120, 900, 3000, 12000], 30, 30000)))}")
    absolute_e = "M82" in lines

    def feed():
        if draw(st.integers(0, 3)):
            return ""
        f = draw(mixed([120, 900, 3000, 12000], 30, 30000)) / g.scale
        return f" F{num(f)}"

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
        kind = draw(st.sampled_from(["G0", "G1", "G1", "arc", "arc", "arc", "G91", "G20", "G92", "misc", "grbl"]
                                    + (["M593", "advance"] if issue29 else [])))
        if kind == "M593":
            lines.append(draw(m593(machine)))
        elif kind == "advance":
            lines.append(draw(advance(machine)))
        elif kind in ("G0", "G1"):
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



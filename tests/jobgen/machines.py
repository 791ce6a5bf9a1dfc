"""Random machines for the property tests: YAML text, the coordinate box their programs stay in, and what the
G-code generator needs to know of them (the shaper types M593's damping is checked against, pressure advance).

Cartesian, corexy, delta; 2 or 3 axes, sometimes an extruder; steps/mm 5 to 400; max velocity 5 to 500 mm/s and
max acceleration 50 to 10,000 mm/s^2 (log-uniform, two orders of magnitude); junction deviation 0.001 to 0.2 mm;
tolerance 1 um to 0.05 mm; per motor no `range`, a range that contains the program's box, or a tight one that may
cut it (the job is then refused at the shape or G-code line); sometimes inverted DIR pins. One machine in four
has an `input_shaper` (a random type, frequency and damping per axis, 2 to 1000 Hz, many of them 10 to 20 Hz;
sometimes a `max_smoothing` above anything its shapers can smooth: over it the plan fails, which `outcome` counts
as a bug), and half the machines with an extruder have `pressure_advance` (K 0 to 0.5, sometimes 0; a smoothing
time up to Klipper's 0.2 s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hypothesis import strategies as st

from codegen.job.schema.shaping import SHAPER_MAX_DAMPING

SHAPER_TYPES = tuple(SHAPER_MAX_DAMPING)
# The largest sum(A_i |T_i - mean|) of any shaper at 1 Hz (any damping it accepts: 3hump_ei's is 0.518 s): the
# shaped tool is never further than that over the frequency times the fastest axis speed from the planned one.
SHAPER_REACH_S = 0.55
FASTEST_DELTA_MM_S = 1500.0  # a delta's tool speed: carriages of at most 500 mm/s near the bed's centre


# ---- numbers as YAML / G-code text (never an exponent: PyYAML reads `1e+04` as a string) ----

def num(x: float, sig: int = 4) -> str:
    x = float(x)
    if x == 0 or not math.isfinite(x):
        return "0"
    digits = min(6, max(0, sig - 1 - math.floor(math.log10(abs(x)))))
    text = f"{x:.{digits}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def point(p) -> str:
    return "[" + ", ".join(num(v) for v in p) + "]"


def log_uniform(lo: float, hi: float, sig: int = 3):
    """Floats from lo to hi, log-uniform, rounded to `sig` significant digits (as people write them)."""
    return st.floats(math.log10(lo), math.log10(hi)).map(lambda e: float(num(10 ** e, sig)))


def mixed(common, lo, hi, sig=3):
    """The values people use, or any value of the span."""
    return st.one_of(st.sampled_from(common), log_uniform(lo, hi, sig))


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


@dataclass
class Drawn:
    """A drawn machine: its YAML text, the box its programs stay in, and what its G-code may say about shaping.
    `shaper_types`: each axis's shaper type (Marlin's zv where the machine has none: M593 D is checked against
    it); `lowest_hz`: with a max_smoothing, the lowest shaper frequency it allows for (M593 F keeps above it);
    `advance`: the machine has pressure_advance (M900 and M572 may set K)."""

    text: str
    box: Box
    extruder: bool
    shaper_types: dict = field(default_factory=lambda: {a: "zv" for a in "xyz"})
    lowest_hz: float | None = None
    advance: bool = False


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
    return f", range: [{num(a, 5)}, {num(b, 5)}]"


def shaper_hz():
    """Shaper frequencies: frames' usual ones, low ones that smooth a lot, any from 2 to 1000 Hz."""
    return st.one_of(st.sampled_from([10.0, 12.5, 15.0, 20.0, 35.0, 48.2, 60.0, 100.0]), log_uniform(2, 1000))


def shaper_damping(draw, kind: str) -> float:
    largest = SHAPER_MAX_DAMPING[kind]
    return draw(st.one_of(st.sampled_from([0.05, 0.1, min(0.2, largest), largest]), st.floats(0.001, largest)
                          .map(lambda d: min(largest, float(num(d, 3))))))


def _input_shaper(draw, drawn: Drawn, speeds: dict) -> list[str]:
    """machine.input_shaper's lines: x, y and (with a z motor) z each shaped or not; sometimes a max_smoothing
    that no shaped motion of the machine reaches (its fastest axes times SHAPER_REACH_S over the lowest frequency
    the job may use)."""
    lines = ["  input_shaper:"]
    for axis in ("x", "y", "z") if drawn.box.three else ("x", "y"):
        if draw(st.integers(0, 3)) == 0:
            continue
        kind = draw(st.sampled_from(SHAPER_TYPES))
        damping = f", damping: {num(shaper_damping(draw, kind), 3)}" if draw(st.booleans()) else ""
        freq = draw(shaper_hz())
        drawn.shaper_types[axis] = kind
        drawn.lowest_hz = min(drawn.lowest_hz or freq, freq)
        lines.append(f"    {axis}: {{type: {kind}, freq: {num(freq)}{damping}}}")
    if draw(st.integers(0, 2)) == 0:
        drawn.lowest_hz = min(drawn.lowest_hz or 1000.0, draw(st.sampled_from([5.0, 10.0, 20.0, 40.0])))
        speed = math.sqrt(sum(v * v for v in speeds.values()))
        lines.append(f"    max_smoothing: {num(1.2 * SHAPER_REACH_S * speed / drawn.lowest_hz, 3)}")
    else:
        drawn.lowest_hz = None
    return lines if len(lines) > 1 else ["  input_shaper: {}"]


def _axis_speeds(kinematics: str, vmax: dict) -> dict:
    """The fastest each of x, y, z may move (mm/s) on the machine's motors."""
    if kinematics == "cartesian":
        return {a: vmax[a] for a in "xyz" if a in vmax}
    if kinematics == "corexy":  # x = (a + b) / 2, y = (a - b) / 2
        return {"x": 0.5 * (vmax["a"] + vmax["b"]), "y": 0.5 * (vmax["a"] + vmax["b"]), "z": vmax.get("z", 0.0)}
    return {a: FASTEST_DELTA_MM_S for a in "xyz"}


@st.composite
def machines(draw, kinematics: str, issue29: bool = True):
    """A Drawn machine of the kinematics; `issue29`: some with input shapers and pressure advance."""
    three = kinematics == "delta" or draw(st.booleans())
    extruder = draw(st.integers(0, 4)) == 0
    names = {"cartesian": ("x", "y", "z"), "corexy": ("a", "b", "z"), "delta": ("a", "b", "c")}[kinematics]
    names = names if three else names[:2]
    text = ["machine:", f"  kinematics: {kinematics}"]
    if kinematics == "delta":
        radius = draw(mixed([60.0, 90.0, 105.2, 140.0], 40, 200))
        rod = float(num(radius * draw(st.floats(1.7, 2.6)), 5))
        height = draw(mixed([150.0, 250.0, 400.0], 100, 600))
        reach = 0.5 * radius
        box = Box((-reach, -reach, 0.0), (reach, reach, min(60.0, 0.5 * height)), True, delta=True)
        top = height + math.sqrt(rod * rod - radius * radius)  # every carriage at home
        motor_span = {n: (0.0, top) for n in names}
        angles = ""
        if draw(st.integers(0, 3)) == 0:
            angles = f", tower_angles: [{', '.join(num(a + draw(st.floats(-4, 4))) for a in (210, 330, 90))}]"
        delta = f"  delta: {{radius: {num(radius, 5)}, diagonal_rod: {num(rod, 5)}, height: {num(height, 5)}{angles}}}"
    else:
        width = draw(st.sampled_from([10.0, 40.0, 80.0]))
        box = Box((0.0, 0.0, 0.0), (width, width, 20.0 if three else 0.0), three)
        if kinematics == "cartesian":
            motor_span = {"x": (0.0, width), "y": (0.0, width), "z": (0.0, 20.0)}
        else:  # A = X + Y, B = X - Y
            motor_span = {"a": (0.0, 2 * width), "b": (-width, width), "z": (0.0, 20.0)}
        delta = ""
    text.append("  steppers:")
    vmaxes = {}
    for name in names + (("e",) if extruder else ()):
        spm = draw(mixed([5, 6.25, 12.732, 40, 80, 100, 157.5, 200, 400], 5, 400, 4))
        vmax = vmaxes[name] = draw(mixed([5, 20, 60, 150, 300, 500], 5, 500))
        amax = draw(mixed([50, 200, 800, 3000, 10000], 50, 10000))
        extra = _range(draw, *motor_span[name]) if name != "e" else ""
        if draw(st.integers(0, 5)) == 0:
            extra += ", invert_dir: true"
        text.append(f"    {name}: {{steps_per_mm: {num(spm, 5)}, max_velocity: {num(vmax)}, "
                    f"max_accel: {num(amax)}{extra}}}")
    if draw(st.integers(0, 5)):
        text.append(f"  junction_deviation: {num(draw(mixed([0.002, 0.01, 0.05, 0.1], 0.001, 0.2)))}")
    if draw(st.integers(0, 5)):
        text.append(f"  tolerance: {num(draw(mixed([0.001, 0.002, 0.005, 0.01, 0.02, 0.05], 0.001, 0.05)))}")
    if delta:
        text.append(delta)
    drawn = Drawn("", box, extruder)
    if issue29 and draw(st.integers(0, 3)) == 3:
        text += _input_shaper(draw, drawn, _axis_speeds(kinematics, vmaxes))
    if issue29 and extruder and draw(st.booleans()):
        drawn.advance = True
        k = draw(st.one_of(st.sampled_from([0.0, 0.02, 0.05, 0.5]), st.floats(0, 0.5).map(lambda v: num(v, 2))))
        smooth = f", smooth_time: {num(draw(mixed([0.01, 0.04, 0.2], 0.001, 0.2)))}" if draw(st.booleans()) else ""
        text.append(f"  pressure_advance: {{k: {num(float(k), 3)}{smooth}}}")
    drawn.text = "\n".join(text)
    return drawn

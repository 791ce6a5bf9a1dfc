"""The pressure advance test: lines printed slow, fast, slow, each with its own K (Marlin's `M900 K`, the K-factor
calibration pattern): the line whose K matches the extruder keeps one width through both speed changes (too little
advance: thick where it slows down, thin where it speeds up; too much: the other way round).

The lines run along x, one above the other in y, in one layer; the K of each is set before it (M900 takes effect
from its place: codegen/gcode, with pressure advance).
"""

from __future__ import annotations

from dataclasses import dataclass

from codegen.calibrate.layout import Band, Calibration, Placement, Writer, number, values

SLOW_SHARE = 0.25  # of a line at each end printed slowly: the middle half fast


@dataclass(frozen=True)
class PressureAdvanceTest:
    start: float = 0.0  # s, the first line's K
    end: float = 0.1  # s, the last line's at most
    step: float = 0.005  # s between lines
    slow: float = 20.0  # mm/s, the lines' ends
    fast: float = 100.0  # mm/s, their middle (at most the machine's slowest x or y motor's top speed)
    length: float = 80.0  # mm, a line
    spacing: float = 5.0  # mm between lines
    layer: float = 0.2  # mm


def pressure_advance_pattern(test: PressureAdvanceTest, place: Placement) -> Calibration:
    """The pattern on a printer (`place.printer`; ValueError otherwise: there is no extruder to advance)."""
    if not place.printer:
        raise ValueError("pressure advance needs a printer: the machine has no extruder (machine.steppers.e) or no z")
    ks = values(test.start, test.end, test.step)
    fast, slow = min(test.fast, place.top_speed), min(test.slow, place.top_speed)
    x0 = place.center[0] - test.length / 2.0
    first_y = place.center[1] - (len(ks) - 1) * test.spacing / 2.0
    w = Writer(f"pressure advance pattern: M900 K from {number(ks[0])} to {number(ks[-1])}, a line each, "
               f"{number(slow)} / {number(fast)} / {number(slow)} mm/s", True)
    parts = [(SLOW_SHARE, slow), (1.0 - 2 * SLOW_SHARE, fast), (SLOW_SHARE, slow)]
    bands = []
    for k, advance in enumerate(ks):
        y = first_y + k * test.spacing
        w.travel(x0, y, z=test.layer if k == 0 else None)
        w.comment(f"line {k + 1}: K {number(advance)}")
        w.code(f"M900 K{number(advance)}")
        x = x0
        for share, speed in parts:
            x += share * test.length
            w.draw(x, y, share * test.length, speed, test.layer)
        bands.append(Band(advance, y, y))
    return Calibration(w.text(), tuple(bands), "y", "M900 K (s)")

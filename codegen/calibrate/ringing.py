"""The ringing test: sharp corners taken fast, the input shaper's frequency changed with M593 every band, so the
band whose frequency cancels the frame's resonance shows the least ringing after its corners (Klipper's ringing
tower with TUNING_TOWER, Marlin's M593 calibration).

A printer prints a thin-walled square tower (one line per side), its frequency changing every few millimetres
of height; another machine draws a rectangle per band, the bands stacked along y. Each M593 brings the machine to
rest (codegen/gcode/shaper_codes.py), at a layer change or between two rectangles, where the print does not mind.
On a delta M593 shapes x and y as anywhere: in cartesian space, before the carriages' transform, as Klipper does.
"""

from __future__ import annotations

from dataclasses import dataclass

from codegen.calibrate.layout import Band, Calibration, Placement, Writer, number, values

TEST_SPEED = 100.0  # mm/s on the sides: Klipper's ringing test prints its walls at 100 mm/s
FIRST_LAYER_SPEED = 30.0  # mm/s: the first layer sticks to the bed
RECTANGLE_SHARE = 0.6  # of a plotted band's height: its rectangle (the rest keeps the bands apart)


@dataclass(frozen=True)
class RingingTest:
    start: float = 20.0  # Hz, the first band's
    end: float = 80.0  # Hz, the last band's at most
    step: float = 5.0  # Hz between bands
    damping: float | None = None  # the M593s' D; None: the machine's (or 0.1)
    axis: str | None = None  # "x" or "y": M593 X or Y; None: both
    height: float = 60.0  # mm: the tower (a printer)
    size: float = 40.0  # mm: the tower's side, or the plotted pattern's width and height
    layer: float = 0.3  # mm: the layer height (a printer)
    speed: float | None = None  # mm/s: TEST_SPEED, or the machine's slowest x or y motor's top speed if slower

    def m593(self, freq: float, first: bool) -> str:
        axis = "" if self.axis is None else f" {self.axis.upper()}"
        damping = f" D{number(self.damping)}" if first and self.damping is not None else ""
        return f"M593{axis} F{number(freq)}{damping}"


def ringing_test(test: RingingTest, place: Placement) -> Calibration:
    freqs = values(test.start, test.end, test.step)
    speed = min(test.speed or TEST_SPEED, place.top_speed)
    if place.printer:
        return _tower(test, place, freqs, speed)
    return _plotted(test, place, freqs, speed)


def _corners(center: tuple[float, float], width: float, height: float, bottom: float | None = None) -> list:
    """A rectangle's corners counter-clockwise from its lower left, and back there."""
    x0, x1 = center[0] - width / 2.0, center[0] + width / 2.0
    y0 = center[1] - height / 2.0 if bottom is None else bottom
    y1 = y0 + height
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]


def _tower(test: RingingTest, place: Placement, freqs: list[float], speed: float) -> Calibration:
    per_band = max(1, round(test.height / test.layer / len(freqs)))  # layers
    corners = _corners(place.center, test.size, test.size)
    w = Writer(f"ringing tower: M593 F from {number(freqs[0])} to {number(freqs[-1])} Hz, {per_band} layers "
               f"({number(per_band * test.layer)} mm) a band", True)
    w.travel(*corners[0], z=test.layer)
    bands = []
    for layer in range(per_band * len(freqs)):
        band, first = divmod(layer, per_band)
        if first == 0:
            bands.append(Band(freqs[band], layer * test.layer, (layer + per_band) * test.layer))
            w.comment(f"band {band + 1}: {number(freqs[band])} Hz from z {number(layer * test.layer)} mm")
            w.code(test.m593(freqs[band], band == 0))
        w.lift((layer + 1) * test.layer)
        side_speed = min(speed, FIRST_LAYER_SPEED) if layer == 0 else speed
        for x, y in corners[1:]:
            w.draw(x, y, test.size, side_speed, test.layer)
    return Calibration(w.text(), tuple(bands), "height z", "M593 F (Hz)")


def _plotted(test: RingingTest, place: Placement, freqs: list[float], speed: float) -> Calibration:
    pitch = test.size / len(freqs)
    bottom = place.center[1] - test.size / 2.0
    w = Writer(f"ringing test card: M593 F from {number(freqs[0])} to {number(freqs[-1])} Hz, a rectangle a band",
               False)
    bands = []
    for k, freq in enumerate(freqs):
        corners = _corners(place.center, test.size, pitch * RECTANGLE_SHARE, bottom + k * pitch)
        bands.append(Band(freq, corners[0][1], corners[2][1]))
        w.travel(*corners[0], z=place.draw_z if k == 0 else None)
        w.comment(f"band {k + 1}: {number(freq)} Hz")
        w.code(test.m593(freq, k == 0))
        for (xa, ya), (xb, yb) in zip(corners[:-1], corners[1:]):
            w.draw(xb, yb, abs(xb - xa) + abs(yb - ya), speed)
    return Calibration(w.text(), tuple(bands), "y", "M593 F (Hz)")

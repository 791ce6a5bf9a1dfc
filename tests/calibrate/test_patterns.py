"""The calibration patterns (codegen/calibrate/) for any sweep: one band per value in order, each value set once
where its band begins, the bands one after the other without gaps or overlaps, every move on the pattern."""

from __future__ import annotations

import re

from hypothesis import given, settings
from hypothesis import strategies as st

from codegen.calibrate import PressureAdvanceTest, RingingTest, pressure_advance_pattern, ringing_test
from codegen.calibrate.layout import Placement, number

PRINTER = Placement((100.0, 100.0), (0.0, 0.0, 0.0), True, 150.0)
PLOTTER = Placement((50.0, 60.0), (0.0, 0.0), False, 150.0)


@st.composite
def sweeps(draw, low: float, high: float, steps: tuple):
    """start, end, step and the values the sweep has: start + k step up to end (end not always one of them)."""
    step = draw(st.sampled_from(steps))
    count = draw(st.integers(1, 15))
    start = draw(st.sampled_from((low, low + 3.5 * steps[0], low + 11 * steps[0])))
    end = min(start + (count - 1) * step + draw(st.sampled_from((0.0, 0.4, 0.99))) * step, high)
    values = [round(start + k * step, 6) for k in range(count) if start + k * step <= end + 1e-9]
    return start, end, step, values


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(sweeps(1.0, 1000.0, (0.5, 5.0, 12.5)), st.booleans(), st.sampled_from((None, "x", "y")))
def test_ringing_sets_every_frequency_once_at_its_band(sweep, printer, axis):
    start, end, step, freqs = sweep
    test = RingingTest(start, end, step, axis=axis, height=12.0, size=20.0, layer=0.4)
    result = ringing_test(test, PRINTER if printer else PLOTTER)
    lines = result.gcode.splitlines()
    setters = [k for k, line in enumerate(lines) if line.startswith("M593")]
    prefix = "M593" + ("" if axis is None else f" {axis.upper()}")
    assert [lines[k] for k in setters] == [f"{prefix} F{number(f)}" for f in freqs]
    assert [b.value for b in result.bands] == freqs
    assert all(a.end <= b.begin + 1e-9 for a, b in zip(result.bands, result.bands[1:]))
    moves = [line for line in lines if line.startswith("G1")]
    xy = {tuple(float(v) for v in re.findall(r"[XY]([-\d.]+)", line)) for line in moves}
    if printer:  # the tower: every side from corner to corner, each band the same number of layers
        assert xy == {(90.0, 90.0), (110.0, 90.0), (110.0, 110.0), (90.0, 110.0)}
        heights = [float(line[4:]) for line in lines if line.startswith("G0 Z")]
        layers = round((result.bands[0].end - result.bands[0].begin) / 0.4)
        assert len(moves) == 4 * len(heights) == 4 * layers * len(freqs)
        assert [b.begin for b in result.bands] == [k * layers * 0.4 for k in range(len(freqs))]
        z_at = [next(float(line[4:]) for line in lines[k:] if line.startswith("G0 Z")) for k in setters]
        assert z_at == [round(b.begin + 0.4, 6) for b in result.bands]  # set before the band's first layer
    else:  # a rectangle a band, inside its band
        assert len(moves) == 4 * len(freqs) and lines.count("M3") == lines.count("M5") == len(freqs)
        assert all(40.0 <= y <= 80.0 and x in (40.0, 60.0) for x, y in xy)


@settings(max_examples=40, deadline=None, derandomize=True, database=None)
@given(sweeps(0.0, 10.0, (0.001, 0.005, 0.02)))
def test_pressure_advance_sets_every_k_once_before_its_line(sweep):
    start, end, step, ks = sweep
    result = pressure_advance_pattern(PressureAdvanceTest(start, end, step, length=40.0, spacing=4.0), PRINTER)
    lines = result.gcode.splitlines()
    setters = [k for k, line in enumerate(lines) if line.startswith("M900")]
    assert [lines[k] for k in setters] == [f"M900 K{number(k)}" for k in ks]
    assert [b.value for b in result.bands] == ks
    ys = [b.begin for b in result.bands]
    assert all(b - a == 4.0 for a, b in zip(ys, ys[1:])) and abs(ys[0] + ys[-1] - 200.0) < 1e-9  # centred
    for k, y in zip(setters, ys):  # its line follows, slow, fast, slow, at its y
        feeds = [re.search(r"F(\d+)", line).group(1) for line in lines[k + 1:k + 4]]
        assert feeds == ["1200", "6000", "1200"] and all(f"Y{number(y)} " in line for line in lines[k + 1:k + 4])

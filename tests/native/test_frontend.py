"""The front end's C helpers (codegen/native/gcodelines.c, staircase.c) give what their Python and numpy versions
give, to the bit: the same toolpath items, batches, warnings and errors from G-code; the same staircase errors.
And a run of lines as one Lines item flattens into the segments its Line items make.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

import codegen.gcode as gcode
from codegen.errors import JobError, SourceRef
from codegen.gcode.fast import NativeLines
from codegen.job import load_job
from codegen.kinematics import make_kinematics
from codegen.motion.pieces import pieces
from codegen.motion.staircase import staircase_error, staircase_error_numpy
from codegen.native import library
from codegen.pipeline.settings import front_end_settings, homing_settings
from codegen.program.program import Program
from codegen.toolpath.items import Lines, Toolpath, expanded
from codegen.toolpath.segments import flatten
from tests.helpers import ROOT, machine

FILES = sorted((ROOT / "tests" / "data" / "gcode").rglob("*.gcode"))

pytestmark = pytest.mark.skipif(any(library(n) is None for n in ("gcodelines", "staircase")),
                                reason="the C helpers could not be built (no gcc)")

# Lines the C must take as Python does, or leave to it: spaces of every kind, case, number forms, comments,
# checksums, delimiters, codes and words it does not know, modes that change what the words mean.
TRICKY = """\
G21 G90 M82
G1 X10 Y10 F1200
g1x11y12.5e.5
G01 X 12 Y+13. E1 ; comment (with parens)
G0 X13\tY14\x0bZ1
\tG1 X14 Y15 E1.5\r
  G1 X15 Y16 E2  ; indented
G00 X1.5 Y2
G1.0 X3
G+1 X4
G001 X5
G1 X6 X7
G1 X
G1 X5 F0
G1 X6 S-1
G1 X7 S300
G1 Y9 Q1
G1 X8 (comment) Y9
N12 G1 X9 Y10*97
G1 X10 Y11 *5
/G1 X99
G1 X00012.500 Y-0 E-.5
G1 X11 Y12 E2.5 F600
M83
G1 X12 E0.4
G1 E-0.8 F2400
M221 S95
G1 X13 Y13 E0.5
M82
G92 E0
G1 X14 E1
M220 S80
M205 S5 T3
G1 X15 Y15 E1.2 F100
G1 X16 F100
M204 P500 T900 R300
G1 X17 E1.4
G1 E1.0
G1 X18
G91
G1 X1 Y1 E0.1
G90
G20
G1 X1 Y1
G21
G92 X0 Y0
G1 X5 Y5
G2 X10 Y10 R20
X11 Y12
G1 X12 Y13
M3 S128
G1 X14 Y14
M5
G1 X15 Y15 Z2 E3
G93 G1 X16 F30
G1 X17 F20
G94
G1 X18 F1200
G1 X19 ; \u00e9
G1 X20 Y1\u00e9
G1 X1234567890123456789012345678901234567890123456789012345678901234567890.5
M205 S0 T0
M220 S100
G1 X99999 Y-100000
G1 X21 Y100000.001 E30000000
G1 X22 F0.00001
G1 X23 F0.0001
G0 Z0.5
G1 E1000 F0.0001
""" + "".join(f"G1 X{20 + k * 0.37:.3f} Y{k % 7}.25 E{3 + k * 0.01:.5f}\n" for k in range(60))


def job(text: str, motors=("x", "y", "z", "e")):
    return NS(machine=machine(motors=motors), path=Path("/nowhere/job.yaml"),
              program=NS(start=(0, 0), feed=1200, travel_feed=None, gcode=text,
                         gcode_source=SourceRef("job.yaml", 8, 5)))


def file_job(path: Path):
    return NS(machine=machine(motors=("x", "y", "z", "e")), path=path.parent / "job.yaml",
              program=NS(start=(0, 0), feed=1200, travel_feed=None, gcode=path.name,
                         gcode_source=SourceRef(str(path.parent / "job.yaml"), 1, 1)))


def described(item) -> list:
    """Every field of an item, floats and arrays by their bits."""
    out = [type(item).__name__]
    for name in item.__dataclass_fields__:
        value = getattr(item, name)
        if isinstance(value, np.ndarray):
            out.append((name, value.dtype.str, value.shape, value.tobytes()))
        else:
            out.append((name, type(value).__name__, np.float64(value).tobytes() if isinstance(value, float)
                        else repr(value)))
    return out


def read(stream_job, native: bool, monkeypatch, size: int = 16) -> tuple:
    """Batches (their items described), the error diagnostics and the warnings of reading the job's G-code."""
    with monkeypatch.context() as patch:
        if not native:
            patch.setattr(NativeLines, "load", classmethod(lambda cls, capacity: None))
        stream, batches, problems = gcode.GcodeStream(stream_job), [], []
        try:
            for batch in stream.batches(size):
                batches.append([described(item) for item in expanded(batch)])
        except JobError as error:
            problems = [(str(d.where), d.message) for d in error.diagnostics]
        return batches, problems, [(str(d.where), d.message) for d in stream.warnings]


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_a_file_reads_in_c_as_in_python(path, monkeypatch):
    native = read(file_job(path), True, monkeypatch, 512)
    assert native == read(file_job(path), False, monkeypatch, 512)
    assert native[0] or native[1]


@pytest.mark.parametrize("motors", [("x", "y", "z", "e"), ("x", "y", "z"), ("x", "y")])
def test_tricky_lines_read_in_c_as_in_python(motors, monkeypatch):
    native = read(job(TRICKY, motors), True, monkeypatch)
    assert native == read(job(TRICKY, motors), False, monkeypatch)
    assert len(native[1]) > 8  # the errors are found, at the same places


def test_lines_after_the_last_error_read_in_c_as_in_python(monkeypatch):
    clean = "\n".join(line for line in TRICKY.splitlines()
                      if not any(bad in line for bad in ("X6 X7", "G1 X\n", "F0", "S-1", "Q1", "(comment) Y", "*",
                                                          "G93", "\u00e9", "1234567890", "X99999", "Y100000"))
                      and line not in ("G1 X", "X11 Y12"))
    native = read(job(clean), True, monkeypatch)
    assert native == read(job(clean), False, monkeypatch)
    assert native[1] == [] and sum(len(batch) for batch in native[0]) > 80


def test_a_program_delimited_by_percent_signs_ends_at_the_second(monkeypatch):
    text = "%\nG1 X1\nG1 X2\n%\nG1 X3\n" + "G1 X4\n" * 5
    batches, problems, _ = read(job(text), True, monkeypatch)
    assert (batches, problems) == read(job(text), False, monkeypatch)[:2]
    assert len(batches[0]) == 2


@pytest.mark.parametrize("kind, motors", [("cartesian", ("x", "y")), ("corexy", ("a", "b")),
                                          ("cartesian", ("x", "y", "z", "e")), ("corexy", ("a", "b", "z", "e"))])
def test_staircase_error_in_c_is_the_numpy_version(kind, motors):
    rng = np.random.default_rng(7)
    n = 2000
    points = np.zeros((n + 1, 4))
    points[:, :len(motors)] = np.cumsum(rng.uniform(-2.0, 2.0, size=(n + 1, len(motors))), axis=0) + 100.0
    points[rng.integers(0, n, 50), :] = points[rng.integers(0, n, 50), :]  # some moves of one axis or none
    items = Lines(points, np.full(n, 50.0), np.ones(n, bool), np.zeros(n, bool), np.full(n, np.inf), np.ones(n),
                  np.zeros(n, bool), "test", np.arange(n), np.ones(n, dtype=np.int64))
    kin = make_kinematics(machine(kind, motors, **{m: {"spm": 80 + 13 * k} for k, m in enumerate(motors)}))
    segments = flatten(Toolpath(points[0], [items]), 0.002)
    which = np.flatnonzero(rng.uniform(size=n) < 0.7)
    native = staircase_error(segments, kin, which)
    assert np.array_equal(native, staircase_error_numpy(segments, kin, which))
    assert native.max() > 0.0


@pytest.mark.parametrize("name", ["laser/hiking.gcode", "plotter/shapes.gcode", "grbl-cam.gcode"])
def test_lines_items_flatten_as_their_line_items(name):
    toolpath, _ = gcode.toolpath_from_gcode(file_job(ROOT / "tests" / "data" / "gcode" / name))
    stream = gcode.GcodeStream(file_job(ROOT / "tests" / "data" / "gcode" / name))
    items = [item for batch in stream.batches() for item in batch]
    assert any(isinstance(item, Lines) for item in items)
    runs, single = flatten(Toolpath(stream.start, items), 0.002), flatten(toolpath, 0.002)
    for field in runs.__dataclass_fields__:
        assert np.array_equal(getattr(runs, field), getattr(single, field), equal_nan=True), field


def test_a_move_out_of_range_is_an_error_at_its_line(tmp_path):
    path = tmp_path / "job.yaml"
    path.write_text("machine:\n  kinematics: cartesian\n  steppers:\n"
                    "    x: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000, range: [0, 100]}\n"
                    "    y: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}\n"
                    "program:\n  gcode: |\n    G1 X10 Y10 F600\n    G1 X20\n      G1 X120 Y5\n    G1 X30\n")
    job = load_job(path)
    kin = make_kinematics(job.machine)
    with pytest.raises(JobError) as error:
        list(pieces(front_end_settings(job), kin, Program(job, kin, homing_settings(job))))
    (d,) = error.value.diagnostics
    assert (d.where.line, d.where.col) == (10, 7)
    assert d.message == "motor x would go to 120.000 mm, outside its range [0, 100]"

"""Small builders shared by the unit tests: machines and toolpaths without a job file."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from codegen.errors import SourceRef
from codegen.kinematics import make_kinematics
from codegen.motion.planner import PlannerLimits, plan
from codegen.motion.staircase import split_long
from codegen.motion.stepgen import segment_steps
from codegen.tables.schedule import Schedule
from codegen.toolpath.items import Line, Toolpath
from codegen.toolpath.segments import flatten
from tests.reference_player import event_ticks

SRC = SourceRef("test.yaml", 1, 1)


def stepper(spm=80.0, vmax=200.0, amax=3000.0):
    return SimpleNamespace(steps_per_mm=spm, max_velocity=vmax, max_accel=amax, invert_dir=False, range=None)


def machine(kinematics="cartesian", motors=("x", "y"), **limits):
    return SimpleNamespace(kinematics=kinematics, motor_names=tuple(motors), home_point=(0.0, 0.0, 0.0),
                           steppers={m: stepper(**limits.get(m, {})) for m in motors})


def point(x, y, z=0.0, e=0.0):
    return np.array([x, y, z, e], dtype=float)


def polyline(points, feed, tool=True):
    pts = [point(*p) for p in points]
    return Toolpath(pts[0], [Line(a, b, feed, tool, SRC) for a, b in zip(pts[:-1], pts[1:])])


def planned(toolpath, mach=None, jd=0.01, tolerance=0.002, max_event_rate=np.inf):
    kin = make_kinematics(mach or machine())
    segments = split_long(flatten(toolpath, tolerance), kin)
    steps = segment_steps(segments, kin)
    return kin, segments, steps, plan(segments, kin, steps, PlannerLimits(jd, max_event_rate=max_event_rate))


ROOT = Path(__file__).resolve().parent.parent  # the repository
EXAMPLES = ROOT / "examples"
DATA = ROOT / "tests" / "data"
GCODE_DATA = DATA / "gcode"
_PRINTER = """name: {name}
target: {target}
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
    y: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
    z: {{steps_per_mm: 400, max_velocity: 12, max_accel: 400}}
{extruder}program:
  gcode: {gcode}
"""
_EXTRUDER = "    e: {steps_per_mm: 100, max_velocity: 80, max_accel: 5000}\n"


def gcode_job_file(folder: Path, name: str, target: str = "avr", extruder: bool = True) -> Path:
    """A job file in `folder`: a cartesian printer (x, y 80 steps/mm, z 400, e 100 with `extruder`) running the
    G-code file tests/data/gcode/`name`."""
    path = Path(folder) / f"{Path(name).stem}-{target}.yaml"
    path.write_text(_PRINTER.format(name=Path(name).stem, target=target, extruder=_EXTRUDER if extruder else "",
                                    gcode=GCODE_DATA / name))
    return path


def make_schedule(motors, blocks, final_tool=False, runs=None, tick_hz=2_000_000):
    """A schedule by hand. blocks: (dirs, steps, modulus, init, tool, [(interval in 1/256 tick, add, count), ...]),
    each with runs of its own; or, with `runs` (the whole program's, crossing block starts), (dirs, steps,
    modulus, init, tool, events)."""
    m = len(motors)
    own = runs is None
    events = [sum(r[2] for r in b[5]) for b in blocks] if own else [b[5] for b in blocks]
    runs = [r for b in blocks for r in b[5]] if own else runs
    per_motor = (lambda k, dtype: np.array([b[k] for b in blocks], dtype=dtype).reshape(len(blocks), m))
    return Schedule(
        motors=tuple(motors), tick_hz=tick_hz, block_dirs=per_motor(0, np.int8), block_steps=per_motor(1, np.int64),
        block_modulus=np.array([b[2] for b in blocks], dtype=np.int64), block_init=per_motor(3, np.int64),
        block_tool=np.array([b[4] for b in blocks], dtype=bool),
        block_segment=np.zeros(len(blocks), dtype=np.int64),
        run_interval=np.array([r[0] for r in runs], dtype=np.int64).reshape(-1),
        run_add=np.array([r[1] for r in runs], dtype=np.int64).reshape(-1),
        run_count=np.array([r[2] for r in runs], dtype=np.int64).reshape(-1), final_tool=final_tool,
        block_events=np.array(events, dtype=np.int64))


def block_spans(schedule):
    """Per block, the ticks of its first and last event (plain Python)."""
    ticks, spans, first = event_ticks(schedule), [], 0
    for events in schedule.events_per_block():
        spans.append((ticks[first], ticks[first + events - 1]))
        first += events
    return spans


# The small star (tests/cli/test_config.py, test_flash.py): examples/star.yaml as it was when these tests were
# written (the example may grow keys some target refuses)
STAR = """name: star
machine:
  kinematics: corexy
  steppers:
    a: {steps_per_mm: 80, max_velocity: 400, max_accel: 8000}
    b: {steps_per_mm: 80, max_velocity: 400, max_accel: 8000}
  junction_deviation: 0.02
program:
  start: [100, 100]
  feed: 18000           # 300 mm/s
  shapes:
    - polyline:
        points: [[100.0, 180.0], [147.023, 35.279], [23.915, 124.721], [176.085, 124.721], [52.977, 35.279],
                 [100.0, 180.0]]
"""


# A cartesian plotter with heaters (`heaters:` formatted in) running {name}.gcode (tests/tables/test_runtime_records.py,
# tests/cli/test_tune.py)
HEATERS_JOB = """name: {name}
target: {target}
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
    y: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
{heaters}program:
  gcode: {name}.gcode
"""


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """`printer-codegen ARGV...` in this process: (exit code, stdout, stderr)."""
    from codegen.cli.main import main

    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def streamed(job_path: Path, out: Path):
    """A job for the streaming firmware as `printer-codegen stream` plans it, the firmware built into `out`:
    (host, image, setup)."""
    from codegen.cli.stream import _firmware, streamed_host
    from codegen.job import load_job
    from codegen.pipeline.streaming import stream_setup

    job = load_job(job_path)
    setup = stream_setup(job, None)
    image, _ = _firmware(job, setup, str(out))
    return streamed_host(job, setup, False, keep=True), image, setup

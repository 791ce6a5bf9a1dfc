"""The machine's keys the planner and the shapers depend on: numbers beyond what the host holds, refused with the
reason, and `input_shaper` per axis (Klipper's defaults, the schema's limits)."""

from __future__ import annotations

import textwrap

from codegen.job import load_job
from tests.job.jobfiles import STEPPERS, errors, write


def test_machine_numbers_beyond_what_the_planner_holds_are_refused_with_the_reason(tmp_path):
    """Issue 28: steps_per_mm 1e9 hung the staircase, max_velocity 1e-6 planned 2.7e67 s, a delta of height 1e9
    allocated 1.16 GiB and one of radius 1e-9 293 MiB."""
    path = write(tmp_path, """\
        machine:
          kinematics: delta
          steppers:
            a: {steps_per_mm: 1e9, max_velocity: 200, max_accel: 3000}
            b: {steps_per_mm: 80, max_velocity: 0.000001, max_accel: 0.5}
            c: {steps_per_mm: 100000, max_velocity: 0.1, max_accel: 1}
          delta: {radius: 1e-9, diagonal_rod: 215, height: 1e9}
        program:
          shapes:
            - line: {to: [1, 1, 5]}
        """)
    assert errors(path) == [
        (4, 23, "machine.steppers.a.steps_per_mm: must be <= 100000 (a step finer than 10 nm is finer than any "
                "drive; positions in steps are int32)"),
        (5, 41, "machine.steppers.b.max_velocity: must be >= 0.1 (mm/s: an axis slower than 6 mm/min plans moves "
                "of days)"),
        (5, 62, "machine.steppers.b.max_accel: must be >= 1 (mm/s^2: a gentler ramp to full speed takes hours)"),
        (7, 19, "machine.delta.radius: must be >= 10 (mm: smaller, a carriage's step moves the tool by millimetres)"),
        (7, 52, "machine.delta.height: must be <= 100000 (mm: 100 m is beyond any machine)"),
    ]


def test_machine_numbers_that_overflowed_the_host_are_refused_with_the_reason(tmp_path):
    """The fuzzer's OverflowErrors in homing (slow_speed or steps_per_mm 1e-308), ValueErrors in the planner
    (max_velocity 1e308: its square is infinite) and in the delta's cuts (tolerance 1e-308)."""
    path = write(tmp_path, """\
        machine:
          kinematics: cartesian
          steppers:
            x: {steps_per_mm: 80, max_velocity: 1e308, max_accel: 1e308}
            y: {steps_per_mm: 1.0e-308, max_velocity: 200, max_accel: 3000}
          homing: {slow_speed: 1.0e-308, backoff: 1e9}
          tolerance: 1.0e-308
          junction_deviation: 1e300
        program:
          shapes:
            - line: {to: [1, 1]}
        """)
    assert errors(path) == [
        (4, 41, "machine.steppers.x.max_velocity: must be <= 100000 (mm/s: 100 m/s is beyond any motor, and its "
                "square overflows the planner)"),
        (4, 59, "machine.steppers.x.max_accel: must be <= 1e+08 (mm/s^2: 10,000 g is beyond any machine, and its "
                "products overflow the planner)"),
        (5, 23, "machine.steppers.y.steps_per_mm: must be >= 0.1 (a step longer than 10 mm is no stepper drive's)"),
        (6, 24, "machine.homing.slow_speed: must be >= 0.1 (mm/s: a slower approach takes hours over a machine's "
                "length)"),
        (6, 43, "machine.homing.backoff: must be <= 1000 (mm: a backoff of a metre leaves any switch behind)"),
        (7, 14, "machine.tolerance: must be >= 0.0001 (mm: finer than 0.1 um, curves would be cut into countless "
                "pieces)"),
        (8, 23, "machine.junction_deviation: must be <= 10 (mm: beyond 10 mm every corner is taken at full speed, "
                "and v^2 overflows)"),
    ]


# ---- the input shaper ----

def test_input_shaper_loads_per_axis_with_klippers_default_damping(tmp_path):
    path = write(tmp_path, STEPPERS + """\
  input_shaper:
    x: {type: mzv, freq: 48.2}
    y: {type: 2hump_ei, freq: 60, damping: 0.2}
    max_smoothing: 0.1
program:
  shapes:
    - line: {to: [10, 0]}
""")
    shaper = load_job(path).machine.input_shaper
    assert (shaper.x.type, shaper.x.freq, shaper.x.damping) == ("mzv", 48.2, 0.1)
    assert (shaper.y.type, shaper.y.damping, shaper.z, shaper.max_smoothing) == ("2hump_ei", 0.2, None, 0.1)
    assert list(shaper.axes) == ["x", "y"]


def test_input_shaper_errors_point_at_the_value(tmp_path):
    path = write(tmp_path, STEPPERS + """\
  input_shaper:
    x: {type: mzz, freq: 48.2}
    y: {type: ei, freq: 0.5}
    z: {type: 3hump_ei, freq: 40, damping: 0.3}
    max_smoothing: -1
    xx: 3
program:
  shapes:
    - line: {to: [10, 0]}
""")
    assert errors(path) == [
        (7, 15, "machine.input_shaper.x.type: 'mzz' is not one of zv, mzv, zvd, ei, 2hump_ei, 3hump_ei "
                "(did you mean 'mzv'?)"),
        (8, 25, "machine.input_shaper.y.freq: must be >= 1 and <= 1000 (Hz: below 1 Hz a shaper lasts seconds, "
                "above 1000 Hz it spans less than the player's step)"),
        (9, 44, "machine.input_shaper.z.damping: must be <= 0.2 for 3hump_ei (its formulas hold up to there)"),
        (10, 20, "machine.input_shaper.max_smoothing: must be > 0"),
        (11, 5, "machine.input_shaper: unknown key 'xx' (did you mean 'x'?)"),
    ]


def test_input_shaper_on_a_delta_is_loaded(tmp_path):
    """A delta is shaped in cartesian space, before its carriages' transform (codegen/motion/shaped_delta.py)."""
    path = write(tmp_path, textwrap.dedent("""\
        machine:
          kinematics: delta
          steppers:
            a: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
            b: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
            c: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
          delta: {radius: 100, diagonal_rod: 200, height: 250}
          input_shaper: {x: {type: zv, freq: 40}}
        program:
          shapes:
            - line: {to: [10, 0]}
        """))
    shaper = load_job(path).machine.input_shaper
    assert (shaper.x.type, shaper.x.freq, shaper.y) == ("zv", 40, None)


def test_the_schemas_damping_limits_are_the_shapers():
    from codegen.job.schema import SHAPER_MAX_DAMPING
    from codegen.motion.shapers import SHAPERS
    assert SHAPER_MAX_DAMPING == {name: largest for name, (_, largest) in SHAPERS.items()}

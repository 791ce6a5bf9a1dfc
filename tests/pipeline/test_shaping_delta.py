"""Input shaping on a delta (codegen/motion/shaped_delta.py): x and y are shaped in cartesian space and the
carriages follow through the inverse kinematics. Shaping moves no step and loses none, every master event is where
the master carriage of the shaped motion crosses its half step, every limit holds on the shaped pulses, the image
plays them in simavr, and the toolhead rings far less than unshaped."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codegen.motion.pieces as pieces
import codegen.motion.shaped_delta as shaped_delta
from codegen.job import load_job
from codegen.motion.shaped_motion import planned_motion, shape
from codegen.pipeline.host import host_build
from codegen.verify.chapters import whole_chapter
from codegen.verify.resonance import AxisResonance
from codegen.verify.vibration import VibrationCheck
from tests.helpers import run_cli

MZV = "{x: {type: mzv, freq: 40}, y: {type: mzv, freq: 40}}"
CORNERS = [[-30, -30, 5], [30, -30, 5], [30, 30, 5], [-10, 10, 5], [-30, 30, 5]]  # corners of 90, 135 and 45 deg
RINGING = [[-15, 0, 5], [15, 0, 5], [15, 20, 5], [-15, 20, 5]]  # sharp corners at 12,000 mm/s^2, 200 steps/mm
CROSSING_STEPS = 1e-3  # how far from its half step the shaped master carriage may be at an event

needs_avr = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                               reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


def delta_job(folder: Path, shaper: str | None, points=CORNERS, name: str = "job", steps_per_mm: float = 80,
              accel: float = 3000, feed: float = 6000, start=(0, 0, 250)) -> Path:
    """The Kossel mini of examples/kossel-mini.yaml travelling from home to a polyline's start and along it."""
    steppers = "".join(f"    {m}: {{steps_per_mm: {steps_per_mm}, max_velocity: 200, max_accel: {accel}}}\n"
                       for m in "abc")
    shaping = "" if shaper is None else f"  input_shaper: {shaper}\n"
    path = folder / f"{name}.yaml"
    path.write_text(f"machine:\n  kinematics: delta\n  steppers:\n{steppers}"
                    f"  delta: {{radius: 105.2, diagonal_rod: 215, height: 250}}\n{shaping}"
                    f"program:\n  start: {list(start)}\n  feed: {feed}\n"
                    f"  shapes:\n    - polyline: {{points: {points}}}\n")
    return path


def assert_events_on_the_shaped_carriages(host) -> None:
    """At every event that steps its master, the master carriage of the shaped motion (the plan before shaping,
    convolved again here, through the inverse kinematics) is half a step short of where the event leaves it."""
    events, kin = host.events, host.kin
    shaped = shape(planned_motion(*host.planned), host.settings.stages.shaping)
    per_block = np.diff(events.block_first)
    block_master = np.argmax(np.abs(events.block_steps), axis=1)
    master = np.repeat(block_master, per_block)
    sign = np.repeat(np.sign(events.block_steps[np.arange(len(per_block)), block_master]), per_block)
    stepping = np.flatnonzero(sign != 0)
    rows = np.arange(len(stepping))
    exact = kin.to_motor(shaped.at(events.time[stepping])) * kin.limits.steps_per_mm
    after = host.pulses.event_position[stepping] + host.start_steps
    miss = exact[rows, master[stepping]] - (after[rows, master[stepping]] - 0.5 * sign[stepping])
    assert len(stepping) > 1000 and np.abs(miss).max() <= CROSSING_STEPS


def test_a_shaped_delta_plans_every_check_passing_on_the_shaped_carriages(tmp_path):
    shaped = host_build(load_job(delta_job(tmp_path, MZV, name="shaped")))
    plain = host_build(load_job(delta_job(tmp_path, None, name="plain")))
    f = shaped.findings
    assert f.ok and plain.findings.ok, f.problems
    assert f.final == plain.findings.final == f.expected_final  # the carriages end where the unshaped job's do
    assert max(f.rate_ratio.values()) <= 1.0 and max(f.accel_ratio.values()) <= 1.0
    assert f.max_path_error_mm <= f.path_limit_mm
    assert 0.01 < f.smoothing_mm < 0.5  # MZV at 40 Hz cuts the corners at 3000 mm/s^2 by about 0.1 mm
    assert_events_on_the_shaped_carriages(shaped)


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(points=st.lists(st.tuples(st.integers(-50, 50), st.integers(-50, 50), st.integers(0, 40)), min_size=2,
                       max_size=4, unique=True),
       shaper=st.sampled_from(["zv", "ei", "2hump_ei"]), freq=st.sampled_from([30, 55]))
def test_any_shaped_delta_path_plans_on_its_carriages(tmp_path, points, shaper, freq):
    """Moves through the middle of the bed and up and down, a carriage turning within a move (its velocity through
    zero as the effector passes under its tower's line): the checks pass, and every event is on the carriages."""
    path = delta_job(tmp_path, f"{{x: {{type: {shaper}, freq: {freq}}}, y: {{type: {shaper}, freq: {freq}}}}}",
                     [list(p) for p in points], start=points[0])
    host = host_build(load_job(path))
    assert host.findings.ok, host.findings.problems
    if host.totals.events > 1000:
        assert_events_on_the_shaped_carriages(host)


def test_where_shaping_would_break_a_carriages_limit_the_plan_slows_down(tmp_path):
    """A corner from +x to +y at full speed (a large junction deviation), x shaped slowly and y not: x's speed
    fades over 0.1 s while y's rises at once, and carriage a, whose tower lies behind both, would run at 0.77 of the
    effector's speed where either axis alone makes it 0.49 or less (150 mm/s against its 100). The plan's segments
    under that stretch are slowed until every carriage keeps its limits on the shaped pulses."""
    points = [[-40, -10, 5], [0, -10, 5], [0, 30, 5]]
    jobs = [delta_job(tmp_path, shaper, points, name, feed=9000, start=points[0])
            for shaper, name in (("{x: {type: zv, freq: 5}}", "shaped"), (None, "plain"))]
    for path in jobs:
        path.write_text(path.read_text().replace("max_velocity: 200", "max_velocity: 100")
                        .replace("  delta:", "  junction_deviation: 5\n  delta:"))
    shaped, plain = (host_build(load_job(path)) for path in jobs)
    f = shaped.findings
    assert f.ok and max(f.rate_ratio.values()) <= 1.0 and max(f.accel_ratio.values()) <= 1.0, f.problems
    spread = shaped.settings.stages.shaping.spread
    assert shaped.totals.duration_s > plain.totals.duration_s + spread + 0.05


def test_a_shaped_delta_plays_in_windows_as_in_one(tmp_path, monkeypatch):
    """Each window plays the shaped motion up to its own end, reading back into the plan before it: cut into many
    windows, the shaped delta job makes the same steps, ends where it should, and keeps to the shaped carriages."""
    path = delta_job(tmp_path, "{x: {type: ei, freq: 45}, y: {type: zv, freq: 60}}", CORNERS)
    few = host_build(load_job(path))
    monkeypatch.setattr(pieces, "CHUNK_EVENTS", 1500)
    many = host_build(load_job(path))
    assert many.totals.windows >= 3 * few.totals.windows
    assert many.findings.ok, many.findings.problems
    assert many.findings.steps == few.findings.steps and many.findings.final == few.findings.final
    assert many.totals.duration_s == pytest.approx(few.totals.duration_s, abs=1e-9)
    assert_events_on_the_shaped_carriages(many)


def test_a_delta_rings_far_less_shaped(tmp_path):
    """verify's resonance model (codegen/verify/vibration.py) on the twin's carriage pulses: the effector's
    residual vibration after the corners, shaped, is a fraction of the unshaped run's (the carriages' steps cost
    the shaper a few percent of the cancellation a cartesian machine reaches)."""
    path = delta_job(tmp_path, MZV, RINGING, steps_per_mm=200, accel=12000, feed=3600, start=RINGING[0])
    host = host_build(load_job(path))
    assert host.findings.ok, host.findings.problems
    resonances = tuple(AxisResonance(axis, 40.0, 0.1) for axis in (0, 1))
    check = VibrationCheck.of(host, resonances)
    check.add(whole_chapter(host), host.pulses.tick / host.target.tick_hz, host.pulses.motor, host.pulses.dir)
    for axis, figures in check.figures().items():
        assert figures["unshaped_peak_um"] > 100, axis
        assert figures["residual_peak_um"] < 0.1 * figures["unshaped_peak_um"], (axis, figures)


def test_a_turn_across_a_standstill_is_one(tmp_path, monkeypatch):
    """Where the effector stops in a corner every carriage turns at once: found a few picoseconds apart, the turns
    leave a piece between them where no carriage moves. The turn is cut all the same (the way each carriage last
    moved carries across), and the job makes the steps of the turns taken as one."""
    path = delta_job(tmp_path, MZV, RINGING, steps_per_mm=200, accel=12000, feed=3600, start=RINGING[0])
    one = host_build(load_job(path))
    monkeypatch.setattr(shaped_delta, "TURN_GAP", 0.0)
    apart = host_build(load_job(path))
    assert apart.findings.ok and apart.findings.steps == one.findings.steps
    assert apart.totals.events == one.totals.events


@needs_avr
def test_a_shaped_delta_verifies_in_simavr(tmp_path, capsys):
    path = delta_job(tmp_path, MZV, [[0, -20, 5], [20, 0, 5], [0, 20, 5]], start=(0, -20, 5))
    code, out, _ = run_cli(capsys, "verify", path, "--out", tmp_path / "build", "--json", "--quiet")
    result = json.loads(out)
    assert code == 0 and result["pass"], result["problems"]
    for motor in result["motors"].values():
        assert motor["final"] == motor["expected_final"]
        assert motor["max_rate_ratio"] <= 1.0 and motor["max_accel_ratio"] <= 1.0
    assert result["max_path_error_mm"] <= result["path_limit_mm"] and result["smoothing_mm"] > 0

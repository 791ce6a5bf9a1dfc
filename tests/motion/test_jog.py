"""Jog keys on the host: the job file's `machine.jog` (positioned errors, did you mean), the ramp table
(codegen/motion/jog.py) and the board's key wiring. The firmware in the simulators: test_mcs51_jog.py, test_avr_jog.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from codegen.errors import BuildError, JobError
from codegen.firmware.avr.board import parse_pin
from codegen.job import load_job
from codegen.motion.jog import ACCEL_HEADROOM, RATE_HEADROOM, STILL, board_keys, direction_code, jog_plan
from codegen.pipeline.settings import jog_settings
from tests.helpers import ROOT

JOB = """\
name: j
target: avr
machine:
  kinematics: {kinematics}
  steppers:
    {a}: {{steps_per_mm: {spm}, max_velocity: 50, max_accel: 800}}
    {b}: {{steps_per_mm: 80, max_velocity: 50, max_accel: 800}}
{extra}  jog: {jog}
program:
  shapes:
    - line: {{to: [1, 1]}}
"""


def job(tmp_path: Path, jog: str, kinematics: str = "cartesian", spm: int = 80, extra: str = "") -> Path:
    a, b = {"cartesian": ("x", "y"), "corexy": ("a", "b"), "delta": ("a", "b")}[kinematics]
    path = tmp_path / "j.yaml"
    path.write_text(JOB.format(kinematics=kinematics, a=a, b=b, spm=spm, jog=jog, extra=extra))
    return path


def errors(path: Path) -> list[tuple[int, int, str]]:
    with pytest.raises(JobError) as info:
        load_job(path)
    return [(d.where.line, d.where.col, d.message) for d in info.value.diagnostics]


def test_jog_section_errors_point_at_the_value(tmp_path):
    assert errors(job(tmp_path, "{speeds: [300, 100]}")) == [
        (8, 17, "machine.jog.speeds: speeds must rise from the slowest to the fastest")]
    assert errors(job(tmp_path, "{speeds: [300, 4000]}")) == [
        (8, 23, "machine.jog.speeds[1]: 4000 mm/min is above the jogged motors' max_velocity (50 mm/s = 3000 mm/min)")]
    assert errors(job(tmp_path, "{speed: [300]}"))[0][2].startswith(
        "machine.jog: unknown key 'speed' (did you mean 'speeds'?)")
    assert errors(job(tmp_path, "{keys: matrx}")) == [
        (8, 15, "machine.jog.keys: 'matrx' is not one of matrix, direct (did you mean 'matrix'?)")]
    assert errors(job(tmp_path, "{accel: 900}")) == [
        (8, 16, "machine.jog.accel: 900 mm/s^2 is above the jogged motors' max_accel (800)")]
    assert errors(job(tmp_path, "{}", spm=100)) == [
        (8, 3, "machine.jog: jog keys step x and y at one rate: their steps_per_mm must agree (100, 80)")]


def test_jog_needs_cartesian_or_corexy(tmp_path):
    extra = "  delta: {radius: 100, diagonal_rod: 200, height: 250}\n"
    path = job(tmp_path, "{}", kinematics="delta", extra=extra)
    text = path.read_text().replace("    b: {steps", "    c: {steps_per_mm: 80, max_velocity: 50, max_accel: 800}\n"
                                                     "    b: {steps")
    path.write_text(text)
    assert (10, 3, "machine.jog: jog keys need cartesian or corexy kinematics") in errors(path)


def test_the_ramp_is_constant_acceleration_within_the_limits(tmp_path):
    j = load_job(job(tmp_path, "{speeds: [60, 600, 3000], accel: 500}"))
    plan = jog_plan(jog_settings(j), ("x", "y"), 2_000_000)
    spm, tick = 80.0, 2_000_000
    assert plan.speeds == (60, 600, 3000) and plan.max_rate == 50 * spm and plan.max_accel == 500 * spm
    # Cruise: the level's rate in whole ticks, never faster than the headroom below max_velocity.
    assert plan.cruise == (25000, 2500, int(np.ceil(tick / (50 * spm * RATE_HEADROOM))))
    ramp = np.array(plan.ramp)
    assert np.all(np.diff(ramp) <= 0) and ramp[0] == int(np.ceil(tick * np.sqrt(2 / (500 * spm * ACCEL_HEADROOM))))
    # Each level climbs until the next entry would be quicker than its cruise.
    for cruise, top in zip(plan.cruise, plan.top):
        assert np.all(ramp[:top] > cruise) and (top == len(ramp) or ramp[top] <= cruise)
    assert plan.top[-1] == len(ramp)
    # Step k of the ramp at sqrt(2 k / A): the rate it reaches after k steps is within the acceleration.
    t = np.concatenate([[0], np.cumsum(ramp)]) / tick
    k = np.arange(len(t))
    assert np.all(t >= np.sqrt(2 * k / (500 * spm * ACCEL_HEADROOM)) - 1e-12)


def test_directions_move_the_right_motors(tmp_path):
    cart = jog_plan(jog_settings(load_job(job(tmp_path, "{}"))), ("x", "y"), 1_000_000)
    assert cart.signs[direction_code(1, 0)] == (1, 0) and cart.signs[direction_code(-1, 1)] == (-1, 1)
    assert cart.signs[STILL] == (0, 0)
    xy = jog_plan(jog_settings(load_job(job(tmp_path, "{}", kinematics="corexy"))), ("a", "b"), 1_000_000)
    assert xy.signs[direction_code(1, 0)] == (1, 1)  # x: both belts
    assert xy.signs[direction_code(0, 1)] == (1, -1)  # y: opposite ways
    assert xy.signs[direction_code(1, 1)] == (1, 0) and xy.signs[direction_code(1, -1)] == (0, 1)  # one belt


def test_too_slow_a_speed_for_16_bit_intervals_is_refused(tmp_path):
    j = load_job(job(tmp_path, "{speeds: [1, 600]}"))
    with pytest.raises(BuildError, match=r"1 mm/min is too slow for the jog timer: 1500000 ticks"):
        jog_plan(jog_settings(j), ("x", "y"), 2_000_000)


def test_board_keys_name_every_problem():
    direct = {"x+": "PA1", "x-": "PA3", "y+": "PA5", "y-": "PA7", "speed+": "PG2", "speed-": "PG0", "start": "PL6"}
    wiring = board_keys("b", {"jog_keys": {"direct": direct}}, None, parse_pin, {})
    assert wiring.kind == "direct" and wiring.keys["start"].name == "PL6"
    bad = {**direct, "x+": "PF0", "zoom": "PB1", "y-": "PA5"}
    del bad["start"]
    with pytest.raises(BuildError) as info:
        board_keys("b", {"jog_keys": {"direct": bad}}, None, parse_pin, {"PF0": "steppers.X.step"})
    message = str(info.value)
    for part in ("unknown key function 'zoom'", "missing key(s) start", "PA5 is used twice",
                 "PF0 is already steppers.X.step"):
        assert part in message
    with pytest.raises(BuildError, match="board b: jog_keys: the board has no matrix keys \\(has direct\\)"):
        board_keys("b", {"jog_keys": {"direct": direct}}, "matrix", parse_pin, {})
    matrix = {"rows": ["PA0"], "cols": ["PA1", "PA2"], "keys": {"x+": [0, 0], "x-": [0, 0], "y+": [1, 0]}}
    with pytest.raises(BuildError) as info:
        board_keys("b", {"jog_keys": {"matrix": matrix}}, None, parse_pin, {})
    assert "key y+: expected [row, col] within the 1 x 2 matrix" in str(info.value)
    assert "keys x+, x- share the key [0, 0]" in str(info.value)


def test_examples_and_boards_document_the_keys():
    root = ROOT
    for board in ("seed-51", "ramps-1.4"):
        assert "jog_keys:" in (root / "targets" / f"{board}.yaml").read_text()
    assert "machine.jog" in (root / "README.md").read_text()

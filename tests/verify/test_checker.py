"""The checker checked: verify's pulse comparison (codegen/verify/compare.py) passes the simulator's own pulses and
fails the same run with one motor's pulses late, early or moved to another motor; so it cannot be comparing the
twin with itself."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

from codegen.sim.avr import simulate
from codegen.verify.compare import compare, simulated_switches

pytestmark = pytest.mark.skipif(shutil.which("simavr") is None, reason="needs simavr (scripts/setup.sh installs it)")


@pytest.fixture(scope="module")
def star_run(star_flash):
    host, image = star_flash
    switches = simulated_switches(host)
    budget = int((host.plan.total * 1.2 + 1.0) * host.target.f_cpu)
    return host, simulate(image.hex_path, host.firmware_config(), budget, switches=switches), switches


def moved(trace, motor: int, cycles: int):
    """The trace with every pulse of `motor` after the first 1000 moved by `cycles` (order kept)."""
    mine = np.flatnonzero((trace.step_motor == motor) & (trace.step_phase == "run"))[1000:]
    step_cycle = trace.step_cycle.copy()
    step_cycle[mine] += cycles
    order = np.argsort(step_cycle, kind="stable")
    return dataclasses.replace(trace, step_cycle=step_cycle[order], step_motor=trace.step_motor[order],
                               step_dir=trace.step_dir[order], step_phase=trace.step_phase[order])


def test_the_simulators_pulses_pass(star_run):
    host, trace, switches = star_run
    verdict = compare(host, trace, switches)
    assert verdict.ok, verdict.findings.problems
    assert max(verdict.timing_error_us.values()) < 2.0


@pytest.mark.parametrize("us", [20, -20, 7])
def test_one_motor_late_or_early_fails_with_its_name(star_run, us):
    host, trace, switches = star_run
    verdict = compare(host, moved(trace, 1, us * host.target.f_cpu // 1_000_000), switches)
    assert not verdict.ok
    assert any(p.startswith("motor b") and "away from its predicted time" in p for p in verdict.problems), verdict.problems
    assert verdict.timing_error_us["b"] >= abs(us) - 1 and verdict.timing_error_us["a"] < 2.0


def test_pulses_of_one_motor_played_by_the_other_fail(star_run):
    host, trace, switches = star_run
    swapped = dataclasses.replace(trace, step_motor=np.where(trace.step_phase == "run", 1 - trace.step_motor,
                                                              trace.step_motor))
    assert not compare(host, swapped, switches).ok

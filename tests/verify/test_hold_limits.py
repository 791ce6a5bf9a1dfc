"""The feed hold's and the override's own limits in `verify` (codegen/verify/hold_limits.py): the factor's ramp
against 20 % of every motor's acceleration at its top speed, and the override's ceilings against every motor's
rate, from the job's settings. The dilated twin shares the ramp and the ceilings with the tables, so a ramp twice as
steep or ceilings from 105 % of the headroom pass the comparison (scripts/mutants.py); these rules find them, on the
host's model and in the simulated run; the right ramp and ceilings pass."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

import codegen.tables.headroom
import codegen.tables.hold
from codegen.cli.main import _build
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.tables.hold import F_ONE, RESUME_TICKS, dilate, override_target
from codegen.verify.hold import hold_verify
from codegen.verify.hold_limits import ceiling_problems, ceiling_shares, ramp_excess, ramp_limit, ramp_problems
from tests.helpers import DATA, EXAMPLES, ROOT

NEAR_RATE = ROOT / "tests" / "data" / "mutants" / "override-near-rate.yaml"  # x cruises at 92.5 % of its rate
needs_simavr = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                  reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


def _held(host, plan):
    """The star held halfway through its events (the host's model) and resumed 20 ms after its rest."""
    at = len(host.pulses.event_tick) // 2
    parked = dilate(host.schedule, plan, [(at, 0)]).parks[0][1]
    return dilate(host.schedule, plan, [(at, 0)], [parked + 40_000 + RESUME_TICKS])


def test_the_star_s_ramps_keep_to_a_fifth_of_its_acceleration(star_host):
    """400 %/s: a fifth of 8000 mm/s^2 at 400 mm/s; the hold, its resume and the override's ramps stay within it
    but for the factor's rounding (under 1 F)."""
    host = star_host
    assert ramp_limit(host) == (4.0, "a")
    per_tick = 4.0 * F_ONE / host.target.tick_hz
    held = _held(host, host.hold_plan)
    assert len(held.parks) == 1 and ramp_problems(host, held) == []
    assert 0.97 < ramp_excess(held, per_tick)[0] < 1.0
    for target in (override_target(5), override_target(15)):
        overridden = dilate(host.schedule, host.hold_plan, [(1, target)])
        assert ramp_problems(host, overridden) == []
        assert 0.97 < ramp_excess(overridden, per_tick)[0] < 1.0


def test_a_ramp_twice_as_steep_is_named(star_host):
    host = star_host
    steep = dataclasses.replace(host.hold_plan, ramp_k=2 * host.hold_plan.ramp_k)
    held = _held(host, steep)
    assert ramp_excess(held, 4.0 * F_ONE / host.target.tick_hz) == (pytest.approx(60.565696), 41628, 43197)
    assert ramp_problems(host, held) == [
        "the feed factor ramps from 100.0 % to 0.8 % in 129.8 ms (after events 41628 to 43197): faster than the "
        "hold's ramp may, 400.0 % per second (20 % of stepper a's acceleration at its top speed)"]


def test_the_star_s_ceilings_keep_its_motors_within_their_rate(star_host):
    """At 130.5 % (its highest ceiling) the star's motors, at 76 % of their rate on its straights, would run at 97.9 %
    of it."""
    shares = ceiling_shares(star_host)
    assert {name: (round(share, 4), ceiling) for name, (share, ceiling, _, _) in shares.items()} == \
        {"a": (0.9791, 167), "b": (0.9791, 167)}
    assert ceiling_problems(shares) == []


def test_ceilings_above_the_headroom_are_named(star_host):
    """A ceiling record of 199.2 % from the first run on: both motors would run half as fast again as their rate."""
    schedule = star_host.schedule
    doctored = dataclasses.replace(schedule, run_ceiling=np.where(np.arange(schedule.n_runs) == 0,
                                                                  override_target(20), -1))
    host = dataclasses.replace(star_host, compressed=dataclasses.replace(star_host.compressed, schedule=doctored))
    assert ceiling_problems(ceiling_shares(host)) == [
        "motor a: the override's ceiling of 199.2 % in force at events 51390 to 51397 would take it to 151.8 % of "
        "its rate over 8 steps (max_velocity x steps_per_mm)",
        "motor b: the override's ceiling of 199.2 % in force at events 489 to 496 would take it to 151.6 % of its "
        "rate over 8 steps (max_velocity x steps_per_mm)"]


def test_a_plan_without_ceilings_above_100_percent_has_nothing_to_check():
    host = host_build(load_job(NEAR_RATE))
    assert host.schedule.n_ceiling == 0 and ceiling_shares(host) == {}


@needs_simavr
def test_verify_names_a_ramp_twice_as_steep(tmp_path, monkeypatch):
    """The image's ramp and its dilated twin's both twice as steep: they agree, the rule does not."""
    monkeypatch.setattr(codegen.tables.hold, "RAMP_SHARE", 2 * codegen.tables.hold.RAMP_SHARE)
    host, image, _ = _build(load_job(EXAMPLES / "star.yaml"), str(tmp_path), reuse=False, strict=False)
    result, _ = hold_verify(host, image, 1.0, None)
    assert not result["pass"]
    assert result["problems"] == [
        "the feed factor ramps from 100.0 % to 0.8 % in 126.1 ms (after events 21924 to 23390): faster than the "
        "hold's ramp may, 400.0 % per second (20 % of stepper a's acceleration at its top speed)"]


@needs_simavr
def test_verify_names_ceilings_above_the_headroom(tmp_path, monkeypatch):
    """Ceilings from 105 % of the headroom let x up to 110 % where it cruises at 92.5 % of its rate: the tables'
    ceiling is named first, then the simulated run's rate."""
    rate_ratio = codegen.tables.headroom._rate_ratio
    monkeypatch.setattr(codegen.tables.headroom, "_rate_ratio", lambda *args: rate_ratio(*args) / 1.05)
    host, image, _ = _build(load_job(NEAR_RATE), str(tmp_path), reuse=False, strict=False)
    result, _ = hold_verify(host, image, None, 150)
    assert not result["pass"]
    assert result["problems"][0] == ("motor x: the override's ceiling of 110.2 % in force at events 305 to 312 would "
                                     "take it to 101.9 % of its rate over 8 steps (max_velocity x steps_per_mm)")
    assert "motor x exceeds its rate over 8 steps by 2.1 %" in result["problems"]
    assert result["hold"]["ceiling_rate_ratio"] == 1.0194


@needs_simavr
def test_the_star_overridden_to_150_percent_passes_both_rules(star_flash):
    host, image = star_flash
    result, _ = hold_verify(host, image, 0.6, 150)
    assert result["pass"], result["problems"]
    hold = result["hold"]
    assert hold["ceiling_rate_ratio"] == 0.9791 and hold["highest_factor_pct"] == 130.5
    assert len(hold["rests"]) == 1


def test_a_ceiling_counts_the_8_steps_that_reach_into_the_window_before():
    """A coarse carriage's 8 steps span the two windows of a slow delta move: the second window's ceiling keeps the
    stretch that began in the first within its rate (it was 100.8 % under 199.2 %)."""
    host = host_build(load_job(DATA / "jobs" / "found" / "delta-coarse-ceiling-across-windows.yaml"))
    assert host.totals.windows == 2 and host.schedule.n_ceiling > 0
    shares = ceiling_shares(host)
    assert ceiling_problems(shares) == [] and max(share for share, _, _, _ in shares.values()) <= 1.0

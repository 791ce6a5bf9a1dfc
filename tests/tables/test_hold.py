"""Feed hold, resume and override by time dilation (codegen/tables/hold.py, the AVR flash image's dilated path,
codegen/verify/hold.py): the star at full speed held at random points and resumed in simavr, every pulse on the
dilated twin's clock and every motor within its limits; an override through the feed keys; the host model over
random machines and programs (hypothesis); and the refusals where there is no hold yet."""

from __future__ import annotations

import dataclasses
import random
import shutil

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import codegen.tables.hold
from codegen.cli.main import _build, main
from codegen.errors import BuildError, JobError
from codegen.firmware.avr.image import render_sources
from codegen.job import load_job
from codegen.pipeline.host import host_build, trains_from
from codegen.pipeline.streaming import stream_setup
from codegen.sim.avr import simulate
from codegen.tables.checks import check
from codegen.tables.hold import (F_MAX, F_ONE, RAMP_SHARE, RESUME_TICKS, STRETCH, dilate, dilation_table,
                                 event_ceilings, event_runs, override_target, run_ceilings)
from codegen.tables.schedule import in_force
from codegen.tables.twin import event_ticks
from codegen.verify.hold import hold_verify
from codegen.verify.hold_limits import ceiling_problems, ceiling_shares, ramp_problems
from codegen.verify.hold_runs import FlashRun
from tests.helpers import ROOT
from tests.jobgen import jobs

needs_simavr = pytest.mark.skipif(shutil.which("avr-gcc") is None, reason="avr-gcc not installed")


@pytest.fixture(scope="module")
def star(star_flash):
    """examples/star.yaml (it has feed_hold), built once (conftest.py)."""
    return star_flash


def test_the_dilation_table_is_the_factor_s_reciprocal():
    d = dilation_table(F_MAX)
    assert F_ONE == 128 and d[F_ONE] == 256 and d[1] == 32768 and d[64] == 512 and d[F_MAX] == 129
    assert np.all(np.diff(d[1:]) <= 0)
    # the override's steps: 12.8 F each, rounded; 200 % is the highest factor, 199 %
    assert [override_target(s) for s in (1, 5, 10, 15, 19, 20)] == [13, 64, F_ONE, 192, 243, F_MAX]


@needs_simavr
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_star_held_at_a_random_point_comes_to_rest_within_its_limits_and_ends_exact(star, seed):
    host, image = star
    at = random.Random(seed).uniform(0.05, host.plan.total - 0.5)
    result, trace = hold_verify(host, image, at, None)
    assert result["pass"], result["problems"]
    hold = result["hold"]
    # at rest (its last pulse) no sooner than the ramp allows (0.262 s from 100 % to 0; the last pulse may come a
    # dilated gap, a few ms, before the factor reaches 0) unless the plan stops at a star's point meanwhile (its
    # clock runs slower than the ramp's), and not much later (the braking it waited for)
    stops = (host.plan.t_start + host.plan.duration)[host.plan.v_exit < 1e-9]
    stops_anyway = np.any((stops > at) & (stops < at + hold["ramp_s"]))
    assert (0 if stops_anyway else hold["ramp_s"] - 0.005) < hold["stopping_s"] < hold["ramp_s"] + 0.15
    assert hold["resume_s"] > hold["at_rest_s"]
    for name, motor in result["motors"].items():
        assert motor["final"] == motor["expected_final"]
        assert motor["max_timing_error_us"] <= 1.0
        assert motor["max_accel_ratio"] <= 1.0 and motor["max_rate_ratio"] <= 1.0
    # no pulse while parked: between the last one before the rest and the resume key (times rounded to 1 us)
    rest, resume = (trace.timer_start_cycle + hold[k] * 16e6 for k in ("at_rest_s", "resume_s"))
    parked = (trace.step_cycle > rest + 40) & (trace.step_cycle < resume)
    assert not parked.any()
    # the hold added its time: stopping, standing, speeding up again
    assert result["duration_s"] > result["planned_duration_s"] - 1e-6 > 0
    assert result["duration_s"] > host.plan.total + (hold["resume_s"] - hold["at_rest_s"])


@needs_simavr
def test_a_hold_too_late_to_stop_before_the_end_slows_the_rest_and_passes(star):
    """The star's last 0.1 s are shorter than the ramp to rest (0.25 s), and it brakes at its end: the machine
    slows down and the job ends before it stands; every pulse is still the dilated twin's."""
    host, image = star
    result, _ = hold_verify(host, image, host.plan.total - 0.1, None)
    assert result["pass"], result["problems"]
    assert result["hold"]["ended_before_rest"] is True and "at_rest_s" not in result["hold"]
    assert result["hold"]["rests"] == [] and result["hold"]["keys"][0]["first_dilated_event"] > 0
    plain, _ = hold_verify(host, image, None, 100)  # no key at all: the plan's own time
    assert result["duration_s"] > plain["duration_s"] + 0.01  # the last pulses came later


@needs_simavr
def test_the_feed_keys_override_the_whole_star_to_half_speed(star):
    host, image = star
    result, _ = hold_verify(host, image, None, 50)
    assert result["pass"], result["problems"]
    assert [k["key"] for k in result["hold"]["keys"]] == ["feed-"] * 5
    # 10 % per 100 ms down to 50 %: the job takes close to twice its time
    assert 1.8 * host.plan.total < result["duration_s"] < 2.0 * host.plan.total
    assert all(m["final"] == m["expected_final"] for m in result["motors"].values())


@needs_simavr
def test_a_bouncing_feed_key_steps_the_override_once(star):
    """Three closings of feed- within 5 ms (its contacts bouncing) take the override to 90 %, not 70 %."""
    host, image = star
    run = FlashRun(host, image)
    tick0, ms = run.tick0(False), host.target.f_cpu // 1000
    pin, at = host.hold_plan.keys["feed-"], tick0 + 10 * ms
    bounces = [(pin, at, at + 2 * ms), (pin, at + 3 * ms, at + 4 * ms), (pin, at + 5 * ms, at + 60 * ms)]
    trace = simulate(image.hex_path, run.config, 3 * run.budget, switches=run.switches, presses=bounces)
    took = (int(trace.step_cycle.max()) - trace.timer_start_cycle) / host.target.f_cpu
    cycles = tick0 + host.pulses.event_tick * (host.target.f_cpu // host.target.tick_hz)
    seen = int(np.searchsorted(cycles, at)) + 2
    predicted = {step: dilate(host.schedule, host.hold_plan, [(seen, override_target(step))]).tick[-1]
                 / host.target.tick_hz for step in (9, 8, 7)}
    assert abs(took - predicted[9]) < 0.001 * predicted[9], (took, predicted)
    assert predicted[8] - predicted[9] > 0.1


@needs_simavr
def test_a_twin_with_another_ramp_does_not_pass(star):
    """The comparison can fail: a ramp one step per tick faster than the firmware's is found out."""
    host, image = star
    wrong = dataclasses.replace(host.hold_plan, ramp_k=host.hold_plan.ramp_k + 1)
    fake = dataclasses.replace(host)
    fake.__dict__["hold_plan"] = wrong
    result, _ = hold_verify(fake, image, 0.7, None)
    assert not result["pass"]
    assert any("away from its predicted time" in p for p in result["problems"])


@needs_simavr
def test_verify_hold_on_the_command_line(star, capsys):
    code = main(["verify", str(ROOT / "examples" / "star.yaml"), "--out", str(star[1].hex_path.parent),
                 "--hold", "1.0"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert out.startswith("PASS star")
    assert "hold at 1.0000 s: the player dilated from event" in out and "hold: at rest" in out


def _with_hold(text: str, override: int = 100) -> str:
    job = yaml.safe_load(text)
    job["machine"]["feed_hold"] = {"override": override}
    return yaml.safe_dump(job, sort_keys=False)


def test_a_hold_key_on_a_pin_the_board_uses_is_an_error(star_host):
    host = star_host
    config = dataclasses.replace(host.firmware_config(), hold=dataclasses.replace(
        host.hold_plan, keys={**host.hold_plan.keys, "feed+": "PF0"}))
    with pytest.raises(BuildError, match=r"hold_keys feed\+ is PF0, which is its steppers.X.step too"):
        render_sources(host.schedule, config)


@needs_simavr
def test_a_delta_held_mid_job_comes_to_rest_within_its_limits_and_ends_exact(tmp_path):
    """A delta's motors speed up and slow down along a straight line: its plan keeps RAMP_SHARE of every motor's
    acceleration for the ramp (the player's ramp is not gated), and a hold anywhere keeps every motor within its
    limits. The Kossel homes first: the verification finds the table's pulses after the homing's."""
    path = tmp_path / "kossel.yaml"
    path.write_text(_with_hold((ROOT / "examples" / "kossel-mini.yaml").read_text()))
    job = load_job(path)
    host, image, _ = _build(job, str(tmp_path / "out"), reuse=False, strict=False)
    assert not host.hold_plan.gated
    assert max(host.findings.accel_ratio.values()) <= 1.0 - RAMP_SHARE + 0.01  # the plan's own share
    at = random.Random(4).uniform(0.5, host.plan.total - 1.0)
    result, _ = hold_verify(host, image, at, None)
    assert result["pass"], result["problems"]
    hold = result["hold"]
    assert hold["ramp_s"] - 0.001 < hold["stopping_s"] < hold["ramp_s"] + 0.15
    for motor in result["motors"].values():
        assert motor["final"] == motor["expected_final"]
        assert motor["max_accel_ratio"] <= 1.0 and motor["max_rate_ratio"] <= 1.0


def test_the_8051_holds_in_its_flash_image_and_stream_up_to_100_percent(tmp_path):
    """The 8051's flash image and streaming firmware have feed hold (tests/verify/test_hold_mcs51.py,
    tests/verify/test_hold_mcs51_stream.py), the stream with no keys (the link's frames) on a board without hold keys too;
    its player has no ceiling records: its override goes up to 100 % (the default there), more is refused."""
    job = yaml.safe_load(_with_hold((ROOT / "examples" / "star.yaml").read_text()))
    job.update(target="mcs51", board="seed-51")
    path = tmp_path / "star.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    host = host_build(load_job(path))
    assert host.hold_plan.top == F_ONE and host.schedule.n_ceiling == 0
    for key, percent in (("max_override", 150), ("override", 120)):
        job["machine"]["feed_hold"] = {key: percent}
        path.write_text(yaml.safe_dump(job, sort_keys=False))
        with pytest.raises(BuildError, match=f"machine.feed_hold.{key}: the 8051's player goes up to 100 % "
                                             rf"\(has {percent} %\)"):
            host_build(load_job(path))
    job["machine"]["feed_hold"] = {}
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    assert stream_setup(load_job(path)).config.hold.top == F_ONE
    job["board"] = "at89c52"  # no hold_keys: its flash image cannot hold, its stream can
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    with pytest.raises(BuildError, match="machine.feed_hold: board at89c52 has no hold_keys"):
        host_build(load_job(path))
    assert stream_setup(load_job(path)).config.hold.keys == {}


def test_an_override_the_keys_cannot_reach_is_an_error(tmp_path):
    path = tmp_path / "job.yaml"
    path.write_text(_with_hold((ROOT / "examples" / "star.yaml").read_text()).replace("override: 100",
                                                                                      "override: 55"))
    with pytest.raises(JobError) as err:
        load_job(path)
    assert "from 10 to 200 in steps of 10" in err.value.render()


HOST = settings(max_examples=25, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much])


@HOST
@given(st.sampled_from(["cartesian", "corexy", "delta"]).flatmap(lambda k: jobs(k, "avr")),
       st.floats(0.05, 0.95), st.integers(0, 5))
def test_the_ramp_keeps_every_motor_within_its_limits_on_random_jobs(tmp_path_factory, text, where, override):
    """The host model of a hold (and an override before it: 70, 40 or 10 %, or 150 or 200 % under the ceiling
    records) over random machines and programs: the dilated pulse trains keep every motor within its rate and
    acceleration, as the planned ones do; the ramp and the ceilings keep to verify's rules (hold_limits.py)."""
    path = tmp_path_factory.mktemp("hold") / "job.yaml"
    path.write_text(_with_hold(text))
    try:
        host = host_build(load_job(path))
    except (JobError, BuildError):
        assume(False)
    assume(host.findings.ok and len(host.pulses.event_tick) > 10)
    twin = host.pulses
    events = len(twin.event_tick)
    step = {0: 10, 1: 7, 2: 4, 3: 1, 4: 15, 5: 20}[override]
    changes = ([(1, override_target(step))] if step != 10 else []) + [(int(where * events), 0)]
    held = dilate(host.schedule, host.hold_plan, changes)
    if held.parks:  # resume 20 ms after the rest, back to 100 %
        resume = held.parks[0][1] + host.target.tick_hz // 50 + RESUME_TICKS
        held = dilate(host.schedule, host.hold_plan, changes, [resume], F_ONE)
    assert np.all(np.diff(held.tick) >= 0)
    assert ramp_problems(host, held) == [] and ceiling_problems(ceiling_shares(host)) == []
    delay = (held.tick - twin.event_tick) / host.target.tick_hz
    trains = trains_from(held.tick[twin.event] / host.target.tick_hz, twin.motor, twin.dir, len(host.kin.motors))
    findings = check(trains, np.zeros((0, len(host.kin.motors)), dtype=np.int64), np.zeros(0, dtype=np.int64),
                     host.segments, host.plan, host.kin, host.expected_final, host.start_steps,
                     host.job.machine.tolerance, lambda t: t + np.interp(t, host.events.time, delay))
    for name in host.kin.motors:
        assert findings.accel_ratio[name] <= max(1.0, host.findings.accel_ratio[name]) + 1e-9, findings.problems
        assert findings.rate_ratio[name] <= max(1.0, host.findings.rate_ratio[name]) + 1e-9, findings.problems


def test_a_steady_stretch_dilated_in_pieces_is_the_twin_s_clock(star_host, monkeypatch):
    """dilate sums a steady stretch STRETCH events at a time: at 100 % from the first event (the star's 83261 events:
    two pieces) every tick is the twin's; overridden to 50 %, pieces of 1000 events give every tick and factor
    that pieces of STRETCH give."""
    schedule, plan = star_host.schedule, star_host.hold_plan
    assert int(schedule.run_count.sum()) == 83261 > STRETCH
    assert np.array_equal(dilate(schedule, plan, [(0, F_ONE)]).tick, event_ticks(schedule))
    half = dilate(schedule, plan, [(0, 64)])
    assert half.factor.dtype == np.int16 and (half.factor == 64).sum() > 80000  # all but the ramp's
    monkeypatch.setattr(codegen.tables.hold, "STRETCH", 1000)
    small = dilate(schedule, plan, [(0, 64)])
    assert np.array_equal(small.tick, half.tick) and np.array_equal(small.factor, half.factor)


def test_event_ceilings_come_from_the_runs_as_the_schedule_s_records_are_in_force(star_host):
    """The ceiling at every event through its run (an int32 run index per event) is in_force's over the events."""
    schedule = star_host.schedule
    assert schedule.n_ceiling == 16
    assert np.array_equal(event_ceilings(schedule), in_force(schedule, schedule.run_ceiling, F_ONE))
    assert len(run_ceilings(schedule)) == len(schedule.run_count) and event_runs(schedule).dtype == np.int32

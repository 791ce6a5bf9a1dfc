"""Feed override above 100 % (codegen/tables/headroom.py's ceiling records, the player's goal under them): a plotter that
draws well below its motors' limits goes up to 200 % only where they allow it, comes back down before every
corner and brake, and ends exact; in the host's model, in the flash image and in the streaming firmware (simavr),
beside a laser whose M4 never burns more than its S; and the comparison fails for a twin that ignores the
ceilings."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

import codegen.tables.hold
from codegen.cli.main import _build
from codegen.cli.stream import _firmware, streamed_host
from codegen.errors import BuildError, JobError
from codegen.job import load_job
from codegen.pipeline.host import host_build, trains_from
from codegen.pipeline.streaming import stream_setup
from codegen.report.summaries import plan_summary
from codegen.tables.checks import check
from codegen.tables.format import encode, stream_bytes
from codegen.tables.hold import F_ONE, dilate, event_ceilings, override_target
from codegen.verify.hold import hold_verify
from tests.helpers import ROOT
from tests.reference_player import play_stream

needs_simavr = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                  reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")

# Drawn at 40 mm/s and travelling at 90 mm/s on motors good for 150 mm/s: headroom on every straight stretch.
PLOTTER = """\
name: headroom
target: avr
board: ramps-1.4
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 80, max_velocity: 150, max_accel: 2000, range: [0, 200]}
    y: {steps_per_mm: 80, max_velocity: 150, max_accel: 2000, range: [0, 200]}
  feed_hold: {}
program:
  start: [0, 0]
  feed: 2400
  travel_feed: 5400
  gcode: |
    G21 G90
    G0 X20 Y20
    M3
    G1 X120 Y20
    G1 X120 Y90
    G2 X50 Y90 I-35 J0
    G1 X20 Y20
    M5
    G0 X150 Y150
"""


def _job(tmp_path: Path, text: str = PLOTTER, **feed_hold):
    job = yaml.safe_load(text)
    job["machine"]["feed_hold"] = feed_hold
    path = tmp_path / "headroom.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    return load_job(path)


def _limits(host, held) -> None:
    """The dilated pulse trains keep every motor within its rate and acceleration."""
    twin, tick_hz = host.pulses, host.target.tick_hz
    delay = (held.tick - twin.event_tick) / tick_hz
    trains = trains_from(held.tick[twin.event] / tick_hz, twin.motor, twin.dir, len(host.kin.motors))
    motors = len(host.kin.motors)
    findings = check(trains, np.zeros((0, motors), dtype=np.int64), np.zeros(0, dtype=np.int64), host.segments,
                     host.plan, host.kin, host.expected_final, host.start_steps, host.job.machine.tolerance,
                     lambda t: t + np.interp(t, host.events.time, delay))
    for name in host.kin.motors:
        assert findings.rate_ratio[name] <= 1.0 and findings.accel_ratio[name] <= 1.0, findings.problems


@pytest.fixture(scope="module")
def plotter(tmp_path_factory):
    folder = tmp_path_factory.mktemp("headroom")
    host, image, _ = _build(_job(folder), str(folder / "out"), reuse=False, strict=False)
    return host, image


def test_the_ceilings_let_the_factor_up_on_straight_stretches_and_down_before_the_limits(plotter):
    host, _ = plotter
    schedule = host.schedule
    assert schedule.n_ceiling >= 4
    ceiling = event_ceilings(schedule)
    assert ceiling.max() == override_target(20) and ceiling.min() == F_ONE
    held = dilate(schedule, host.hold_plan, [(1, override_target(20))])
    played = held.factor[:-1]
    above = np.flatnonzero(played > ceiling[1:])  # only while it falls to a lower ceiling
    assert len(above) and np.all(played[above] <= played[above - 1])
    assert played.max() > 1.8 * F_ONE
    took, planned = held.tick[-1] / host.target.tick_hz, host.plan.total
    assert took < 0.75 * planned, (took, planned)
    _limits(host, held)


def test_ceiling_records_are_in_the_table_where_the_schedule_puts_them(plotter):
    host, _ = plotter
    schedule = host.schedule
    ceilings: list = []
    pulses, _, _ = play_stream(encode(schedule).data, len(schedule.motors), ceiling=ceilings)
    run_first = np.cumsum(schedule.run_count) - schedule.run_count
    records = schedule.run_ceiling >= 0
    assert ceilings == list(zip(run_first[records].tolist(), schedule.run_ceiling[records].tolist()))
    assert [t for t, _, _ in pulses] == host.pulses.tick.tolist()  # they change no pulse


def test_a_machine_at_its_limits_gets_no_headroom(tmp_path):
    """A rectangle at the motors' top speed: no motor has any to spare (a diagonal would: each motor at 71 %)."""
    text = PLOTTER.replace("feed: 2400", "feed: 9000").replace("travel_feed: 5400", "travel_feed: 9000")
    body = "".join(f"    G1 {move}\n" for move in ("X120 Y20", "X120 Y90", "X20 Y90", "X20 Y20"))
    text = text[:text.index("    G1 X120 Y20")] + body
    host = host_build(_job(tmp_path, text))
    assert host.plan.v_peak.max() == pytest.approx(150.0)
    assert host.schedule.n_ceiling == 0


def test_max_override_100_makes_no_records_and_bounds_the_keys(tmp_path):
    host = host_build(_job(tmp_path, max_override=100))
    assert host.schedule.n_ceiling == 0 and host.hold_plan.top == F_ONE
    with pytest.raises(BuildError, match=r"from 10 % to 100 % \(machine.feed_hold.max_override\)"):
        hold_verify(host, None, None, 150)


def test_the_plan_accounts_for_every_byte_of_the_ceilings(plotter, tmp_path):
    host, _ = plotter
    plain = host_build(_job(tmp_path, max_override=100))
    hold = plan_summary(host)["feed_hold"]
    assert hold["ceiling_records"] == host.schedule.n_ceiling and hold["max_override_pct"] == 200
    assert hold["ceiling_bytes"] == stream_bytes(host.schedule) - stream_bytes(plain.schedule) > 4 * hold[
        "ceiling_records"]  # each record and the run it splits
    assert plan_summary(plain)["feed_hold"]["ceiling_bytes"] == 0


def test_an_override_above_max_override_is_an_error(tmp_path):
    with pytest.raises(JobError) as err:
        _job(tmp_path, override=150, max_override=120)
    assert "expected at most max_override (120 %)" in err.value.render()


@needs_simavr
def test_the_flash_image_overridden_to_200_percent_goes_faster_within_its_limits(plotter):
    host, image = plotter
    result, _ = hold_verify(host, image, None, 200)
    assert result["pass"], result["problems"]
    hold = result["hold"]
    assert hold["highest_factor_pct"] > 180 and hold["ceiling_records"] == host.schedule.n_ceiling
    assert result["duration_s"] < 0.8 * host.plan.total
    for motor in result["motors"].values():
        assert motor["final"] == motor["expected_final"]
        assert motor["max_accel_ratio"] <= 1.0 and motor["max_rate_ratio"] <= 1.0


@needs_simavr
def test_a_hold_above_100_percent_comes_to_rest_and_resumes_exact(plotter):
    host, image = plotter
    result, _ = hold_verify(host, image, 1.5, 200)
    assert result["pass"], result["problems"]
    assert result["hold"]["stopping_s"] > 0 and result["hold"]["highest_factor_pct"] > 150
    assert all(m["final"] == m["expected_final"] for m in result["motors"].values())


@needs_simavr
def test_a_twin_that_ignores_the_ceilings_does_not_pass(plotter, monkeypatch):
    """The comparison can fail: a player whose factor went up to the override whatever the ceilings is found out."""
    host, image = plotter
    monkeypatch.setattr(codegen.tables.hold, "run_ceilings",
                        lambda schedule: np.full(len(schedule.run_count), override_target(20)))
    result, _ = hold_verify(host, image, None, 200)
    assert not result["pass"]
    assert any("away from its predicted time" in p for p in result["problems"])


@needs_simavr
def test_a_streamed_plotter_overridden_by_feed_up_frames(tmp_path):
    job = _job(tmp_path)
    setup = stream_setup(job, None)
    image, _ = _firmware(job, setup, str(tmp_path / "out"))
    host = streamed_host(job, setup, False, keep=True)
    assert host.schedule.n_ceiling >= 4
    result, _ = hold_verify(host, image, None, 180, setup)
    assert result["pass"], result["problems"]
    assert result["link"]["retransmits"] == 0 and result["link"]["underruns"] == 0
    assert result["hold"]["highest_factor_pct"] > 160
    assert all(m["final"] == m["expected_final"] for m in result["motors"].values())


@needs_simavr
def test_m4_keeps_its_power_above_100_percent(tmp_path):
    """The laser example with feed_hold, overridden to 150 %: M4 follows the speed up to its S, no further."""
    job = yaml.safe_load((ROOT / "examples" / "laser" / "power.yaml").read_text())
    job["machine"]["feed_hold"] = {}
    path = tmp_path / "laser-over.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    host, image, _ = _build(load_job(path), str(tmp_path / "out"), reuse=False, strict=False)
    result, _ = hold_verify(host, image, None, 150)
    assert result["pass"], result["problems"]
    assert result["laser"]["max_power_error_pct"] <= 1.0
    assert result["hold"]["highest_factor_pct"] > 100

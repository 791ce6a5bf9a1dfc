"""Laser power (codegen/tables/laser.py): M3 constant and M4 dynamic power as power records, played by the AVR's flash
image and its streaming firmware and measured in simavr from the writes of the PWM's compare register."""

from __future__ import annotations

import json

import numpy as np
import pytest

from codegen.cli.main import main
from codegen.job import load_job
from codegen.link.protocol import Status
from codegen.link.serial_port import status_line
from codegen.pipeline.host import host_build
from codegen.tables.format import POWER_BYTES, encode
from codegen.tables.laser import POWER_STEP, event_power, planned_speed, played_counts, with_power
from codegen.tables.twin import event_ticks
from tests.helpers import ROOT, make_schedule
from tests.reference_player import play_stream

POWER_JOB = ROOT / "examples" / "laser" / "power.yaml"


@pytest.fixture(scope="module")
def power_host():
    return host_build(load_job(POWER_JOB))


def _event_segments(host):
    return np.repeat(host.events.block_segment, np.diff(host.events.block_first))


def test_splitting_runs_for_power_records_moves_no_event():
    schedule = make_schedule(("x",), [((1,), (20,), 20, (0,), True, 20)], runs=[(3000, 40, 12), (2500, -7, 8)])
    counts = np.array([0] * 3 + [500] * 6 + [800] * 5 + [0] * 6)
    split = with_power(schedule, counts, before=0)
    assert np.array_equal(event_ticks(split), event_ticks(schedule))
    assert split.n_power == 3
    assert np.array_equal(played_counts(split), counts)
    power = []
    play_stream(encode(split).data, 1, power=power)
    assert power == [(3, 500), (9, 800), (14, 0)]  # each before the run of the event that takes it
    assert len(encode(split).data) == len(encode(schedule).data) + 3 * POWER_BYTES + 3 * 6  # three splits


def test_m4_power_follows_the_planned_speed_and_g0_is_dark(power_host):
    host = power_host
    top = host.laser.top
    counts, ideal = played_counts(host.schedule), event_power(host.events, host.plan, host.segments)
    assert np.max(np.abs(counts / top - ideal)) <= POWER_STEP / 2 + 0.5 / top
    segment = _event_segments(host)
    tool = np.repeat(host.events.block_tool, np.diff(host.events.block_first))
    assert np.all(counts[~tool] == 0)  # G0 and M5: dark
    dynamic = tool & host.segments.dynamic[segment]
    speed = planned_speed(host.plan, segment[dynamic], host.events.time[dynamic])
    want = host.segments.power[segment[dynamic]] * np.minimum(speed / host.segments.feed[segment[dynamic]], 1)
    assert np.allclose(ideal[dynamic], want)
    assert counts[dynamic].min() < 0.3 * top  # slowed down at the zigzag's corners: a fraction of S1000
    assert counts[dynamic].max() == top  # S1000 at its feed: full power
    assert len(np.unique(counts[dynamic])) > 50  # it follows the ramps, not once per segment


def test_m3_changes_power_mid_cut_without_stopping(power_host):
    host = power_host
    counts = played_counts(host.schedule)
    top = host.laser.top
    change = np.flatnonzero((counts[1:] == round(0.9 * top)) & (counts[:-1] == round(0.3 * top)))[0] + 1
    segment = _event_segments(host)[change]
    speed = planned_speed(host.plan, np.array([segment]), host.events.time[[change]])[0]
    assert speed > 0.9 * 30.0  # G1 X10 S900 after G1 X25 (F1800 = 30 mm/s) on the same line: no stop there


def test_a_laser_where_the_board_has_no_pwm_is_an_error(tmp_path, capsys):
    job = tmp_path / "laser51.yaml"
    job.write_text(POWER_JOB.read_text().replace("name: laser-power", "name: laser51\ntarget: mcs51"))
    assert main(["plan", str(job)]) == 1
    assert "has no laser PWM output" in capsys.readouterr().err


def test_status_carries_the_laser_power():
    payload = bytes([2]) + (1234).to_bytes(4, "little") + (56).to_bytes(2, "little") \
        + (7).to_bytes(4, "little", signed=True) + (-3).to_bytes(4, "little", signed=True) + (4321).to_bytes(2, "little")
    status = Status.parse(payload, 2)
    assert status.position == (7, -3) and status.laser == 4321 and status.heaters == ()
    assert status_line(status, ("x", "y"), (), 8000) == "playing, ring 56 B, x +7 y -3, laser 54.0 %"


def _verify(capsys, *args) -> dict:
    code = main(["verify", str(POWER_JOB), "--json", *args])
    result = json.loads(capsys.readouterr().out)
    assert code == 0, result["problems"]
    return result


@pytest.mark.parametrize("stream", [False, True], ids=["flash", "stream"])
def test_the_simulated_pwm_plays_the_planned_power_at_every_step(tmp_path, capsys, stream):
    result = _verify(capsys, "--out", str(tmp_path), *(["--stream"] if stream else []))
    laser = result["laser"]
    assert laser["max_power_error_pct"] <= 100 * (POWER_STEP / 2) + 0.1
    assert laser["cuts"] == 2 and laser["max_energy_per_mm_error_pct"] < 0.5
    assert laser["pwm_hz"] == 1000.0


def test_verify_fails_a_pwm_that_differs_from_the_tables(tmp_path, monkeypatch, capsys):
    """The check can fail: the same simulated run against tables whose power records come one event later."""
    import codegen.verify.laser as verify_laser

    real = verify_laser.played_counts
    monkeypatch.setattr(verify_laser, "played_counts", lambda schedule, before=0: np.roll(real(schedule, before), 1))
    code = main(["verify", str(POWER_JOB), "--json", "--out", str(tmp_path)])
    result = json.loads(capsys.readouterr().out)
    assert code == 1
    assert any(p.startswith("laser: at simulated event") and "differ" in p for p in result["problems"])


def test_status_while_streaming_reports_the_pwm(tmp_path):
    """A STATUS answer mid-cut carries the power the PWM holds then (what `stream` shows live)."""
    import codegen.tables.format as tables
    from codegen.cli.stream import _firmware, streamed_host
    from codegen.link.host import HostLink
    from codegen.pipeline.streaming import stream_chunks, stream_setup
    from codegen.sim.avr_link import simulate_stream
    from tests.firmware.avr.helpers import Scripted

    job = load_job(POWER_JOB)
    setup = stream_setup(job)
    image, _ = _firmware(job, setup, str(tmp_path))
    host = streamed_host(job, setup, False, keep=True)
    link = HostLink(stream_chunks(tables.encode(host.schedule).data, 2), 2, setup.identity, 10 / setup.layout.baud,
                    host.link_plan.prefill_bytes, payload=setup.budget.payload,
                    stream_bytes=host.link_plan.stream_bytes, laser_top=host.laser.top)
    trace, _ = simulate_stream(image.hex_path, setup.config, Scripted(link, [(8.0, "request_status")]),
                               20 * 16_000_000)
    assert link.outcome == "finished" and link.status.state == "playing"
    seconds, counts = trace.laser_duty[:, 0] / 16e6, trace.laser_duty[:, 1]
    held = counts[(seconds <= 8.0)][-1:].tolist() + counts[(seconds > 8.0) & (seconds < 8.05)].tolist()
    assert 0 < link.status.laser <= host.laser.top and link.status.laser in held  # what the PWM held as it answered

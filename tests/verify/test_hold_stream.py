"""Feed hold over the link (HOLD, RESUME, FEED_DOWN, FEED_UP frames to the streaming firmware) and the program
pause M0/M1 (flash image and stream): simulated in simavr, every pulse against the dilated twin, positions exact;
and what M0/M1 does where there is no resume key; STATUS carries the feed factor, and `stream` takes Grbl's keys."""

from __future__ import annotations

import json
import random
import shutil

import numpy as np
import pytest

from codegen.cli.main import _build, main
from codegen.errors import JobError
from codegen.job import load_job
from codegen.link import protocol
from codegen.link.host import HostLink
from codegen.link.serial_port import send_hold_keys, status_line, terminal_keys
from codegen.pipeline.host import host_build
from codegen.sim.avr_link import simulate_stream
from codegen.tables.hold import F_ONE
from codegen.verify import hold_runs
from codegen.verify.compare import simulated_switches
from codegen.verify.hold import hold_verify
from codegen.verify.stream import new_link
from tests.helpers import ROOT, streamed
from tests.verify.helpers import Watched

PEN_CHANGE = ROOT / "examples" / "gcode" / "pen-change.yaml"
pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


def _exact(result: dict) -> None:
    assert result["pass"], result["problems"]
    assert result["link"]["retransmits"] == 0 and result["link"]["underruns"] == 0
    for motor in result["motors"].values():
        assert motor["final"] == motor["expected_final"]
        assert motor["max_accel_ratio"] <= 1.0 and motor["max_rate_ratio"] <= 1.0


@pytest.mark.parametrize("seed", [4, 5])
def test_a_streamed_star_holds_over_the_link_and_resumes_exactly(star_stream, seed):
    host, image, setup = star_stream
    at = random.Random(seed).uniform(0.05, host.plan.total - 0.5)
    result, _ = hold_verify(host, image, at, None, setup)
    _exact(result)
    hold = result["hold"]
    assert hold["ramp_s"] - 0.001 < hold["stopping_s"] < hold["ramp_s"] + 0.15
    assert hold["resume_s"] > hold["at_rest_s"]
    # the HOLD frame reaches the firmware within a frame's bytes of the time asked for (the line was idle)
    assert abs(hold["hold_s"] - at) < 0.003
    limit = 5.0 + host.target.isr_latency_us
    assert all(m["max_timing_error_us"] <= limit for m in result["motors"].values())


def test_feed_down_frames_slow_a_streamed_star_to_a_third(star_stream):
    host, image, setup = star_stream
    result, _ = hold_verify(host, image, None, 30, setup)
    _exact(result)
    assert [k["key"] for k in result["hold"]["keys"]] == ["feed-"] * 7
    assert 2.6 * host.plan.total < result["duration_s"] < 3.4 * host.plan.total


def _steps_at(trace, cycle: int, motors: int) -> list[int]:
    before = trace.step_cycle < cycle
    return [int(trace.step_dir[before & (trace.step_motor == m)].sum()) for m in range(motors)]


def test_m0_parks_the_flash_image_at_the_pen_change_until_resume(tmp_path, capsys):
    code = main(["verify", str(PEN_CHANGE), "--out", str(tmp_path), "--json"])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and result["pass"], result["problems"]
    (rest,) = result["hold"]["rests"]
    assert rest["kind"] == "pause" and result["hold"]["keys"] == []
    assert rest["resume_s"] - rest["at_rest_s"] > 0.0199  # REST_S, to the microsecond


def test_m0_parks_where_the_program_says(tmp_path):
    """At rest at X110 Y20 (8800, 1600 steps from the start at 0, 0) from the park to the resume."""
    job = load_job(PEN_CHANGE)
    host, image, _ = _build(job, str(tmp_path), reuse=False, strict=False)
    result, trace = hold_verify(host, image, None, None)
    assert result["pass"], result["problems"]
    (rest,) = result["hold"]["rests"]
    t0 = trace.timer_start_cycle
    at_rest = t0 + int(rest["at_rest_s"] * 16e6) + 40
    resumed = t0 + int(rest["resume_s"] * 16e6)
    assert _steps_at(trace, at_rest, 2) == [8800, 1600] == _steps_at(trace, resumed, 2)


def test_m0_in_a_stream_waits_for_resume(tmp_path):
    host, image, setup = streamed(PEN_CHANGE, tmp_path)
    result, _ = hold_verify(host, image, None, None, setup)
    _exact(result)
    assert [r["kind"] for r in result["hold"]["rests"]] == ["pause"]


def test_m0_without_a_resume_key_is_an_error_at_its_line(tmp_path):
    job = tmp_path / "job.yaml"
    job.write_text(PEN_CHANGE.read_text().replace("  feed_hold: {}", "  # no feed_hold"))
    with pytest.raises(JobError) as err:
        host_build(load_job(job))
    text = err.value.render()
    assert "job.yaml:26:" in text and "M0 waits for the resume key: the machine needs feed_hold" in text
    assert main(["plan", str(job)]) == 2


def test_marlin_timed_m0_is_a_dwell(planned_example, tmp_path):
    job = tmp_path / "job.yaml"
    job.write_text(PEN_CHANGE.read_text().replace("    M0                 ; change the pen, then resume",
                                                  "    M1 S2              ; Marlin: wait 2 s"))
    plain = planned_example("gcode/pen-change.yaml")
    timed = host_build(load_job(job))
    assert timed.runtime is not None and len(timed.runtime) == 0  # no pause record
    assert 1.99 < timed.plan.total - plain.plan.total < 2.01


def test_status_reports_the_feed_factor_through_a_hold(star_stream):
    """STATUS while playing at 100 %, while held at rest (F 0, the positions standing), and after the resume."""
    host, image, setup = star_stream
    f_cpu = host.target.f_cpu
    start = hold_runs.StreamRun(host, image, setup).tick0(False)
    hold, resume = start + f_cpu, start + 2 * f_cpu  # HOLD 1 s into the job, RESUME a second later
    asks = [start + f_cpu // 2, hold + f_cpu // 2, hold + f_cpu * 3 // 4, resume + f_cpu // 2]
    watched = Watched(new_link(host, setup), [(hold, protocol.HOLD), (resume, protocol.RESUME)], f_cpu, asks)
    simulate_stream(image.hex_path, setup.config, watched, int(10 * f_cpu), switches=simulated_switches(host))
    assert watched.link.outcome == "finished"
    feeds = [(s.state, s.feed) for _, s in watched.answers]
    assert feeds == [("playing", F_ONE), ("playing", 0), ("playing", 0), ("playing", F_ONE)]
    assert watched.answers[1][1].position == watched.answers[2][1].position  # standing still while held
    line = status_line(watched.answers[1][1], ("a", "b"), ())
    assert line.endswith("held")


def test_terminal_keys_become_link_requests():
    link = HostLink([b""], 2, 0, 1e-4, 0)
    send_hold_keys(link, "x!-+~?")
    assert link._feed == [protocol.HOLD, protocol.FEED_DOWN, protocol.FEED_UP, protocol.RESUME]
    with terminal_keys(False) as keys:
        assert keys() == ""
    assert np.array_equal(sorted(protocol.NAMES), sorted(set(protocol.NAMES)))

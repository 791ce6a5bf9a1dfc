"""Feed hold over the link on the 8051's streaming firmware (HOLD, RESUME, FEED_DOWN, FEED_UP frames into hold.c's
hold_poll, the dilated path of templates/mcs51/player.c.j2 reading from the ring), end to end with the real SDCC
and s51's closed-loop link (codegen/sim/mcs51_link.py): every pulse on the dilated twin's clock, every motor within
its limits, the end positions exact, no retransmits or underruns; M0/M1 pause records in the stream; STATUS's factor;
the internal-RAM ring of a board without XRAM."""

from __future__ import annotations

import dataclasses
import random
import shutil
from pathlib import Path

import pytest

from codegen.link import protocol
from codegen.sim.mcs51_link import simulate_stream
from codegen.tables.hold import F_ONE
from codegen.verify.compare import simulated_switches
from codegen.verify.hold import hold_verify
from codegen.verify.hold_runs import StreamRun
from codegen.verify.stream import new_link
from tests.helpers import streamed
from tests.verify.helpers import Watched, job_file

pytestmark = pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None,
                                reason="needs sdcc and s51 (scripts/setup.sh installs them)")

PAUSES = "program:\n  gcode: |\n    G1 X15 F2400\n    M0\n    G1 Y10\n    M1\n    G1 X0 Y0\n"


def _board(folder: Path, board: str, program: str | None = None) -> Path:
    """tests/verify/helpers.py's plotter (test_hold_mcs51.py's) (2.15 s at its motors' full speed) for `board`, or another program."""
    path = job_file(folder)
    text = path.read_text().replace("board: seed-51", f"board: {board}")
    path.write_text(text if program is None else text.split("program:")[0] + program)
    return path


@pytest.fixture(scope="module")
def plotter(tmp_path_factory):
    out = tmp_path_factory.mktemp("hold51-stream")
    return streamed(_board(out, "seed-51"), out / "out")


def _exact(result: dict) -> None:
    assert result["pass"], result["problems"]
    assert result["link"]["retransmits"] == 0 and result["link"]["underruns"] == 0
    assert result["link"]["lost_bytes"] == 0
    for motor in result["motors"].values():
        assert motor["final"] == motor["expected_final"]
        assert motor["max_accel_ratio"] <= 1.0 and motor["max_rate_ratio"] <= 1.0


@pytest.mark.parametrize("seed", [2])  # the STATUS test holds at another time
def test_a_streamed_plotter_holds_over_the_link_and_resumes_exactly(plotter, seed):
    host, image, setup = plotter
    assert setup.config.hold is not None and setup.layout.ring_bytes == 255  # seed-51: the ring in external RAM
    at = random.Random(seed).uniform(0.1, host.plan.total - 0.6)
    result, _ = hold_verify(host, image, at, None, setup)
    _exact(result)
    hold = result["hold"]
    assert hold["ramp_s"] - 0.001 < hold["stopping_s"] < hold["ramp_s"] + 0.1
    assert hold["resume_s"] > hold["at_rest_s"]
    # the HOLD frame (6 bytes at 9600 baud) reaches the firmware a frame's time after the line is idle
    assert 0.006 <= hold["hold_s"] - at < 0.05
    limit = 5.0 + host.target.isr_latency_us
    assert all(m["max_timing_error_us"] <= limit for m in result["motors"].values())


def test_feed_down_frames_slow_the_streamed_plotter_to_half(plotter):
    host, image, setup = plotter
    result, _ = hold_verify(host, image, None, 50, setup)
    _exact(result)
    assert [k["key"] for k in result["hold"]["keys"]] == ["feed-"] * 5
    assert 1.7 * host.plan.total < result["duration_s"] < 2.0 * host.plan.total
    assert max(m["max_rate_ratio"] for m in result["motors"].values()) < 1.0


def test_a_twin_with_another_ramp_does_not_pass(plotter):
    """The comparison can fail: a ramp one step per tick faster than the firmware's is found out (slowing to 50 %:
    a hold would send its RESUME before the firmware is at rest, and the job would wait for ever)."""
    host, image, setup = plotter
    fake = dataclasses.replace(host)
    fake.__dict__["hold_plan"] = dataclasses.replace(host.hold_plan, ramp_k=host.hold_plan.ramp_k + 1)
    result, _ = hold_verify(fake, image, None, 50, setup)
    assert not result["pass"]
    assert any("away from its predicted time" in p for p in result["problems"])


def test_status_carries_the_feed_factor_through_a_hold(plotter):
    """STATUS while playing at 100 %, while held at rest (F 0, the positions standing), and after the resume."""
    host, image, setup = plotter
    f_cpu = host.target.f_cpu
    start = StreamRun(host, image, setup).tick0(False)
    hold, resume = start + f_cpu // 2, start + 6 * f_cpu // 5  # HOLD 0.5 s into the job, RESUME at 1.2 s
    asks = [start + f_cpu // 4, hold + 2 * f_cpu // 5, hold + f_cpu // 2, resume + f_cpu // 2]
    watched = Watched(new_link(host, setup), [(hold, protocol.HOLD), (resume, protocol.RESUME)], f_cpu, asks)
    simulate_stream(image.hex_path, setup.config, watched, int(10 * f_cpu), switches=simulated_switches(host))
    assert watched.link.outcome == "finished"
    feeds = [(s.state, s.feed) for _, s in watched.answers]
    assert feeds == [("playing", F_ONE), ("playing", 0), ("playing", 0), ("playing", F_ONE)]
    assert watched.answers[1][1].position == watched.answers[2][1].position  # standing still while held


def test_m0_and_m1_in_an_8051_stream_wait_for_resume(tmp_path):
    """Each pause is a runtime record in the ring: F 0 where the plan rests, RESUME goes on at 100 %; a hold after
    the first pause is placed on the resumed clock."""
    host, image, setup = streamed(_board(tmp_path, "seed-51", PAUSES), tmp_path / "out")
    assert len(host.runtime) == 2
    result, _ = hold_verify(host, image, None, None, setup)
    _exact(result)
    assert [r["kind"] for r in result["hold"]["rests"]] == ["pause", "pause"]
    held, _ = hold_verify(host, image, 0.6, None, setup)
    _exact(held)
    assert sorted(r["kind"] for r in held["hold"]["rests"]) == ["hold", "pause", "pause"]


def test_the_internal_ram_ring_holds_too(tmp_path):
    """The at89c52 board has no XRAM and no hold keys: its ring is at the top of internal RAM (MOV @Ri), with room
    below it for hold's variables and the dilated path's pushes; the frames are the only way in."""
    host, image, setup = streamed(_board(tmp_path, "at89c52"), tmp_path / "out")
    assert setup.layout.iram_base and "hold_keys" not in host.target.board_data
    assert image.sections["stack_free"] >= 23
    result, _ = hold_verify(host, image, 0.8, None, setup)
    _exact(result)
    assert "at_rest_s" in result["hold"]


def test_the_streaming_firmware_grows_by_the_hold(plotter, tmp_path):
    _, image, _ = plotter
    plain = tmp_path / "plain"
    plain.mkdir()
    _, without, _ = streamed(job_file(plain, hold=""), plain / "out")
    assert 700 < image.flash_bytes - without.flash_bytes < 1100, (image.flash_bytes, without.flash_bytes)
    assert (image.hex_path.parent / "hold.c").exists() and not (plain / "out" / "hold.c").exists()

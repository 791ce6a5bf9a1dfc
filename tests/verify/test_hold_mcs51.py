"""Feed hold, resume and override on the 8051's flash image (codegen/firmware/mcs51/hold.py, the dilated path of
templates/mcs51/player.c.j2), end to end with the real SDCC and s51: seed-51's hold keys on its key matrix pressed
by the s51 script (codegen/sim/mcs51_keys.py), every pulse on the dilated twin's clock (codegen/tables/hold.py), every
motor within its limits, the end positions exact; M0/M1 pauses; and what the 8051 refuses."""

from __future__ import annotations

import dataclasses
import random
import shutil
from pathlib import Path

import numpy as np
import pytest

from codegen.cli.main import _build, main
from codegen.errors import BuildError
from codegen.firmware.mcs51.image import render_sources
from codegen.job import load_job
from codegen.sim.mcs51 import simulate
from codegen.sim.mcs51_keys import seen_at
from codegen.tables.hold import RAMP_SHARE, dilate, override_target
from codegen.verify.hold import hold_verify
from tests.verify.helpers import HOLD, job_file

pytestmark = pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None,
                                reason="needs sdcc and s51 (scripts/setup.sh installs them)")

F_CPU = 12_000_000


@pytest.fixture(scope="module")
def plotter(tmp_path_factory):
    out = tmp_path_factory.mktemp("hold51")
    host, image, _ = _build(load_job(job_file(out)), str(out / "out"), reuse=False, strict=False)
    return host, image


def _within_limits(result: dict) -> None:
    assert result["pass"], result["problems"]
    for motor in result["motors"].values():
        assert motor["final"] == motor["expected_final"]
        assert motor["max_accel_ratio"] <= 1.0 and motor["max_rate_ratio"] <= 1.0


@pytest.mark.parametrize("seed", [1])  # the CLI test and the wrong twin hold at other times
def test_held_mid_move_comes_to_rest_within_its_limits_and_ends_exact(plotter, seed):
    host, image = plotter
    assert not host.hold_plan.gated  # the 8051's plan keeps RAMP_SHARE of every motor's acceleration
    assert host.hold_plan.ramp_k == 41  # the ramp step: 16 x 8 bits
    assert max(host.findings.accel_ratio.values()) <= 1.0 - RAMP_SHARE + 0.01
    at = random.Random(seed).uniform(0.1, host.plan.total - 0.6)
    result, trace = hold_verify(host, image, at, None)
    _within_limits(result)
    hold = result["hold"]
    assert hold["ramp_s"] - 0.001 < hold["stopping_s"] < hold["ramp_s"] + 0.1
    assert hold["resume_s"] > hold["at_rest_s"]
    # no pulse while parked: between the last one before the rest and the resume key (times rounded to 1 us)
    rest, resume = (trace.timer_start_cycle + hold[k] * F_CPU for k in ("at_rest_s", "resume_s"))
    assert not ((trace.step_cycle > rest + 120) & (trace.step_cycle < resume)).any()
    assert result["duration_s"] > host.plan.total + (hold["resume_s"] - hold["at_rest_s"])


def test_a_ramp_of_more_than_255_per_tick_holds_too(tmp_path):
    """RAMP_K 335 (F.frac16 per tick): the ramp's step takes the 16 x 16-bit product (41 above takes 16 x 8)."""
    host, image, _ = _build(load_job(job_file(tmp_path, velocity=25, accel=5000)), str(tmp_path / "out"),
                            reuse=False, strict=False)
    assert host.hold_plan.ramp_k == 335
    result, _ = hold_verify(host, image, 0.5, None)
    _within_limits(result)
    assert result["hold"]["stopping_s"] < 0.1


def test_the_feed_keys_override_the_plotter_to_half_speed(plotter):
    host, image = plotter
    result, _ = hold_verify(host, image, None, 50)
    _within_limits(result)
    assert [k["key"] for k in result["hold"]["keys"]] == ["feed-"] * 5
    assert 1.7 * host.plan.total < result["duration_s"] < 2.0 * host.plan.total


def test_a_bouncing_feed_key_steps_the_override_once(plotter):
    """Two closings of feed- 10 ms apart (its contacts bouncing; main looks at the keys every 2 ms, so it
    sees both) take the override to 90 %, not 80 %."""
    host, image = plotter
    config, ms = host.firmware_config(), F_CPU // 1000
    tick0 = simulate(image.hex_path, config, 4 * F_CPU).timer_start_cycle
    at = tick0 + 100 * ms
    bounces = [("feed-", at, at + 5 * ms), ("feed-", at + 10 * ms, at + 60 * ms)]
    trace = simulate(image.hex_path, config, 8 * F_CPU, hold_keys=bounces)
    took = (int(trace.step_cycle.max()) - trace.timer_start_cycle) / F_CPU
    seen = seen_at(trace.hold_polls, trace.hold_changes, at)
    cycles = tick0 + host.pulses.event_tick * (F_CPU // host.target.tick_hz)
    first = int(np.searchsorted(cycles, seen)) + 1
    predicted = {step: dilate(host.schedule, host.hold_plan, [(first, override_target(step))]).tick[-1]
                 / host.target.tick_hz for step in (9, 8)}
    assert abs(took - predicted[9]) < 0.001 * predicted[9], (took, predicted)
    assert predicted[8] - predicted[9] > 0.1


def test_a_twin_with_another_ramp_does_not_pass(plotter):
    """The comparison can fail: a ramp one step per tick faster than the firmware's is found out."""
    host, image = plotter
    fake = dataclasses.replace(host)
    fake.__dict__["hold_plan"] = dataclasses.replace(host.hold_plan, ramp_k=host.hold_plan.ramp_k + 1)
    result, _ = hold_verify(fake, image, 0.7, None)
    assert not result["pass"]
    assert any("away from its predicted time" in p for p in result["problems"])


def test_verify_hold_on_the_command_line(plotter, capsys):
    host, image = plotter
    code = main(["verify", str(host.job.path), "--out", str(image.hex_path.parent), "--hold", "1.0"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert out.startswith("PASS hold51") and "hold: at rest" in out


def test_hold_keys_beside_jog_keys_on_one_matrix(tmp_path):
    """Jog mode first (its start key), then the job, held and resumed: both keys' models on seed-51's P0."""
    path = job_file(tmp_path, hold=HOLD + "\n  jog: {speeds: [150, 600, 2400]}")
    host, image, _ = _build(load_job(path), str(tmp_path / "out"), reuse=False, strict=False)
    result, _ = hold_verify(host, image, 0.7, None)
    _within_limits(result)
    assert "at_rest_s" in result["hold"]


def test_the_image_grows_by_the_hold_and_runs_no_movx(plotter, tmp_path):
    """The keys share P0 with the idle XRAM bus: nothing of the player, the display or the keys is in XRAM."""
    host, image = plotter
    assert image.sections["xram_used"] == 0
    plain = tmp_path / "plain"
    plain.mkdir()
    _, without, _ = _build(load_job(job_file(plain, hold="")), str(plain / "out"), reuse=False, strict=False)
    code = image.flash_bytes - image.table_bytes
    assert 700 < code - (without.flash_bytes - without.table_bytes) < 1100, (code, without.flash_bytes)


def test_a_hold_key_on_a_jog_key_is_an_error(plotter):
    host, _ = plotter
    config = dataclasses.replace(host.firmware_config(), hold=dataclasses.replace(
        host.hold_plan, keys={**host.hold_plan.keys, "feed+": (1, 1)}))
    with pytest.raises(BuildError, match=r"hold_keys feed\+ is at \[1, 1\], a jog key's place"):
        render_sources(host.schedule, config)


def _paused(folder: Path):
    """Two M0/M1 pauses in G-code: the plan rests at each, and the player parks there until the resume key."""
    path = job_file(folder)
    path.write_text(path.read_text().split("program:")[0] + "program:\n  gcode: |\n    G1 X15 F2400\n    M0\n"
                                                            "    G1 Y10\n    M1\n    G1 X0 Y0\n")
    host, image, _ = _build(load_job(path), str(folder / "out"), reuse=False, strict=False)
    return host, image


def test_m0_and_m1_park_the_8051_until_the_resume_key(tmp_path):
    """Each pause's runtime record sets F 0 where the plan rests; resume goes on at 100 % (no ramp): verify presses
    it once the machine is at rest; a hold after the first pause is placed on the resumed clock."""
    host, image = _paused(tmp_path)
    assert len(host.runtime) == 2
    result, _ = hold_verify(host, image, None, None)
    _within_limits(result)
    rests = result["hold"]["rests"]
    assert [r["kind"] for r in rests] == ["pause", "pause"] and rests[0]["resume_s"] > rests[0]["at_rest_s"]
    held, _ = hold_verify(host, image, 0.6, None)
    _within_limits(held)
    assert sorted(r["kind"] for r in held["hold"]["rests"]) == ["hold", "pause", "pause"]

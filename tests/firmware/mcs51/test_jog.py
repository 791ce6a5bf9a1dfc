"""Jog keys on the 8051, end to end with the real SDCC and s51: seed-51's key matrix on P0 pressed by the s51
script (codegen/sim/mcs51_keys.py), all 8 directions and speed changes, the firmware's position counts against
the pulses, the display, the limits on the pulses, then the job played from there."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import pytest

from codegen.errors import BuildError
from codegen.firmware.mcs51.image import build_image, render_sources
from codegen.firmware.mcs51.lcd import board_lcd
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.sim.keys import KeyPress
from codegen.sim.mcs51 import simulate
from codegen.tables.format import stream_bytes
from tests.firmware.mcs51.helpers import job_file
from tests.jog_checks import FINAL_LEVEL, SCRIPT, check_session

pytestmark = pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None,
                                reason="needs sdcc and s51 (scripts/setup.sh installs them)")

F_CPU = 12_000_000


def built(path: Path, out: Path):
    host = host_build(load_job(path))
    config = host.firmware_config()
    image = build_image(render_sources(host.schedule, config), out, stream_bytes(host.schedule))
    return host, config, image


def test_seed51_jogs_in_8_directions_with_speed_changes(tmp_path):
    host, config, image = built(job_file(tmp_path), tmp_path / "out")
    assert image.sections["xram_used"] == 0  # the matrix shares P0 with the idle XRAM bus
    trace = simulate(image.hex_path, config, 50_000_000, keys=SCRIPT)
    figures = check_session(trace, config.jog, F_CPU)
    assert 0.95 < figures["rate_ratio"] <= 1 and figures["accel_ratio"] <= 1  # the top level at max_velocity
    # The display at rest before the job: the jogged positions and the speed (mm/min) of the last level.
    lcd = board_lcd("seed-51", ["x", "y", "F"])
    before = [text for clock, text in trace.display.states if clock < trace.timer_start_cycle]
    shown = [text for text in before if text[1].startswith("F")]  # then jog mode blanks the speed as it ends
    assert shown[-1] == lcd.expected_text(figures["positions"] + [config.jog.speeds[FINAL_LEVEL]])
    assert before[-1] == (shown[-1][0], " " * 16)
    assert trace.display.problems == []
    # Then the job, from where jogging left the tool (its program.start): every step of the plan.
    run = trace.run_only()
    for m, name in enumerate(config.motors):
        assert int(run.step_dir[run.step_motor == m].sum()) == host.findings.final[name.name]
    print(f"\nseed-51 jog: {figures}")


def test_jog_code_size_and_unchanged_image_without_jog(tmp_path):
    host, config, image = built(job_file(tmp_path), tmp_path / "jog")
    plain = build_image(render_sources(host.schedule, dataclasses.replace(config, jog=None)), tmp_path / "plain",
                        stream_bytes(host.schedule))
    growth = image.flash_bytes - plain.flash_bytes
    print(f"\nseed-51 code: {plain.flash_bytes} bytes without jog, {image.flash_bytes} with (+{growth}), "
          f"internal RAM {plain.ram_bytes} -> {image.ram_bytes}")
    assert 0 < growth < 1600
    sources = render_sources(host.schedule, dataclasses.replace(config, jog=None))
    assert "jog.c" not in sources and "jog_mode" not in sources["player.c"]


def test_a_corexy_jogs_its_belts(tmp_path):
    """corexy on the board without a display: x moves both belts, a diagonal one belt."""
    host, config, image = built(job_file(tmp_path, kinematics="corexy"), tmp_path / "out")
    keys = [KeyPress("x+", 0.01, 0.05), KeyPress("x+y+", 0.08, 0.12), KeyPress("y-", 0.15, 0.19),
            KeyPress("start", 0.22, 0.25)]
    trace = simulate(image.hex_path, config, 50_000_000, keys=keys)
    before = trace.step_cycle < trace.timer_start_cycle
    net = [int(trace.step_dir[before & (trace.step_motor == m)].sum()) for m in config.jog.motors]
    assert trace.jog_positions == net
    # x+ steps a and b up together, x+y+ steps a up alone, y- steps a down and b up.
    a = trace.step_dir[before & (trace.step_motor == 0)]
    b = trace.step_dir[before & (trace.step_motor == 1)]
    assert (a > 0).sum() > (a < 0).sum() > 0 and (b > 0).sum() > 0 and (b < 0).sum() == 0


def test_a_board_without_keys_and_too_fast_a_speed_are_refused(tmp_path):
    path = job_file(tmp_path, board="at89c52")
    with pytest.raises(BuildError, match="board at89c52 has no jog keys"):
        built(path, tmp_path / "out")
    assert not (tmp_path / "out" / "firmware.hex").exists()
    with pytest.raises(BuildError, match=r"2400 mm/min needs a step every 319 ticks; the at89c52's jog loop"):
        built(job_file(tmp_path, spm=80), tmp_path / "fast")

"""Jog keys on the ATmega2560, end to end with the real avr-gcc and simavr: RAMPS's direct keys on AUX-4 pressed by
the harness (codegen/sim/simavr_keys.c), all 8 directions and speed changes, the firmware's position counts
against the pulses, the limits on the pulses, then the job played from there."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest

from codegen.errors import BuildError
from codegen.firmware.avr.image import build_image, render_sources
from codegen.firmware.avr.jog import EVENT_TICKS
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.sim.avr import simulate
from codegen.sim.keys import KeyPress
from codegen.tables.format import stream_bytes
from tests.firmware.avr.helpers import JOB
from tests.jog_checks import SCRIPT, check_session, jog_pulses, moves

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs avr-gcc and simavr (scripts/setup.sh installs them)")

F_CPU = 16_000_000


def built(folder: Path, speeds: str = "150, 600, 6000", spm: int = 80):
    """A plotter whose fastest jog level is its motors' max_velocity (7,840 steps/s at 80 steps/mm)."""
    path = folder / f"jogavr-{spm}.yaml"
    path.write_text(JOB.format(speeds=speeds, spm=spm))
    host = host_build(load_job(path))
    config = host.firmware_config()
    image = build_image(render_sources(host.schedule, config), folder / "out", stream_bytes(host.schedule))
    return host, config, image


def test_ramps_jogs_in_8_directions_with_speed_changes(tmp_path):
    host, config, image = built(tmp_path)
    trace = simulate(image.hex_path, config, 20_000_000, keys=SCRIPT)
    figures = check_session(trace, config.jog, F_CPU)
    assert 0.95 < figures["rate_ratio"] <= 1 and figures["accel_ratio"] <= 1  # the top level at max_velocity
    run = trace.run_only()
    for m, motor in enumerate(config.motors):
        assert int(run.step_dir[run.step_motor == m].sum()) == host.findings.final[motor.name]
    print(f"\nRAMPS jog: {figures}")


def test_the_fastest_cruise_holds_while_keys_change_the_level(tmp_path):
    """At the loop's shortest interval (EVENT_TICKS), a scan at every step and a debounce ending now and then:
    every step within a tick of its table interval."""
    host, config, image = built(tmp_path, spm=320)
    assert min(config.jog.cruise) == 64 >= EVENT_TICKS
    keys = [KeyPress("x+y-", 0.01, 0.40), KeyPress("start", 0.45, 0.48)]
    keys += [KeyPress("speed+" if i != 4 else "speed-", 0.02 + 0.04 * i, 0.04 + 0.04 * i) for i in range(9)]
    trace = simulate(image.hex_path, config, 20_000_000, keys=keys)
    pulses = jog_pulses(trace, config.jog, F_CPU)
    (move,) = moves(pulses, config.jog, F_CPU)
    iv = np.diff(move.ticks)
    table = np.array(sorted(set(config.jog.ramp) | set(config.jog.cruise)))
    assert np.abs(iv[:, None] - table[None, :]).min(axis=1).max() <= 1
    assert np.count_nonzero(np.abs(iv - min(config.jog.cruise)) <= 1) > 100
    assert trace.jog_positions == [int(d.sum()) for _, d in pulses]


def test_jog_code_size_and_unchanged_image_without_jog(tmp_path):
    host, config, image = built(tmp_path)
    plain = build_image(render_sources(host.schedule, dataclasses.replace(config, jog=None)), tmp_path / "plain",
                        stream_bytes(host.schedule))
    print(f"\nRAMPS flash: {plain.flash_bytes} bytes without jog, {image.flash_bytes} with "
          f"(+{image.flash_bytes - plain.flash_bytes}), RAM {plain.ram_bytes} -> {image.ram_bytes}")
    sources = render_sources(host.schedule, dataclasses.replace(config, jog=None))
    assert "jog.c" not in sources and "jog_mode" not in sources["player.c"]


def test_too_fast_a_speed_is_refused(tmp_path):
    with pytest.raises(BuildError, match=r"6000 mm/min needs a step every 52 ticks; the atmega2560's jog loop"):
        built(tmp_path, spm=400)
    assert not (tmp_path / "out" / "firmware.hex").exists()

"""Main's interrupts-off stretches in the ATmega2560 images (codegen/firmware/avr/interrupts_off.py): walked from the
generated assembly, each within the figure the plan's rate budget counts on (targets/atmega2560.yaml), a longer one
refused at build time, a loop with interrupts off an error. And the plan keeps its limits however late the step
interrupt comes within that budget: every pulse of a real print delayed by up to the worst latency."""

from __future__ import annotations

from pathlib import Path

import pytest

from codegen.cli.stream import streamed_host
from codegen.errors import BuildError
from codegen.firmware.avr.image import render_sources
from codegen.firmware.avr.interrupts_off import check_interrupts_off, longest_stretch
from codegen.firmware.avr.stream import render_stream_sources
from codegen.job import load_job
from codegen.motion.planner import RATE_WINDOW
from codegen.pipeline.streaming import stream_setup
from codegen.targets import TargetInfo
from tests.helpers import EXAMPLES

ROOT = Path(__file__).resolve().parents[3]
SNAPSHOT = "    cli ; the ring's free space and the stream bytes taken (rx_total + rx_uncounted), at one moment\n"


def stream_sources(name: str) -> tuple[dict[str, str], object]:
    config = stream_setup(load_job(EXAMPLES / name)).config
    return render_stream_sources(config), config


@pytest.mark.parametrize("name, cycles, cli", [
    ("line.yaml", 34, SNAPSHOT),  # two motors, nothing else: link_status reading the ring's state at one moment
    ("printers/benchy-mini.yaml", 34, SNAPSHOT),  # four motors, two heaters and a fan
    ("star.yaml", 221, "    cli ; the hold keys and the link's hold requests"),  # every key and request at one look
])
def test_the_streaming_images_longest_stretch_is_what_the_plan_counts_on(name, cycles, cli):
    sources, _ = stream_sources(name)
    stretch = longest_stretch(sources)
    file, line = stretch.where.split(":")
    assert stretch.cycles == cycles and sources[file].splitlines()[int(line) - 1].startswith(cli.rstrip())


def test_flash_images_hold_interrupts_off_for_the_key_poll_at_most(star_flash, planned_example):
    host, _ = star_flash
    assert longest_stretch(render_sources(host.schedule, host.firmware_config())).cycles == 218
    plain = planned_example("line.yaml")
    assert longest_stretch(render_sources(plain.schedule, plain.firmware_config())).cycles == 0


def test_a_longer_stretch_is_refused_at_build_time():
    """Ten NOPs more in link_status's longest stretch: 44 cycles where the plan counts on 34."""
    sources, config = stream_sources("line.yaml")
    assert sources["link_tx.S"].count(SNAPSHOT) == 1
    sources["link_tx.S"] = sources["link_tx.S"].replace(SNAPSHOT, SNAPSHOT + "    nop\n" * 10)
    assert longest_stretch(sources).cycles == 44
    with pytest.raises(BuildError, match=r"main holds interrupts off for 44 cycles from link_tx.S:\d+: the plan's "
                                         r"rate budget counts on at most 34 \(targets/atmega2560.yaml\)"):
        check_interrupts_off(sources, config, stream=True)


def test_a_loop_with_interrupts_off_is_an_error():
    sources, _ = stream_sources("line.yaml")
    sources["link_tx.S"] = sources["link_tx.S"].replace(SNAPSHOT, SNAPSHOT + "8:  rjmp 8b\n")
    with pytest.raises(BuildError, match="a loop with interrupts off"):
        longest_stretch(sources)


def worst_rate(host, jitter_s: float) -> float:
    """The highest rate over 8 steps / the limit of any motor when each pulse may come up to `jitter_s` later than
    the twin's (the step interrupt waiting for the link and main): the first of 8 steps late, the last on time."""
    pulses, tick_hz = host.pulses, host.schedule.tick_hz
    worst = 0.0
    for m, rate in enumerate(host.kin.limits.max_rate):
        ticks = pulses.of_motor(m)[0].astype(float)
        if len(ticks) > RATE_WINDOW:
            span = (ticks[RATE_WINDOW:] - ticks[:-RATE_WINDOW]) / tick_hz - jitter_s
            worst = max(worst, float((RATE_WINDOW / span).max() / rate))
    return worst


FAST_LINE = """name: fast-line
target: avr
board: ramps-1.4
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 80, max_velocity: 300, max_accel: 3000, range: [0, 400]}
    y: {steps_per_mm: 80, max_velocity: 300, max_accel: 3000, range: [0, 400]}
program:
  start: [0, 0]
  feed: 18000
  shapes:
    - line: {from: [0, 0], to: [300, 20]}
"""


@pytest.fixture(scope="module")
def fast_line(tmp_path_factory):
    """x at its limit (24 kHz: 8 steps in 333 us) for most of a 300 mm line: the latency matters there."""
    path = tmp_path_factory.mktemp("fast-line") / "fast-line.yaml"
    path.write_text(FAST_LINE)
    return load_job(path)


def test_every_pulse_late_by_up_to_the_worst_latency_keeps_every_rate(fast_line):
    setup = stream_setup(fast_line)
    jitter = setup.target.pulse_jitter_s()
    assert round(jitter * setup.target.f_cpu) == 121 + 34 + 4  # a link interrupt, then link_status's stretch
    host = streamed_host(fast_line, setup, strict=False, keep=True)
    assert 0.98 < worst_rate(host, jitter) <= 1.0


def test_a_plan_without_the_latency_in_its_budget_breaks_a_rate(fast_line, monkeypatch):
    """The same line planned as if the step interrupt always came on time: late pulses break x's rate."""
    jitter = stream_setup(fast_line).target.pulse_jitter_s()
    monkeypatch.setattr(TargetInfo, "pulse_jitter_s", lambda self, heaters=False: 0.0)
    host = streamed_host(fast_line, stream_setup(fast_line), strict=False, keep=True)
    assert worst_rate(host, 0.0) <= 1.0 < worst_rate(host, jitter)

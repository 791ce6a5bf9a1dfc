"""Jog mode in the streaming ATmega2560 firmware, end to end with the real avr-gcc and simavr: RAMPS's direct keys
pressed by the harness while the firmware waits for a job, then a host's session (codegen/link/host.py) over the
simulated USART. The jog pulses against the jog plan and the motors' limits (tests/jog_checks.py), the job's pulses
against the twin's, a START during a jog move waiting for its ramp down, jog mode again after FINISHED."""

from __future__ import annotations

import dataclasses
import math
import shutil
from dataclasses import dataclass, field

import numpy as np
import pytest

import codegen.tables.format as tables
from codegen.errors import BuildError
from codegen.firmware.avr.stream import render_stream_sources
from codegen.job import load_job
from codegen.link import protocol
from codegen.link.host import HostLink
from codegen.pipeline.host import host_build
from codegen.pipeline.streaming import build_stream_firmware, stream_chunks, stream_setup
from codegen.sim.avr_link import StreamSim
from codegen.sim.keys import KeyPress
from tests.firmware.avr.helpers import CYCLES, F_CPU, JOB, MAX_LATE, Scripted, check_pulses
from tests.jog_checks import SCRIPT, check_limits, check_move, check_session, jog_pulses, moves

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs avr-gcc and simavr (scripts/setup.sh installs them)")

BUDGET = 3 * F_CPU  # cycles per session: 3 s simulated
# A jog step may come late by a link interrupt in its way (9 ticks at most measured, with the session's bytes).
LINK_LATE_TICKS = math.ceil(MAX_LATE / CYCLES)
TOP = 2  # the fastest level: 6000 mm/min, 7,683 steps/s


@dataclass
class Later:
    """A host whose session begins at `at` (s from reset): the line stays idle until then."""

    host: Scripted
    at: float
    begun: bool = field(default=False)

    @property
    def link(self) -> HostLink:
        return self.host.link

    @property
    def done(self) -> bool:
        return self.host.done

    def wake_at(self):
        return self.host.wake_at() if self.begun else self.at

    def transmit(self, now):
        if now < self.at:
            return b""
        self.begun = True
        return self.host.transmit(now)

    def receive(self, data, now):
        self.host.receive(data, now)


@pytest.fixture(scope="module")
def jogged(tmp_path_factory):
    """The RAMPS plotter of tests/firmware/avr/test_jog.py (jog levels 150, 600 and 6000 mm/min), its streaming firmware and
    its job planned for the link."""
    folder = tmp_path_factory.mktemp("stream-jog")
    path = folder / "jogstream.yaml"
    path.write_text(JOB.format(speeds="150, 600, 6000", spm=80))
    job = load_job(path)
    setup = stream_setup(job)
    image, _ = build_stream_firmware(setup, folder / "out")
    return setup, image, host_build(job, link=setup.budget)


def session_host(setup, host) -> Scripted:
    motors = len(setup.config.motors)
    chunks = stream_chunks(tables.encode(host.schedule).data, motors)
    return Scripted(HostLink(chunks, motors, setup.identity, 10 / setup.layout.baud, host.link_plan.prefill_bytes,
                             payload=setup.budget.payload, stream_bytes=host.link_plan.stream_bytes))


def played_like_the_twin(host, script, trace) -> None:
    twin = check_pulses(host.schedule, trace)
    assert script.link.outcome == "finished" and script.link.position == tuple(twin.final_positions())


def test_jog_in_8_directions_then_the_job(jogged):
    """tests/jog_checks.py's session before the host comes (its start key does nothing here), then the job."""
    setup, image, host = jogged
    script = session_host(setup, host)
    with StreamSim(image.hex_path, setup.config, keys=SCRIPT) as sim:
        trace, link = sim.session(Later(script, 1.2), BUDGET)
        trace.jog_positions = sim.jog_positions()
    figures = check_session(trace, setup.config.jog, F_CPU)
    assert figures["rate_ratio"] <= 1 and figures["accel_ratio"] <= 1
    played_like_the_twin(host, script, trace)
    assert link.lost_bytes == 0 and link.underruns == 0
    print(f"\nRAMPS streaming jog: {figures}")


def test_start_during_a_jog_move_waits_for_the_ramp_down_and_jog_comes_back_after_finished(jogged):
    """x+ at the fastest level while the host's session begins: the START that ends it comes during the cruise,
    the move goes down the whole ramp (the acceleration limit), then the job plays; released during the job, so
    that after FINISHED jog mode takes y- (from the slowest level again), then a second session."""
    setup, image, host = jogged
    plan = setup.config.jog
    keys = [KeyPress("speed+", 0.01, 0.03), KeyPress("speed+", 0.05, 0.07), KeyPress("x+", 0.09, 0.31),
            KeyPress("y-", 0.60, 0.70)]
    first, second = session_host(setup, host), session_host(setup, host)
    first.actions.append((0.0, "request_status"))  # goes out with START: answered by jog mode, at a scan with room
    with StreamSim(image.hex_path, setup.config, keys=keys) as sim:
        trace, _ = sim.session(Later(first, 0.2), BUDGET)
        again, _ = sim.session(Later(second, 0.8), BUDGET)
        positions = sim.jog_positions()

    pulses = jog_pulses(trace, plan, F_CPU)
    (move,) = moves(pulses, plan, F_CPU)
    assert move.ways == (1, 0)
    check_move(move, plan, TOP, tolerance=LINK_LATE_TICKS)
    check_limits(pulses, plan, F_CPU)
    start = first.sent[protocol.START] * F_CPU  # START's last byte in the firmware (cycles)
    steps, iv, down = pulses[0][0], np.diff(move.ticks), plan.top[TOP]
    assert np.abs(iv[::-1][:down] - np.array(plan.ramp[:down])).max() <= LINK_LATE_TICKS  # the whole ramp down ...
    turn = steps[-down - 1]  # ... from the step that took its first interval: the first after a scan after START
    assert start < turn < start + F_CPU * (0.002 + plan.cruise[TOP] / plan.tick_hz)
    assert np.abs(iv[-down - 20:-down] - plan.cruise[TOP]).max() <= LINK_LATE_TICKS  # cruising until then
    assert steps[-1] < trace.timer_start_cycle
    assert first.link.status.state == "idle" and first.arrived[protocol.STATUS_REPLY] * F_CPU < steps[-1]
    played_like_the_twin(host, first, trace)

    pulses = jog_pulses(again, plan, F_CPU)
    (back,) = moves(pulses, plan, F_CPU)
    assert back.ways == (0, -1)
    check_move(back, plan, 0)
    played_like_the_twin(host, second, again)
    assert positions == [len(move.ticks), -len(back.ticks)]


def test_identity_names_the_jog_keys_and_the_8051_refuses_them(jogged, tmp_path):
    setup, image, _ = jogged
    config = setup.config
    plain = dataclasses.replace(config, jog=None)
    assert setup.identity != protocol.firmware_identity(plain, F_CPU, 2_000_000)
    assert "jog.c" not in render_stream_sources(plain) and "jog_mode" not in render_stream_sources(plain)["stream.c"]
    bare = build_stream_firmware(dataclasses.replace(setup, config=plain), tmp_path / "plain")[0]
    print(f"\nRAMPS streaming flash: {bare.flash_bytes} bytes without jog, {image.flash_bytes} with "
          f"(+{image.flash_bytes - bare.flash_bytes}), RAM {bare.ram_bytes} -> {image.ram_bytes}, ring "
          f"{bare.ring_bytes} -> {image.ring_bytes} bytes")
    assert image.ring_bytes == bare.ring_bytes - 4 * len(config.jog.motors)

    from codegen.firmware.mcs51.stream import render_stream_sources as mcs51_sources
    from tests.firmware.mcs51.helpers import job_file

    seed = stream_setup(load_job(job_file(tmp_path)))
    with pytest.raises(BuildError, match="8051 streaming firmware has no jog mode"):
        mcs51_sources(seed.config)

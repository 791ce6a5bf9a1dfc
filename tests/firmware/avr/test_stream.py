"""The streaming ATmega2560 firmware end to end, with the real avr-gcc and simavr: hand-made schedules streamed by the
host's own protocol code (codegen/link/host.py) into the simulated USART at 250000 baud, every simulated pulse
compared with the twin's (motor, direction, order, time within the player's latency with the link busy), the
positions the firmware reports with the pulses, and each fault of the line ending in retransmissions.
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

import codegen.tables.format as tables
from codegen.errors import BuildError
from codegen.firmware.avr.stream import build_stream_image, render_stream_sources
from codegen.firmware.config import FirmwareConfig, MotorPins
from codegen.link import protocol
from codegen.link.faults import Faulty, LineFaults
from codegen.link.host import HostLink
from codegen.link.ring import link_budget
from codegen.program.homing import HomingAxis
from codegen.sim.avr_link import StreamSim, simulate_stream
from codegen.tables.twin import predict
from tests.firmware.avr.helpers import (BAUD, BLOCKS, BUDGET, BYTE_S, CYCLES, F_CPU, MAX_LATE, RUNS, TICK_HZ, Scripted,
                                        check_pulses, cut, make_schedule)


def config(motors, sockets, board="ramps-1.4", inverted=(), homing=(), baud=0):
    pins = tuple(MotorPins(n, s, invert_dir=n in inverted) for n, s in zip(motors, sockets))
    return FirmwareConfig("stream", "tests/firmware/avr/test_stream.py", "avr", board, pins, homing=homing, baud=baud)


CONFIGS = {
    "x": config(("x",), ("X",)),
    "xyz": config(("x", "y", "z"), ("X", "Y", "Z"), inverted=("y",)),  # z's Bresenham in SRAM
    "xzeb": config(("x", "z", "e", "b"), ("X", "Z", "E0", "E1"), board="mks-gen-l"),  # four STEP ports
}


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    out = tmp_path_factory.mktemp("stream")
    return {name: build(cfg, out / name) for name, cfg in CONFIGS.items()}


def build(cfg, out_dir):
    image = build_stream_image(render_stream_sources(cfg), out_dir)
    image.identity = protocol.firmware_identity(cfg, F_CPU, TICK_HZ)  # what the host checks
    return image


def long_schedule(motors, events=3000, seed=7, gap_ticks=(600, 1000)):
    """One block of `events` events, each with a run record of its own (6 bytes every 300-500 us: the stream
    outruns the ring, 20 KB/s of the link's 25), every other motor a Bresenham slave."""
    rng = np.random.default_rng(seed)
    runs = [(int(v), int(a), 1) for v, a in zip(rng.integers(gap_ticks[0] * 256, gap_ticks[1] * 256, events),
                                                 rng.integers(-200, 200, events))]
    steps = (events,) + tuple(int(s) for s in rng.integers(1, events, len(motors) - 1))
    dirs = (1,) + (-1,) * (len(motors) - 1)
    return make_schedule(motors, [(dirs, steps, events, (events // 2,) * len(motors), False, runs)])


def short_schedule(motors):
    """test_avr_firmware's blocks and runs: short and long records, a dwell, runs across blocks, long waits."""
    return make_schedule(motors, cut(BLOCKS, len(motors)), final_tool=True, runs=RUNS)


def stream_of(schedule):
    return tables.encode(schedule).data + protocol.tail_padding(len(schedule.motors))


def host_for(schedule, image, prefill=2000, identity=None, chunk=300):
    data = stream_of(schedule)
    chunks = [data[i:i + chunk] for i in range(0, len(data), chunk)]
    return HostLink(chunks, len(schedule.motors), image.identity if identity is None else identity, BYTE_S,
                    min(prefill, len(data)))


def net_steps(trace, motors):
    run = trace.run_only()
    return tuple(int(run.step_dir[run.step_motor == m].sum()) for m in range(motors))


@pytest.mark.parametrize("name", list(CONFIGS))
def test_a_stream_longer_than_the_ring_plays_like_the_twin(images, name):
    """Streaming while it plays (the ring refilled many times over, the records read across its end), blocks and
    runs of every form: the pulses are the twin's, FINISHED's positions its net steps; STATUS is answered while it
    plays, and answering it keeps no step waiting longer than the latency the target states (its interrupts off
    for a few instructions at a time); no byte is lost and the ring never ran dry."""
    cfg, image = CONFIGS[name], images[name]
    motors = tuple(m.name for m in cfg.motors)
    for schedule in (short_schedule(motors), long_schedule(motors)):
        host = host_for(schedule, image)
        requests = [(0.1 + 0.0002 * k, "request_status") for k in range(8)]  # each lands at another instruction
        trace, link = simulate_stream(image.hex_path, cfg, Scripted(host, requests), BUDGET)
        twin = check_pulses(schedule, trace)
        assert host.outcome == "finished" and host.position == tuple(twin.final_positions())
        assert link.lost_bytes == 0 and link.underruns == 0 and link.retransmits == 0
        assert link.min_ring_fill_bytes >= protocol.max_record_bytes(len(motors))
        assert host.status is not None and host.status.state in ("playing", "finished")
    assert len(stream_of(schedule)) > 2 * image.ring_bytes
    assert host.status.state == "playing" and 0 < host.status.played < len(stream_of(schedule))


def test_waits_of_every_length(images):
    """Tick deltas around half and a whole timer period (the late-event check must not take an event 0x8000 ticks
    or more ahead for one past), and past it (compare B's periods)."""
    runs = [(0x7F00 * 256, 0, 2), (0x8100 * 256, 0, 2), (0xC000 * 256 + 99, 0, 2), (0xFEFF * 256, 0, 2),
            (0xFF00 * 256, 0, 2), (0x10000 * 256, 0, 2), (0x17FFF * 256 + 255, 0, 2), (600 * 256, 0, 7)]
    schedule = make_schedule(("x", "y", "z"), [((1, -1, 1), (21, 7, 3), 21, (9, 3, 1), False, 21)], runs=runs)
    host = host_for(schedule, images["xyz"])
    trace, _ = simulate_stream(images["xyz"].hex_path, CONFIGS["xyz"], host, BUDGET)
    twin = check_pulses(schedule, trace)
    assert host.outcome == "finished" and host.position == tuple(twin.final_positions())


def test_a_firmware_of_another_identity_is_refused(images):
    schedule = short_schedule(("x", "y", "z"))
    host = host_for(schedule, images["xyz"], identity=images["xyz"].identity ^ 1)
    trace, _ = simulate_stream(images["xyz"].hex_path, CONFIGS["xyz"], host, BUDGET)
    assert host.outcome == "refused" and "another machine" in host.message
    assert len(trace.step_cycle) == 0


@pytest.mark.parametrize("faults", [
    LineFaults(corrupt_bytes=frozenset({3000})),
    LineFaults(drop_bytes=frozenset({5000})),
    LineFaults(duplicate_frames=frozenset({30})),
    LineFaults(swap_frames=frozenset({40})),
    LineFaults(corrupt_bytes=frozenset({100, 9000, 9001}), drop_bytes=frozenset({12000}),
               duplicate_frames=frozenset({90}), swap_frames=frozenset({120})),
], ids=lambda f: f.describe())
def test_line_faults_end_in_retransmissions_and_the_same_pulses(images, faults):
    """A frame lost or out of order is sent again (a duplicate is only REJECTED); at 6 KB/s, as the host queues up
    to the ring's free space on the line and a lost frame costs all of it again."""
    schedule = long_schedule(("x", "y", "z"), gap_ticks=(1500, 2500))
    host = host_for(schedule, images["xyz"])
    trace, link = simulate_stream(images["xyz"].hex_path, CONFIGS["xyz"], Faulty(host, faults), BUDGET)
    twin = check_pulses(schedule, trace)
    assert host.outcome == "finished" and host.position == tuple(twin.final_positions())
    assert link.retransmits > 0 or not (faults.corrupt_bytes or faults.drop_bytes or faults.swap_frames)
    assert link.underruns == 0 and link.lost_bytes == 0


def test_a_host_pause_longer_than_the_ring_lasts_ends_in_underrun(images):
    """The ring runs dry: the player stops at once and reports where the motors are (the pulses made so far, the
    twin's first ones)."""
    schedule = long_schedule(("x", "y", "z"))
    host = host_for(schedule, images["xyz"])
    trace, link = simulate_stream(images["xyz"].hex_path, CONFIGS["xyz"], Faulty(host, LineFaults(pause=(0.3, 2.0))),
                                  BUDGET)
    assert host.outcome == "underrun" and link.underruns == 1
    check_pulses(schedule, trace, prefix=True)
    made = len(trace.run_only().step_cycle)
    assert 0 < made < len(predict(schedule).tick)
    assert host.position == net_steps(trace, 3)


@pytest.mark.parametrize("name, at", [("xyz", 0.35), ("xzeb", 0.2), ("x", 0.1)])
def test_abort_stops_at_once_and_reports_the_positions(images, name, at):
    """ABORT (queued behind the frames already on the line) stops the player before its next event; ABORTED (after
    the rest of the block's Bresenham played in C) says where the motors are: the pulses made so far."""
    cfg, image = CONFIGS[name], images[name]
    motors = tuple(m.name for m in cfg.motors)
    schedule = long_schedule(motors)
    host = host_for(schedule, image)
    script = Scripted(host, [(at, "abort")])
    trace, _ = simulate_stream(image.hex_path, cfg, script, BUDGET)
    assert host.outcome == "aborted"
    twin = check_pulses(schedule, trace, prefix=True)
    run = trace.run_only()
    made, abort_s = len(run.step_cycle), script.sent[protocol.ABORT]
    due_s = (trace.timer_start_cycle + CYCLES * np.sort(twin.tick)) / F_CPU  # each pulse's tick, in time
    assert at < due_s[made - 1] < abort_s <= due_s[made] + MAX_LATE / F_CPU < script.arrived[protocol.ABORTED]
    assert host.position == net_steps(trace, len(motors))


def test_a_second_session_after_finished(images):
    cfg, image = CONFIGS["xyz"], images["xyz"]
    with StreamSim(image.hex_path, cfg) as sim:
        for schedule in (short_schedule(("x", "y", "z")), long_schedule(("x", "y", "z"), events=500, seed=3)):
            host = host_for(schedule, image)
            trace, _ = sim.session(host, BUDGET)
            twin = check_pulses(schedule, trace)
            assert host.outcome == "finished" and host.position == tuple(twin.final_positions())


@pytest.fixture(scope="module")
def homing_image(tmp_path_factory):
    axes = tuple(HomingAxis((m,), (-1,), switch, -1, 400, 300, 600, 20)
                 for m, switch in enumerate(("x_min", "y_min", "z_min")))
    cfg = config(("x", "y", "z"), ("X", "Y", "Z"), homing=axes)
    return cfg, build(cfg, tmp_path_factory.mktemp("homing"))


def test_homing_then_the_stream(homing_image):
    """START homes the machine first (homing.c), then STARTED and the stream; positions count from there."""
    cfg, image = homing_image
    schedule = short_schedule(("x", "y", "z"))
    host = host_for(schedule, image)
    trace, _ = simulate_stream(image.hex_path, cfg, host, BUDGET, switches={0: -30, 1: -40, 2: -50})
    twin = check_pulses(schedule, trace)
    assert host.outcome == "finished" and host.position == tuple(twin.final_positions())
    home = trace.step_phase == "home"
    assert [int(home[trace.step_motor == m].sum()) for m in range(3)] == [30 + 40, 40 + 40, 50 + 40]


def test_a_switch_that_never_closes_ends_in_homing_failed(homing_image):
    """HOMING_FAILED's status: the axis's bit and the phase << 4 (y, the fast approach: 0x12); nothing plays."""
    cfg, image = homing_image
    host = host_for(short_schedule(("x", "y", "z")), image)
    trace, _ = simulate_stream(image.hex_path, cfg, host, BUDGET, switches={0: -30, 1: None, 2: -50})
    assert host.outcome == "homing failed" and "0x12" in host.message
    assert trace.homing_failed and "motor y (switch y_min)" in trace.homing_fault
    assert trace.timer_start_cycle is None and int((trace.step_motor == 1).sum()) == 400


def test_window_updates_spare_the_host_its_pings(images, tmp_path):
    """The player takes 6 bytes every 2-2.5 ms, a tenth of what the link carries: the ring fills and the host, blocked
    on credit, waits. player_run's window update (link_window: an ACK unasked once the player has made room for a
    DATA frame) brings the next frame long before the host's fallback ping (budget.ping_s) would: no ping. The same
    firmware without them leaves the host waiting for its pings."""
    cfg, image = CONFIGS["x"], images["x"]
    sources = render_stream_sources(cfg)
    call = "    rcall link_window ; room for a DATA frame again: an ACK unasked (link_tx.S)\n"
    assert sources["player_isr.S"].count(call) == 1
    sources["player_isr.S"] = sources["player_isr.S"].replace(call, "")
    without = build_stream_image(sources, tmp_path)
    without.identity = image.identity
    schedule = long_schedule(("x",), events=3000, gap_ticks=(4000, 5000))
    budget = link_budget(BAUD, image.ring_bytes, 1, window_updates=True)  # as streaming.py makes it
    assert len(stream_of(schedule)) > 2 * image.ring_bytes and budget.payload == 128
    pings = []
    for hex_path in (image.hex_path, without.hex_path):
        data = stream_of(schedule)
        host = HostLink([data], 1, image.identity, BYTE_S, 2000, payload=budget.payload, ping_s=budget.ping_s)
        trace, link = simulate_stream(hex_path, cfg, host, BUDGET)
        assert host.outcome == "finished", host.message
        check_pulses(schedule, trace)
        assert link.lost_bytes == 0 and link.underruns == 0
        pings.append(host.stats.pings)
    assert pings[0] == 0 and pings[1] >= 20, pings


def test_build_reports_the_ring_and_every_byte(images):
    image = images["xyz"]
    assert sum(image.flash_parts.values()) == image.flash_bytes and image.flash_parts["table"] == 0
    assert sum(image.ram_parts.values()) == image.ram_capacity
    assert image.ring_bytes > 7000 and image.ring_address + image.ring_bytes == 0x2100
    assert "#define LINK_UBRR 7 " in render_stream_sources(CONFIGS["xyz"])["link.h"]
    assert render_stream_sources(CONFIGS["xyz"]) == render_stream_sources(CONFIGS["xyz"])
    symbols = subprocess.run(["avr-nm", str(image.elf_path)], capture_output=True, text=True, check=True).stdout
    for helper in ("divmod", "sf3", "sqrt", "__fix", "__float"):
        assert helper not in symbols


def test_a_baud_rate_the_usart_cannot_make_is_refused():
    """At 16 MHz (double speed: F_CPU / (8 * (UBRR + 1))) 115200 is 2.1 % off and 230400 3.5 %."""
    for baud in (115200, 230400):
        with pytest.raises(BuildError, match=f"{baud} cannot be made within 2%"):
            render_stream_sources(config(("x",), ("X",), baud=baud))
    assert "#define LINK_UBRR 3 " in render_stream_sources(config(("x",), ("X",), baud=500_000))["link.h"]
    assert "#define LINK_UBRR 51 " in render_stream_sources(config(("x",), ("X",), baud=38_400))["link.h"]

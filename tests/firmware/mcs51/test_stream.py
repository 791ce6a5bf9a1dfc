"""The 8051 streaming firmware end to end, with the real SDCC and s51: hand-made schedules streamed by the host's own
protocol code (codegen/link/host.py) into the simulated UART at 9600 baud in a closed loop
(codegen/sim/mcs51_link.py), every simulated pulse compared with the twin's (motor, direction, order, time within
one constant latency), the positions the firmware reports with the pulses, and each fault of the line.
"""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest

from codegen.errors import BuildError
from codegen.firmware.homing import homing_steps
from codegen.firmware.mcs51.lcd import board_lcd
from codegen.firmware.mcs51.sdcc import MAP_FILE
from codegen.firmware.mcs51.stream import render_stream_sources, ring_layout
from codegen.link import protocol
from codegen.link.faults import Faulty, LineFaults
from codegen.link.host import HostLink
from codegen.program.homing import HomingAxis
from codegen.sim.mcs51_link import simulate_stream
from codegen.tables.twin import predict
from tests.firmware.mcs51.stream_helpers import (BAUD, BUDGET, F_CPU, MOTORS, TICK_HZ, build, check_pulses, config,
                                                 make_schedule, net_steps, short_schedule, stream_of)

pytestmark = pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None,
                                reason="needs sdcc and s51 (scripts/setup.sh installs them)")


def homing_config():
    axes = tuple(HomingAxis((m,), (1,), key, 1, 2000, 1000, 3000, 50) for m, key in enumerate(("x_max", "y_max",
                                                                                                "z_max")))
    return config(homing=axes)


@pytest.fixture(scope="module")
def seed(tmp_path_factory):
    return build(config(), tmp_path_factory.mktemp("seed"))


@pytest.fixture(scope="module")
def stc(tmp_path_factory):
    return build(config("stc89c52rc"), tmp_path_factory.mktemp("stc"))


@pytest.fixture(scope="module")
def homed(tmp_path_factory):
    return build(homing_config(), tmp_path_factory.mktemp("homed"))


def long_schedule(events=200, seed=7):
    """One block of `events` events, each with a run record of its own (6 bytes every 9-12 ms: 1.2 KB, the ring
    five times over, at most of the link's rate); a the master, b and c Bresenham slaves."""
    rng = np.random.default_rng(seed)
    runs = [(int(v), int(a), 1) for v, a in zip(rng.integers(9000 * 256, 12000 * 256, events),
                                                 rng.integers(-200, 200, events))]
    return make_schedule(MOTORS, [((1, -1, -1), (events, events * 5 // 8, events // 2), events, (events // 2,) * 3,
                                   False, runs)])


def host_for(schedule, cfg, prefill=200, identity=None):
    data = stream_of(schedule)
    ident = protocol.firmware_identity(cfg, F_CPU, TICK_HZ) if identity is None else identity
    return HostLink([data], len(cfg.motors), ident, 10 / BAUD, min(prefill, len(data)),
                    payload=ring_layout(cfg).ring_bytes // 8)


class Tap:
    """A host (HostLink's interface) whose answers from the firmware are kept, as frames."""

    def __init__(self, host):
        self.host, self.link = host, getattr(host, "link", host)
        self.frames, self._parser = [], protocol.Parser(protocol.MAX_ANSWER)

    done = property(lambda self: self.host.done)

    def transmit(self, now):
        return self.host.transmit(now)

    def wake_at(self):
        return self.host.wake_at()

    def receive(self, data, now):
        self.frames += self._parser.feed(data)
        self.host.receive(data, now)


class Sessions:
    """Several HostLinks one after the other on the same line, with actions on the current one at given times."""

    def __init__(self, links, actions=()):
        self.links, self.actions, self.k = list(links), sorted(actions, key=lambda a: a[0]), 0
        self.link = self.links[0]  # whose figures the simulation reports

    @property
    def done(self):
        return self.k == len(self.links) - 1 and self.links[-1].done

    def _current(self, now):
        while self.actions and now >= self.actions[0][0]:
            self.actions.pop(0)[1](self.links[self.k])
        if self.links[self.k].done and self.k < len(self.links) - 1:
            self.k += 1
        return self.links[self.k]

    def transmit(self, now):
        return self._current(now).transmit(now)

    def receive(self, data, now):
        self.links[self.k].receive(data, now)

    def wake_at(self):
        times = [self.links[self.k].wake_at()] + [a[0] for a in self.actions[:1]]
        if self.links[self.k].done and not self.done:
            times.append(0.0)
        return min((t for t in times if t is not None), default=None)


def test_a_stream_five_rings_long_plays_like_the_twin(seed):
    """The seed board (512 B external RAM, the display on P2 beside A8): 1.2 KB of records through a 255-byte ring,
    every pulse the twin's, FINISHED with the twin's net steps, nothing lost, the ring never short."""
    image, cfg = seed
    sched = long_schedule()
    link = host_for(sched, cfg)
    trace, figures = simulate_stream(image.hex_path, cfg, link, BUDGET)
    assert link.outcome == "finished", link.message
    check_pulses(sched, trace)
    assert link.position == tuple(int(p) for p in predict(sched).final_positions()) == net_steps(trace)
    assert figures.lost_bytes == 0 and figures.underruns == 0 and figures.retransmits == 0
    assert protocol.max_record_bytes(3) <= figures.min_ring_fill_bytes < 255
    assert figures.bytes > len(stream_of(sched)) and figures.baud == BAUD
    lcd = board_lcd(cfg.board, MOTORS)
    assert trace.display.lines == lcd.expected_text(link.position) and trace.display.problems == []


def test_records_of_every_kind_on_the_on_chip_ram(stc):
    """The STC89C52RC's on-chip XRAM (SDCC's small model, no display): short and long records, runs across
    blocks, a dwell with long waits, the tool at each block and at the end."""
    image, cfg = stc
    sched = short_schedule()
    link = host_for(sched, cfg)
    trace, figures = simulate_stream(image.hex_path, cfg, link, BUDGET)
    assert link.outcome == "finished", link.message
    check_pulses(sched, trace)
    assert link.position == tuple(int(p) for p in predict(sched).final_positions())
    assert [on for _, on in trace.tool_edges] == [1, 0, 1, 0, 1]
    assert trace.tool_edges[-1][0] > trace.step_cycle[-1] and figures.lost_bytes == 0


@pytest.mark.parametrize("faults", [
    LineFaults(corrupt_bytes=frozenset({300})), LineFaults(drop_bytes=frozenset({300})),
    LineFaults(duplicate_frames=frozenset({9})), LineFaults(swap_frames=frozenset({9})),
], ids=["corrupt", "drop", "duplicate", "swap"])
def test_line_faults_end_in_retransmissions_and_the_same_pulses(seed, faults):
    """A flipped byte or a lost one spoils a frame (its CRC, or the next SYNC), a copy or frames out of order
    come out of sequence: the firmware drops them, ACKs say REJECTED, the host sends again."""
    image, cfg = seed
    sched = long_schedule()
    link = host_for(sched, cfg)
    tap = Tap(Faulty(link, faults))
    trace, figures = simulate_stream(image.hex_path, cfg, tap, BUDGET)
    assert link.outcome == "finished", link.message
    check_pulses(sched, trace)
    assert link.position == net_steps(trace)
    rejected = sum(1 for f in tap.frames if f.kind == protocol.ACK and f.payload[2] & protocol.REJECTED)
    if faults.duplicate_frames:  # the copy is dropped: nothing is missing
        assert rejected >= 1
    else:
        assert figures.retransmits >= 1
    assert rejected >= bool(faults.swap_frames) and figures.lost_bytes == 0


def test_a_host_pause_longer_than_the_ring_lasts_ends_in_underrun(seed):
    """The host stalls for 1.5 s while playing: the player stops at the first record it cannot have whole,
    reports UNDERRUN with exact positions, and plays nothing more."""
    image, cfg = seed
    sched = long_schedule()
    link = host_for(sched, cfg)
    trace, figures = simulate_stream(image.hex_path, cfg, Faulty(link, LineFaults(pause=(0.6, 1.5))), BUDGET)
    assert link.outcome == "underrun"
    made = check_pulses(sched, trace, whole=False)
    assert 0 < sum(made) < len(predict(sched).tick)
    assert link.position == net_steps(trace)
    assert figures.underruns == 1 and figures.min_ring_fill_bytes < protocol.max_record_bytes(3)


def test_abort_stops_at_once_then_a_report_says_why_nothing_plays(stc):
    """ABORT while playing: the timer stops between two events, ABORTED gives the positions of the pulses made;
    a START afterwards gets the same report again."""
    image, cfg = stc
    sched = long_schedule()
    first, second = host_for(sched, cfg), host_for(sched, cfg)
    trace, _ = simulate_stream(image.hex_path, cfg, Sessions([first, second], [(1.0, lambda link: link.abort())]),
                               BUDGET)
    assert first.outcome == "aborted" and second.outcome == "aborted"
    check_pulses(sched, trace, whole=False)
    assert first.position == second.position == net_steps(trace)
    assert 0 < len(trace.step_cycle) < len(predict(sched).tick)


def test_status_while_playing_and_a_second_session(stc):
    """STATUS while playing (the ring's bytes, the stream played, where the block ends); after FINISHED the next
    session streams and plays again from positions 0, without a reset."""
    image, cfg = stc
    sched = long_schedule()
    first, second = host_for(sched, cfg), host_for(sched, cfg)
    trace, _ = simulate_stream(image.hex_path, cfg,
                               Sessions([first, second], [(0.8, lambda link: link.request_status())]), BUDGET)
    final = tuple(int(p) for p in predict(sched).final_positions())
    assert first.outcome == second.outcome == "finished" and first.position == second.position == final
    status = first.status
    assert status.state == "playing" and status.position == final  # one block: where it ends
    assert 0 < status.fill <= 255 and 0 < status.played < len(stream_of(sched))
    assert len(trace.step_cycle) == 2 * len(predict(sched).tick) and net_steps(trace) == tuple(2 * p for p in final)


def test_homing_at_start_then_the_stream(homed):
    """A machine that homes: at START the towers go up to their keys (fast, back off, slow), then STARTED and the
    stream plays from positions 0."""
    image, cfg = homed
    sched = long_schedule(events=80)
    switches = {0: 30, 1: 40, 2: 50}
    link = host_for(sched, cfg)
    trace, figures = simulate_stream(image.hex_path, cfg, link, BUDGET, switches=switches)
    assert link.outcome == "finished", link.message
    home = trace.step_phase == "home"
    for k, axis in enumerate(cfg.homing):
        assert int((home & (trace.step_motor == k)).sum()) == sum(homing_steps(axis, switches[k]))
    check_pulses(sched, trace.run_only())
    assert link.position == tuple(int(p) for p in predict(sched).final_positions()) and figures.lost_bytes == 0


def test_a_switch_that_never_closes_ends_in_homing_failed(homed):
    image, cfg = homed
    sched = long_schedule(events=80)
    link = host_for(sched, cfg)
    trace, _ = simulate_stream(image.hex_path, cfg, link, BUDGET, switches={0: 30, 1: None, 2: 50})
    assert link.outcome == "homing failed" and "0x12" in link.message  # fast approach (1 << 4), axis bit 2
    assert trace.homing_failed and len(trace.run_only().step_cycle) == 0


def test_a_firmware_of_another_identity_is_refused(stc):
    image, cfg = stc
    link = host_for(long_schedule(), cfg, identity=0x12345678)
    simulate_stream(image.hex_path, cfg, link, BUDGET)
    assert link.outcome == "refused" and link.ident is None


def test_build_reports_every_byte_and_refuses_what_cannot_stream(seed, homed, stc, tmp_path):
    image, cfg = homed
    assert image.flash_bytes <= 8192 and image.table_bytes == 0  # homing and the display fit in 8 KB
    for img, _ in (seed, homed, stc):
        assert sum(img.flash_parts.values()) == img.flash_bytes and img.flash_parts["link"] > 0
        assert img.sections["ring_bytes"] == 256
    assert stc[0].sections["xram_used"] == 0 and seed[0].sections["xram_used"] <= 256
    assert render_stream_sources(cfg) == render_stream_sources(cfg)
    symbols = (image.hex_path.with_name(MAP_FILE)).read_text()
    for helper in ("__mul", "__div", "__mod", "___fs", "__gptr", "__sdcc_call"):
        assert helper not in symbols
    link_c = render_stream_sources(cfg)["link.c"]
    assert re.search(r"#define BAUD_RELOAD 0xFFD9U .* 9615\.4 baud", link_c)  # 9600 within 0.16 %
    assert abs(ring_layout(cfg).baud_error_pct - 0.16) < 0.01
    # no XRAM: the ring goes into internal RAM (tests/firmware/mcs51/test_stream_iram.py)
    assert "#define RING_BASE 0xC0 " in render_stream_sources(config("at89c52"))["link.h"]
    assert abs(ring_layout(config(baud=19200)).baud_error_pct + 2.34) < 0.01  # 18750 baud: still within 2.5 %
    with pytest.raises(BuildError, match="115200 baud: .* more than 2.5 %"):
        ring_layout(config(baud=115200))

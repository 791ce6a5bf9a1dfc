"""The link protocol's frames and the host's session (codegen/link/), against a byte-level model of the firmware's
receive side (tests/link_model.py): handshake, credits, retransmission after each kind of line fault, window
updates."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from codegen.link import protocol as p
from codegen.link.faults import Faulty, LineFaults
from codegen.link.host import HostLink
from codegen.link.ring import Ring, link_budget
from tests.link_model import RECORD, FirmwareModel, run_session

BYTE_S = 10 / 250000
IDENTITY = 0x1234ABCD


def stream(n: int, seed: int = 7) -> bytes:
    """n pseudo-random stream bytes (with SYNC bytes inside, which frames must carry as data)."""
    x, out = seed, bytearray()
    for _ in range(n):
        x = (1103515245 * x + 12345) & 0x7FFFFFFF
        out.append((x >> 16) & 0xFF)
    return bytes(out)


def session(data: bytes, faults: LineFaults | None = None, rate: float = 20000.0, ring: int = 1024,
            prefill: int = 512, identity: int = IDENTITY, **link):
    chunks = [data[i:i + 300] for i in range(0, len(data), 300)]
    host = HostLink(chunks, 3, IDENTITY, BYTE_S, prefill, ack_timeout_s=0.005, **link)
    model = FirmwareModel(identity, 3, ring, rate, len(data))
    driver = host if faults is None else Faulty(host, faults)
    run_session(driver, model, BYTE_S, step_s=2e-4)
    return host, model


def test_crc_is_ccitt_false_and_a_good_frame_checks_to_zero():
    assert p.crc16(b"123456789") == 0x29B1
    f = p.frame(p.DATA, 300, b"\x7e\x00\xff")
    assert f[:4] == bytes([p.SYNC, 3, 300 & 0xFF, p.DATA])
    assert p.crc16(f[1:]) == 0


def test_parser_finds_frames_among_noise_and_drops_a_bad_crc():
    good = p.frame(p.ACK, 9, b"\x10\x00\x00")
    bad = bytearray(p.frame(p.ACK, 8, b"\x20\x00\x00"))
    bad[5] ^= 1
    parser = p.Parser(p.MAX_ANSWER)
    frames = parser.feed(b"\x00\x13" + bytes(bad) + good[:3]) + parser.feed(good[3:])
    assert [(f.kind, f.seq, f.payload) for f in frames] == [(p.ACK, 9, b"\x10\x00\x00")]
    assert parser.bad == 1


def test_a_frame_over_the_payload_limit_is_refused():
    with pytest.raises(ValueError, match="at most 250"):
        p.frame(p.DATA, 0, bytes(251))


def test_a_clean_session_delivers_every_byte_in_order():
    data = stream(20000)
    host, model = session(data)
    assert host.outcome == "finished", host.message
    assert bytes(model.received) == data
    assert host.stats.retransmits == 0
    assert host.stats.data_bytes == len(data)
    assert model.min_fill >= p.max_record_bytes(3)
    assert host.started_at is not None


def test_credits_never_overflow_the_ring():
    data = stream(30000)
    host, model = session(data, ring=300, prefill=200, rate=5000.0)
    assert host.outcome == "finished", host.message
    assert bytes(model.received) == data  # a DATA frame over the free space would have been REJECTED


@pytest.mark.parametrize("faults", [
    LineFaults(corrupt_bytes=frozenset({700})),
    LineFaults(drop_bytes=frozenset({1500})),
    LineFaults(duplicate_frames=frozenset({12})),
    LineFaults(swap_frames=frozenset({20})),
    LineFaults(corrupt_bytes=frozenset({100, 2000, 2001}), drop_bytes=frozenset({5000}),
               duplicate_frames=frozenset({40}), swap_frames=frozenset({60})),
], ids=["corrupted", "dropped", "duplicated", "out-of-order", "all"])
def test_faults_are_retransmitted_and_the_stream_arrives_whole(faults):
    data = stream(12000)
    host, model = session(data, faults, rate=10000.0)
    assert host.outcome == "finished", host.message
    assert bytes(model.received) == data
    if faults.duplicate_frames != frozenset({12}):  # a duplicate is only rejected: nothing is missing
        assert host.stats.retransmits > 0


def test_a_host_pause_longer_than_the_ring_ends_in_an_underrun():
    data = stream(40000)
    host, model = session(data, LineFaults(pause=(0.2, 0.5)))
    assert host.outcome == "underrun"
    assert model.state == "underrun"
    assert host.position == (int(model.played),) * 3


def test_firmware_of_another_identity_is_refused():
    host, model = session(stream(1000), identity=0x0BADF00D)
    assert host.outcome == "refused"
    assert "built for another machine" in host.message
    assert model.state == "idle" and not model.received


def test_no_answer_gives_up_after_some_hellos():
    host = HostLink([b"x"], 3, IDENTITY, BYTE_S, 1, ack_timeout_s=0.001)
    now = 0.0
    while not host.done:
        host.transmit(now)
        now = host.wake_at()
    assert host.outcome == "no answer"
    assert host.stats.frames == 5


def test_status_is_answered_and_abort_stops_with_positions():
    data = stream(60000)
    chunks = [data[i:i + 300] for i in range(0, len(data), 300)]
    host = HostLink(chunks, 3, IDENTITY, BYTE_S, 512, ack_timeout_s=0.005)
    model = FirmwareModel(IDENTITY, 3, 1024, 20000.0, len(data))

    class AbortLater:
        """Asks for a status at 0.1 s and aborts at 0.5 s."""
        done = property(lambda self: host.done)
        wake_at = host.wake_at
        receive = host.receive
        asked = aborted = False

        def transmit(self, now):
            if now >= 0.1 and not self.asked:
                self.asked = True
                host.request_status()
            if now >= 0.5 and not self.aborted:
                self.aborted = True
                host.abort()
            return host.transmit(now)

    run_session(AbortLater(), model, BYTE_S, step_s=2e-4)
    assert host.status is not None and host.status.state == "playing"
    assert host.outcome == "aborted"
    assert model.state == "aborted"
    assert host.position == (int(model.played),) * 3
    assert 0 < model.played < len(data)


def test_the_first_ending_frame_ends_the_session():
    """Ctrl-C as the job ends: the host sends ABORT before it has read FINISHED, and the firmware, idle again,
    answers it with ABORTED. Both frames come in one read when the host is slow to read: the job finished, and
    the session says so (what came after its end does not change it)."""
    host = HostLink([stream(8)], 2, IDENTITY, BYTE_S, 8)
    host.receive(p.frame(p.IDENT, 0, p.Ident(p.VERSION, IDENTITY, 1024, 2).payload()), 0.0)
    host.abort()
    assert host.transmit(0.01)  # the ABORT, among the session's first frames
    end = struct.pack("<2i", 7200, 4400)
    host.receive(p.frame(p.FINISHED, 1, end) + p.frame(p.ABORTED, 2, end), 0.02)
    assert (host.outcome, host.position) == ("finished", (7200, 4400))


def test_ident_payload_round_trip():
    ident = p.Ident(1, 0xDEADBEEF, 4096, 4)
    assert p.Ident.parse(ident.payload()) == ident
    status = p.Status.parse(struct.pack("<BIH3i", 2, 1000, 77, 1, -2, 3), 3)
    assert status == p.Status("playing", 1000, 77, (1, -2, 3))


@pytest.mark.parametrize("window_s, outcome", [(0.02, "finished"), (1.0, "underrun")])
def test_a_bad_byte_costs_a_round_trip_not_the_line_queue(window_s, outcome):
    """The player takes more than the line carries (a dense stretch played from the ring): credit allows kilobytes
    on the line, and every frame behind a bad byte is rejected. Within the window the resend comes a round trip
    later; with all the credit on the line (window_s 1 s), it waits behind kilobytes and the ring runs dry."""
    host, model = session(stream(100000), LineFaults(corrupt_bytes=frozenset({60000})), rate=24000.0, ring=7805,
                          prefill=7000, window_s=window_s)
    assert host.outcome == outcome
    assert host.stats.retransmits > 0


def test_the_faulty_line_shows_the_links_figures():
    host = HostLink([b"x"], 3, IDENTITY, BYTE_S, 1)
    line = Faulty(host, LineFaults(corrupt_bytes=frozenset({0})))
    line.transmit(0.0)
    assert line.stats is host.stats and line.stats.frames == 1
    assert line.outcome is None and line.position is None


def test_pings_leave_a_slow_line_mostly_free():
    """9600 baud, the ring full and the player slow: the host pings for credit, at most every 48 byte times."""
    byte_s = 10 / 9600
    data = stream(3000)
    host = HostLink([data], 3, IDENTITY, byte_s, 256, ack_timeout_s=0.2)
    model = FirmwareModel(IDENTITY, 3, 256, 20.0, len(data))
    run_session(host, model, byte_s, limit_s=5.0, step_s=1e-3)
    assert 0 < host.stats.pings <= 5.0 / (48 * byte_s) + 1


def bursts(idle_s: float, records: int, spacing_s: float, cycles: int) -> np.ndarray:
    """When the player reads each record (s after START): the first at once, then `cycles` times `idle_s` of
    nothing and `records` records `spacing_s` apart."""
    cycle = idle_s + records * spacing_s
    return np.concatenate([[0.0]] + [c * cycle + idle_s + np.arange(records) * spacing_s for c in range(cycles)])


@pytest.mark.parametrize("updates", [True, False], ids=["window updates", "pings only"])
def test_bursts_the_plan_takes_keep_a_small_ring_fed(updates):
    """9600 baud into the at89c52's ring of 63 bytes, in 8-byte frames: bursts of 7 records 4 ms apart (1.5 kB/s,
    nearly three times what the link carries), each after 100 ms in which the ring fills and the host, blocked on
    credit, has nothing in flight. The plan, counting on window updates, finds the ring holds them: it counts on
    what the host keeps (the ring less 7 bytes: it sends whole frames) less the burst's first six records, 20
    bytes, and the firmware model goes exactly there, the refill coming after the burst. Without window updates
    the plan counts on the host's pings, later still, and slows every burst; the firmware model without them is
    fed by the pings."""
    byte_s = 10 / 9600
    times = bursts(0.1, 7, 0.004, 10)
    sizes = np.full(len(times), RECORD)
    data = stream(int(sizes.sum()))
    budget = link_budget(9600, 63, 3, window_updates=True)
    ring = Ring(budget)
    assert ring.add(times, sizes) == []
    prefill, low = ring.result(len(data))
    assert (budget.kept, budget.usable, budget.need, prefill, low) == (56, 22, 15, 39, 20)
    without = link_budget(9600, 63, 3)
    assert without.usable == 3 and len(Ring(without).add(times, sizes)) == 5
    host = HostLink([data], 3, IDENTITY, byte_s, prefill, payload=budget.payload, ack_timeout_s=0.2)
    model = FirmwareModel(IDENTITY, 3, 63, 0.0, len(data), window_update=budget.payload if updates else 0,
                          read_at=tuple(times))
    run_session(host, model, byte_s, step_s=1e-4)
    assert (host.outcome, model.min_fill) == ("finished", low) and bytes(model.received) == data
    assert (host.stats.pings, model.window_updates) == ((1, 9) if updates else (7, 0))


def nearly_full_then_drained(records: int, phase_s: float) -> np.ndarray:
    """6-byte records every 17 ms (about what one 8-byte frame a round trip carries: each ACK reports room for one
    frame and not two), then `records` at once `phase_s` later and 16 more 11.5 ms apart (the link's rate)."""
    slow = np.arange(24) * 0.017
    drain = slow[-1] + 0.017 + phase_s
    return np.concatenate([slow, drain + np.arange(records) * 3e-4, drain + 0.0115 * np.arange(1, 17)])


def test_the_plan_counts_on_the_frame_in_flight_when_a_nearly_full_ring_drains():
    """Issue 28 (the at89c52 in s51 at 9 bytes where the plan counted on 11, then dry). The ring nearly full, the
    host sends a frame on each ACK and hears of the room the player makes meanwhile only from that frame's ACK: the
    refill runs at the line's rate two ACKs and two frames after the ACK it went by, not one and one. Five records
    at once were 17 bytes of lowest fill to the plan that counted on one and one; the firmware model runs dry there
    (at 12 bytes, even with the ring full at START): the plan slows them now. The drains it takes leave the
    firmware model no lower than it counts on, whatever their phase."""
    byte_s = 10 / 9600
    budget = link_budget(9600, 63, 3, window_updates=True)

    def replay(times: np.ndarray, prefill: int) -> FirmwareModel:
        data = stream(RECORD * len(times) + budget.ring_bytes)  # every record counts: a ring is still to come
        host = HostLink([data], 3, IDENTITY, byte_s, prefill, payload=budget.payload, ack_timeout_s=0.2)
        model = FirmwareModel(IDENTITY, 3, 63, 0.0, len(data), window_update=budget.payload, read_at=tuple(times))
        run_session(host, model, byte_s, limit_s=times[-1] + 0.05, step_s=1e-4)
        return model

    five = nearly_full_then_drained(5, 0.0065)
    assert Ring(budget).add(five, np.full(len(five), RECORD)) != []
    dry = replay(five, budget.max_prefill)
    assert (dry.state, dry.min_fill) == ("underrun", 12)
    for records in (1, 2):
        for phase_s in (0.0, 0.0065, 0.013):
            times = nearly_full_then_drained(records, phase_s)
            ring = Ring(budget)
            assert ring.add(times, np.full(len(times), RECORD)) == []
            prefill, low = ring.result(RECORD * len(times) + budget.ring_bytes)
            model = replay(times, prefill)
            assert model.state == "playing" and model.min_fill >= low, (records, phase_s)

"""The host's side of a streaming session, without I/O (codegen/link/protocol.py): the caller moves the bytes
and the time, so the same code drives a real serial port (`printer-codegen stream`) and a simulated UART
(`verify --stream`).

    link = HostLink(chunks, motors=3, identity=..., byte_s=10 / baud, prefill_bytes=...)
    while not link.done:
        line.send(link.transmit(now))         # whole frames, to go out back to back from `now`
        data, now = line.wait(until=link.wake_at())   # bytes from the firmware, or the wake-up time
        link.receive(data, now)

The session: HELLO until IDENT answers (a firmware of another identity is refused); DATA frames while the
firmware's credit (the free ring space of its last ACK, less what has been sent since) holds them, and no more than
`window_s` of the line's bytes unacknowledged (what is on the line cannot be taken back: a frame resent after a bad
byte, or an ABORT, waits behind it); START once `prefill_bytes` of the stream have gone out (or all of it); then
the rest, and the end: FINISHED, UNDERRUN, ABORTED, HOMING_FAILED or FAULT (the heaters' protection tripped:
`fault` says why). Every frame stays in flight until an ACK counts past it: an ACK that says REJECTED, or no ACK
within `ack_timeout_s` of a frame's last byte, sends every frame in flight again from the first the firmware lacks
(go-back-N). Blocked on credit with nothing in flight, the host pings (an empty DATA frame) every `ping_s`, and
never more often than every PING_BYTES byte times (a ping and its ACK must not fill a slow line), for a fresh ACK;
a firmware that sends window updates (an ACK unasked once its ring has room for a DATA frame again, after an ACK
that said it had not: both targets') leaves the pings a fallback (LinkBudget.ping_s: rarer). `refill_byte_times`
says how long the line may stand idle behind what the host last heard of the ring, either way (the plan counts on
it: codegen/link/ring.py).
Times within TIME_SLACK_S of a deadline count as at it: the caller's clock may round.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

from codegen.link import protocol as p

HELLO_TRIES = 5  # at the least, before giving up
MAX_IN_FLIGHT = 100  # frames: far below the 256 sequence numbers
ANSWER_BYTES = 12  # an ACK's bytes on the line, and a few byte times for the firmware to answer
PING_S = 0.01  # between pings, blocked on credit (HostLink.ping_s)
PING_BYTES = 48  # byte times between pings at the least: a ping and its ACK take under a third of the line
MIN_WINDOW_FRAMES = 2  # frames on the line unacknowledged at the least, whatever window_s says
TIME_SLACK_S = 1e-9


def refill_byte_times(payload: int, baud: int, window_updates: bool) -> float:
    """Byte times from the ACK whose free space the host last went by to when the line, idle since (the host
    blocked on credit), has brought the first frame of the refill: the lag of the host's knowledge, and a frame.

    The worst case is a frame in flight, not a full ring: an ACK (ANSWER_BYTES on the line, with the firmware's
    time to answer) reports room for one frame and less than two; the host sends that frame and waits for its ACK,
    which reports the room the player made meanwhile: two ACKs and two frames. Measured in s51 (the at89c52 at
    9600 baud, issue 28: one 8-byte frame every 23.6 byte times while its ACKs said 10 to 14 bytes free) against
    a plan that counted on one ACK and one frame, the ring fell 2 bytes below the planned lowest fill and ran dry.
    With window updates the host's fallback ping may be on the line ahead of that frame (its bytes); without them,
    blocked with nothing in flight, the host hears of room only from the ACK of its next ping, up to a ping
    interval after the ACK that stopped it."""
    frame = p.OVERHEAD_BYTES + payload
    in_flight = 2 * ANSWER_BYTES + 2 * frame
    if window_updates:
        return in_flight + p.OVERHEAD_BYTES
    ping = max(PING_S * baud / 10, PING_BYTES)
    return max(in_flight, 2 * ANSWER_BYTES + ping + p.OVERHEAD_BYTES + frame)


@dataclass
class LinkStats:
    bytes: int = 0  # sent on the line, every frame and retransmission included
    frames: int = 0
    retransmits: int = 0  # frames sent again
    pings: int = 0  # empty DATA frames, sent blocked on credit for a fresh ACK
    data_bytes: int = 0  # table stream bytes (with the tail padding) acknowledged by the firmware
    bad_frames: int = 0  # firmware frames whose CRC failed


@dataclass
class _Sent:
    seq: int  # unbounded; the frame carries seq & 0xFF
    kind: int
    payload: bytes
    done_at: float = 0.0  # when its last byte leaves the line


@dataclass
class HostLink:
    chunks: Iterable[bytes]  # the table stream, end marker and tail padding included
    motors: int
    identity: int
    byte_s: float  # seconds per byte on the line (10 bit times)
    prefill_bytes: int
    payload: int = 64  # DATA bytes per frame
    ack_timeout_s: float = 0.05  # after a frame's last byte
    answer_within_s: float = 0.0  # HELLOs go on this long at the least (a board that resets when its port opens)
    ping_s: float = PING_S
    window_s: float = 0.02  # seconds of line bytes that may be unacknowledged: more than a round trip
    latency_s: float = 0.0  # the line's answer delay beyond its byte times (a USB serial adapter: milliseconds)
    stream_bytes: int | None = None  # the stream's length, when known (for `in_tail`)
    heaters: tuple[str, ...] = ()  # the firmware's heaters by index (FAULT and STATUS frames name them so)
    laser_top: int = 0  # a laser firmware's PWM counts of full power (STATUS carries its power in counts)
    stats: LinkStats = field(default_factory=LinkStats)
    outcome: str | None = None  # finished | underrun | aborted | homing failed | fault | refused | no answer
    message: str = ""
    ident: p.Ident | None = None
    started_at: float | None = None
    position: tuple[int, ...] | None = None  # the firmware's report at the end
    status: p.Status | None = None  # the last STATUS answer
    fault: p.Fault | None = None  # a FAULT frame's report
    fault_at: float | None = None  # when it arrived

    def __post_init__(self):
        self._source: Iterator[bytes] = iter(self.chunks)
        self._pending = bytearray()  # stream bytes not yet framed
        self._exhausted = False
        self._parser = p.Parser(p.MAX_ANSWER)
        self._next_seq = 0
        self._acked = 0  # the firmware expects this sequence number next
        self._flight: deque[_Sent] = deque()
        self._free = 0  # ring bytes free at the last ACK
        self._line_free = 0.0
        self._hello_tries = 0
        self._first_hello: float | None = None
        self._hello_due = 0.0
        self._start_sent = False
        self._streamed = 0  # stream bytes framed so far
        self._resend_from: int | None = None
        self._ping_due: float | None = None
        self._abort = False
        self._status_wanted = False
        self._feed: list[int] = []  # HOLD, RESUME, FEED_DOWN, FEED_UP frames to send

    def heater_name(self, index: int) -> str:
        return self.heaters[index] if 0 <= index < len(self.heaters) else f"#{index}"

    # -- what the caller drives --
    @property
    def done(self) -> bool:
        return self.outcome is not None

    def abort(self) -> None:
        """Send ABORT with the next transmit; the session ends when ABORTED comes back."""
        self._abort = True

    def request_status(self) -> None:
        self._status_wanted = True

    def feed(self, kind: int) -> None:
        """Send HOLD, RESUME, FEED_DOWN or FEED_UP (a firmware with feed hold) first with the next transmit, once
        the session has begun."""
        self._feed.append(kind)

    @property
    def line_free_at(self) -> float:
        """When the bytes sent so far have left the host (seconds): a frame sent then goes out at once."""
        return self._line_free

    @property
    def in_tail(self) -> bool:
        """Less than the firmware's ring of the stream is left to send: from here the ring may drain as planned."""
        ring = self.ident.ring_bytes if self.ident else 0
        return self.stream_bytes is not None and self._streamed >= self.stream_bytes - ring

    def wake_at(self) -> float | None:
        """When to call transmit again if no byte arrives first (None: only when bytes arrive)."""
        times = [t for t in (self._ack_deadline(), self._ping_due) if t is not None]
        if self.ident is None and self.outcome is None:
            times.append(self._hello_due)
        return min(times) if times else None

    def transmit(self, now: float) -> bytes:
        if self.done:
            return b""
        out = bytearray()
        if self._abort:
            self._abort = False
            out += self._send(p.ABORT, b"", now, track=False)
        if self.ident is None:
            if now >= self._hello_due - TIME_SLACK_S:
                if self._first_hello is None:
                    self._first_hello = now
                if self._hello_tries >= HELLO_TRIES and now >= self._first_hello + self.answer_within_s:
                    self._end("no answer", f"no IDENT after {self._hello_tries} HELLOs in "
                                           f"{now - self._first_hello:.1f} s: is the streaming firmware flashed, and "
                                           f"the baud rate right?")
                    return bytes(out)
                self._hello_tries += 1
                self._next_seq = self._acked = 0
                out += self._send(p.HELLO, b"", now, track=False)
                self._next_seq = self._acked = 1
                self._hello_due = self._line_free + self.ack_timeout_s + 20 * self.byte_s
            return bytes(out)
        for kind in self._feed:  # first: the line takes them at once
            out += self._send(kind, b"", now)
        self._feed.clear()
        deadline = self._ack_deadline()
        if self._resend_from is None and deadline is not None and now >= deadline - TIME_SLACK_S:
            self._resend_from = self._acked
        if self._resend_from is not None:
            for sent in self._flight:
                if sent.seq >= self._resend_from:
                    self.stats.retransmits += 1
                    out += self._emit(sent, now)
            self._resend_from = None
        if self._status_wanted:
            self._status_wanted = False
            out += self._send(p.STATUS, b"", now)
        out += self._stream(now)
        return bytes(out)

    def receive(self, data: bytes, now: float) -> None:
        for f in self._parser.feed(data):
            if self.done:  # the first ending frame ends the session (an ABORT's ABORTED may follow a FINISHED)
                break
            self._answer(f, now)
        self.stats.bad_frames = self._parser.bad

    # -- the session --
    def _stream(self, now: float) -> bytes:
        out = bytearray()
        while len(self._flight) < MAX_IN_FLIGHT:
            if not self._start_sent and (self._streamed >= self.prefill_bytes or self._drained()):
                self._start_sent = True
                out += self._send(p.START, b"", now)
                continue
            if self._drained():
                break
            self._fill(self.payload)
            size = min(self.payload, len(self._pending))
            if self._unacknowledged() + p.OVERHEAD_BYTES + size > self._window():
                break  # an ACK will come for what is on the line
            if size > self._credit():
                if not any(s.kind == p.DATA for s in self._flight) and self._ping_due is None:
                    self._ping_due = now + max(self.ping_s, PING_BYTES * self.byte_s)
                break
            chunk = bytes(self._pending[:size])
            del self._pending[:size]
            self._streamed += size
            self._ping_due = None  # credit came (a window update, an ACK of another frame): no ping is due
            out += self._send(p.DATA, chunk, now)
        if self._ping_due is not None and now >= self._ping_due - TIME_SLACK_S and not self._flight:
            self._ping_due = None
            self.stats.pings += 1
            out += self._send(p.DATA, b"", now)
        return bytes(out)

    def _answer(self, f: p.Frame, now: float) -> None:
        if f.kind == p.IDENT:
            ident = p.Ident.parse(f.payload)
            if ident.identity != self.identity or ident.version != p.VERSION or ident.motors != self.motors:
                self._end("refused", f"the firmware on the line was built for another machine, board or format "
                                     f"(identity {ident.identity:08x}, protocol {ident.version}, {ident.motors} "
                                     f"motors; this job needs {self.identity:08x}, protocol {p.VERSION}, "
                                     f"{self.motors} motors): build and flash `printer-codegen build --stream`")
                return
            if self.ident is None:
                self.ident = ident
                self._free = ident.ring_bytes
            return
        if self.ident is None:
            return
        if f.kind == p.ACK:
            self._acknowledge(f, now)
        elif f.kind == p.STARTED:
            self.started_at = now
        elif f.kind == p.STATUS_REPLY:
            self.status = p.Status.parse(f.payload, self.motors)
        elif f.kind in (p.FINISHED, p.UNDERRUN, p.ABORTED):
            self.position = p.positions(f.payload, self.motors)
            outcome = {p.FINISHED: "finished", p.UNDERRUN: "underrun", p.ABORTED: "aborted"}[f.kind]
            self._end(outcome, "")
        elif f.kind == p.HOMING_FAILED:
            self._end("homing failed", f"homing failed (status 0x{f.payload[0]:02X})")
        elif f.kind == p.FAULT:
            self.fault, self.fault_at = p.Fault.parse(f.payload, self.motors), now
            self.position = self.fault.position
            self._end("fault", f"heater {self.heater_name(self.fault.heater)} tripped: {self.fault.reason}; every "
                               f"heater off, the machine stopped at positions {list(self.position)}")

    def _acknowledge(self, f: p.Frame, now: float) -> None:
        expected = self._acked + ((f.seq - self._acked) & 0xFF)
        if expected > self._next_seq:  # an ACK from before a HELLO, or garbage: ignore
            return
        free, flags = int.from_bytes(f.payload[:2], "little"), f.payload[2]
        while self._flight and self._flight[0].seq < expected:
            done = self._flight.popleft()
            if done.kind == p.DATA:
                self.stats.data_bytes += len(done.payload)
        self._acked = expected
        self._free = free
        # A rejection that comes after the last copy of the frame the firmware lacks has arrived: that copy
        # was lost too (rejections of the frames that were queued behind an earlier copy come before).
        if (flags & p.REJECTED and self._flight and self._flight[0].seq == expected
                and now >= self._flight[0].done_at + ANSWER_BYTES * self.byte_s + self.latency_s):
            self._resend_from = expected

    def _unacknowledged(self) -> int:
        return sum(p.OVERHEAD_BYTES + len(s.payload) for s in self._flight)

    def _window(self) -> int:
        return max(MIN_WINDOW_FRAMES * (p.OVERHEAD_BYTES + self.payload), int(self.window_s / self.byte_s))

    def _credit(self) -> int:
        return self._free - sum(len(s.payload) for s in self._flight if s.kind == p.DATA)

    def _fill(self, want: int) -> None:
        while len(self._pending) < want and not self._exhausted:
            chunk = next(self._source, None)
            if chunk is None:
                self._exhausted = True
            else:
                self._pending += chunk

    def _drained(self) -> bool:
        self._fill(1)
        return self._exhausted and not self._pending

    def _ack_deadline(self) -> float | None:
        return self._flight[0].done_at + self.ack_timeout_s if self._flight else None

    def _send(self, kind: int, payload: bytes, now: float, track: bool = True) -> bytes:
        sent = _Sent(self._next_seq, kind, payload)
        if track:
            self._next_seq += 1
            self._flight.append(sent)
        return self._emit(sent, now)

    def _emit(self, sent: _Sent, now: float) -> bytes:
        data = p.frame(sent.kind, sent.seq, sent.payload)
        self._line_free = max(self._line_free, now) + len(data) * self.byte_s
        sent.done_at = self._line_free
        self.stats.bytes += len(data)
        self.stats.frames += 1
        return data

    def _end(self, outcome: str, message: str) -> None:
        self.outcome, self.message = outcome, message


@dataclass
class LinkFigures:
    """What a simulated streaming run measured of its link (`verify --stream --json`'s `link`, and more)."""

    baud: int
    bytes: int  # host to firmware, on the line (retransmissions included)
    frames: int
    retransmits: int
    min_ring_fill_bytes: int | None  # the fewest ring bytes the player held when it went for a record
    underruns: int
    lost_bytes: int  # bytes a real UART would have lost: not read before the next one had arrived
    wall_s: float  # the simulation's wall-clock time

"""A model of a streaming firmware's link side, byte by byte as the MCU parses it (codegen/link/protocol.py), and a
line between it and the host with byte times: to test the host's protocol code fast, without a simulator.

The model's player takes `rate` ring bytes per second once started, or records at the times `read_at` gives (a
record at a time: it needs max_record_bytes in the ring before each), until it has taken `total` bytes. With
`window_update` (a DATA payload), the model sends window updates as the 8051 firmware does: an ACK unasked once
the player has made room for a frame after an ACK that reported less.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from codegen.link import protocol as p

RECORD = 6  # bytes the model's player takes at a time


@dataclass
class FirmwareModel:
    identity: int
    motors: int
    ring_bytes: int
    rate: float  # bytes/s the player consumes while playing (unless read_at says when)
    total: int  # stream bytes the job has (the tail padding included)
    received: bytearray = field(default_factory=bytearray)  # the stream as committed
    fill: int = 0
    state: str = "idle"
    expected: int = 0
    played: float = 0.0
    min_fill: int | None = None
    out: bytearray = field(default_factory=bytearray)
    window_update: int = 0  # the host's DATA payload: the room that owes it an ACK unasked (0: no window updates)
    window_updates: int = 0  # ACKs sent unasked
    read_at: tuple[float, ...] = ()  # when the player reads each record, s after START

    def __post_init__(self):
        self._hunt = True
        self._frame = bytearray()
        self._clock = 0.0  # s since START
        self._records = 0  # records read
        self._reported_free = self.ring_bytes  # what the last ACK said

    def feed(self, byte: int) -> None:
        """One received byte, as the receive interrupt handles it."""
        if self._hunt:
            if byte == p.SYNC:
                self._hunt = False
                self._frame = bytearray()
            return
        self._frame.append(byte)
        length = self._frame[0]
        if length > p.MAX_PAYLOAD:
            self._hunt = True
            return
        if len(self._frame) < length + 5:
            return
        self._hunt = True
        if p.crc16(bytes(self._frame)) != 0:
            return
        seq, kind, payload = self._frame[1], self._frame[2], bytes(self._frame[3:3 + length])
        self._take(seq, kind, payload)

    def _take(self, seq: int, kind: int, payload: bytes) -> None:
        rejected = 0
        if kind == p.HELLO:
            self.expected = (seq + 1) & 0xFF
            if self.state != "playing":
                self.fill, self.received, self.played, self.state = 0, bytearray(), 0.0, "idle"
        elif kind == p.ABORT:
            if self.state == "playing":
                self.state = "aborted"
        elif seq != self.expected or (kind == p.DATA and len(payload) > self.ring_bytes - self.fill):
            rejected = p.REJECTED
        else:
            self.expected = (seq + 1) & 0xFF
            if kind == p.DATA:
                self.received += payload
                self.fill += len(payload)
            elif kind == p.START and self.state == "idle":
                self.state = "playing"
                self._reply(p.STARTED, b"", ack_first=True)
                return
        self._ack(rejected)
        if kind == p.HELLO:
            self._reply(p.IDENT, p.Ident(p.VERSION, self.identity, self.ring_bytes, self.motors).payload())
        elif kind == p.ABORT and self.state == "aborted":
            self._reply(p.ABORTED, self._positions())
        elif kind == p.STATUS and not rejected:
            self._reply(p.STATUS_REPLY, struct.pack("<BIH", 2, int(self.played), self.fill) + self._positions())

    def _reply(self, kind: int, payload: bytes, ack_first: bool = False) -> None:
        if ack_first:
            self._ack(0)
        self.out += p.frame(kind, self.expected, payload)

    def _ack(self, flags: int) -> None:
        self._reported_free = self.ring_bytes - self.fill
        self.out += p.frame(p.ACK, self.expected, struct.pack("<HB", self._reported_free, flags))

    def _positions(self) -> bytes:
        return struct.pack(f"<{self.motors}i", *([int(self.played)] * self.motors))

    def advance(self, dt: float) -> None:
        """The player takes records of RECORD bytes for dt seconds, each when `rate` or `read_at` says, and needs
        max_record_bytes in the ring before each (fewer, short of the stream's end, is an underrun)."""
        if self.state != "playing":
            return
        self._clock += dt
        need = p.max_record_bytes(self.motors)
        while self._due() and self.state == "playing":
            self._records += 1
            left = self.total - self.played
            if self.played + self.fill < self.total:  # the stream's tail may be all the ring holds
                self.min_fill = self.fill if self.min_fill is None else min(self.min_fill, self.fill)
                if self.fill < need:
                    self.state = "underrun"
                    self.out += p.frame(p.UNDERRUN, self.expected, self._positions())
                    return
            take = min(RECORD, left)
            self.played += take
            self.fill -= take
            if self._reported_free < self.window_update <= self.ring_bytes - self.fill:
                self.window_updates += 1
                self._ack(0)
            if self.played >= self.total:
                self.state = "finished"
                self.out += p.frame(p.FINISHED, self.expected, self._positions())

    def _due(self) -> bool:
        """The next record's time has come: read_at's, else RECORD bytes' worth of `rate` after the one before."""
        if self.read_at:
            return self._records < len(self.read_at) and self.read_at[self._records] <= self._clock
        return self.rate * self._clock >= (self._records + 1) * RECORD


def run_session(host, model: FirmwareModel, byte_s: float, limit_s: float = 60.0, step_s: float = 1e-3) -> float:
    """Drive `host` (HostLink's interface) against `model` over a full-duplex line of `byte_s` per byte; returns
    the time the session ended."""
    now, line_free = 0.0, 0.0
    to_model: list[tuple[float, int]] = []  # (arrival time, byte)
    to_host: list[tuple[float, bytes]] = []
    model_line_free = 0.0
    while not host.done and now < limit_s:
        for b in host.transmit(now):
            line_free = max(line_free, now) + byte_s
            to_model.append((line_free, b))
        end = now + step_s
        while to_model and to_model[0][0] <= end:
            t, b = to_model.pop(0)
            model.advance(max(0.0, t - now))
            now = max(now, t)
            model.feed(b)
            if model.out:
                model_line_free = max(model_line_free, now) + len(model.out) * byte_s
                to_host.append((model_line_free, bytes(model.out)))
                model.out.clear()
        model.advance(max(0.0, end - now))
        now = end
        if model.out:
            model_line_free = max(model_line_free, now) + len(model.out) * byte_s
            to_host.append((model_line_free, bytes(model.out)))
            model.out.clear()
        while to_host and to_host[0][0] <= now:
            host.receive(to_host.pop(0)[1], now)
    return now

"""A model of a streaming firmware's link side, byte by byte as the MCU parses it (codegen/link/protocol.py), and a
line between it and the host with byte times: to test the host's protocol code fast, without a simulator.

The model's player takes `rate` ring bytes per second once started (a record at a time: it needs
max_record_bytes in the ring before each), until it has taken `total` bytes.
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
    rate: float  # bytes/s the player consumes while playing
    total: int  # stream bytes the job has (the tail padding included)
    received: bytearray = field(default_factory=bytearray)  # the stream as committed
    fill: int = 0
    state: str = "idle"
    expected: int = 0
    played: float = 0.0
    min_fill: int | None = None
    out: bytearray = field(default_factory=bytearray)

    def __post_init__(self):
        self._hunt = True
        self._frame = bytearray()
        self._owed = 0.0  # bytes the player is due but has not taken (it takes whole bytes)

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
        self._reply(p.ACK, struct.pack("<HB", self.ring_bytes - self.fill, rejected))
        if kind == p.HELLO:
            self._reply(p.IDENT, p.Ident(p.VERSION, self.identity, self.ring_bytes, self.motors).payload())
        elif kind == p.ABORT and self.state == "aborted":
            self._reply(p.ABORTED, self._positions())
        elif kind == p.STATUS and not rejected:
            self._reply(p.STATUS_REPLY, struct.pack("<BIH", 2, int(self.played), self.fill) + self._positions())

    def _reply(self, kind: int, payload: bytes, ack_first: bool = False) -> None:
        if ack_first:
            self._reply(p.ACK, struct.pack("<HB", self.ring_bytes - self.fill, 0))
        self.out += p.frame(kind, self.expected, payload)

    def _positions(self) -> bytes:
        return struct.pack(f"<{self.motors}i", *([int(self.played)] * self.motors))

    def advance(self, dt: float) -> None:
        """The player takes records of RECORD bytes for dt seconds, each when `rate` says, and needs
        max_record_bytes in the ring before each (fewer, short of the stream's end, is an underrun)."""
        if self.state != "playing":
            return
        self._owed += self.rate * dt
        need = p.max_record_bytes(self.motors)
        while self._owed >= RECORD and self.state == "playing":
            self._owed -= RECORD
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
            if self.played >= self.total:
                self.state = "finished"
                self.out += p.frame(p.FINISHED, self.expected, self._positions())


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

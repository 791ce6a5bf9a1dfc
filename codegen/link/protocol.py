"""The link protocol between the host and a streaming firmware: frames, their CRC, the firmware's identity.

Both directions use one frame layout (little-endian fields; the CRC high byte first):

    SYNC 0x7E | LEN u8 (payload bytes) | SEQ u8 | TYPE u8 | payload (LEN bytes) | CRC-16 hi | CRC-16 lo

The CRC is CRC-16/CCITT-FALSE (polynomial 0x1021, initial 0xFFFF, no reflection; Python's binascii.crc_hqx)
over LEN, SEQ, TYPE and the payload; sent high byte first, so the CRC over LEN..CRC of a good frame is 0. A
receiver hunts for SYNC, takes the next byte as LEN (over MAX_PAYLOAD: hunt again), and drops a frame whose CRC
fails; there is no escaping (a SYNC inside a frame is data).

Host to firmware; SEQ counts the host's frames (mod 256). The firmware takes a frame in sequence only: SEQ equal
to the one it expects next, which it then counts on. HELLO and ABORT are taken whatever their SEQ.
    DATA   0x01  table stream bytes (codegen/tables/format.py), appended to the ring; LEN 0 is a ping (asks for an ACK)
    HELLO  0x02  a session begins: the firmware expects SEQ + 1 next and, when it is not playing, empties its ring
    START  0x03  play: home (if the machine homes), then play the ring's records from the first
    STATUS 0x04  asks for a STATUS frame
    ABORT  0x05  stop stepping at once
    HOLD   0x06  feed hold (a firmware with machine.feed_hold, codegen/tables/hold.py): slow down to a stop on the path
    RESUME 0x07  go on after a hold or an M0/M1 pause, at the override
    FEED_DOWN 0x08, FEED_UP 0x09  the feed override 10 % lower or higher (10 % to machine.feed_hold.max_override),
                  as the hold keys'

Firmware to host; SEQ is the host sequence number the firmware expects next (every frame acknowledges).
    ACK       0x81  free u16 (ring bytes free after every frame it took), flags u8 (bit 0 REJECTED: the frame
                    was out of sequence or larger than the free space, and was dropped). Sent for every frame
                    whose CRC is good, before any other answer to it; and by the 8051 unasked (a window update,
                    flags 0) once its ring has room for a DATA frame after an ACK that said it had not.
    IDENT     0x82  version u8, identity u32, ring bytes u16, motors u8: the answer to HELLO
    STARTED   0x83  the first record is about to play (after homing)
    FINISHED  0x84  position i32 per motor (net steps since START, after homing): the end marker has played
    UNDERRUN  0x85  position i32 per motor: the ring ran dry while moving; the firmware plays nothing more until
                    reset
    STATUS    0x86  state u8 (STATES), played u32 (stream bytes consumed), fill u16 (ring bytes held), position
                    i32 per motor (while playing: where the current block ends; stopped: exact), then per heater
                    of a firmware that runs them: temperature i16 and target i16 (0.1 degC; target 0: off), then
                    a laser firmware's power u16 (its PWM's counts), then a feed hold firmware's factor u8 (F,
                    0..255: 0 at rest in a hold or a pause; the payload's one odd byte)
    ABORTED   0x87  position i32 per motor: stopped by ABORT; nothing more plays until reset
    HOMING_FAILED 0x88  status u8: the failed axes' bits (low nibble) and the homing phase << 4; nothing more plays
                    until reset
    FAULT     0x89  reason u8 (1 + its index in codegen.heaters.protection.REASONS), heater u8 (its index in the
                    firmware's heaters), position i32 per motor: the thermal protection stopped the machine (every
                    heater off, the steppers stopped and disabled); nothing more plays until reset

The player never reads a record unless the ring holds at least `max_record_bytes(motors)` bytes (the longest
record): fewer while a job plays is an underrun. So the host sends `tail_padding(motors)` zero bytes after the
end marker.
"""

from __future__ import annotations

import binascii
import hashlib
import json
import struct
from dataclasses import dataclass, field

import codegen.tables.format as table_format
from codegen.heaters.protection import REASONS
from codegen.tables.format import LONG_RUN_BYTES, end_marker, long_block_bytes

VERSION = 1
SYNC = 0x7E
HEADER_BYTES = 4  # SYNC, LEN, SEQ, TYPE
CRC_BYTES = 2
OVERHEAD_BYTES = HEADER_BYTES + CRC_BYTES
MAX_PAYLOAD = 250  # what a receiver takes at most; the host's DATA frames are smaller (host.py)
MAX_ANSWER = 32  # the firmware's longest frame payload (STATUS with 4 motors and 2 heaters: 31)

DATA, HELLO, START, STATUS, ABORT, HOLD, RESUME, FEED_DOWN, FEED_UP = range(0x01, 0x0A)
ACK, IDENT, STARTED, FINISHED, UNDERRUN, STATUS_REPLY, ABORTED, HOMING_FAILED, FAULT = range(0x81, 0x8A)
REJECTED = 0x01  # ACK flags
STATES = {0: "idle", 1: "homing", 2: "playing", 3: "finished", 4: "underrun", 5: "aborted", 6: "homing failed",
          7: "fault"}
NAMES = {DATA: "DATA", HELLO: "HELLO", START: "START", STATUS: "STATUS", ABORT: "ABORT", HOLD: "HOLD",
         RESUME: "RESUME", FEED_DOWN: "FEED_DOWN", FEED_UP: "FEED_UP", ACK: "ACK",
         IDENT: "IDENT", STARTED: "STARTED", FINISHED: "FINISHED", UNDERRUN: "UNDERRUN", STATUS_REPLY: "STATUS",
         ABORTED: "ABORTED", HOMING_FAILED: "HOMING_FAILED", FAULT: "FAULT"}


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE: the firmware's per-byte form is x = (crc >> 8) ^ byte; x ^= x >> 4;
    crc = (crc << 8) ^ (x << 12) ^ (x << 5) ^ x (16 bits)."""
    return binascii.crc_hqx(data, crc)


def frame(kind: int, seq: int, payload: bytes = b"") -> bytes:
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"a frame holds at most {MAX_PAYLOAD} payload bytes, not {len(payload)}")
    body = bytes([len(payload), seq & 0xFF, kind]) + payload
    return bytes([SYNC]) + body + crc16(body).to_bytes(2, "big")


@dataclass(frozen=True)
class Frame:
    kind: int
    seq: int
    payload: bytes

    @property
    def name(self) -> str:
        return NAMES.get(self.kind, f"0x{self.kind:02X}")


@dataclass
class Parser:
    """Frames out of a byte stream, as the firmware finds them: hunt for SYNC, then LEN, then the rest; a frame
    whose CRC fails is dropped (counted in `bad`) and the hunt goes on after its SYNC."""

    max_payload: int = MAX_PAYLOAD  # a LEN above this is no frame (the host: the firmware's longest answer)
    buffer: bytearray = field(default_factory=bytearray)
    bad: int = 0

    def feed(self, data: bytes) -> list[Frame]:
        self.buffer += data
        frames = []
        while True:
            start = self.buffer.find(SYNC)
            if start < 0:
                self.buffer.clear()
                return frames
            del self.buffer[:start]
            if len(self.buffer) < 2:
                return frames
            length = self.buffer[1]
            if length > self.max_payload:
                del self.buffer[:1]
                continue
            total = OVERHEAD_BYTES + length
            if len(self.buffer) < total:
                return frames
            body = bytes(self.buffer[1:total])
            if crc16(body) != 0:
                self.bad += 1
                del self.buffer[:1]
                continue
            frames.append(Frame(body[2], body[1], body[3:3 + length]))
            del self.buffer[:total]


def max_record_bytes(motors: int) -> int:
    """The longest record of the table stream: what the player needs in its ring before it reads one."""
    return max(long_block_bytes(motors), LONG_RUN_BYTES)


def tail_padding(motors: int) -> bytes:
    """Zero bytes after the end marker, so that the player finds a whole record's worth in the ring there too."""
    return bytes(max_record_bytes(motors) - len(end_marker(False)))


def firmware_identity(config, f_cpu: int, tick_hz: int) -> int:
    """32 bits naming what a streaming firmware can play: the protocol and table format, the board, the motors
    and their sockets, pulse timing, homing, clocks, heaters, laser, jog keys. The job's program and name do not
    count."""
    canonical = {
        "protocol": VERSION, "tables": [table_format.__doc__.split("\n\n")[0], table_format.REVISION],
        "board": config.board,
        "target": config.target, "motors": [[m.name, m.socket, m.invert_dir] for m in config.motors],
        "step_pulse_us": config.step_pulse_us, "dir_setup_us": config.dir_setup_us,
        "homing": [repr(h) for h in config.homing], "f_cpu": f_cpu, "tick_hz": tick_hz,
    }
    if config.heaters:  # a firmware without heaters keeps the identity it had before them
        canonical["heaters"] = [repr(h) for h in config.heaters]
    if config.laser:  # and one without a laser
        canonical["laser"] = [config.laser.pin, config.laser.prescaler, config.laser.top]
    if config.jog:  # and one without jog keys
        canonical["jog"] = repr(config.jog)
    if config.hold:  # and one without feed hold
        canonical["hold"] = [repr(config.hold), config.hold_override]
    digest = hashlib.sha256(json.dumps(canonical, sort_keys=True).encode()).digest()
    return int.from_bytes(digest[:4], "little")


def positions(payload: bytes, motors: int, offset: int = 0) -> tuple[int, ...]:
    return struct.unpack_from(f"<{motors}i", payload, offset)


@dataclass(frozen=True)
class Ident:
    version: int
    identity: int
    ring_bytes: int
    motors: int

    @staticmethod
    def parse(payload: bytes) -> "Ident":
        return Ident(*struct.unpack("<BIHB", payload[:8]))

    def payload(self) -> bytes:
        return struct.pack("<BIHB", self.version, self.identity, self.ring_bytes, self.motors)


@dataclass(frozen=True)
class Status:
    state: str
    played: int
    fill: int
    position: tuple[int, ...]
    heaters: tuple[tuple[float, float], ...] = ()  # per heater: temperature and target, degC
    laser: int | None = None  # a laser firmware's power, in its PWM's counts
    feed: int | None = None  # a feed hold firmware's factor F (codegen/tables/hold.py F_ONE: 100 %; 0: at rest, held or paused)

    @staticmethod
    def parse(payload: bytes, motors: int) -> "Status":
        state, played, fill = struct.unpack_from("<BIH", payload)
        after = 7 + 4 * motors
        feed = None
        if (len(payload) - after) % 2:  # a feed hold firmware's factor: the one odd byte, last
            feed, payload = payload[-1], payload[:-1]
        words = (len(payload) - after) // 2  # two per heater, then one for a laser
        pairs = struct.unpack_from(f"<{words - words % 2}h", payload, after)
        heaters = tuple((pairs[i] / 10, pairs[i + 1] / 10) for i in range(0, len(pairs) - 1, 2))
        laser = struct.unpack_from("<H", payload, len(payload) - 2)[0] if words % 2 else None
        return Status(STATES.get(state, f"state {state}"), played, fill, positions(payload, motors, 7), heaters,
                      laser, feed)


@dataclass(frozen=True)
class Fault:
    """A FAULT frame: why the thermal protection stopped the machine, which heater, and where the motors are."""

    reason: str  # one of codegen.heaters.protection.REASONS
    heater: int  # its index in the firmware's heaters
    position: tuple[int, ...]

    @staticmethod
    def parse(payload: bytes, motors: int) -> "Fault":
        reason, heater = payload[0], payload[1]
        name = REASONS[reason - 1] if 1 <= reason <= len(REASONS) else f"reason {reason}"
        return Fault(name, heater, positions(payload, motors, 2))

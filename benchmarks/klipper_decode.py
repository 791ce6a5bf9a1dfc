"""Klipper's batch-mode output (out.serial) decoded into every stepper's step times, with numpy.

Our own decoder of Klipper's documented MCU protocol (Klipper's docs/Protocol.md and docs/MCU_Commands.md);
no Klipper code is copied or imported. The data dictionary (out/klipper.dict, plain JSON in batch mode) names
every message id and its parameters. out.serial is a sequence of message blocks:

    length (5..64), sequence (0x10 | n), payload, CRC-16 (2 bytes), sync byte 0x7E

A payload is a run of messages, each its id followed by its parameters, every integer a variable-length
quantity (7 bits a byte, high bit set on all but the last; the first byte's 0x60 bits set means negative);
strings are a length byte and the bytes. The step commands of one stepper (oid), in stream order:

    reset_step_clock oid clock         the stepper's last step clock becomes `clock` (32 bits)
    set_next_step_dir oid dir          the direction of the steps queued after it (1: forward, before inversion)
    queue_step oid interval count add  `count` steps: the first `interval` ticks after the last step, each next
                                       one `add` ticks further apart than the one before

so step k (0-based) of a queue_step is at last + (k + 1) * interval + add * k * (k + 1) / 2, and the last of
them becomes `last`. Clocks are the MCU's (16 MHz here), made 64-bit here. The framing is checked by length,
sequence bits and sync byte; the CRC is not recomputed (a file, not a serial line).
Checked on 2026-11-29 against Klipper's own klippy/parsedump.py text of the Benchy's out.serial, expanded
step by step: every one of the 12.7 M step times and directions equal (tests/benchmarks/test_klipper_steps.py
checks the decoder on a synthetic stream, without Klipper).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SYNC, SEQ_MASK, SEQ_DEST = 0x7E, 0xF0, 0x10
HEADER, TRAILER = 2, 3
MAX_VARINT_BYTES = 5


class DecodeError(ValueError):
    """out.serial does not follow the protocol or the dictionary."""


@dataclass(frozen=True)
class MessageKind:
    name: str
    params: tuple[tuple[str, str], ...]  # (name, format: %u %i %hu %hi %c %s %*s %.*s)

    @property
    def ints_only(self) -> bool:
        return not any(fmt.endswith("s") for _, fmt in self.params)


@dataclass(frozen=True)
class Dictionary:
    kinds: dict[int, MessageKind]  # by message id
    pins: dict[int, str]  # pin number -> name (the "pin" enumeration)
    clock_hz: float

    def id_of(self, name: str) -> int:
        return next(mid for mid, kind in self.kinds.items() if kind.name == name)


def read_dictionary(path: str | Path) -> Dictionary:
    data = json.loads(Path(path).read_text())
    kinds = {}
    for section in ("commands", "responses", "output"):
        for text, mid in data.get(section, {}).items():
            words = text.split()
            params = tuple(tuple(word.split("=", 1)) for word in words[1:] if "=" in word)
            kinds[mid] = MessageKind(words[0] if section != "output" else "#output", params)
    pins = {}
    for name, value in data.get("enumerations", {}).get("pin", {}).items():
        if isinstance(value, int):
            pins[value] = name
            continue
        root = name.rstrip("0123456789")  # a range: "PA0": [first value, count]
        first_index = int(name[len(root):] or 0)
        for i in range(value[1]):
            pins[value[0] + i] = f"{root}{first_index + i}"
    return Dictionary(kinds, pins, float(data["config"]["CLOCK_FREQ"]))


def block_payloads(data: bytes) -> np.ndarray:
    """The payload bytes of every message block, joined (no message spans two blocks)."""
    raw = np.frombuffer(data, dtype=np.uint8)
    starts, pos = [], 0
    while pos < len(data):  # one step a block (~60 bytes each)
        starts.append(pos)
        pos += data[pos]
    starts = np.asarray(starts, dtype=np.int64)
    lengths = raw[starts].astype(np.int64)
    if pos != len(data) or lengths.min(initial=5) < 5:
        raise DecodeError("out.serial: the block lengths do not add up to the file")
    if ((raw[starts + 1] & SEQ_MASK) != SEQ_DEST).any() or (raw[starts + lengths - 1] != SYNC).any():
        raise DecodeError("out.serial: a block without its sequence bits or sync byte")
    sizes = lengths - HEADER - TRAILER
    first = np.repeat(starts + HEADER - np.concatenate([[0], np.cumsum(sizes)[:-1]]), sizes)
    return raw[first + np.arange(int(sizes.sum()))]


def varints(payload: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every variable-length integer of the payload as if all were integers: (value, first byte, last byte).
    Inside a string the values are meaningless; the message walk skips them."""
    last = np.flatnonzero((payload & 0x80) == 0)
    first = np.concatenate([[0], last[:-1] + 1]).astype(np.int64)
    length = np.minimum(last - first + 1, MAX_VARINT_BYTES)
    head = payload[first].astype(np.int64)
    value = np.where((head & 0x60) == 0x60, (head & 0x7F) - 0x80, head & 0x7F)
    for j in range(1, MAX_VARINT_BYTES):
        more = length > j
        value[more] = value[more] * 128 + (payload[first[more] + j] & 0x7F)
    return value, first, last


@dataclass
class Messages:
    """Every message of the stream in order: its id and where its parameters start in `values`."""

    dictionary: Dictionary
    values: np.ndarray  # every integer of the payload (signed, as parsed)
    ids: np.ndarray  # (M,) message id
    at: np.ndarray  # (M,) index in `values` of the message id; the parameters follow it

    def of(self, name: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The messages named `name`: their places in the stream and their integer parameters by name."""
        mid = self.dictionary.id_of(name)
        kind = self.dictionary.kinds[mid]
        where = np.flatnonzero(self.ids == mid)
        params = {}
        for j, (param, fmt) in enumerate(kind.params):
            value = self.values[self.at[where] + 1 + j]
            params[param] = value if fmt in ("%i", "%hi") else value & 0xFFFFFFFF
        return where, params


def parse_messages(dictionary: Dictionary, payload: np.ndarray) -> Messages:
    values, first, last = varints(payload)
    low = min(dictionary.kinds)
    span = np.full(max(dictionary.kinds) - low + 1, -1, dtype=np.int64)  # integers a message takes; -1: strings
    for mid, kind in dictionary.kinds.items():
        span[mid - low] = 1 + len(kind.params) if kind.ints_only else -1
    known = (values >= low) & (values - low < len(span))
    step = np.where(known, span[np.clip(values - low, 0, len(span) - 1)], 0).tolist()
    ids, at, k, count = [], [], 0, len(values)
    while k < count:  # one step a message
        if step[k] > 0:
            ids.append(int(values[k]))
            at.append(k)
            k += step[k]
            continue
        kind = dictionary.kinds.get(int(values[k]))
        if kind is None:
            raise DecodeError(f"out.serial: message id {int(values[k])} is not in the dictionary")
        ids.append(int(values[k]))
        at.append(k)
        k = _after_strings(kind, payload, values, first, last, k)
    return Messages(dictionary, values, np.asarray(ids, np.int64), np.asarray(at, np.int64))


def _after_strings(kind: MessageKind, payload: np.ndarray, values, first, last, k: int) -> int:
    """The index of the integer after a message with string parameters (walked byte by byte)."""
    byte = int(last[k]) + 1
    for _, fmt in kind.params:
        if fmt.endswith("s"):
            byte += 1 + int(payload[byte])
        else:
            byte = int(last[np.searchsorted(first, byte)]) + 1
    return int(np.searchsorted(first, byte))


@dataclass
class StepperSteps:
    name: str  # the printer.cfg section (stepper_x, extruder, ...)
    oid: int
    clock: np.ndarray  # (S,) int64 MCU clock of every step
    dir: np.ndarray  # (S,) +1 / -1 (the dir pin's inversion undone)
    message: np.ndarray  # (S,) the stream index of the queue_step that made it


def stepper_steps(messages: Messages, oid: int, name: str, invert_dir: bool = False) -> StepperSteps:
    """Every step of stepper `oid`, from its queue_step, set_next_step_dir and reset_step_clock messages."""
    q_where, q = messages.of("queue_step")
    d_where, d = messages.of("set_next_step_dir")
    r_where, r = messages.of("reset_step_clock")
    mine = q["oid"] == oid
    q_where, interval, count, add = q_where[mine], q["interval"][mine], q["count"][mine], q["add"][mine]
    d_where, d_dir = d_where[d["oid"] == oid], d["dir"][d["oid"] == oid]
    r_where, r_clock = r_where[r["oid"] == oid], r["clock"][r["oid"] == oid]
    last_dir = np.searchsorted(d_where, q_where) - 1  # the direction in force at each queue_step
    forward = np.where(last_dir >= 0, d_dir[np.maximum(last_dir, 0)], 0) != int(invert_dir)
    span = interval * count + add * (count * (count - 1) // 2)  # ticks from the last step to this one's last
    summed = np.concatenate([[0], np.cumsum(span)])
    resets_before = np.searchsorted(r_where, q_where)  # each reset starts a new stretch of queue_steps
    origin = np.zeros(len(q_where), dtype=np.int64)  # the clock of the last step before each queue_step
    clock_at = 0  # the MCU's step clock starts at 0
    for stretch in range(len(r_where) + 1):  # few: one after each homing move on a real MCU
        if stretch:
            clock_at += (int(r_clock[stretch - 1]) - clock_at + 2**31) % 2**32 - 2**31  # the nearest 64-bit clock
        queued = np.flatnonzero(resets_before == stretch)
        if len(queued):
            origin[queued] = clock_at + summed[queued] - summed[queued[0]]
            clock_at = int(origin[queued[-1]] + span[queued[-1]])
    run = np.repeat(np.arange(len(q_where)), count)
    k = np.arange(int(count.sum()), dtype=np.int64) - np.repeat(np.cumsum(count) - count, count)
    clock = origin[run] + (k + 1) * interval[run] + add[run] * (k * (k + 1) // 2)
    return StepperSteps(name, oid, clock, np.where(forward[run], 1, -1).astype(np.int8), q_where[run])


def homing_end(messages: Messages, steppers: dict[str, StepperSteps], pause_s: float = 0.1) -> int:
    """The clock at which the last homing pass (G28) ends: steps after it are the program's; -1 without
    homing. Each endstop_home that starts a pass names a trsync, which stepper_stop_on_trigger ties to the
    steppers it stops; a pass is the stepper's steps from that clock on in one direction, none `pause_s`
    apart. (Found by clocks: Klipper's batch mode writes a message that needs no clock, as the end of a
    homing pass, when it sends it, which may be after the next moves' steps.)"""
    start_where, start = messages.of("endstop_home")
    _, stops = messages.of("stepper_stop_on_trigger")
    by_oid = {steps.oid: steps for steps in steppers.values()}
    end = -1
    for where, clock, trsync in zip(start_where.tolist(), start["clock"].tolist(), start["trsync_oid"].tolist()):
        if clock == 0:  # the end of a pass: the endstop stops watching
            continue
        for oid in set(stops["oid"][stops["trsync_oid"] == trsync].tolist()) & by_oid.keys():
            steps = by_oid[oid]
            before = steps.clock[steps.message < where]
            near = int(before[-1]) if len(before) else 0  # a 64-bit clock near the pass's start
            first_clock = near + (clock - near + 2**31) % 2**32 - 2**31
            first = int(np.searchsorted(steps.clock, first_clock))
            if first == len(steps.clock):
                continue
            pause = int(pause_s * messages.dictionary.clock_hz)
            turn = (steps.dir[first:] != steps.dir[first]) | (np.diff(steps.clock[first:], prepend=first_clock) > pause)
            last = first + (int(np.argmax(turn[1:])) if turn[1:].any() else len(turn) - 1)
            end = max(end, int(steps.clock[last]))
    return end


def decode(serial: str | Path, dictionary: str | Path, step_pins: dict[str, tuple[str, bool]]) -> \
        tuple[dict[str, StepperSteps], Messages]:
    """Each configured stepper's steps, by its printer.cfg section. `step_pins`: section -> (its step pin,
    whether its dir pin is inverted), from the config; the oids are matched to them by config_stepper."""
    table = read_dictionary(dictionary)
    messages = parse_messages(table, block_payloads(Path(serial).read_bytes()))
    _, config = messages.of("config_stepper")
    by_pin = {pin: (section, invert) for section, (pin, invert) in step_pins.items()}
    steppers = {}
    for oid, pin in zip(config["oid"].tolist(), config["step_pin"].tolist()):
        section, invert = by_pin[table.pins[pin]]
        steppers[section] = stepper_steps(messages, oid, section, invert)
    return steppers, messages

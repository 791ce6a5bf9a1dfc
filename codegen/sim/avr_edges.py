"""The simavr harness's pin records (EDGES.bin, codegen/sim/simavr_harness.c) decoded into step pulses, all at once
or a piece at a time while the harness writes them.

A record is 10 bytes: cycle u64, pin u8, level u8, in cycle order. Pins 0.. are the watched pins (codegen/sim/avr.py
`watched`: STEP and DIR of each motor, then the tool, the enables, the endstops); START_PIN marks each start of the
player's timer, DUTY_LOW_PIN and DUTY_HIGH_PIN a laser's compare register writes (TOP_LOW_PIN and TOP_HIGH_PIN
its TOP register's). An EdgeDecoder carries what a
record's meaning needs of the records before it (each DIR's level, a STEP still high, a DIR change no step has
followed yet), so a run of any length decodes in pieces of bounded size; the slow pins (all but STEP and DIR) and
the timer starts are kept whole: they change a few times a job, not at every step.
"""

from __future__ import annotations

import ctypes
import os
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

EDGE_RECORD = np.dtype([("cycle", "<u8"), ("pin", "u1"), ("level", "u1")])
START_PIN, DUTY_LOW_PIN, DUTY_HIGH_PIN = 0xFD, 0xFE, 0xFF
TOP_LOW_PIN, TOP_HIGH_PIN = 0xFB, 0xFC  # the laser PWM's TOP register (its period)
FALLOC_PUNCH_HOLE = 0x03  # FALLOC_FL_PUNCH_HOLE | FALLOC_FL_KEEP_SIZE (linux/falloc.h)
PAGE = 1 << 16


@dataclass(frozen=True)
class RunPins:
    """What reading a target's edges file needs of its board (codegen/verify/run_reader.py): its clock, the pins'
    names in the file's order (STEP and DIR of each motor, then the tool, then the slow pins), their level after
    reset."""

    f_cpu: int
    cycles_per_tick: int
    start_to_tick0: int  # cycles from a START_PIN record (the player's timer start) to its tick 0
    invert_dir: tuple[bool, ...]
    names: tuple[str, ...]
    tool_on_level: int
    reset_level: int


class PinWave(NamedTuple):
    """One recorded pin's levels: at reset, then each change."""

    initial: int
    cycle: np.ndarray  # (E,) int64
    level: np.ndarray  # (E,) 0 / 1


@dataclass
class Steps:
    """Step pulses in time order (motors in config order within a cycle)."""

    cycle: np.ndarray  # (P,) int64 STEP rising edges
    motor: np.ndarray  # (P,) int64
    dir: np.ndarray  # (P,) +1 / -1: DIR at the rise, invert_dir undone

    @staticmethod
    def empty() -> Steps:
        return Steps(*(np.zeros(0, np.int64) for _ in range(3)))


def _min(a: int | None, values: np.ndarray) -> int | None:
    if not len(values):
        return a
    low = int(values.min())
    return low if a is None else min(a, low)


class EdgeDecoder:
    """Feed it the records in order (`feed`): the step pulses of each piece from cycle `since` on (records before
    it count only for the levels), with the pulse widths and DIR setup times carried over the pieces."""

    def __init__(self, invert_dir: list[bool], slow_names: list[str], since: int = 0, reset_level: int = 0):
        motors = len(invert_dir)
        self.invert = np.asarray(invert_dir, dtype=np.int64)
        self.since, self.reset_level = since, reset_level
        self.dir_level = np.full(motors, reset_level, dtype=np.int64)  # an AVR's pins are low after reset
        self.high_since: list[int | None] = [None] * motors  # a STEP still high: its rise
        self.dir_changed: list[int | None] = [None] * motors  # the latest DIR change no rise has followed yet
        self.width_min: list[int | None] = [None] * motors  # cycles, from `since` on
        self.setup_min: list[int | None] = [None] * motors
        self.slow_names = slow_names  # pins 2 x motors on, by name
        self._slow: list[list[np.ndarray]] = [[] for _ in slow_names]
        self._duty: list[np.ndarray] = []
        self._top: list[np.ndarray] = []
        self._starts: list[np.ndarray] = []
        self._held = np.zeros(0, EDGE_RECORD)  # a register write's low record, its high one not yet read
        self.last_cycle = 0
        self.motor_edges: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # the last piece's, per motor:
        #                                                                  STEP rises, STEP falls, DIR changes

    def feed(self, rec: np.ndarray) -> Steps:
        rec = np.concatenate([self._held, rec]) if len(self._held) else rec
        split = len(rec) and int(rec["pin"][-1]) in (DUTY_LOW_PIN, TOP_LOW_PIN)  # a register write's high record
        self._held, rec = (rec[-1:].copy(), rec[:-1]) if split else (rec[:0], rec)  # is in the next piece: it waits
        if not len(rec):
            return Steps.empty()
        self.last_cycle = int(rec["cycle"][-1])
        order = np.argsort(rec["pin"], kind="stable")  # each pin's records together, in time order
        bounds = np.searchsorted(rec["pin"][order], np.arange(257))
        mine = lambda pin: rec[order[bounds[pin]:bounds[pin + 1]]]  # noqa: E731
        cycles, motors, dirs = [], [], []
        self.motor_edges = []
        for m in range(len(self.invert)):
            step, direction = mine(2 * m), mine(2 * m + 1)
            rise, fall = self._rises_falls(m, step)
            d_cycle = direction["cycle"].astype(np.int64)
            self.motor_edges.append((rise, fall, d_cycle))
            levels = np.concatenate([[self.dir_level[m]], direction["level"].astype(np.int64)])
            level = levels[np.searchsorted(d_cycle, rise, side="right")]
            self.dir_level[m] = levels[-1]
            self._setup(m, rise, d_cycle)
            keep = rise >= self.since
            cycles.append(rise[keep])
            motors.append(np.full(int(keep.sum()), m, dtype=np.int64))
            dirs.append(np.where(level[keep] ^ self.invert[m], 1, -1).astype(np.int64))
        for k in range(len(self.slow_names)):  # (only pieces that have some: a run is read in thousands)
            wave = mine(2 * len(self.invert) + k)
            if len(wave):
                self._slow[k].append(wave)
        starts = mine(START_PIN)["cycle"].astype(np.int64)
        if len(starts):
            self._starts.append(starts[starts >= self.since])
        registers = ((self._duty, DUTY_LOW_PIN, DUTY_HIGH_PIN), (self._top, TOP_LOW_PIN, TOP_HIGH_PIN))
        for writes, low_pin, high_pin in registers:
            low, high = mine(low_pin), mine(high_pin)  # a write's two, in order
            if len(low):
                writes.append(np.stack([low["cycle"].astype(np.int64),
                                        low["level"].astype(np.int64) | high["level"].astype(np.int64) << 8], axis=1))
        cyc, mot, dirs = (np.concatenate(a) for a in (cycles, motors, dirs))
        order = np.lexsort((mot, cyc))
        return Steps(cyc[order], mot[order], dirs[order])

    def _rises_falls(self, m: int, step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Motor m's STEP rises in the piece, the widths of its pulses taken into width_min."""
        cyc, level = step["cycle"].astype(np.int64), step["level"]
        rise, fall = cyc[level == 1], cyc[level == 0]
        if self.high_since[m] is not None:  # high since the piece before
            rise_all = np.concatenate([[self.high_since[m]], rise])
        else:
            rise_all = rise
        n = min(len(rise_all), len(fall))
        widths = fall[:n] - rise_all[:n]
        self.width_min[m] = _min(self.width_min[m], widths[rise_all[:n] >= self.since])
        self.high_since[m] = int(rise_all[n]) if len(rise_all) > n else None
        return rise, fall

    def _setup(self, m: int, rise: np.ndarray, dir_cycles: np.ndarray) -> None:
        """From each DIR change (from `since` on) to the next rise of the same motor: setup_min."""
        changes = dir_cycles[dir_cycles >= self.since]
        if self.dir_changed[m] is not None:
            changes = np.concatenate([[self.dir_changed[m]], changes])
        nxt = np.searchsorted(rise, changes, side="right")
        followed = nxt < len(rise)
        self.setup_min[m] = _min(self.setup_min[m], rise[nxt[followed]] - changes[followed])
        self.dir_changed[m] = int(changes[-1]) if len(changes) and not followed[-1] else None

    def starts(self) -> np.ndarray:
        """Every start of the player's timer from `since` on (cycles)."""
        return np.concatenate(self._starts) if self._starts else np.zeros(0, np.int64)

    def duty(self) -> np.ndarray:
        """(K, 2) each compare register write: cycle, counts."""
        return np.concatenate(self._duty) if self._duty else np.zeros((0, 2), np.int64)

    def forget_duty(self, start: int, upcoming: int) -> None:
        """Drop the compare register's writes from cycle `start` on that come before the last one at or before
        `upcoming`: a level at `upcoming` or later reads none of them (those before `start` stay)."""
        duty = self.duty()
        if len(duty) < 2:
            return
        cycle = duty[:, 0]
        in_force = int(np.searchsorted(cycle, upcoming, side="right")) - 1
        first = int(np.searchsorted(cycle, start, side="left"))
        if in_force > first:
            self._duty = [np.concatenate([duty[:first], duty[in_force:]])]

    def top(self) -> np.ndarray:
        """(K, 2) each TOP register write: cycle, counts."""
        return np.concatenate(self._top) if self._top else np.zeros((0, 2), np.int64)

    def waves(self) -> dict[str, PinWave]:
        """The slow pins' levels, by name (every change, `since` or not)."""
        out = {}
        for name, parts in zip(self.slow_names, self._slow):
            rec = np.concatenate(parts) if parts else np.zeros(0, EDGE_RECORD)
            out[name] = PinWave(self.reset_level, rec["cycle"].astype(np.int64), rec["level"])
        return out


def read_edges(path: Path) -> np.ndarray:
    return np.fromfile(path, dtype=EDGE_RECORD)


class EdgeFile:
    """EDGES.bin read as the harness writes it: whole records only, `chunk` at most at a time. What has been read
    is given back to the file system (a hole punched where the file system can), so the file holds what is yet to
    be read, whatever the run's length; with `keep`, it keeps every byte (it is read again)."""

    def __init__(self, path: Path, chunk: int = 1 << 19, keep: bool = False):
        self.path, self.chunk, self.keep = Path(path), chunk, keep
        self.offset = 0
        self._file = None
        self._punched = 0

    def read(self) -> np.ndarray:
        if self._file is None:
            if not self.path.exists():
                return np.zeros(0, EDGE_RECORD)
            self._file = open(self.path, "rb")
        self._file.seek(self.offset)
        data = self._file.read(self.chunk * EDGE_RECORD.itemsize)
        whole = len(data) - len(data) % EDGE_RECORD.itemsize
        self.offset += whole
        self._punch()
        return np.frombuffer(data[:whole], dtype=EDGE_RECORD)

    def _punch(self) -> None:
        upto = self.offset // PAGE * PAGE
        if self.keep or upto - self._punched < 64 * PAGE:
            return
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.fallocate(self._file.fileno(), FALLOC_PUNCH_HOLE, ctypes.c_long(0), ctypes.c_long(upto))
        except (OSError, AttributeError):  # a file system without holes keeps the bytes: only disk, not memory
            pass
        self._punched = upto

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def size(self) -> int:
        try:
            return os.path.getsize(self.path)
        except OSError:
            return 0

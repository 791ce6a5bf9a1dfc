"""The table stream read back, record by record, as a player reads it (the format: codegen/tables/format.py's
docstring), and compared with the schedule the twin plays: so that verify proves the bytes an image ships, not
only the schedule in memory. Written from the format's description, not from its encoder: a wrong encoder is found
too. A loop per record (a flash table holds tens of thousands), none per step.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np

from codegen.tables.format import block_fields
from codegen.tables.schedule import Schedule

LONG = 0x80
RUNTIME = 0x90  # a long record with master bits 01
TOOL = 0x40
MOST_PROBLEMS = 5
READ_BYTES = 1 << 16  # of a streamed table read at a time


class TableError(ValueError):
    """The bytes are not a table stream (cut short, a record no player reads)."""


@dataclass
class Decoded:
    motors: int
    flags: list[int] = field(default_factory=list)  # per block, as stored (LONG and master bits cleared)
    modulus: list[int] = field(default_factory=list)
    steps: list[list[int]] = field(default_factory=list)
    init: list[list[int]] = field(default_factory=list)  # -1: not stored (a short master; no or every event)
    block_at: list[int] = field(default_factory=list)  # byte offset of each block record
    runtime: list[tuple[int, int, int]] = field(default_factory=list)  # (command, value, the block it precedes)
    runs: list[tuple[int, int, int]] = field(default_factory=list)  # (count, interval, add)
    run_at: list[int] = field(default_factory=list)
    power: dict[int, int] = field(default_factory=dict)  # run index -> PWM counts
    ceiling: dict[int, int] = field(default_factory=dict)  # run index -> F
    final_tool: bool = False


class TableReader:
    """The records of a table stream read from `source` (a binary file) as a player reads them: `read(events)` gives
    those it reads while it plays the next `events` events (the blocks and runs they need, and the runtime, power and
    ceiling records before them), `close()` those after the last event and the end marker. Only the bytes not yet
    read stay in memory; byte offsets and block indices count from the stream's start."""

    def __init__(self, source: BinaryIO, motors: int):
        self.source, self.motors = source, motors
        self.buffer, self.base = b"", 0  # the bytes from stream offset `base` on, read from the source so far
        self.at = 0  # the next record's offset in the stream
        self.event = self.block_end = self.run_end = 0
        self.blocks = self.runs = 0  # records read so far

    def _u(self, at: int, width: int) -> int:
        while at + width > self.base + len(self.buffer):
            more = self.source.read(READ_BYTES)
            if not more:
                raise TableError(f"the table ends inside a record at byte {at}")
            self.buffer = self.buffer[self.at - self.base:] + more  # what is behind the next record goes
            self.base = self.at
        return int.from_bytes(self.buffer[at - self.base:at - self.base + width], "little")

    def _i(self, at: int, width: int) -> int:
        value = self._u(at, width)
        return value - (1 << 8 * width) if value >> (8 * width - 1) else value

    def read(self, events: int) -> Decoded:
        """The records the next `events` events need."""
        out = Decoded(self.motors)
        stop = self.event + events
        while self.event < stop:
            if self.event == self.block_end:
                self._runtime(out)
                if self._block(out):
                    raise TableError(f"the end marker at byte {self.at - 2}, {stop - self.event} events early")
            if self.event == self.run_end:
                self._run(out)
            self.event = min(self.block_end, self.run_end)
        return out

    def close(self) -> Decoded:
        """The runtime records after the last event, the end marker (its tool), and nothing after it."""
        out = Decoded(self.motors)
        self._runtime(out)
        if not self._block(out):
            raise TableError(f"block at byte {out.block_at[-1]} after the last event: the end marker belongs there")
        if self.source.read(1) or self.at < self.base + len(self.buffer):
            raise TableError(f"bytes after the end marker at byte {self.at - 2}")
        return out

    def _runtime(self, out: Decoded) -> None:
        while self._u(self.at, 1) == RUNTIME:
            out.runtime.append((self._u(self.at + 1, 1), self._u(self.at + 2, 2), self.blocks))
            self.at += 4

    def _block(self, out: Decoded) -> bool:
        """The next block record into `out`; True when it is the end marker instead (its tool into `out`)."""
        at, motors = self.at, self.motors
        flags = self._u(at, 1)
        if flags & LONG:
            modulus = self._u(at + 1, 2)
            steps = [self._u(at + 3 + 2 * m, 2) for m in range(motors)]
            init = [self._u(at + 3 + 2 * (motors + m), 2) for m in range(motors)]
            size = 3 + 4 * motors
            if modulus == 0:
                raise TableError(f"block at byte {at}: a long record of modulus 0")
        else:
            modulus = self._u(at + 1, 1)
            if modulus == 0:
                out.final_tool = bool(flags & TOOL)
                self.at += 2
                return True
            master = (flags >> 4) & 3
            if master >= motors:
                raise TableError(f"block at byte {at}: master motor {master} of {motors}")
            slaves = [m for m in range(motors) if m != master]
            steps, init = [0] * motors, [-1] * motors
            steps[master] = modulus
            size = 2 + len(slaves)
            for k, m in enumerate(slaves):
                steps[m] = self._u(at + 2 + k, 1)
            for m in slaves:  # only a Bresenham slave's init is stored (neither 0 steps nor every event)
                if 0 < steps[m] < modulus:
                    init[m] = self._u(at + size, 1)
                    size += 1
        out.flags.append(flags & ~(LONG | 0x30))
        out.modulus.append(modulus)
        out.steps.append(steps)
        out.init.append(init)
        out.block_at.append(at)
        self.at += size
        self.block_end += modulus
        self.blocks += 1
        return False

    def _run(self, out: Decoded) -> None:
        at = self.at
        if self._u(at, 1) == 0 and self._u(at + 1, 2) == 0:  # a power record for the next run
            out.power[len(out.runs)] = self._u(at + 3, 2)
            at += 5
        if self._u(at, 1) == 0 and self._u(at + 1, 2) == 0xFFFF:  # a ceiling record
            out.ceiling[len(out.runs)] = self._u(at + 3, 1)
            at += 4
        count = self._u(at, 1)
        out.run_at.append(at)
        if count:
            out.runs.append((count, self._u(at + 1, 3), self._i(at + 4, 2)))
            at += 6
        else:
            count = self._u(at + 1, 2)
            if count == 0:
                raise TableError(f"run at byte {at}: a long run of count 0")
            out.runs.append((count, self._u(at + 3, 4), self._i(at + 7, 3)))
            at += 10
        self.at = at
        self.run_end += count
        self.runs += 1


def decode(data: bytes, motors: int) -> Decoded:
    """Every record of `data` (a whole table stream, the end marker included), in the order a player reads them:
    at an event that ends the block, its runtime records and the next block; at one that ends the run, a power
    record, a ceiling record and the next run."""
    reader = TableReader(io.BytesIO(data), motors)
    out = Decoded(motors)
    while True:
        reader._runtime(out)
        if reader._block(out):
            break
        while reader.event < reader.block_end:
            if reader.event == reader.run_end:
                reader._run(out)
            reader.event = min(reader.block_end, reader.run_end)
    if reader.at != len(data):
        raise TableError(f"{len(data) - reader.at} bytes after the end marker at byte {reader.at - 2}")
    return out


def differences(decoded: Decoded, schedule: Schedule) -> list[str]:
    """Where the decoded table and the schedule differ (empty: they are the same program), the first few."""
    problems: list[str] = []
    modulus, steps, init = block_fields(schedule)
    if len(decoded.modulus) != schedule.n_blocks or len(decoded.runs) != schedule.n_runs:
        return [f"it holds {len(decoded.modulus)} blocks and {len(decoded.runs)} runs, the plan "
                f"{schedule.n_blocks} and {schedule.n_runs}"]
    got_init = np.array(decoded.init, dtype=np.int64).reshape(-1, decoded.motors)
    block_checks = {
        "flags (directions, tool)": (np.array(decoded.flags, dtype=np.int64), schedule.block_flags()),
        "modulus": (np.array(decoded.modulus, dtype=np.int64), modulus),
        "steps": (np.array(decoded.steps, dtype=np.int64).reshape(-1, decoded.motors), steps),
        "Bresenham start": (got_init, np.where(got_init < 0, -1, init)),
    }
    for what, (got, planned) in block_checks.items():
        differ = np.asarray(got != planned)
        wrong = np.flatnonzero(differ.reshape(len(got), -1).any(axis=1)) if len(got) else []
        problems += [f"block {k} (byte {decoded.block_at[k]}): {what} {got[k].tolist()}, planned "
                     f"{planned[k].tolist()}" for k in wrong[:MOST_PROBLEMS]]
    runs = np.array(decoded.runs, dtype=np.int64).reshape(-1, 3)
    planned = np.stack([schedule.run_count, schedule.run_interval, schedule.run_add], axis=1)
    for k in np.flatnonzero((runs != planned).any(axis=1))[:MOST_PROBLEMS]:
        problems.append(f"run {k} (byte {decoded.run_at[k]}): count, interval, add {runs[k].tolist()}, planned "
                        f"{planned[k].tolist()}")
    for name, got_map, column in (("power", decoded.power, schedule.run_power),
                                  ("ceiling", decoded.ceiling, schedule.run_ceiling)):
        want = {int(k): int(v) for k, v in enumerate(column) if v >= 0} if len(column) else {}
        if got_map != want:
            first = min(set(got_map.items()) ^ set(want.items()))[0]
            problems.append(f"run {first}: {name} {got_map.get(first)}, planned {want.get(first)}")
    runtime = [(int(c), int(v), int(b)) for c, v, b in zip(schedule.runtime_command, schedule.runtime_value,
                                                           schedule.runtime_block)]
    if decoded.runtime != runtime:
        k = next((k for k, (a, b) in enumerate(zip(decoded.runtime, runtime)) if a != b),
                 min(len(decoded.runtime), len(runtime)))
        problems.append(f"runtime record {k} (command, value, block): "
                        f"{decoded.runtime[k] if k < len(decoded.runtime) else None}, planned "
                        f"{runtime[k] if k < len(runtime) else None}")
    if decoded.final_tool != schedule.final_tool:
        problems.append(f"the end marker leaves the tool {'on' if decoded.final_tool else 'off'}, planned "
                        f"{'on' if schedule.final_tool else 'off'}")
    return problems

"""The table stream every player reads: short records where the numbers are small, and rate runs that go on across
block starts (8 KB of 8051 code memory holds the whole job; each byte is a byte less to send down a serial line).

Semantics are codegen/tables/schedule.py's: a block lasts exactly `modulus` events (a dwell is a block of `events`
step-less events), and the runs form one sequence over all events, independent of the blocks. The player reads
one stream in the order it needs the records: at an event that starts a block and a run, the
block record comes first. Little-endian.

Block record, first byte `flags`: bit m (m < 4) motor m moves in + direction, bits 4-5 the master motor (short
form), bit 6 the tool is on, and
    bit 7 clear   short form: modulus u8 (1..255), then steps u8 of every motor but the master (which steps at
                  every event), in motor order, then init u8 of each of them whose steps are neither 0 nor the
                  modulus (a Bresenham slave; the others step at no event or at every one) (motors + 1 to
                  2 * motors bytes)
                  modulus 0: the end of the program; nothing follows and the tool takes bit 6 (2 bytes)
    bit 7 (LONG)  long form:  modulus u16, steps u16 x motors, init u16 x motors       (3 + 4 * motors bytes)
                  (a dwell, whose motors all stand, is always long)
Runtime record (a setting of the heaters or the fan, at its place in the program), before the block record it
precedes (several in a row allowed), or before the end marker: flags 0x90 (LONG, and master bits 01, which no long
block uses), then command u8 and value u16                                          (4 bytes)
    RT_TARGET_HOTEND, RT_TARGET_BED   the heater's target in 0.1 degC (0: off)
    RT_FAN                            the fan's duty, 0..255
    RT_WAIT                           hold until the heaters of the mask (bit 0 hot end, bit 1 bed) have settled
                                      (the player stops its timer and restarts it at tick 0, codegen/tables/schedule.py)
    RT_PAUSE                          M0/M1 (value 0): the player parks before the block until the resume key
                                      (an image with feed_hold, codegen/tables/hold.py)
The player reads them at the event that reads the block record after them, and hands each to the runtime.
Run record, first byte `count`:
    1..255        short form: interval u24 (16.8 ticks), add i16 (8.8 ticks)           (6 bytes)
    0             long form:  count u16, interval u32 (24.8), add i24 (16.8)           (10 bytes)
Power record (a laser's, codegen/tables/laser.py), before the run record whose first event takes it: a long run of count
0, then the PWM's counts u16: 0, 0, 0, counts u16                                       (5 bytes)
Ceiling record (the feed override's headroom, codegen/tables/headroom.py), after the power record of the same run, if
any: a long run of count 0xFFFF, then the factor's ceiling u8: 0, 0xFF, 0xFF, F        (4 bytes)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codegen.tables.schedule import RUNTIME_NAMES, TOOL_BIT, Schedule

REVISION = 2  # of the records' layout, raised whenever a player must change to read them (2: packed inits)
LONG_BIT = 0x80
MASTER_SHIFT = 4
RUNTIME_FLAGS = LONG_BIT | 1 << MASTER_SHIFT  # a long record with master bits 01: a runtime record
RUNTIME_BYTES = 4
MAX_MOTORS = 4  # direction bits 0..3 of the flags
SHORT_RUN_BYTES = 6
LONG_RUN_BYTES = 10
POWER_BYTES = 5
CEILING_BYTES = 4
CEILING_MARK = 0xFFFF  # the long run count of a ceiling record (no run counts that many: MAX_COUNT)
MAX_LONG_MODULUS = 0xFFFF
_HEX = [f"0x{b:02X}" for b in range(256)]


@dataclass
class CompactTable:
    data: bytes
    block_offsets: np.ndarray  # (B,) byte offset of every block record
    block_long: np.ndarray  # (B,) bool
    run_long: np.ndarray  # (R,) bool
    runtime_offsets: np.ndarray  # (T,) byte offset of every runtime record
    power_offsets: np.ndarray  # (P,) byte offset of every power record
    ceiling_offsets: np.ndarray  # (C,) byte offset of every ceiling record

    def counts(self) -> dict[str, int]:
        return {"short_blocks": int((~self.block_long).sum()), "long_blocks": int(self.block_long.sum()),
                "short_runs": int((~self.run_long).sum()), "long_runs": int(self.run_long.sum())}


def short_block_bytes(motors: int) -> int:
    """The longest short block record (every slave a Bresenham one)."""
    return 2 * motors


def _slave_order(master: np.ndarray, motors: int) -> np.ndarray:
    """(B, motors - 1): a short block's slaves, every motor but its master, in motor order."""
    slave = np.arange(motors)[None, :] != master[:, None]
    return np.argsort(~slave, axis=1, kind="stable")[:, :motors - 1]


def _bresenham_slaves(modulus: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """(B, motors - 1) of short blocks: which slaves (in `_slave_order`) store their init."""
    master = np.argmax(steps, axis=1)
    slave_steps = np.take_along_axis(steps, _slave_order(master, steps.shape[1]), axis=1)
    return (slave_steps > 0) & (slave_steps != modulus[:, None])


def _block_bytes(modulus: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Every block record's bytes."""
    motors = steps.shape[1]
    short = 1 + motors + _bresenham_slaves(modulus, steps).sum(axis=1)
    return np.where(_long_blocks(modulus, steps), long_block_bytes(motors), short)


def long_block_bytes(motors: int) -> int:
    return 3 + 4 * motors


def _le(values: np.ndarray, width: int) -> np.ndarray:
    v = np.asarray(values, dtype=np.int64)
    return np.stack([(v >> (8 * i)) & 0xFF for i in range(width)], axis=-1).astype(np.uint8)


def block_fields(schedule: Schedule) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(modulus, steps, init) as the player counts them: a dwell's modulus is its event count."""
    events = schedule.events_per_block()
    dwell = ~np.any(schedule.block_steps > 0, axis=1)
    modulus = np.where(dwell, events, schedule.block_modulus)
    init = np.where(dwell[:, None], 0, schedule.block_init)
    if np.any(events != modulus):
        raise ValueError("a moving block of the compact stream must last exactly `modulus` events")
    return modulus, schedule.block_steps, init


def _long_blocks(modulus: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Blocks that need the long record: a modulus over a byte, a dwell (no motor moves), or no motor stepping
    at every event (the short record's master does)."""
    return (modulus > 0xFF) | (steps.max(axis=1, initial=0) != modulus)


def _long_runs(count: np.ndarray, interval: np.ndarray, add: np.ndarray) -> np.ndarray:
    return (count > 0xFF) | (interval >= 1 << 24) | (add < -(1 << 15)) | (add >= 1 << 15)


def stream_bytes(schedule: Schedule) -> int:
    """len(encode(schedule).data), without encoding."""
    modulus, steps, _ = block_fields(schedule)
    long_runs = int(_long_runs(schedule.run_count, schedule.run_interval, schedule.run_add).sum())
    return (int(_block_bytes(modulus, steps).sum())
            + long_runs * LONG_RUN_BYTES + (schedule.n_runs - long_runs) * SHORT_RUN_BYTES
            + RUNTIME_BYTES * schedule.n_runtime + POWER_BYTES * schedule.n_power
            + CEILING_BYTES * schedule.n_ceiling + 2)


def encode(schedule: Schedule) -> CompactTable:
    motors = len(schedule.motors)
    if motors > MAX_MOTORS:
        raise ValueError(f"the compact stream holds at most {MAX_MOTORS} motors")
    schedule.validate()
    modulus, steps, init = block_fields(schedule)
    if np.any(modulus < 1) or np.any(modulus > MAX_LONG_MODULUS):
        raise ValueError("block modulus out of the compact stream's range")
    flags = schedule.block_flags()
    master = np.argmax(steps, axis=1)
    block_long = _long_blocks(modulus, steps)
    width = long_block_bytes(motors)
    blocks = np.zeros((schedule.n_blocks, width), dtype=np.uint8)
    short = np.flatnonzero(~block_long)
    blocks[:, 0] = flags | np.where(block_long, LONG_BIT, master << MASTER_SHIFT)
    blocks[short, 1] = modulus[short]
    # A short block's slaves' steps, then the inits of its Bresenham slaves, packed to the front.
    order = _slave_order(master[short], motors)
    slave_init = np.take_along_axis(init[short], order, axis=1)
    stored = _bresenham_slaves(modulus[short], steps[short])
    blocks[short[:, None], 2 + np.arange(motors - 1)[None, :]] = np.take_along_axis(steps[short], order, axis=1)
    packed = np.argsort(~stored, axis=1, kind="stable")  # the stored inits first, in slave order
    blocks[short[:, None], motors + 1 + np.arange(motors - 1)[None, :]] = np.where(
        np.take_along_axis(stored, packed, axis=1), np.take_along_axis(slave_init, packed, axis=1), 0)
    blocks[block_long, 1:3] = _le(modulus[block_long], 2)
    for m in range(motors):
        blocks[block_long, 3 + 2 * m:5 + 2 * m] = _le(steps[block_long, m], 2)
        blocks[block_long, 3 + 2 * (motors + m):5 + 2 * (motors + m)] = _le(init[block_long, m], 2)
    block_len = _block_bytes(modulus, steps)

    count, interval, add = schedule.run_count, schedule.run_interval, schedule.run_add
    run_long = _long_runs(count, interval, add)
    runs = np.zeros((schedule.n_runs, LONG_RUN_BYTES), dtype=np.uint8)
    rs = ~run_long
    runs[rs, 0] = count[rs]
    runs[rs, 1:4] = _le(interval[rs], 3)
    runs[rs, 4:6] = _le(add[rs] & 0xFFFF, 2)
    runs[run_long, 1:3] = _le(count[run_long], 2)
    runs[run_long, 3:7] = _le(interval[run_long], 4)
    runs[run_long, 7:10] = _le(add[run_long] & 0xFFFFFF, 3)
    run_len = np.where(run_long, LONG_RUN_BYTES, SHORT_RUN_BYTES)

    runtime = np.zeros((schedule.n_runtime, RUNTIME_BYTES), dtype=np.uint8)
    runtime[:, 0] = RUNTIME_FLAGS
    runtime[:, 1] = schedule.runtime_command
    runtime[:, 2:4] = _le(schedule.runtime_value, 2)

    power = np.zeros((schedule.n_power, POWER_BYTES), dtype=np.uint8)
    power[:, 3:5] = _le(schedule.run_power[schedule.run_power >= 0], 2)

    ceiling = np.zeros((schedule.n_ceiling, CEILING_BYTES), dtype=np.uint8)
    ceiling[:, 1:3] = _le(np.full(schedule.n_ceiling, CEILING_MARK), 2)
    ceiling[:, 3] = schedule.run_ceiling[schedule.run_ceiling >= 0]

    order, key = _record_order(schedule)
    size = max(width, LONG_RUN_BYTES)
    matrix = np.zeros((len(key), size), dtype=np.uint8)
    nt, nb, npw, nc = schedule.n_runtime, schedule.n_blocks, schedule.n_power, schedule.n_ceiling
    matrix[:nt, :RUNTIME_BYTES] = runtime
    matrix[nt:nt + nb, :width] = blocks
    matrix[nt + nb:nt + nb + npw, :POWER_BYTES] = power
    matrix[nt + nb + npw:nt + nb + npw + nc, :CEILING_BYTES] = ceiling
    matrix[nt + nb + npw + nc:, :LONG_RUN_BYTES] = runs
    length = np.concatenate([np.full(nt, RUNTIME_BYTES), block_len, np.full(npw, POWER_BYTES),
                             np.full(nc, CEILING_BYTES), run_len])[order]
    matrix = matrix[order]
    body = matrix[np.arange(size)[None, :] < length[:, None]]
    data = body.astype(np.uint8).tobytes() + end_marker(schedule.final_tool)
    offsets = np.empty(len(key), dtype=np.int64)
    offsets[order] = np.cumsum(length) - length
    return CompactTable(data, offsets[nt:nt + nb], block_long, run_long, offsets[:nt],
                        offsets[nt + nb:nt + nb + npw], offsets[nt + nb + npw:nt + nb + npw + nc])


def _record_order(schedule: Schedule) -> tuple[np.ndarray, np.ndarray]:
    """Records in the order the player needs them, runtime records first, then blocks, power records, ceiling
    records, runs: by the event that starts them (a runtime record: its block's first event, or after the last
    event), a runtime record before a block before a power record before a ceiling record before a run (order),
    and the sort key (2 x that event, + 1 for a power or ceiling record or a run)."""
    events = schedule.events_per_block()
    block_first = np.cumsum(events) - events
    run_first = np.cumsum(schedule.run_count) - schedule.run_count
    runtime_first = np.append(block_first, int(events.sum()))[schedule.runtime_block]
    power_first = run_first[schedule.run_power >= 0] if schedule.n_power else np.zeros(0, dtype=np.int64)
    ceiling_first = run_first[schedule.run_ceiling >= 0] if schedule.n_ceiling else np.zeros(0, dtype=np.int64)
    key = np.concatenate([2 * runtime_first, 2 * block_first, 2 * power_first + 1, 2 * ceiling_first + 1,
                          2 * run_first + 1])
    return np.argsort(key, kind="stable"), key


def record_events(schedule: Schedule) -> tuple[np.ndarray, np.ndarray]:
    """Every record of the stream in order (the end marker aside): the event it starts, and its bytes."""
    modulus, steps, _ = block_fields(schedule)
    block_len = _block_bytes(modulus, steps)
    run_len = np.where(_long_runs(schedule.run_count, schedule.run_interval, schedule.run_add), LONG_RUN_BYTES,
                       SHORT_RUN_BYTES)
    order, key = _record_order(schedule)
    sizes = [np.full(schedule.n_runtime, RUNTIME_BYTES), block_len, np.full(schedule.n_power, POWER_BYTES),
             np.full(schedule.n_ceiling, CEILING_BYTES), run_len]
    return key[order] >> 1, np.concatenate(sizes)[order]


def end_marker(final_tool: bool) -> bytes:
    """The record that ends the program (what `encode` puts last)."""
    return bytes([TOOL_BIT if final_tool else 0, 0])


def table_lines(table: CompactTable, schedule: Schedule, line_bytes: int) -> list[dict]:
    """table.c's lines of at most `line_bytes`, with a comment line where each block starts."""
    flags = schedule.block_flags()
    marks = {int(o): f"block {b}: flags 0x{int(flags[b]):02X}{' (long)' if table.block_long[b] else ''}"
             for b, o in enumerate(table.block_offsets)}
    data = table.data
    for k, o in enumerate(table.runtime_offsets):
        marks[int(o)] = f"runtime: {RUNTIME_NAMES[int(schedule.runtime_command[k])]} {int(schedule.runtime_value[k])}"
    for o, counts in zip(table.power_offsets, schedule.run_power[schedule.run_power >= 0]):
        marks[int(o)] = f"laser power: {int(counts)} counts"
    for o, ceiling in zip(table.ceiling_offsets, schedule.run_ceiling[schedule.run_ceiling >= 0]):
        marks[int(o)] = f"feed ceiling: F {int(ceiling)}"
    marks[len(data) - 2] = "end marker"
    cuts = sorted(set(marks) | {0, len(data)})
    lines = []
    for a, b in zip(cuts, cuts[1:]):
        for i in range(a, b, line_bytes):
            comment = f"0x{a:04X}: {marks[a]}" if i == a and a in marks else ""
            lines.append({"comment": comment, "text": ", ".join(_HEX[x] for x in data[i:min(i + line_bytes, b)])})
    return lines

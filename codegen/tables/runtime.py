"""A program's heater and fan settings as the tables' runtime records (codegen/tables/format.py, codegen/tables/schedule.py).

The flash image of a board with heater outputs plays them at their place: each setting (codegen/toolpath/segments.py
gathers them as (item index, Output) while it flattens the program) comes before the block of the first segment
at or after its item (a wait's own dwell, see segments.WAIT_REST_S), or before the end marker after the last
move. A heater setting becomes a target record (0.1 degC), M109 / M190 a target and a WAIT record; M106 / M107
a fan record (duty 0..255). A wait for 0 (off) is no wait. Settings of a heater the image does not run are left
out (the build warns).

The player reads a block's runtime records in the interrupt before its first event: `block_extra_ticks` is what
they add to that event's gap (compress's `needed`), runtime_record_cycles each (targets/<mcu>.yaml).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from codegen.tables.schedule import HEATER_COMMANDS, RT_FAN, RT_PAUSE, RT_WAIT, WAIT_MASKS, Schedule
from codegen.toolpath.items import Output

FAN_FULL = 255  # the fan record's duty at M106 S255


@dataclass(frozen=True)
class RuntimeRecords:
    """Records in program order: the item index each comes before, its command and value."""

    item: np.ndarray  # (T,) int64, non-decreasing
    command: np.ndarray  # (T,) RT_*
    value: np.ndarray  # (T,) u16

    def __len__(self) -> int:
        return len(self.item)


def played_outputs(heaters: tuple[str, ...], fan: bool) -> tuple[str, ...]:
    """The outputs whose settings an image plays: its heaters, and the fan when it drives one."""
    return heaters + (("fan",) if fan else ())


def runtime_records(settings: list[tuple[int, Output]], played: tuple[str, ...]) -> RuntimeRecords:
    """The records of `settings` (item index, Output) for the outputs in `played`."""
    rows = []
    for index, out in settings:
        if out.name not in played:
            continue
        if out.name == "pause":
            rows.append((index, RT_PAUSE, 0))
            continue
        if out.name == "fan":
            rows.append((index, RT_FAN, min(FAN_FULL, max(0, round(out.value * FAN_FULL)))))
            continue
        rows.append((index, HEATER_COMMANDS[out.name], round(out.value * 10)))  # deci-degrees
        if out.wait and out.value > 0:  # M109 S0 turns it off: nothing to wait for
            rows.append((index, RT_WAIT, WAIT_MASKS[out.name]))
    item, command, value = (np.array(c, dtype=np.int64) for c in zip(*rows)) if rows else \
        (np.zeros(0, dtype=np.int64),) * 3
    return RuntimeRecords(item, command, value)


def records_before(records: RuntimeRecords, block_item: np.ndarray, previous_item: int) -> np.ndarray:
    """How many records come before each block: those after the previous block's item, up to its own
    (`block_item`: each block's segment's item; `previous_item`: the item of the block before the first, -1)."""
    before = np.concatenate([[previous_item], block_item[:-1]])
    return np.searchsorted(records.item, block_item, "right") - np.searchsorted(records.item, before, "right")


def block_extra_ticks(records: RuntimeRecords, block_item: np.ndarray, previous_item: int, cycles: int,
                      tick_hz: int, f_cpu: int) -> np.ndarray | None:
    """The ticks each block's first event needs more for the runtime records before it (None: no record)."""
    if not len(records):
        return None
    count = records_before(records, block_item, previous_item)
    return np.ceil(count * cycles * tick_hz / f_cpu).astype(np.int64)


def with_runtime(schedule: Schedule, records: RuntimeRecords, segment_item: np.ndarray) -> Schedule:
    """The whole program's schedule with its records placed (`segment_item`: every segment's item index)."""
    block_item = segment_item[schedule.block_segment]
    block = np.searchsorted(block_item, records.item, "left")  # the first block at or after the setting
    return replace(schedule, runtime_block=block.astype(np.int64), runtime_command=records.command,
                   runtime_value=records.value)


def window_runtime(schedule: Schedule, records: RuntimeRecords, segment_item: np.ndarray, prior_item: int,
                   last: bool) -> Schedule:
    """One window's schedule with its records (those after `prior_item`, the item of the block before it, up to
    its last block's; the last window's: all the rest, after its blocks those before the end marker)."""
    block_item = segment_item[schedule.block_segment]
    end = np.inf if last or not len(block_item) else block_item[-1]
    mine = (records.item > prior_item) & (records.item <= end)
    return with_runtime(schedule, RuntimeRecords(records.item[mine], records.command[mine], records.value[mine]),
                        segment_item)


def runtime_cycles(target) -> int:
    """CPU cycles one runtime record adds to the interrupt that reads it (targets/<mcu>.yaml)."""
    return int(target.mcu_data["runtime_record_cycles"])

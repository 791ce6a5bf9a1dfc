"""A stream's table bytes proven as verify proves a flash image's (codegen/verify/shipped.py): the file the host link
sends its DATA frames from, decoded window by window as a player reads it (codegen/tables/decode.py, written from
the format's description, not from its encoder) and held against each window's schedule as the twin plays it. The
decoder keeps only the bytes not yet read: a print of any length.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from pathlib import Path

import numpy as np

from codegen.tables.decode import TableError, TableReader, differences
from codegen.tables.schedule import Schedule

MOST_PROBLEMS = 5


class StreamTableCheck:
    """`window` for each final window in order (its schedule as the table stream carries it), then `close`."""

    def __init__(self, path: Path, motors: int):
        self.file = open(path, "rb")
        self.reader = TableReader(self.file, motors)
        self.windows = 0
        self.planned_runtime: deque = deque()  # (command, value, block of the stream) not yet matched ...
        self.read_runtime: deque = deque()  # ... on either side
        self.blocks = 0  # the planned blocks of the windows so far
        self.problems: list[str] = []
        self.broken = False  # the bytes stopped being a table stream: nothing after it is compared

    def window(self, schedule: Schedule, events: int) -> None:
        if self.broken or len(self.problems) >= MOST_PROBLEMS:
            return
        try:
            decoded = self.reader.read(events)
        except TableError as exc:
            self._broken(exc)
            return
        self.read_runtime.extend(decoded.runtime)
        self.planned_runtime.extend(zip(schedule.runtime_command.tolist(), schedule.runtime_value.tolist(),
                                        (schedule.runtime_block + self.blocks).tolist()))
        self._match_runtime()
        empty = np.zeros(0, dtype=np.int64)
        bare = dataclasses.replace(schedule, runtime_command=empty, runtime_value=empty, runtime_block=empty)
        decoded.runtime, decoded.final_tool = [], bare.final_tool  # runtime records are matched across windows
        self.problems += [f"window {self.windows}: {p}" for p in differences(decoded, bare)]
        self.windows += 1
        self.blocks += schedule.n_blocks

    def close(self, final_tool: bool = False) -> list[str]:
        """The problems: where the bytes are not the plan's, or no table stream at all."""
        if not self.broken and len(self.problems) < MOST_PROBLEMS:
            try:
                end = self.reader.close()
                self.read_runtime.extend(end.runtime)
                self._match_runtime()
                if self.planned_runtime or self.read_runtime:
                    self.problems.append(f"runtime records: the stream holds {list(self.read_runtime)[:3]} beyond "
                                         f"the plan's, the plan {list(self.planned_runtime)[:3]} beyond the stream's")
                if end.final_tool != final_tool:
                    self.problems.append(f"the end marker leaves the tool {'on' if end.final_tool else 'off'}")
            except TableError as exc:
                self._broken(exc)
        self.file.close()
        return [f"the streamed table is not the plan's: {p}" for p in self.problems[:MOST_PROBLEMS]]

    def _match_runtime(self) -> None:
        """Runtime records in order on both sides: a record at the end of a window may be read with the next."""
        while self.planned_runtime and self.read_runtime:
            planned, read = self.planned_runtime.popleft(), self.read_runtime.popleft()
            if planned != read:
                self.problems.append(f"runtime record (command, value, block) {list(read)}, planned {list(planned)}")

    def _broken(self, exc: TableError) -> None:
        self.problems.append(f"window {self.windows}: not a table stream: {exc}")
        self.broken = True

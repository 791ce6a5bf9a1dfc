"""Schedule: the tables the player runs, and their byte encoding.

The motion is a sequence of *blocks*. A block moves every motor by a fixed number of steps in a fixed
direction; its motors are coupled by Bresenham over `modulus` master events. The timing of its events is a
list of *rate runs* `(interval, add, count)`.

Player semantics (the firmware and the twin implement exactly this):

    pos = 0                                  # timer position in 1/256 tick, tick 0 = timer start
    for block in blocks:
        set DIR pins from block.dirs, the tool pin from block.tool
        acc[m] = init[m] for every motor     # 0 <= init < modulus, chosen by the host
        for (interval, add, count) in block.runs:
            repeat count times:
                pos += interval              # an *event* happens at tick floor(pos / 256)
                for every motor m:           # Bresenham
                    acc[m] -= steps[m]
                    if acc[m] < 0: acc[m] += modulus; motor m steps once in its direction
                interval += add

`interval` is unsigned 24.8 fixed point ticks, `add` signed 16.8 (24 bits), `count` 1..65535. A block whose motors all
have 0 steps is a dwell (its events only pass time). Bresenham counts fit 16-bit signed arithmetic:
`modulus <= MAX_MODULUS`, every `steps[m] <= modulus` and `init[m] < modulus`. After i events motor m has made
`ceil((i * steps[m] - init[m]) / modulus)` steps, exactly `steps[m]` after `modulus` events.

Byte stream (little-endian), per block:
    flags   u8   bit m: motor m moves in + direction (DIR pin level before inversion); bit 6: tool on
    nruns   u16  number of runs; 0 marks the end of the program (flags then give the final tool state)
    modulus u16
    steps   u16 x motors
    init    u16 x motors
    runs    nruns x (interval u32, add i24, count u16)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FRAC_BITS = 8
FRAC_ONE = 1 << FRAC_BITS
MAX_MODULUS = 32767
MAX_COUNT = 65535
MAX_INTERVAL = (1 << 32) - 1  # 24.8 fixed point: just under 2**24 ticks
MAX_ADD = (1 << 23) - 1
TOOL_BIT = 0x40
RUN_BYTES = 9


@dataclass
class Schedule:
    motors: tuple[str, ...]
    tick_hz: int
    block_dirs: np.ndarray  # (B, M) int8, +1 / -1
    block_steps: np.ndarray  # (B, M) int64, >= 0
    block_modulus: np.ndarray  # (B,) int64, >= 1
    block_init: np.ndarray  # (B, M) int64, Bresenham accumulators at the block's start
    block_tool: np.ndarray  # (B,) bool
    block_runs: np.ndarray  # (B + 1,) int64: runs of block b are run_* [block_runs[b]:block_runs[b + 1]]
    block_segment: np.ndarray  # (B,) int64, the Segments index the block comes from
    run_interval: np.ndarray  # (R,) int64, 24.8 fixed point ticks
    run_add: np.ndarray  # (R,) int64, 16.8 fixed point ticks
    run_count: np.ndarray  # (R,) int64
    final_tool: bool = False
    # Events of every block when runs may run on across block starts (the compact tables of the 8051); None:
    # every block has runs of its own, block_runs partitions them and gives the counts.
    block_events: np.ndarray | None = None

    @property
    def runs_cross_blocks(self) -> bool:
        return self.block_events is not None

    def events_per_block(self) -> np.ndarray:
        if self.block_events is not None:
            return self.block_events
        counts = np.zeros(self.n_blocks, dtype=np.int64)
        if self.n_runs:
            run_block = np.repeat(np.arange(self.n_blocks), np.diff(self.block_runs))
            np.add.at(counts, run_block, self.run_count)
        return counts

    @property
    def n_blocks(self) -> int:
        return len(self.block_modulus)

    @property
    def n_runs(self) -> int:
        return len(self.run_count)

    def header_bytes(self) -> int:
        return 5 + 4 * len(self.motors)

    def table_bytes(self) -> int:
        """Size of the encoded stream, end marker included."""
        if self.runs_cross_blocks:
            from codegen.tables import stream_bytes  # the compact stream (its module imports this one)
            return stream_bytes(self)
        return self.n_blocks * self.header_bytes() + self.n_runs * RUN_BYTES + 3

    def block_flags(self) -> np.ndarray:
        bits = (self.block_dirs > 0).astype(np.int64) << np.arange(len(self.motors))[None, :]
        return bits.sum(axis=1) | np.where(self.block_tool, TOOL_BIT, 0)

    def validate(self) -> None:
        """Raise ValueError when a field is out of the encodable range (a bug in the compressor)."""
        problems = []
        if np.any(self.block_modulus < 1) or np.any(self.block_modulus > MAX_MODULUS):
            problems.append("block modulus out of range")
        if np.any(self.block_steps < 0) or np.any(self.block_steps > self.block_modulus[:, None]):
            problems.append("block steps out of range")
        if np.any(self.block_init < 0) or np.any(self.block_init >= self.block_modulus[:, None]):
            problems.append("block init out of range")
        if np.any(self.run_count < 1) or np.any(self.run_count > MAX_COUNT):
            problems.append("run count out of range")
        if np.any(self.run_interval < 0) or np.any(self.run_interval > MAX_INTERVAL):
            problems.append("run interval out of range")
        if np.any(np.abs(self.run_add) > MAX_ADD):
            problems.append("run add out of range")
        if np.any(np.diff(self.block_runs) > 0xFFFF):
            problems.append("too many runs in a block")
        if self.block_events is not None and int(self.block_events.sum()) != int(self.run_count.sum()):
            problems.append("the blocks' events and the runs' events differ")
        if problems:
            raise ValueError("; ".join(problems))

    def encode(self) -> bytes:
        """The byte stream described in the module docstring (vectorised)."""
        if self.runs_cross_blocks:
            raise ValueError("runs that cross block starts need the compact encoding (codegen.tables)")
        self.validate()
        motors = len(self.motors)
        n_runs = np.diff(self.block_runs)
        header = np.zeros((self.n_blocks, self.header_bytes()), dtype=np.uint8)
        header[:, 0] = self.block_flags()
        header[:, 1:3] = _le(n_runs, 2)
        header[:, 3:5] = _le(self.block_modulus, 2)
        for m in range(motors):
            header[:, 5 + 2 * m: 7 + 2 * m] = _le(self.block_steps[:, m], 2)
            header[:, 5 + 2 * (motors + m): 7 + 2 * (motors + m)] = _le(self.block_init[:, m], 2)
        runs = np.zeros((self.n_runs, RUN_BYTES), dtype=np.uint8)
        runs[:, 0:4] = _le(self.run_interval, 4)
        runs[:, 4:7] = _le(self.run_add & 0xFFFFFF, 3)
        runs[:, 7:9] = _le(self.run_count, 2)
        # Interleave: block b's header is followed by its runs.
        sizes = self.header_bytes() + RUN_BYTES * n_runs
        out = np.zeros(int(sizes.sum()) + 3, dtype=np.uint8)
        block_at = (np.cumsum(sizes) - sizes).astype(np.int64)
        out[block_at[:, None] + np.arange(self.header_bytes())[None, :]] = header
        run_block = np.repeat(np.arange(self.n_blocks), n_runs)
        run_rank = np.arange(self.n_runs) - self.block_runs[run_block]
        run_at = (block_at[run_block] + self.header_bytes() + RUN_BYTES * run_rank).astype(np.int64)
        out[run_at[:, None] + np.arange(RUN_BYTES)[None, :]] = runs
        out[-3] = TOOL_BIT if self.final_tool else 0
        return out.tobytes()

    def block_offsets(self) -> np.ndarray:
        """Byte offset of every block in the stream (for comments in generated sources)."""
        sizes = self.header_bytes() + RUN_BYTES * np.diff(self.block_runs)
        return (np.cumsum(sizes) - sizes).astype(np.int64)


def _le(values: np.ndarray, width: int) -> np.ndarray:
    v = np.asarray(values, dtype=np.int64)
    return np.stack([(v >> (8 * i)) & 0xFF for i in range(width)], axis=-1).astype(np.uint8)

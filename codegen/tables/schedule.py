"""Schedule: the tables the player runs (their bytes: codegen/tables/format.py).

The motion is a sequence of *blocks*. A block moves every motor by a fixed number of steps in a fixed
direction; its motors are coupled by Bresenham over `modulus` master events. Event times come from one
sequence of *rate runs* `(interval, add, count)` over all events, whatever the blocks: a run goes on across
block starts.

Player semantics (both firmwares and the twin implement exactly this):

    pos = 0                                  # timer position in 1/256 tick, tick 0 = the player's first tick
    runs = iter(runs)
    for block in blocks:
        set DIR pins from block.dirs, the tool pin from block.tool
        acc[m] = init[m] for every motor     # 0 <= init < modulus, chosen by the host
        repeat block.events times:           # modulus events (a dwell: its own count)
            if the run is used up: (interval, add, count) = next(runs)
            pos += interval                  # an *event* happens at tick floor(pos / 256)
            for every motor m:               # Bresenham
                acc[m] -= steps[m]
                if acc[m] < 0: acc[m] += modulus; motor m steps once in its direction
            interval += add

Runtime settings (heater targets, the fan, temperature waits: `runtime_*`) come before a block (or, at block
index B, before the end): the player hands them to the runtime at the event that loads that block, and they
change no pulse. A WAIT holds the player there: it stops its timer after that event and, once the heaters of its
mask have settled, restarts it at tick 0 with pos at that event's fraction of a tick (pos mod 256): the events
after a wait are timed from the wait's event as if from tick 0. The twin plays the events as if no hold came.

Laser power (an image with a PWM laser, codegen/tables/laser.py): a power record before a rate run (`run_power` >= 0)
sets the PWM's counts at the run's first event: the player reads it with the run, and writes it to the PWM with
that event's STEP edge. Power changes no pulse.

Feed override above 100 % (an image with feed_hold, codegen/tables/headroom.py): a ceiling record before a rate run
(`run_ceiling` >= 0) caps the feed factor from the run's first event on. Ceilings change no pulse either.

`interval` is unsigned 24.8 fixed point ticks, `add` signed 16.8 (24 bits), `count` 1..65534 (65535 marks a
ceiling record). A block whose motors all have 0 steps is a dwell (its events only pass time).
`modulus <= MAX_MODULUS`, every `steps[m] <= modulus` and `init[m] < modulus`. After i events motor m has made
`ceil((i * steps[m] - init[m]) / modulus)` steps, exactly `steps[m]` after `modulus` events.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from codegen.motion.blocks import MAX_MODULUS

FRAC_BITS = 8
FRAC_ONE = 1 << FRAC_BITS
MAX_COUNT = 65534  # a long run's count 0xFFFF is a ceiling record's mark (codegen/tables/format.py)
MAX_INTERVAL = (1 << 32) - 1  # 24.8 fixed point: just under 2**24 ticks
MAX_ADD = (1 << 23) - 1
TOOL_BIT = 0x40
MAX_POWER = 0xFFFF  # a power record's PWM counts, u16
# Runtime commands (codegen/tables/format.py's runtime record) and their values.
RT_TARGET_HOTEND, RT_TARGET_BED, RT_FAN, RT_WAIT = 0, 1, 2, 3  # 0.1 degC; 0.1 degC; duty 0..255; heater mask
RT_PAUSE = 4  # M0/M1: the player parks before the block until the resume key (value 0; codegen/tables/hold.py)
RUNTIME_NAMES = ("target hotend", "target bed", "fan", "wait", "pause")
HEATER_COMMANDS = {"hotend": RT_TARGET_HOTEND, "bed": RT_TARGET_BED}
WAIT_MASKS = {"hotend": 1, "bed": 2}


@dataclass
class Schedule:
    motors: tuple[str, ...]
    tick_hz: int
    block_dirs: np.ndarray  # (B, M) int8, +1 / -1
    block_steps: np.ndarray  # (B, M) int64, >= 0
    block_modulus: np.ndarray  # (B,) int64, >= 1
    block_init: np.ndarray  # (B, M) int64, Bresenham accumulators at the block's start
    block_tool: np.ndarray  # (B,) bool
    block_events: np.ndarray  # (B,) int64: events of every block (a moving block's: its modulus)
    block_segment: np.ndarray  # (B,) int64, the Segments index the block comes from
    run_interval: np.ndarray  # (R,) int64, 24.8 fixed point ticks
    run_add: np.ndarray  # (R,) int64, 16.8 fixed point ticks
    run_count: np.ndarray  # (R,) int64
    final_tool: bool = False
    runtime_block: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # (T,) 0..B, in order
    runtime_command: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # (T,) RT_*
    runtime_value: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # (T,) u16
    # (R,) a laser's PWM counts set at each run's first event, or -1 (no record); empty: no laser
    run_power: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    # (R,) the feed factor's ceiling from each run's first event on (codegen/tables/hold.py F), or -1; empty: none
    run_ceiling: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def events_per_block(self) -> np.ndarray:
        return self.block_events

    @property
    def n_blocks(self) -> int:
        return len(self.block_modulus)

    @property
    def n_runtime(self) -> int:
        return len(self.runtime_block)

    def waits(self) -> np.ndarray:
        """The runtime records that hold the player (RT_WAIT), as indices into runtime_*."""
        return np.flatnonzero(self.runtime_command == RT_WAIT)

    @property
    def n_runs(self) -> int:
        return len(self.run_count)

    @property
    def n_power(self) -> int:
        """Power records (a laser's PWM counts, before the runs whose run_power is >= 0)."""
        return int(np.count_nonzero(self.run_power >= 0))

    @property
    def n_ceiling(self) -> int:
        """Ceiling records (the feed override's headroom, before the runs whose run_ceiling is >= 0)."""
        return int(np.count_nonzero(self.run_ceiling >= 0))

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
        block, command, value = self.runtime_block, self.runtime_command, self.runtime_value
        if np.any(np.diff(block) < 0) or np.any(block < 0) or np.any(block > self.n_blocks) \
                or np.any((value < 0) | (value > 0xFFFF)) or np.any((command < 0) | (command > RT_PAUSE)):
            problems.append("runtime records out of range or out of order")
        if len(self.run_power) not in (0, self.n_runs) or np.any(self.run_power > MAX_POWER):
            problems.append("power records out of range")
        if len(self.run_ceiling) not in (0, self.n_runs) or np.any(self.run_ceiling > 0xFF):
            problems.append("ceiling records out of range")
        if int(self.block_events.sum()) != int(self.run_count.sum()):
            problems.append("the blocks' events and the runs' events differ")
        if problems:
            raise ValueError("; ".join(problems))


def in_force(schedule: Schedule, records: np.ndarray, before: int) -> np.ndarray:
    """(E,) at every event, the latest of the runs' `records` (run_power or run_ceiling: >= 0 where a run has one)
    at or before it; `before` until the first."""
    events = int(schedule.run_count.sum())
    if not np.any(records >= 0):
        return np.full(events, before, dtype=np.int64)
    set_at = np.full(events, -1, dtype=np.int64)
    run_first = np.cumsum(schedule.run_count) - schedule.run_count
    has = records >= 0
    set_at[run_first[has]] = np.flatnonzero(has)
    last = np.maximum.accumulate(set_at)
    return np.where(last >= 0, records[np.maximum(last, 0)], before)


def split_runs(schedule: Schedule, starts: np.ndarray) -> tuple[Schedule, np.ndarray]:
    """The schedule with a run starting at each of `starts` (sorted events; a run split there goes on with the
    same times), and the index of the run each of them starts. A split's second part has no power or ceiling
    record of its own."""
    n, interval, add = schedule.run_count, schedule.run_interval, schedule.run_add
    run_first = np.cumsum(n) - n
    first = np.union1d(run_first, starts)  # every run's first event, the splits' included
    parent = np.searchsorted(run_first, first, side="right") - 1
    offset = first - run_first[parent]
    count = np.diff(np.append(first, int(n.sum())))
    fresh = offset > 0

    def carried(records: np.ndarray) -> np.ndarray:
        return records if not len(records) else np.where(fresh, -1, records[parent])

    out = replace(schedule, run_interval=interval[parent] + offset * add[parent], run_add=add[parent].copy(),
                  run_count=count, run_power=carried(schedule.run_power), run_ceiling=carried(schedule.run_ceiling))
    return out, np.searchsorted(first, starts)

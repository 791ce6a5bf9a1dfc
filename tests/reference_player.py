"""Plain-Python, event-by-event readings of the player semantics (slow; tests only): `play` from a Schedule's arrays
(codegen/tables/schedule.py, the runs one sequence over all events, each block taking its events in turn), `play_stream`
from the bytes of the compact record stream (codegen/tables/format.py), the way the firmware reads them."""

from codegen.tables.schedule import FRAC_BITS, Schedule


def event_ticks(schedule: Schedule) -> list[int]:
    """The tick of every event: the runs one after the other, pos += interval, interval += add."""
    ticks, pos = [], 0
    for r in range(schedule.n_runs):
        interval = int(schedule.run_interval[r])
        for _ in range(int(schedule.run_count[r])):
            pos += interval
            ticks.append(pos >> FRAC_BITS)
            interval += int(schedule.run_add[r])
    return ticks


def play(schedule: Schedule) -> list[tuple[int, int, int]]:
    """(tick, motor, dir) of every pulse: each block takes its events from the runs' sequence in turn."""
    pulses = []
    ticks = iter(event_ticks(schedule))
    for b, events in enumerate(schedule.events_per_block()):
        n = int(schedule.block_modulus[b])
        steps = [int(s) for s in schedule.block_steps[b]]
        dirs = [int(d) for d in schedule.block_dirs[b]]
        acc = [int(a) for a in schedule.block_init[b]]
        for _ in range(int(events)):
            tick = next(ticks)
            for m, d in enumerate(steps):
                acc[m] -= d
                if acc[m] < 0:
                    acc[m] += n
                    pulses.append((tick, m, dirs[m]))
    return pulses


class _Reader:
    def __init__(self, data: bytes):
        self.data, self.at = data, 0

    def u(self, width: int) -> int:
        value = int.from_bytes(self.data[self.at:self.at + width], "little")
        self.at += width
        return value

    def i(self, width: int) -> int:
        value = self.u(width)
        return value - (1 << 8 * width) if value >> (8 * width - 1) else value


def _next_run(read, power: list | None, event: int, ceiling: list | None = None) -> tuple[int, int, int]:
    """The next rate run (count, interval, add), the power records before it going to `power` and the ceiling
    records to `ceiling`."""
    while True:
        count = read.u(1)
        if count:
            return count, read.u(3), read.i(2)
        count = read.u(2)
        if count == 0xFFFF:  # a long run of count 0xFFFF: a ceiling record
            factor = read.u(1)
            if ceiling is not None:
                ceiling.append((event, factor))
            continue
        if count:
            return count, read.u(4), read.i(3)
        counts = read.u(2)  # a long run of count 0: a power record
        if power is not None:
            power.append((event, counts))


def play_stream(data: bytes, motors: int, runtime: list | None = None, power: list | None = None,
                ceiling: list | None = None) \
        -> tuple[list[tuple[int, int, int]], list[int], bool]:
    """(tick, motor, dir) of every pulse, the tool flag of every event and the final tool state, from the compact
    stream: a block lasts `modulus` events; a short block's master steps at every event; the runs follow one
    another over all events; at an event that starts a block and a run, the block record comes first. Runtime
    records (flags 0x90) go to `runtime` as (the events played before them, command, value); power records (a long
    run of count 0, then counts u16) to `power` as (the event that takes them, counts); ceiling records (a long run
    of count 0xFFFF, then F u8) to `ceiling` as (the event that takes them, F)."""
    read = _Reader(data)
    pulses, tools = [], []
    pos = interval = add = run_left = 0
    while True:
        flags = read.u(1)
        if flags == 0x90:
            command, value = read.u(1), read.u(2)
            if runtime is not None:
                runtime.append((len(tools), command, value))
            continue
        if flags & 0x80:
            modulus = read.u(2)
            steps = [read.u(2) for _ in range(motors)]
            acc = [read.u(2) for _ in range(motors)]
        else:
            modulus = read.u(1)
            if modulus == 0:
                return pulses, tools, bool(flags & 0x40)
            master = flags >> 4 & 3
            slaves = [m for m in range(motors) if m != master]
            steps, acc = [modulus] * motors, [0] * motors
            for m in slaves:
                steps[m] = read.u(1)
            for m in slaves:
                if 0 < steps[m] < modulus:
                    acc[m] = read.u(1)
        dirs = [1 if flags >> m & 1 else -1 for m in range(motors)]
        for _ in range(modulus):
            if run_left == 0:
                run_left, interval, add = _next_run(read, power, len(tools), ceiling)
            else:
                interval += add
            run_left -= 1
            pos += interval
            tools.append(bool(flags & 0x40))
            for m in range(motors):
                acc[m] -= steps[m]
                if acc[m] < 0:
                    acc[m] += modulus
                    pulses.append((pos >> FRAC_BITS, m, dirs[m]))

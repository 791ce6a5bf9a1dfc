"""A plain-Python, event-by-event reading of the player semantics in codegen/schedule.py (slow; tests only)."""

from codegen.schedule import Schedule


def event_ticks(schedule: Schedule) -> list[int]:
    """The tick of every event: the runs one after the other, pos += interval, interval += add."""
    ticks, pos = [], 0
    for r in range(schedule.n_runs):
        interval = int(schedule.run_interval[r])
        for _ in range(int(schedule.run_count[r])):
            pos += interval
            ticks.append(pos >> 8)
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

"""A plain-Python, event-by-event reading of the player semantics in codegen/schedule.py (slow; tests only)."""

from codegen.schedule import Schedule


def play(schedule: Schedule) -> list[tuple[int, int, int]]:
    """(tick, motor, dir) of every pulse."""
    pulses = []
    pos = 0
    for b in range(schedule.n_blocks):
        n = int(schedule.block_modulus[b])
        steps = [int(s) for s in schedule.block_steps[b]]
        dirs = [int(d) for d in schedule.block_dirs[b]]
        acc = [int(a) for a in schedule.block_init[b]]
        for r in range(int(schedule.block_runs[b]), int(schedule.block_runs[b + 1])):
            interval = int(schedule.run_interval[r])
            for _ in range(int(schedule.run_count[r])):
                pos += interval
                for m, d in enumerate(steps):
                    acc[m] -= d
                    if acc[m] < 0:
                        acc[m] += n
                        pulses.append((pos >> 8, m, dirs[m]))
                interval += int(schedule.run_add[r])
    return pulses

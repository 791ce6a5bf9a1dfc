"""The twin predicts exactly what the player semantics say: the compact stream's (codegen/tables/format.py), where a
block lasts `modulus` events and the rate runs go on across block starts."""

import numpy as np

import codegen.tables.format as tables
from codegen.tables.schedule import Schedule
from codegen.tables.twin import predict
from tests.reference_player import play, play_stream


def schedule(blocks, runs, motors=("x", "y")):
    """blocks: (dirs, steps, modulus[, init]) lasting `modulus` events each (a dwell: (dirs, zeros, events));
    runs: (interval, add, count), one sequence over all events."""
    events = [b[2] for b in blocks]
    return Schedule(
        motors=motors, tick_hz=2_000_000,
        block_dirs=np.array([b[0] for b in blocks], dtype=np.int8),
        block_steps=np.array([b[1] for b in blocks], dtype=np.int64),
        block_modulus=np.array([b[2] for b in blocks], dtype=np.int64),
        block_init=np.array([b[3] if len(b) > 3 else [b[2] >> 1] * len(b[1]) for b in blocks], dtype=np.int64),
        block_tool=np.zeros(len(blocks), bool),
        block_segment=np.arange(len(blocks), dtype=np.int64),
        run_interval=np.array([r[0] for r in runs], dtype=np.int64),
        run_add=np.array([r[1] for r in runs], dtype=np.int64),
        run_count=np.array([r[2] for r in runs], dtype=np.int64),
        block_events=np.array(events, dtype=np.int64),
    )


def test_bresenham_slave_and_fractional_ticks():
    s = schedule([((1, -1), (5, 3), 5)], [(100 * 256 + 128, 0, 5)])
    p = predict(s)
    assert p.event_tick.tolist() == [100, 201, 301, 402, 502]
    y = p.motor == 1
    assert p.tick[y].tolist() == [100, 301, 502]  # ceil((3 i - 2) / 5) steps after event i
    assert set(p.dir[y].tolist()) == {-1}
    assert p.final_positions().tolist() == [5, -3]


def test_add_changes_the_interval_after_each_event():
    s = schedule([((1, 1), (3, 0), 3)], [(1000 * 256, -100 * 256, 3)])
    assert predict(s).event_tick.tolist() == [1000, 1900, 2700]


def test_a_run_goes_on_across_block_starts():
    """One accelerating run over two blocks and a dwell: the interval keeps adding where a block starts."""
    s = schedule([((1, 1), (2, 1), 2, (0, 1)), ((1, 1), (0, 0), 2), ((-1, 1), (3, 3), 3, (0, 2))],
                 [(1000 * 256, 10 * 256, 7)])
    p = predict(s)
    assert p.event_tick.tolist() == [1000, 2010, 3030, 4060, 5100, 6150, 7210]
    assert p.event_block.tolist() == [0, 0, 1, 1, 2, 2, 2]
    assert p.final_positions().tolist() == [-1, 4]


def test_random_schedules_match_the_reference_players():
    """The twin, the schedule's plain reading and the stream's bytes read back all give the same pulses."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        blocks = []
        for _ in range(rng.integers(1, 6)):
            n = int(rng.integers(1, 300))
            if rng.random() < 0.15:  # a dwell
                blocks.append((tuple(int(d) for d in rng.choice([-1, 1], 3)), (0, 0, 0), n))
                continue
            steps = (n, int(rng.integers(0, n + 1)), int(rng.integers(0, n + 1)))
            init = tuple(int(i) for i in rng.integers(0, n, 3))
            blocks.append((tuple(int(d) for d in rng.choice([-1, 1], 3)), tuple(rng.permutation(steps)), n, init))
        left, runs = sum(b[2] for b in blocks), []
        while left:
            c = int(rng.integers(1, min(left, 400) + 1))
            runs.append((int(rng.integers(300 * 256, 5000 * 256)), int(rng.integers(-200, 200)), c))
            left -= c
        s = schedule(blocks, runs, motors=("x", "y", "z"))
        p = predict(s)
        got = list(zip(p.tick.tolist(), p.motor.tolist(), p.dir.tolist()))
        assert got == play(s)
        assert got == play_stream(tables.encode(s).data, 3)[0]

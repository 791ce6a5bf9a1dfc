"""The twin predicts exactly what the player semantics say."""

import numpy as np

from codegen.schedule import Schedule
from codegen.twin import predict
from tests.reference_player import play


def schedule(blocks, runs, motors=("x", "y")):
    """blocks: (dirs, steps, modulus, n_runs[, init]); runs: (interval, add, count)."""
    n_runs = [b[3] for b in blocks]
    return Schedule(
        motors=motors, tick_hz=16_000_000,
        block_dirs=np.array([b[0] for b in blocks], dtype=np.int8),
        block_steps=np.array([b[1] for b in blocks], dtype=np.int64),
        block_modulus=np.array([b[2] for b in blocks], dtype=np.int64),
        block_init=np.array([b[4] if len(b) > 4 else [b[2] >> 1] * len(b[1]) for b in blocks], dtype=np.int64),
        block_tool=np.zeros(len(blocks), bool),
        block_runs=np.concatenate([[0], np.cumsum(n_runs)]).astype(np.int64),
        block_segment=np.arange(len(blocks), dtype=np.int64),
        run_interval=np.array([r[0] for r in runs], dtype=np.int64),
        run_add=np.array([r[1] for r in runs], dtype=np.int64),
        run_count=np.array([r[2] for r in runs], dtype=np.int64),
    )


def test_bresenham_slave_and_fractional_ticks():
    s = schedule([((1, -1), (5, 3), 5, 1)], [(100 * 256 + 128, 0, 5)])
    p = predict(s)
    assert p.event_tick.tolist() == [100, 201, 301, 402, 502]
    y = p.motor == 1
    assert p.tick[y].tolist() == [100, 301, 502]  # ceil((3 i - 2) / 5) steps after event i
    assert set(p.dir[y].tolist()) == {-1}
    assert p.final_positions().tolist() == [5, -3]


def test_add_changes_the_interval_after_each_event():
    s = schedule([((1, 1), (3, 0), 3, 1)], [(1000 * 256, -100 * 256, 3)])
    assert predict(s).event_tick.tolist() == [1000, 1900, 2700]


def test_random_schedules_match_the_reference_player():
    rng = np.random.default_rng(3)
    for _ in range(20):
        blocks, runs = [], []
        for _ in range(rng.integers(1, 6)):
            n = int(rng.integers(1, 40))
            steps = (n, int(rng.integers(0, n + 1)), int(rng.integers(0, n + 1)))
            counts = []
            left = n
            while left:
                c = int(rng.integers(1, left + 1))
                counts.append(c)
                left -= c
            init = tuple(int(i) for i in rng.integers(0, n, 3))
            blocks.append((tuple(int(d) for d in rng.choice([-1, 1], 3)), tuple(rng.permutation(steps)), n,
                           len(counts), init))
            runs += [(int(rng.integers(300 * 256, 5000 * 256)), int(rng.integers(-200, 200)), c) for c in counts]
        s = schedule(blocks, runs, motors=("x", "y", "z"))
        p = predict(s)
        got = list(zip(p.tick.tolist(), p.motor.tolist(), p.dir.tolist()))
        assert got == play(s)

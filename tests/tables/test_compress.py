"""Rate runs: within the timing window of the plan, never closer than the player allows, compact."""

import math

import numpy as np

from codegen.motion.stepgen import generate
from codegen.tables.compress import TimingWindow, compress, spread
from codegen.tables.format import stream_bytes
from codegen.tables.twin import predict
from codegen.toolpath.items import Arc, Toolpath
from tests.helpers import SRC, machine, planned, point, polyline

TICK = 16_000_000
MIN_GAP = 200
BLOCK_GAP = 400


def compressed(toolpath, **kw):
    kin, segments, steps, p = planned(toolpath, max_event_rate=TICK / (1.25 * MIN_GAP))
    events = generate(segments, p, kin, steps, max_gap=1.0)
    return events, compress(events, kin.motors, TICK, MIN_GAP, BLOCK_GAP, **kw)


def test_spread_pushes_events_apart_like_the_loop():
    t = np.array([5.0, 6.0, 6.5, 30.0, 30.0, 31.0])
    expect, last = [], 0.0
    for x in t:
        last = max(x, last + 4.0)
        expect.append(last)
    assert np.allclose(spread(t, 4.0), expect)


def test_every_event_within_its_window_and_gap():
    rng = np.random.default_rng(1)
    pts = np.cumsum(rng.uniform(-5, 5, size=(60, 2)), axis=0)
    events, c = compressed(polyline(pts, feed=120))
    err = np.abs(c.emitted_ticks - c.ideal_ticks)
    assert np.all(err <= c.window_ticks)
    gaps = np.diff(np.concatenate([[0], c.emitted_ticks]))
    assert np.all(gaps >= MIN_GAP)
    assert np.all(gaps[events.block_first[:-1]] >= BLOCK_GAP)
    assert np.array_equal(predict(c.schedule).event_tick, c.emitted_ticks)
    window = TimingWindow()
    assert np.all(c.window_ticks <= window.max_us * 1e-6 * TICK)


def test_long_straight_line_is_a_handful_of_runs():
    events, c = compressed(polyline([(0, 0), (200, 0)], feed=100))
    assert len(events.time) == 16000
    assert c.schedule.n_blocks == 1
    assert c.schedule.n_runs <= 40
    assert stream_bytes(c.schedule) <= 400


def test_circle_block_per_chord_and_exact_totals():
    r = 20.0
    arc = Arc(point(r, 0), point(r, 0), (0.0, 0.0), r, 0.0, 2 * math.pi, 30.0, True, SRC)
    events, c = compressed(Toolpath(point(r, 0), [arc]))
    p = predict(c.schedule)
    assert p.final_positions().tolist() == [0, 0]
    assert int((p.motor == 0).sum()) == 6400  # x: 20 -> -20 -> 20 mm at 80 steps/mm
    assert int((p.motor == 1).sum()) == 6400
    assert c.schedule.n_blocks == len(events.block_modulus) > 100


def test_pushed_events_catch_up_within_every_motors_rate():
    """A block start that needs more time than the plan leaves before it pushes its event; the events after it
    catch up no faster than the motors may step (not at the player's own pace)."""
    mach = machine(x={"vmax": 100.0}, y={"vmax": 100.0})  # 8000 steps/s: 2000 ticks a step, near the limit
    kin, segments, steps, p = planned(polyline([(0, 0), (10, 0.05), (20, 0.1), (30, 0.15)], feed=100), mach)
    events = generate(segments, p, kin, steps, max_gap=1.0)
    block_gap = 3000  # longer than the planned gap at every block start
    c = compress(events, kin.motors, TICK, MIN_GAP, block_gap, max_rate=kin.limits.max_rate)
    assert np.any(c.ideal_ticks - events.time * TICK > 500)  # the block starts were pushed
    pulses = predict(c.schedule)
    for m in range(2):
        t = pulses.tick[pulses.motor == m] / TICK
        if len(t) > 8:
            assert 7 / np.min(t[7:] - t[:-7]) <= kin.limits.max_rate[m]
    # Catching up at the player's pace would overspeed x.
    fast = compress(events, kin.motors, TICK, MIN_GAP, block_gap)
    t = predict(fast.schedule).tick[predict(fast.schedule).motor == 0] / TICK
    assert 7 / np.min(t[7:] - t[:-7]) > kin.limits.max_rate[0]

"""What a simulated jog session must show, for both targets: the pulses made before the player's timer started
(jog mode), split into moves, checked against the jog plan (codegen/motion/jog.py) and the motors' limits."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codegen.sim.keys import KeyPress
from codegen.tables.motor_checks import AccelCheck, RateCheck

# A session that goes through every direction and speed change (seconds from reset; the 8051's display needs
# its first 30 ms). Levels: 0 at power-up, + at 0.20 and 0.48, - while x- moves at 0.60: x- slows down.
SCRIPT = [
    KeyPress("x+", 0.04, 0.16),
    KeyPress("speed+", 0.20, 0.23),
    KeyPress("y+", 0.25, 0.35),
    KeyPress("x+y+", 0.38, 0.46),
    KeyPress("speed+", 0.48, 0.50),
    KeyPress("x-", 0.52, 0.66),
    KeyPress("speed-", 0.60, 0.62),
    KeyPress("x-y-", 0.69, 0.76),
    KeyPress("y-", 0.79, 0.84),
    KeyPress("x+y-", 0.87, 0.92),
    KeyPress("x-y+", 0.95, 1.00),
    KeyPress("x+", 1.03, 1.08),  # x+ and y+ together: the x+y+ diagonal
    KeyPress("y+", 1.03, 1.08),
    KeyPress("start", 1.12, 1.16),
]
# Each move's way per jogged motor (x, y) and a level it cruises at.
MOVES = [((1, 0), 0), ((0, 1), 1), ((1, 1), 1), ((-1, 0), 2), ((-1, -1), 1), ((0, -1), 1), ((1, -1), 1),
         ((-1, 1), 1), ((1, 1), 1)]
FINAL_LEVEL = 1
TICK_TOLERANCE = 1  # a jog step comes 0 or 1 tick after its tick (the timer's poll loop)


@dataclass
class Move:
    ways: tuple[int, ...]  # per jogged motor: +1, -1, 0
    ticks: np.ndarray  # the master's step times (ticks)


def jog_pulses(trace, plan, f_cpu: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per jogged motor: (CPU cycles, +-1) of every step before the player's timer started."""
    before = trace.step_cycle < trace.timer_start_cycle
    return [(trace.step_cycle[before & (trace.step_motor == m)], trace.step_dir[before & (trace.step_motor == m)])
            for m in plan.motors]


def moves(pulses, plan, f_cpu: int) -> list[Move]:
    """The session's moves: steps of the same motors the same ways, apart by at most the longest interval."""
    clocks = f_cpu // plan.tick_hz
    times = sorted({int(c) for cycles, _ in pulses for c in cycles})
    gap = max(plan.ramp[:1] + plan.cruise) + 2
    out, start = [], 0
    t = np.array(times, dtype=np.int64) // clocks
    for i in range(1, len(t) + 1):
        if i == len(t) or t[i] - t[i - 1] > gap:
            span = set(times[start:i])
            ways = []
            for cycles, dirs in pulses:
                mine = dirs[np.isin(cycles, list(span))]
                assert len(set(mine.tolist())) <= 1, "a motor changes direction within a move"
                ways.append(int(mine[0]) if len(mine) else 0)
            out.append(Move(tuple(ways), t[start:i]))
            start = i
    return out


def check_move(move: Move, plan, level: int, tolerance: int = TICK_TOLERANCE) -> None:
    """Every interval is a ramp entry or a cruise interval (a late step would make one longer and the next
    shorter); the move starts up the ramp from rest and ends down it (or at a level slower than its first
    entry); it cruises at `level`'s. `tolerance`: ticks a step may be late (more with interrupts on)."""
    iv = np.diff(move.ticks)
    table = np.array(sorted(set(plan.ramp) | set(plan.cruise)))
    off = np.abs(iv[:, None] - table[None, :]).min(axis=1)
    assert off.max(initial=0) <= tolerance, f"intervals off the tables: {iv[off > tolerance]}"
    n = len(iv) // 2
    for end, way in ((iv[:n], "up"), (iv[::-1][:n], "down")):  # from rest up the ramp, to rest down it
        k = 0
        while k < min(n, len(plan.ramp)) and abs(end[k] - plan.ramp[k]) <= tolerance:
            k += 1
        flat = [c for c, top in zip(plan.cruise, plan.top) if top == 0]  # levels slower than the ramp's start
        assert n == 0 or k >= 1 or np.abs(end[0] - np.array(flat + [-9])).min() <= tolerance, \
            f"a move does not start {way} the ramp"
    cruise = plan.cruise[level]
    assert np.count_nonzero(np.abs(iv - cruise) <= tolerance) >= 3, f"no cruise at {cruise} ticks"


def check_limits(pulses, plan, f_cpu: int) -> tuple[float, float]:
    """codegen.tables.motor_checks on each jogged motor's pulses: (the worst rate ratio, the worst acceleration ratio)."""
    rate = accel = 0.0
    for cycles, dirs in pulses:
        t = cycles / f_cpu
        r, a = RateCheck(plan.max_rate), AccelCheck(plan.max_accel)
        over = r.add(t)[0]
        assert len(over) == 0, f"over the rate limit: {r.worst:.3f}"
        late = a.add(t, dirs, np.zeros(0), np.zeros(0), last=True)[0]
        assert len(late) == 0, f"over the acceleration limit: {a.worst:.3f}"
        rate, accel = max(rate, r.worst), max(accel, a.worst)
    return rate, accel


def check_session(trace, plan, f_cpu: int) -> dict:
    """The whole SCRIPT session: positions, moves, directions, levels and limits; returns figures."""
    pulses = jog_pulses(trace, plan, f_cpu)
    net = [int(d.sum()) for _, d in pulses]
    assert trace.jog_positions == net, f"firmware counts {trace.jog_positions}, pulses {net}"
    found = moves(pulses, plan, f_cpu)
    assert [m.ways for m in found] == [w for w, _ in MOVES]
    for move, (_, level) in zip(found, MOVES):
        check_move(move, plan, level)
    rate, accel = check_limits(pulses, plan, f_cpu)
    return {"positions": net, "moves": len(found), "steps": sum(len(c) for c, _ in pulses), "rate_ratio": rate,
            "accel_ratio": accel}

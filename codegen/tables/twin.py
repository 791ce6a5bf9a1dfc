"""The twin: a numpy model of the player's integer arithmetic that predicts every pulse of the image.

It reads only the Schedule (what the tables say), never the plan, and follows the semantics documented in
codegen/tables/schedule.py to the bit: 24.8 fixed-point event times, `interval += add`, Bresenham with
per-block accumulator starts. `predict` plays the events in C (codegen/native/twin.c, one pass) where the
helper could be built; `predict_numpy` is the same prediction vectorised, and the tests compare the two.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass

import numpy as np

from codegen.motion.blocks import bresenham
from codegen.native import contiguous, library, pointer
from codegen.tables.schedule import FRAC_BITS, Schedule


@dataclass
class Pulses:
    """Step pulses in time order (events in order, motors in table order within an event)."""

    tick: np.ndarray  # (P,) int64 timer ticks since the timer started
    motor: np.ndarray  # (P,) int index into the schedule's motors
    dir: np.ndarray  # (P,) +1 / -1
    event: np.ndarray  # (P,) index of the event that made the pulse
    event_tick: np.ndarray  # (E,) tick of every event
    event_block: np.ndarray  # (E,) block of every event
    event_position: np.ndarray  # (E, M) motor positions in steps after each event (relative to the start)
    # Each motor's pulses together (motor m's from motor_first[m] on), where the player in C made them.
    motor_tick: np.ndarray | None = None
    motor_dir: np.ndarray | None = None
    motor_first: np.ndarray | None = None  # (M + 1,)

    def of_motor(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        if self.motor_first is not None:
            span = slice(self.motor_first[m], self.motor_first[m + 1])
            return self.motor_tick[span], self.motor_dir[span]
        sel = self.motor == m
        return self.tick[sel], self.dir[sel]

    def final_positions(self) -> np.ndarray:
        if len(self.event_position):
            return self.event_position[-1].copy()
        return np.zeros(self.event_position.shape[1], dtype=np.int64)


def event_ticks(schedule: Schedule, origin_fx: int = 0) -> np.ndarray:
    """Tick of every event: floor(pos / 256) with pos the running 24.8 sum of the intervals, from `origin_fx`
    (1/256 tick: where the player's clock stands when the schedule begins)."""
    n, interval, add = schedule.run_count, schedule.run_interval, schedule.run_add
    span = interval * n + add * (n * (n - 1) // 2)
    origin = origin_fx + np.concatenate([[0], np.cumsum(span)[:-1]]).astype(np.int64)
    run = np.repeat(np.arange(len(n)), n)
    k = np.arange(int(n.sum()), dtype=np.int64) - np.repeat(np.cumsum(n) - n, n) + 1
    pos = origin[run] + k * interval[run] + add[run] * (k * (k - 1) // 2)
    return pos >> FRAC_BITS


def predict(schedule: Schedule, origin_fx: int = 0, position: np.ndarray | None = None) -> Pulses:
    """Every pulse of the schedule, its clock starting at `origin_fx` (1/256 tick) and the motors at `position`
    (steps; default 0)."""
    lib = library("twin")
    if lib is None:
        return predict_numpy(schedule, origin_fx, position)
    motors = len(schedule.motors)
    counts = schedule.events_per_block()
    signed, modulus, init = contiguous(np.int64, schedule.block_steps * schedule.block_dirs.astype(np.int64),
                                       schedule.block_modulus, schedule.block_init)
    # Each motor's pulses: after n events of a block, ceil((n * steps - init) / modulus) (codegen/tables/schedule.py).
    made = -((init - counts[:, None] * np.abs(signed)) // modulus[:, None])
    per_motor = np.maximum(made, 0).sum(axis=0)
    motor_first = np.concatenate([[0], np.cumsum(per_motor)]).astype(np.int64)
    events, pulses = int(counts.sum()), int(motor_first[-1])
    here, = contiguous(np.int64, np.zeros(motors) if position is None else position)
    out = Pulses(tick=np.empty(pulses, np.int64), motor=np.empty(pulses, np.int64), dir=np.empty(pulses, np.int64),
                 event=np.empty(pulses, np.int64), event_tick=np.empty(events, np.int64),
                 event_block=np.empty(events, np.int64), event_position=np.empty((events, motors), np.int64),
                 motor_tick=np.empty(pulses, np.int64), motor_dir=np.empty(pulses, np.int64), motor_first=motor_first)
    blocks = [signed, modulus, init, *contiguous(np.int64, counts)]
    runs = contiguous(np.int64, schedule.run_count, schedule.run_interval, schedule.run_add)
    i64 = ctypes.c_int64
    lib.play(i64(schedule.n_blocks), i64(motors), *map(pointer, blocks), i64(len(runs[0])), *map(pointer, runs),
             i64(origin_fx), *map(pointer, (here, out.event_tick, out.event_block, out.event_position, out.tick,
                                          out.motor, out.dir, out.event, motor_first, out.motor_tick,
                                          out.motor_dir)))
    return out


def predict_numpy(schedule: Schedule, origin_fx: int = 0, position: np.ndarray | None = None) -> Pulses:
    ticks = event_ticks(schedule, origin_fx)
    counts = schedule.events_per_block()
    signed = schedule.block_steps * schedule.block_dirs.astype(np.int64)
    start = position
    block, stepped, position = bresenham(signed, schedule.block_modulus, schedule.block_init, counts)
    event_idx, motor = np.nonzero(stepped)
    return Pulses(
        tick=ticks[event_idx],
        motor=motor,
        dir=schedule.block_dirs[block[event_idx], motor].astype(np.int64),
        event=event_idx,
        event_tick=ticks,
        event_block=block,
        event_position=position.reshape(len(block), len(schedule.motors)) + (0 if start is None else start),
    )

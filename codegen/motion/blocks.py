"""Blocks: each motor moves by a fixed number of steps, coupled by Bresenham to the master's events.

The player's accumulators are 16-bit: a block has at most MAX_MODULUS events, and after i of them motor m has made
`ceil((i * steps[m] - init[m]) / modulus)` steps (codegen/tables/schedule.py describes the tables that carry them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_MODULUS = 32767  # the player's Bresenham accumulators are signed 16-bit


@dataclass
class Events:
    """Blocks and the ideal time (s) of each of their events, in program order."""

    block_segment: np.ndarray  # (B,) segment index
    block_steps: np.ndarray  # (B, M) signed steps
    block_modulus: np.ndarray  # (B,)
    block_init: np.ndarray  # (B, M) Bresenham accumulator starts
    block_tool: np.ndarray  # (B,) bool
    block_first: np.ndarray  # (B + 1,) index of each block's first event
    time: np.ndarray  # (E,) s
    phase: np.ndarray  # (E,) 0 accelerating, 1 cruising, 2 decelerating, 3 dwell


def bresenham_init(x0: np.ndarray, x1: np.ndarray, master: np.ndarray, steps: np.ndarray,
                   modulus: np.ndarray) -> np.ndarray:
    """Accumulator starts that keep each slave near the exact line, not the line between rounded ends.

    When the master reaches step P0 + i, the slave's exact count is i * |slope| + beta (its position minus
    its rounded start). The player makes ceil((i * d - init) / N) steps, about i * d / N - init / N + 1/2.
    The rounded total d differs from N * |slope|, so init centres the difference at the block's middle.
    """
    rows = np.arange(len(master))
    mx0, mx1 = x0[rows, master], x1[rows, master]
    span = (mx1 - mx0)[:, None]
    slope = np.divide(x1 - x0, span, out=np.zeros_like(x0), where=span != 0)
    beta = ((x0 - np.round(x0)) + (np.round(mx0)[:, None] - mx0[:, None]) * slope) * np.sign(steps)
    n = modulus[:, None].astype(float)
    init = np.round(n * (0.5 - beta) + 0.5 * n * (np.abs(steps) - n * np.abs(slope)))
    init = np.where(steps != 0, init, modulus[:, None] >> 1)
    return np.clip(init, 0, modulus[:, None] - 1).astype(np.int64)


def bresenham(block_steps: np.ndarray, modulus: np.ndarray, init: np.ndarray,
              events_per_block: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per event: its block, which motors step (E, M) bool, and positions after it (E, M), counted from
    the first block's start.

    `block_steps` is signed. After i events of a block motor m has stepped ceil((i*d - init) / N) times;
    in float64 that is exact (i*d < 2**31, and a non-integer quotient is at least 1/N from the next one)."""
    block = np.repeat(np.arange(len(modulus), dtype=np.int64), events_per_block)
    first = np.cumsum(events_per_block) - events_per_block
    i = np.arange(len(block), dtype=np.float64) - first[block] + 1.0
    d = np.abs(block_steps).astype(np.float64)
    done = np.ceil((i[:, None] * d[block] - init[block]) / modulus[block][:, None].astype(np.float64))
    done = done.astype(np.int32)
    before = np.empty_like(done)  # steps done after the previous event of the same block
    before[1:] = done[:-1]
    before[first[events_per_block > 0]] = 0
    stepped = done != before
    base = (np.cumsum(block_steps, axis=0) - block_steps)[block]  # where each block starts
    position = base + done * np.sign(block_steps)[block]
    return block, stepped, position

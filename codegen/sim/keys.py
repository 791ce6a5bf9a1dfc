"""Key presses for the simulators: a script of jog keys pressed and released at simulated times.

A script is a list of KeyPress(key, press_s, release_s), key a function of codegen/motion/jog.py (x+, x-y+, speed+,
start, ...), times in simulated seconds from reset. Several keys may be held at once (x+ with y+ is a diagonal).
A jog image waits in jog mode for its start key: simulated without a script (`verify`), it gets START_ONLY.
"""

from __future__ import annotations

from dataclasses import dataclass

from codegen.errors import BuildError
from codegen.motion.jog import KEYS

START_S = 0.05  # START_ONLY's press: after the 8051 display's power-up waits (30 ms)


@dataclass(frozen=True)
class KeyPress:
    key: str  # a jog key function: x+, x-, y+, y-, x+y+, ..., speed+, speed-, start
    press_s: float  # simulated seconds from reset
    release_s: float

    def __post_init__(self) -> None:
        if self.key not in KEYS:
            raise BuildError(f"unknown jog key {self.key!r} (keys: {', '.join(KEYS)})")
        if not 0 <= self.press_s < self.release_s:
            raise BuildError(f"key {self.key}: pressed at {self.press_s} s, released at {self.release_s} s")


START_ONLY = (KeyPress("start", START_S, 2 * START_S),)  # no jogging: the job at once


def session(config, script: list[KeyPress] | None) -> list[KeyPress] | None:
    """The key script a simulation of `config`'s image plays: `script`, or START_ONLY for a jog image without
    one; None for an image without jog mode."""
    if config.jog is None:
        return None
    return list(START_ONLY) if script is None else script


def key_events(script: list[KeyPress], wired: dict) -> list[tuple[float, frozenset[str]]]:
    """The script as changes of the set of pressed keys: (seconds, the keys held from then on), in time order.
    `wired` holds the keys the board has (a key it lacks is an error)."""
    missing = sorted({k.key for k in script} - set(wired))
    if missing:
        raise BuildError(f"the board has no jog key {', '.join(missing)}")
    times = sorted({t for k in script for t in (k.press_s, k.release_s)})
    return [(t, frozenset(k.key for k in script if k.press_s <= t < k.release_s)) for t in times]


def script_end_s(script: list[KeyPress]) -> float:
    return max((k.release_s for k in script), default=0.0)

"""The homing sequence of both targets' firmware: its step counts and time bound, the board-free checks of its axes."""

from __future__ import annotations

import math
from collections.abc import Iterator

from codegen.firmware.config import FirmwareConfig
from codegen.program.homing import HomingAxis

MAX_COUNT = (1 << 31) - 1  # steps and ticks are uint32 in the firmware; keep them clear of the top bit
PHASE_PAUSE_US = 1000.0  # the motors stand still before each phase (the first: the pull-ups charge the cables)


def backoff_limit(axis: HomingAxis) -> int:
    """The most steps of the back off: a switch still closed after them is stuck (an error)."""
    return 2 * axis.backoff_steps


def homing_steps(axis: HomingAxis, distance: int) -> tuple[int, int, int]:
    """Steps of the (fast approach, back off, slow approach) when the switch is closed from `distance` steps
    away (towards it) from the start on, and open short of it; for a switch that works (it closes within
    max_steps and opens within backoff_limit)."""
    fast = max(distance, 0)  # a switch closed at the start: no fast steps
    back = max(axis.backoff_steps, fast - distance + 1)  # on until the switch opens
    return fast, back, distance - (fast - back)


def homing_ticks_bound(config: FirmwareConfig, distances: dict[int, int | None], tick_hz: int) -> int:
    """At most how long homing takes (timer ticks at `tick_hz`) when axis k's switch (config.homing[k]) closes
    `distances[k]` steps away towards it (None or no entry: never), failures included."""
    total = 0
    pause = math.ceil(PHASE_PAUSE_US * tick_hz / 1e6)
    for round_ in sorted({h.round for h in config.homing}):
        phases = [[0], [0], [0]]
        for k, h in enumerate(config.homing):
            if h.round != round_:
                continue
            d = distances.get(k)
            # The fast approach may go on to max_steps: a switch that never closes, or one the firmware homes away
            # from (its fault state then names the axis, where a budget run out would not).
            steps = (h.max_steps, 0, 0) if d is None else (h.max_steps, *homing_steps(h, d)[1:])
            limits = (h.max_steps, backoff_limit(h), h.max_steps)
            intervals = (h.fast_interval, h.fast_interval, h.slow_interval)
            for phase, (n, limit, interval) in enumerate(zip(steps, limits, intervals)):
                phases[phase].append((min(n, limit) + 1) * interval)
        total += sum(2 * pause + max(p) for p in phases)  # a pause's worth of slack per phase
    return total


def stepping_motors(config: FirmwareConfig) -> int:
    """The most motors that step at one homing event: those of the busiest round."""
    rounds: dict[int, int] = {}
    for h in config.homing:
        rounds[h.round] = rounds.get(h.round, 0) + len(h.motors)
    return max(rounds.values(), default=1)


def homed_axes(config: FirmwareConfig, motors: list[dict], problems: list[str]
               ) -> Iterator[tuple[str, int, HomingAxis, list[dict]]]:
    """Each homing axis with its index, its motors' entries of `motors` and its name in messages
    (`homing[k] (axis x: motors a, b)`). A motor index out of range (the axis is left out), a motor in two axes
    of one round, or too long a DIR setup for the pause adds to `problems`."""
    if config.dir_setup_us > PHASE_PAUSE_US / 2:
        problems.append(f"dir_setup_us = {config.dir_setup_us} is too long for homing's {PHASE_PAUSE_US:g} us pause")
    seen = set()
    for k, h in enumerate(config.homing):
        bad = [m for m in h.motors if not 0 <= m < len(motors)]
        if bad:
            problems.append(f"homing[{k}]: motor index {bad[0]} out of range (the image has {len(motors)} motors)")
        if not h.motors or len(h.motor_directions) != len(h.motors):
            problems.append(f"homing[{k}]: {len(h.motors)} motors with {len(h.motor_directions)} directions")
        if bad or not h.motors or len(h.motor_directions) != len(h.motors):
            continue
        mine = [motors[m] for m in h.motors]
        names = ", ".join(m["name"] for m in mine)
        where = f"homing[{k}] (motor {names})" if len(mine) == 1 else \
            f"homing[{k}] (axis {h.label([m['name'] for m in motors])}: motors {names})"
        for m in h.motors:
            if (h.round, m) in seen:
                problems.append(f"{where}: motor {motors[m]['name']} is homed twice in round {h.round}")
            seen.add((h.round, m))
        if any(d not in (1, -1) for d in h.motor_directions):
            problems.append(f"{where}: motor directions must be +1 or -1, not {list(h.motor_directions)}")
        yield where, k, h, mine


def axis_problems(where: str, h: HomingAxis, shortest: int) -> list[str]:
    """What is wrong with one axis's direction, step counts and intervals (at least `shortest` timer ticks),
    whatever the board."""
    problems = [] if h.direction in (1, -1) else [f"{where}: direction must be +1 or -1, not {h.direction}"]
    for field, low in (("max_steps", 1), ("backoff_steps", 1), ("fast_interval", shortest),
                       ("slow_interval", shortest)):
        value = getattr(h, field)
        high = MAX_COUNT // 2 if field == "backoff_steps" else MAX_COUNT
        if not isinstance(value, int) or not low <= value <= high:
            unit = "timer ticks" if field.endswith("interval") else "steps"
            problems.append(f"{where}: {field} = {value} {unit} is outside {low}..{high}"
                            + (" (one homing event's work and the STEP pulse)" if low == shortest else ""))
    return problems


def axis_context(k: int, h: HomingAxis, mine: list[dict], motor_names: list[str]) -> dict:
    """The template's entry of one homing axis (its switch's pin added by the target)."""
    label = h.label(motor_names)
    return {"name": label, "id": _ident(label).upper(), "var": f"axis{k}", "flag": 1 << k, "round": h.round,
            "switch": h.switch, "direction": h.direction, "names": ", ".join(m["name"] for m in mine),
            "motors": [{**{key: m[key] for key in ("name", "id", "step", "dir")},
                        "towards_high": (d > 0) != m["invert"]} for m, d in zip(mine, h.motor_directions)],
            "fast_interval": h.fast_interval, "slow_interval": h.slow_interval, "max_steps": h.max_steps,
            "backoff_steps": h.backoff_steps, "backoff_limit": backoff_limit(h)}


def rounds_context(axes: list[dict]) -> list[dict]:
    """The rounds in order, each with the axes it homes together."""
    return [{"index": r, "axes": [a for a in axes if a["round"] == r],
             "mask": " | ".join(f"HOME_{a['id']}" for a in axes if a["round"] == r)}
            for r in sorted({a["round"] for a in axes})]


def _ident(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name)

"""Homing at power-up for the ATmega2560 image: check `FirmwareConfig.homing` against the board and the MCU,
and give templates/avr/homing.c.j2 (and config.h.j2) what they need.

The firmware's sequence (homing.c.j2), round by round (`HomingAxis.round`: a corexy homes x, then y), the axes
of a round together, each phase ending when every axis of the round has finished it, and each starting with the
DIR pins set and a PHASE_PAUSE_US standstill. An axis steps all its motors at once (a corexy's x: both belts):
  1. fast approach: towards the switch, one step per `fast_interval` ticks, until the switch reads closed
     (at most `max_steps` steps);
  2. back off: away from it at `fast_interval`, `backoff_steps` steps, then on while the switch still reads
     closed, at most `backoff_limit(axis)` steps in all;
  3. slow approach: towards the switch, one step per `slow_interval` ticks, until it reads closed again
     (at most `max_steps` steps); the position there is `home_steps`.
An axis reads its switch when its next step is due. With a switch that closes d >= 1 steps away (towards it)
and opens again one step short of that, the axis makes exactly d + backoff_steps + backoff_steps steps;
`homing_steps` gives the counts in every case. The 8051 image homes the same way (mcs51_homing.py uses the
sequence's figures and the board-free checks here)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import TYPE_CHECKING

from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig
from codegen.program.homing import HomingAxis

if TYPE_CHECKING:
    from codegen.firmware.avr.image import BoardPins

MAX_COUNT = (1 << 31) - 1  # steps and ticks are uint32 in the firmware; keep them clear of the top bit
SWITCH_REREAD_US = 1.0  # a switch is believed when two reads this far apart agree
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
            steps = (h.max_steps, 0, 0) if d is None else homing_steps(h, d)
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


def min_interval_cycles(mcu: dict, f_cpu: int, n_motors: int, step_pulse_us: float) -> int:
    """The shortest homing step interval (CPU cycles) with `n_motors` stepping at once: one event's work and the
    STEP pulse. (DIR pins change only before a phase's pause, far ahead of the next step.)"""
    work = mcu["homing_event_cycles"]
    return int(work[min(n_motors, len(work)) - 1]) + math.ceil(step_pulse_us * f_cpu / 1e6)


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


def homing_context(config: FirmwareConfig, pins: BoardPins, motors: list[dict], mcu: dict) -> dict:
    """Template variables for homing (`homing` is empty without it); BuildError lists every problem. Intervals
    are in Timer1 ticks (the MCU file's tick_hz, as the player's)."""
    f_cpu = int(mcu["f_cpu"])
    tick_hz = int(mcu.get("tick_hz", f_cpu))
    context = {"homing": [], "homing_rounds": [], "homing_step_ports": [],
               "switch_reread_cycles": math.ceil(SWITCH_REREAD_US * f_cpu / 1e6),
               "pause_ticks": math.ceil(PHASE_PAUSE_US * tick_hz / 1e6), "pause_us": f"{PHASE_PAUSE_US:g}"}
    if not config.homing:
        return context
    cycles = min_interval_cycles(mcu, f_cpu, stepping_motors(config), config.step_pulse_us)
    shortest = math.ceil(cycles * tick_hz / f_cpu)
    problems, axes, seen_switches = [], [], set()
    names = [m["name"] for m in motors]
    for where, k, h, mine in homed_axes(config, motors, problems):
        switch = pins.endstop(h.switch)
        if switch is None:
            endstops = ", ".join(e.name for e in pins.endstops) or "none"
            problems.append(f"{where}: board {config.board} has no endstop `{h.switch}` (has {endstops})")
        elif h.switch in seen_switches:
            problems.append(f"{where}: switch {h.switch} is used by two axes")
        seen_switches.add(h.switch)
        problems += axis_problems(where, h, shortest)
        if switch is None or problems:
            continue
        us = (lambda ticks: f"{ticks / tick_hz * 1e6:g}")
        axes.append({**axis_context(k, h, mine, names), "pin": switch.pin.__dict__,
                     "closed_high": switch.closed_high, "fast_us": us(h.fast_interval), "slow_us": us(h.slow_interval)})
    if problems:
        raise BuildError("bad homing configuration: " + "; ".join(problems))
    ports = []
    for port in sorted({m["step"]["port"] for a in axes for m in a["motors"]}):
        group = [(a, m) for a in axes for m in a["motors"] if m["step"]["port"] == port]
        ports.append({"port": port, "var": port.lower(), "entries": group,
                      "names": ", ".join(dict.fromkeys(m["name"] for _, m in group))})
    return {**context, "homing": axes, "homing_rounds": rounds_context(axes), "homing_step_ports": ports}

"""Homing at power-up for the ATmega2560 image: check `FirmwareConfig.homing` against the board and the MCU,
and give templates/avr/homing.c.j2 (and config.h.j2) what they need.

The firmware's sequence (homing.c.j2), all homed motors together, each phase ending when every motor has
finished it, and each starting with the DIR pins set and a PHASE_PAUSE_US standstill:
  1. fast approach: towards the switch, one step per `fast_interval` ticks, until the switch reads closed
     (at most `max_steps` steps);
  2. back off: away from it at `fast_interval`, `backoff_steps` steps, then on while the switch still reads
     closed, at most `backoff_limit(axis)` steps in all;
  3. slow approach: towards the switch, one step per `slow_interval` ticks, until it reads closed again
     (at most `max_steps` steps); the position there is `home_steps`.
A motor reads its switch when its next step is due. With a switch that closes d >= 1 steps away (towards it)
and opens again one step short of that, the motor makes exactly d + backoff_steps + backoff_steps steps;
`homing_steps` gives the counts in every case. The 8051 image homes the same way (mcs51_homing.py uses the
sequence's figures and the board-free checks here)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import TYPE_CHECKING

from codegen.errors import BuildError
from codegen.firmware import FirmwareConfig, HomingAxis

if TYPE_CHECKING:
    from codegen.firmware.avr import BoardPins

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


def homing_ticks_bound(config: FirmwareConfig, distances: dict[int, int | None], f_cpu: int) -> int:
    """At most how long homing takes (timer ticks = CPU cycles) when motor m's switch closes `distances[m]`
    steps away towards it (None or no entry: never), failures included."""
    phases = [[0], [0], [0]]
    for h in config.homing:
        d = distances.get(h.motor)
        steps = (h.max_steps, 0, 0) if d is None else homing_steps(h, d)
        limits = (h.max_steps, backoff_limit(h), h.max_steps)
        for phase, (n, limit, interval) in enumerate(zip(steps, limits, (h.fast_interval,) * 2 + (h.slow_interval,))):
            phases[phase].append((min(n, limit) + 1) * interval)
    pause = math.ceil(PHASE_PAUSE_US * f_cpu / 1e6)
    return sum(2 * pause + max(p) for p in phases)  # a pause's worth of slack per phase


def min_interval_cycles(mcu: dict, f_cpu: int, n_motors: int, step_pulse_us: float) -> int:
    """The shortest homing step interval with `n_motors` homed: one event's work and the STEP pulse. (DIR pins
    change only before a phase's pause, far ahead of the next step.)"""
    work = mcu["homing_event_cycles"]
    return int(work[min(n_motors, len(work)) - 1]) + math.ceil(step_pulse_us * f_cpu / 1e6)


def homed_motors(config: FirmwareConfig, motors: list[dict], problems: list[str]
                 ) -> Iterator[tuple[str, HomingAxis, dict]]:
    """Each homing axis with its entry of `motors` and its name in messages (`homing[k] (motor x)`). A motor
    index out of range (the axis is left out), a motor homed twice or too long a DIR setup for the pause adds
    to `problems`."""
    if config.dir_setup_us > PHASE_PAUSE_US / 2:
        problems.append(f"dir_setup_us = {config.dir_setup_us} is too long for homing's {PHASE_PAUSE_US:g} us pause")
    seen = set()
    for k, h in enumerate(config.homing):
        if not 0 <= h.motor < len(motors):
            problems.append(f"homing[{k}]: motor index {h.motor} out of range (the image has {len(motors)} motors)")
            continue
        m = motors[h.motor]
        where = f"homing[{k}] (motor {m['name']})"
        if h.motor in seen:
            problems.append(f"{where}: the motor is homed twice")
        seen.add(h.motor)
        yield where, h, m


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


def homing_context(config: FirmwareConfig, pins: BoardPins, motors: list[dict], mcu: dict) -> dict:
    """Template variables for homing (`homing` is empty without it); BuildError lists every problem."""
    f_cpu = int(mcu["f_cpu"])
    context = {"homing": [], "homing_step_ports": [],
               "switch_reread_cycles": math.ceil(SWITCH_REREAD_US * f_cpu / 1e6),
               "pause_ticks": math.ceil(PHASE_PAUSE_US * f_cpu / 1e6), "pause_us": f"{PHASE_PAUSE_US:g}"}
    if not config.homing:
        return context
    shortest = min_interval_cycles(mcu, f_cpu, len(config.homing), config.step_pulse_us)
    problems, axes, seen_switches = [], [], set()
    for where, h, m in homed_motors(config, motors, problems):
        switch = pins.endstop(h.switch)
        if switch is None:
            names = ", ".join(e.name for e in pins.endstops) or "none"
            problems.append(f"{where}: board {config.board} has no endstop `{h.switch}` (has {names})")
        elif h.switch in seen_switches:
            problems.append(f"{where}: switch {h.switch} is used by two motors")
        seen_switches.add(h.switch)
        problems += axis_problems(where, h, shortest)
        if switch is None or problems:
            continue
        us = (lambda ticks: f"{ticks / f_cpu * 1e6:g}")
        axes.append({**{key: m[key] for key in ("name", "id", "var", "flag", "step", "dir")},
                     "switch": h.switch, "pin": switch.pin.__dict__, "closed_high": switch.closed_high,
                     "direction": h.direction, "towards_high": (h.direction > 0) != m["invert"],
                     "fast_interval": h.fast_interval, "slow_interval": h.slow_interval,
                     "fast_us": us(h.fast_interval), "slow_us": us(h.slow_interval), "max_steps": h.max_steps,
                     "backoff_steps": h.backoff_steps, "backoff_limit": backoff_limit(h), "home_steps": h.home_steps})
    if problems:
        raise BuildError("bad homing configuration: " + "; ".join(problems))
    ports = []
    for port in sorted({a["step"]["port"] for a in axes}):
        group = [a for a in axes if a["step"]["port"] == port]
        ports.append({"port": port, "var": port.lower(), "axes": group, "names": ", ".join(a["name"] for a in group)})
    return {**context, "homing": axes, "homing_step_ports": ports}

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
`homing_steps` gives the counts in every case. The 8051 image homes the same way: codegen/firmware/homing.py has
the sequence's figures and the board-free checks both images use."""

from __future__ import annotations

import math

from codegen.errors import BuildError
from codegen.firmware.avr.board import BoardPins
from codegen.firmware.config import FirmwareConfig
from codegen.firmware.homing import (PHASE_PAUSE_US, axis_context, axis_problems, homed_axes, rounds_context,
                                     stepping_motors)

SWITCH_REREAD_US = 1.0  # a switch is believed when two reads this far apart agree


def min_interval_cycles(mcu: dict, f_cpu: int, n_motors: int, step_pulse_us: float) -> int:
    """The shortest homing step interval (CPU cycles) with `n_motors` stepping at once: one event's work and the
    STEP pulse. (DIR pins change only before a phase's pause, far ahead of the next step.)"""
    work = mcu["homing_event_cycles"]
    return int(work[min(n_motors, len(work)) - 1]) + math.ceil(step_pulse_us * f_cpu / 1e6)


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

"""Homing at power-up for the 8051 image: the board's endstop keys, checks of `FirmwareConfig.homing` against the
board and the MCU, and what templates/mcs51/homing.c.j2 needs.

The sequence is the ATmega2560's (codegen/firmware/avr/homing.py: fast approach, back off, slow approach, the
same step counts, `homing_steps` and `backoff_limit` of codegen/firmware/homing.py, the same pause before each
phase), timed by Timer1 while Timer0 and its interrupt wait for the player. Intervals are in timer ticks
(machine cycles, 12 CPU clocks). Endstops come from the board file: `endstops: {x_min: {pin: P3.2, closed: low},
...}`; several names may share a pin (one key per socket, at whichever end its machine homes to).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig
from codegen.firmware.homing import (PHASE_PAUSE_US, axis_context, axis_problems, homed_axes, rounds_context,
                                     stepping_motors)
from codegen.firmware.mcs51.board import Pin, board_data, parse_pin

ARM_STOP_TICKS = 8  # cycles Timer1 stands still in timer1_wait: clr TR1 .. setb TR1 (calibrated in s51)
PULSE_BASE_TICKS = 2  # machine cycles a STEP pin stays high in homing_pulse besides the hold, per STEP port
STATUS_PHASE_SHIFT = 4  # the fault status: phase << 4 | the axis's bit
MAX_AXIS_BITS = 0x0F


@dataclass(frozen=True)
class Endstop:
    """A board's endstop input: a key read through the port's weak pull-up."""

    name: str  # x_min, x_max, ...
    pin: Pin
    closed_high: bool  # the level the pin reads while the key is closed (a key to ground: low)


def endstops(board: str) -> dict[str, Endstop]:
    """The board file's `endstops: {x_min: {pin: P3.2, closed: low}, ...}`."""
    table = board_data(board)[0].get("endstops") or {}
    out = {}
    for name, spec in table.items():
        if not isinstance(spec, dict) or set(spec) != {"pin", "closed"} or spec["closed"] not in ("low", "high"):
            raise BuildError(f"board {board}: endstop {name} must read {{pin: P3.2, closed: low}} (closed: low or "
                             f"high, the level of the pin while the key is closed), not {spec!r}")
        out[str(name)] = Endstop(str(name), parse_pin(spec["pin"]), spec["closed"] == "high")
    return out


def decode_status(status: int) -> tuple[int, int]:
    """The fault status homing_fault() gets: (the axis bits, the phase 1..3)."""
    return status & MAX_AXIS_BITS, status >> STATUS_PHASE_SHIFT


def shortest_interval(mcu: dict, n_motors: int, pulse_ticks: int) -> int:
    """The shortest homing step interval (ticks) with `n_motors` homed: one event's work (measured, in CPU
    clocks like every cost in the MCU file) and the STEP pulse."""
    work = mcu["homing_event_cycles"]
    clocks = int(work[min(n_motors, len(work)) - 1])
    return math.ceil(clocks * int(mcu["tick_hz"]) / int(mcu["f_cpu"])) + pulse_ticks


def homing_context(config: FirmwareConfig, pins: dict, motors: list[dict], pulse_ticks: int) -> dict:
    """Template variables for homing (`homing` is empty without it); BuildError lists every problem.
    `pins` is board.board_pins(config), `motors` the player's motor entries."""
    _, mcu = board_data(config.board)
    tick_hz = int(mcu["tick_hz"])
    context = {"homing": [], "homing_rounds": [], "homing_step_ports": [], "switch_ports": [],
               "arm_stop_ticks": ARM_STOP_TICKS,
               "pause_ticks": math.ceil(PHASE_PAUSE_US * tick_hz / 1e6), "pause_us": f"{PHASE_PAUSE_US:g}"}
    if not config.homing:
        return context
    keys = endstops(config.board)
    outputs = {p.name for m in pins["motors"] for p in (m["step"], m["dir"], m["enable"])}
    outputs |= {pins["tool"].name} | {h["pin"].name for h in pins["held"]}
    shortest = shortest_interval(mcu, stepping_motors(config), pulse_ticks)
    problems, axes, seen_pins = [], [], {}
    names = [m["name"] for m in motors]
    for where, k, h, mine in homed_axes(config, motors, problems):
        if 1 << k > MAX_AXIS_BITS:
            problems.append(f"{where}: at most four axes can home (the fault status has four axis bits)")
        key = keys.get(h.switch)
        if key is None:
            problems.append(f"{where}: board {config.board} has no endstop `{h.switch}` "
                            f"(has {', '.join(keys) or 'none'})")
        elif key.pin.name in outputs:
            problems.append(f"{where}: endstop {h.switch} is on {key.pin.name}, which the board drives as an output")
        elif key.pin.name in seen_pins:
            problems.append(f"{where}: endstop {h.switch} is on {key.pin.name}, the key of "
                            f"{seen_pins[key.pin.name]} too")
        else:
            seen_pins[key.pin.name] = f"{'motor' if len(h.motors) == 1 else 'axis'} {h.label(names)}"
        problems += axis_problems(where, h, shortest)
        if key is None or problems:
            continue
        us = (lambda ticks: f"{ticks * 1e6 / tick_hz:g}")
        axes.append({**axis_context(k, h, mine, names),
                     "pin": {"name": key.pin.name, "sfr": key.pin.sfr, "mask": key.pin.mask,
                             "sbit": f"P{key.pin.port}_{key.pin.bit}"},
                     "closed_high": key.closed_high, "fast_us": us(h.fast_interval), "slow_us": us(h.slow_interval)})
    if problems:
        raise BuildError("bad homing configuration: " + "; ".join(problems))
    step_ports, switch_ports = [], []
    for sfr in sorted({m["step"]["sfr"] for a in axes for m in a["motors"]}):
        group = [(a, m) for a in axes for m in a["motors"] if m["step"]["sfr"] == sfr]
        motors_here = {m["name"]: m["step"]["mask"] for _, m in group}  # a corexy's belts serve two axes
        step_ports.append({"sfr": sfr, "var": group[0][1]["step"]["var"], "entries": group,
                           "pins": sum(motors_here.values()), "names": ", ".join(motors_here)})
    for sfr in sorted({a["pin"]["sfr"] for a in axes}):
        group = [a for a in axes if a["pin"]["sfr"] == sfr]
        switch_ports.append((sfr, sum(a["pin"]["mask"] for a in group),
                             ", ".join(f"{a['switch']} on {a['pin']['name']}" for a in group)))
    hold = max(0, pulse_ticks - PULSE_BASE_TICKS * len(step_ports))
    return {**context, "homing": axes, "homing_rounds": rounds_context(axes), "homing_step_ports": step_ports,
            "switch_ports": switch_ports,
            "hold_ticks": hold}

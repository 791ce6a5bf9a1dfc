"""Jog keys on the ATmega2560 image: the board's direct keys, checks of the jog plan against the jog loop, and what
templates/avr/jog.c.j2 needs (codegen/motion/jog.py has the host's half: the ramp table and the directions).

Jog mode runs in main before homing and the player, polling Timer1 (the player's timer, its interrupts not yet
on) as homing does. Intervals are timer ticks (TICK_HZ). The AVR scans direct keys, one pin each with the
internal pull-up (a matrix is the 8051 boards' choice: the Mega has pins to spare). The streaming firmware
(templates/avr/jog.c.j2 with `stream`) runs the same loop whenever it waits for a job, its link's interrupts on:
the host's START ends it once the motors are at rest.
"""

from __future__ import annotations

import math
import re

from codegen.errors import BuildError
from codegen.firmware.avr.board import parse_pin
from codegen.firmware.config import FirmwareConfig, board_pin_uses, load_target
from codegen.motion.jog import DIRECTIONS, KEYS, STILL, board_keys, check_jog_rate

SCAN_US = 2000  # between key scans
DEBOUNCE_SCANS = 5  # a key state must hold this long (10 ms) to count
START_US = 100  # a move's first step after its DIR change (the drivers' DIR setup; the start's own code is shorter)
# Measured in simavr (avr-gcc 5.4 -Os, RAMPS's 11 direct keys), keys changing the level at every debounce while
# the motors cruise: every step within a tick of its interval at a 41-tick cruise, steps up to 5 ticks late at 35
# (a step with a scan and a debounce's end takes about 40 ticks). With margin: the shortest step interval
# (EVENT_TICKS; tests/firmware/avr/test_jog.py runs at 64) and the most a scan alone may take before a step. Ticks (0.5 us).
SCAN_WORK_TICKS = 50
EVENT_TICKS = 60
# The streaming firmware answers a STATUS at a scan only this far before the next step: link_status() with its call
# is about 135 cycles with 2 motors (avr-objdump), each motor 22 more, each heater 17, a laser 11: at most 229 cycles
# (29 ticks) with 4 motors, 2 heaters and a laser. With margin.
STATUS_WORK_TICKS = 40
KEY_IDS = {"x+": "XP", "x-": "XM", "y+": "YP", "y-": "YM", "x+y+": "XP_YP", "x-y+": "XM_YP", "x-y-": "XM_YM",
           "x+y-": "XP_YM", "speed+": "SPEED_UP", "speed-": "SPEED_DOWN", "start": "START"}
_PIN = re.compile(r"P[A-L][0-7]")
_BOOKKEEPING = {"name", "target", "mcu", "jog_keys"}


def taken_pins(board: dict) -> dict[str, str]:
    """Every pin the board file names outside its jog keys (pin name -> where)."""
    return board_pin_uses(board, _PIN, _BOOKKEEPING)


def jog_context(config: FirmwareConfig, motors: list[dict]) -> dict:
    """Template variables of jog.c (`jog` is None without jog mode); `motors` are the player's motor entries."""
    plan = config.jog
    if plan is None:
        return {"jog": None}
    board = load_target(config.board)
    mcu = load_target(board["mcu"])
    wiring = board_keys(config.board, board, plan.keys, parse_pin, taken_pins(board))
    if wiring.kind != "direct":
        raise BuildError(f"board {config.board}: the {board['mcu']} scans direct jog keys, not a matrix")
    tick_hz = int(mcu.get("tick_hz", mcu["f_cpu"]))
    check_jog_rate(plan, tick_hz, EVENT_TICKS, board["mcu"])
    entries = [{**motors[i], "ways": [plan.signs[code][k] for code in range(9)]} for k, i in enumerate(plan.motors)]
    step_ports = []
    for port in sorted({m["step"]["port"] for m in entries}):
        group = [m for m in entries if m["step"]["port"] == port]
        step_ports.append({"port": port, "var": port.lower(), "names": ", ".join(m["name"] for m in group),
                           "pins": sum(1 << m["step"]["bit"] for m in group),
                           "masks": [sum(1 << m["step"]["bit"] for m in group if m["ways"][c]) for c in range(9)]})
    dir_ports = []
    for port in sorted({m["dir"]["port"] for m in entries}):
        group = [m for m in entries if m["dir"]["port"] == port]
        levels = [sum(1 << m["dir"]["bit"] for m in group if m["ways"][c] and (m["ways"][c] > 0) != m["invert"])
                  for c in range(9)]
        dir_ports.append({"port": port, "var": port.lower(), "names": ", ".join(m["name"] for m in group),
                          "mask": sum(1 << m["dir"]["bit"] for m in group), "levels": levels})
    keys = []
    for bit, name in enumerate(n for n in KEYS if n in wiring.keys):
        dx, dy = DIRECTIONS.get(name, (0, 0))
        pin = wiring.keys[name]
        keys.append({"name": name, "id": KEY_IDS[name], "bit": 1 << bit, "direction": name in DIRECTIONS,
                     "dx": dx, "dy": dy, "pin": pin, "where": pin.name})
    inputs: dict[str, int] = {}
    for pin in wiring.pins():
        inputs[pin.port] = inputs.get(pin.port, 0) | 1 << pin.bit
    ticks = (lambda us: math.ceil(us * tick_hz / 1e6))
    levels = [{"speed": s, "cruise": c, "top": t} for s, c, t in zip(plan.speeds, plan.cruise, plan.top)]
    return {"jog": {
        "functions": keys, "input_ports": sorted(inputs.items()), "motors": entries, "step_ports": step_ports,
        "dir_ports": dir_ports, "levels": levels, "ramp": list(plan.ramp),
        "accel": f"{plan.max_accel / plan.steps_per_mm:g}", "still": STILL, "scan_ticks": ticks(SCAN_US),
        "scan_us": SCAN_US, "gap_ticks": SCAN_WORK_TICKS, "debounce_scans": DEBOUNCE_SCANS,
        "start_ticks": max(ticks(START_US), ticks(config.dir_setup_us)), "status_ticks": STATUS_WORK_TICKS,
    }}

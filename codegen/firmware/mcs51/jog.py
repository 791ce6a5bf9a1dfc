"""Jog keys on the 8051 image: the board's keys, checks of the jog plan against the jog loop, and what
templates/mcs51/jog.c.j2 needs (codegen/motion/jog.py has the host's half: the ramp table and the directions).

Jog mode runs in main before homing and the player, polling Timer0 (the player's timer, its interrupt not yet on)
as homing polls Timer1. Intervals are timer ticks (machine cycles). The keys share no pin with anything else on
the board but, on a board with external RAM, its bus: jog mode and the flash player run no MOVX (their state is in
internal RAM), so the bus is idle and a matrix on P0 (open drain: pull-ups on the board) reads like any port.
The streaming firmware reads its ring with MOVX: it has no jog mode.
"""

from __future__ import annotations

import math

from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig
from codegen.firmware.mcs51.board import board_data, parse_pin
from codegen.firmware.mcs51.lcd import pin_uses
from codegen.motion.jog import DIRECTIONS, KEYS, STILL, board_keys, check_jog_rate

SCAN_US = 2000  # between key scans
DEBOUNCE_SCANS = 5  # a key state must hold this long (10 ms) to count
SETTLE_US = 10  # a matrix row driven low to its columns' reads (10 kOhm pull-ups and the cable's capacitance)
START_US = 200  # a move's first step after its DIR change (the drivers' DIR setup; the start's own code takes less)
# Measured in s51 (SDCC 4.2, seed-51's 4x4 matrix, large model): a step with a key scan in the same event took up
# to 524 ticks (steps at a 500-tick cruise came 24 ticks late after each scan), and a cruise of 560 ticks held
# every step within 1 tick while keys changed level at every debounce; with margin, the shortest step interval
# (EVENT_TICKS) and the most a scan alone may take before a step (SCAN_WORK_TICKS). Machine cycles = ticks.
SCAN_WORK_TICKS = 450
EVENT_TICKS = 600
ARM_STOP_TICKS = 8  # jog_wait's clr TR0 .. setb TR0, as homing's timer1_wait
KEY_IDS = {"x+": "XP", "x-": "XM", "y+": "YP", "y-": "YM", "x+y+": "XP_YP", "x-y+": "XM_YP", "x-y-": "XM_YM",
           "x+y-": "XP_YM", "speed+": "SPEED_UP", "speed-": "SPEED_DOWN", "start": "START"}


def taken_pins(board: dict) -> dict[str, str]:
    """The board's pins other than its jog keys (pin name -> what), without its external RAM's bus (idle in a
    flash image: see the top of this file)."""
    return pin_uses({k: v for k, v in board.items() if k != "jog_keys"}, 0)


def jog_context(config: FirmwareConfig, motors: list[dict], pulse_ticks: int, fields: int | None) -> dict:
    """Template variables of jog.c (`jog` is None without jog mode). `motors` are the player's motor entries,
    `fields` the display's fields (None: no display), where the speed goes after the motors' if there is room."""
    plan = config.jog
    if plan is None:
        return {"jog": None}
    board, mcu = board_data(config.board)
    if any(m["coil"] for m in motors):
        raise BuildError(f"board {config.board}: jog keys with coil-driven motors are not supported")
    wiring = board_keys(config.board, board, plan.keys, parse_pin, taken_pins(board))
    tick_hz = int(mcu["tick_hz"])
    ticks = (lambda us: math.ceil(us * tick_hz / 1e6))
    check_jog_rate(plan, tick_hz, EVENT_TICKS, board["mcu"])
    jogged = [motors[i] for i in plan.motors]
    entries = []
    for m, k in zip(jogged, range(len(jogged))):
        ways = [plan.signs[code][k] for code in range(9)]
        entries.append({**m, "index": plan.motors[k], "ways": ways})
    step_ports = []
    for sfr in sorted({m["step"]["sfr"] for m in entries}):
        group = [m for m in entries if m["step"]["sfr"] == sfr]
        step_ports.append({"sfr": sfr, "var": group[0]["step"]["var"], "names": ", ".join(m["name"] for m in group),
                           "pins": sum(m["step"]["mask"] for m in group),
                           "masks": [sum(m["step"]["mask"] for m in group if m["ways"][c]) for c in range(9)]})
    dir_ports = []
    for sfr in sorted({m["dir"]["sfr"] for m in entries}):
        group = [m for m in entries if m["dir"]["sfr"] == sfr]
        levels = [sum(m["dir"]["mask"] for m in group if m["ways"][c] and (m["ways"][c] > 0) != m["invert"])
                  for c in range(9)]
        dir_ports.append({"sfr": sfr, "var": group[0]["dir"]["var"], "names": ", ".join(m["name"] for m in group),
                          "mask": sum(m["dir"]["mask"] for m in group), "levels": levels})
    keys = []
    for bit, name in enumerate(n for n in KEYS if n in wiring.keys):
        dx, dy = DIRECTIONS.get(name, (0, 0))
        entry = {"name": name, "id": KEY_IDS[name], "bit": 1 << bit, "direction": name in DIRECTIONS,
                 "dx": dx, "dy": dy}
        if wiring.kind == "matrix":
            row, col = wiring.keys[name]
            entry.update(row=row, col_sbit=_sbit(wiring.cols[col]),
                         where=f"row {row} ({wiring.rows[row].name}), column {col} ({wiring.cols[col].name})")
        else:
            entry.update(sbit=_sbit(wiring.keys[name]), where=wiring.keys[name].name)
        keys.append(entry)
    rows = [{"sbit": _sbit(pin), "row_keys": [k for k in keys if k.get("row") == r]}
            for r, pin in enumerate(wiring.rows)]
    inputs: dict[str, int] = {}
    for pin in wiring.pins():
        inputs[pin.sfr] = inputs.get(pin.sfr, 0) | pin.mask
    show_speed = fields is not None and fields < 4
    levels = [{"speed": s, "cruise": c, "top": t} for s, c, t in zip(plan.speeds, plan.cruise, plan.top)]
    return {"jog": {
        "kind": wiring.kind, "functions": keys, "rows": rows if wiring.kind == "matrix" else [], "cols": wiring.cols,
        "input_ports": sorted(inputs.items()), "motors": entries, "step_ports": step_ports, "dir_ports": dir_ports,
        "levels": levels, "ramp": list(plan.ramp), "accel": f"{plan.max_accel / plan.steps_per_mm:g}",
        "still": STILL, "scan_ticks": ticks(SCAN_US), "scan_us": SCAN_US, "gap_ticks": SCAN_WORK_TICKS,
        "debounce_scans": DEBOUNCE_SCANS, "settle_ticks": ticks(SETTLE_US),
        "start_ticks": max(ticks(START_US), ticks(config.dir_setup_us), ARM_STOP_TICKS + 1),
        "show_speed": show_speed, "speed_field": fields if show_speed else None, "arm_stop_ticks": ARM_STOP_TICKS,
    }}


def _sbit(pin) -> str:
    return f"P{pin.port}_{pin.bit}"

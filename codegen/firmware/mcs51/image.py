"""8051 (AT89C52 / STC89C52RC class) firmware: render the step-table player for a board, build it with SDCC,
measure the fit.

The player (templates/mcs51/) plays the compact stream of codegen/tables/format.py from code memory with a Timer0
interrupt written in assembly (the streaming firmware, stream.py, builds on this module). Everything here is
deterministic: the same schedule and config give byte-identical sources, and the same sources an identical
firmware.hex. Next to it, firmware.sym.json gives the simulator the addresses it needs (the timer start and
halt()), and firmware.map is SDCC's map of the image.
"""

from __future__ import annotations

import math
import re

import codegen.tables.format as tables
from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig
from codegen.firmware.mcs51.board import Pin, board_data, board_pins, memories, parse_pin
from codegen.firmware.mcs51.hold import hold_context
from codegen.firmware.mcs51.homing import homing_context
from codegen.firmware.mcs51.jog import jog_context
from codegen.firmware.mcs51.lcd import board_lcd, render_lcd
# build_image: codegen/cli/main.py builds every target's image with its image module's render_sources and build_image.
from codegen.firmware.mcs51.sdcc import START_TICKS, build_image  # noqa: F401
from codegen.firmware.render import render
from codegen.tables.schedule import TOOL_BIT, Schedule

LINE_BYTES = 16  # table bytes per line of table.c
TOOL_FLAG_BIT = TOOL_BIT.bit_length() - 1
STOP_TICKS = 7  # cycles Timer0 stands still in the interrupt's `arm` sequence (calibrated in s51)
# Shortest STEP high time of each path of the interrupt (machine cycles from the rise to the fall), before pads.
PATH_TICKS = {"same": 20, "run": 12, "block": 10}
# Where the interrupt finds the STEP pins of each port (in port order) when it raises them: set by the previous
# interrupt, left alone by main's idle loop.
RAISE_REGS = ("a", "r0", "r1", "b")
MAX_PAD = 511
BLOCK_REGS = (3, 4, 5, 6)  # bank 0 registers a block load uses (saved when main runs)
LONG_REGS = (2, 3, 4, 5, 6, 7)  # and a long wait
# The 8-phase half-step sequence of a 4-wire coil drive over (coil 1, 2, 3, 4); + direction = the next phase.
HALF_STEPS = ((1, 0, 0, 0), (1, 1, 0, 0), (0, 1, 0, 0), (0, 1, 1, 0), (0, 0, 1, 0), (0, 0, 1, 1), (0, 0, 0, 1),
              (1, 0, 0, 1))


def _pin_dict(pin: Pin) -> dict:
    return {"name": pin.name, "sfr": pin.sfr, "mask": pin.mask, "var": pin.var, "bit": pin.bit}


def render_sources(schedule: Schedule, config: FirmwareConfig) -> dict[str, str]:
    """The C sources of the image (file name -> text): config.h, table.h, table.c, player.c (and homing.c for
    an image that homes at power-up)."""
    if tuple(m.name for m in config.motors) != tuple(schedule.motors):
        raise BuildError(f"firmware motors {[m.name for m in config.motors]} differ from the schedule's "
                         f"{list(schedule.motors)}")
    context, lcd = player_context(config)
    table = tables.encode(schedule)
    context.update(table_bytes=len(table.data), blocks=schedule.n_blocks, runs=schedule.n_runs, **table.counts(),
                   lines=tables.table_lines(table, schedule, LINE_BYTES))
    return render_player(context, lcd, config, ("config.h", "table.h", "table.c"))


def render_player(context: dict, lcd, config: FirmwareConfig, first: tuple[str, ...]) -> dict[str, str]:
    """The templates `first` (by file name), the display's files, player.c, and homing.c if the machine homes."""
    sources = {name: render(f"mcs51/{name}.j2", **context) for name in first}
    if lcd is not None:
        sources.update(render_lcd(lcd, context))
    sources["player.c"] = _tidy_asm(render("mcs51/player.c.j2", **context))
    if config.homing:
        sources["homing.c"] = render("mcs51/homing.c.j2", **context)
    if config.jog:
        sources["jog.c"] = render("mcs51/jog.c.j2", **context)
    if context.get("hold"):
        sources["hold.c"] = render("mcs51/hold.c.j2", **context)
    return sources


def player_context(config: FirmwareConfig, stream: bool = False) -> tuple[dict, object]:
    """What the player's templates need but the table (pins, ports, timing, homing, display), and the board's
    display (lcd.Lcd) or None. `stream`: the streaming player's (codegen/firmware/mcs51/stream.py)."""
    pins = board_pins(config)
    mem = memories(config.board)
    motors = []
    for index, w in enumerate(pins["motors"]):
        entry = {"name": w["name"], "socket": w["socket"], "id": re.sub(r"\W", "_", w["name"]).upper(),
                 "var": f"m{index}", "invert": w["invert"], "flag": 1 << index, "coil": w["coils"] is not None}
        if w["coils"] is None:
            entry.update(step=_pin_dict(w["step"]), dir=_pin_dict(w["dir"]), enable=_pin_dict(w["enable"]))
        else:
            entry.update(step=None, dir=None, enable=None, coils=[_pin_dict(c) for c in w["coils"]],
                         patterns=[sum(c.mask for c, on in zip(w["coils"], bits) if on) for bits in HALF_STEPS])
        motors.append(entry)
    ports = sorted({m["step"]["sfr"] for m in motors if not m["coil"]})
    c_ports = sorted({m["coils"][0]["sfr"] for m in motors if m["coil"]})
    if len(ports) + len(c_ports) > len(RAISE_REGS):
        raise BuildError(f"board {config.board}: STEP and coil pins on more than {len(RAISE_REGS)} ports")
    step_ports = []
    for sfr, reg in zip(ports, RAISE_REGS):
        group = [m for m in motors if not m["coil"] and m["step"]["sfr"] == sfr]
        step_ports.append({"sfr": sfr, "var": group[0]["step"]["var"], "pins": sum(m["step"]["mask"] for m in group),
                           "names": ", ".join(m["name"] for m in group), "reg": reg})
    enables: dict[str, int] = {}
    for m in motors:
        if not m["coil"]:
            enables[m["enable"]["sfr"]] = enables.get(m["enable"]["sfr"], 0) | m["enable"]["mask"]
    coil_ports = []
    for sfr, reg in zip(c_ports, RAISE_REGS[len(step_ports):]):
        group = [m for m in motors if m["coil"] and m["coils"][0]["sfr"] == sfr]
        if any(c["sfr"] != sfr for m in group for c in m["coils"]):
            raise BuildError(f"board {config.board}: the 4 coil pins of a socket must be on one port")
        mask = sum(c["mask"] for m in group for c in m["coils"])
        # The other pins of the port keep the level main gives them: 1 from reset, held pins and enables.
        static = 0xFF & ~mask
        for sfr_e, bits in enables.items():
            if sfr_e == sfr:
                static = static & ~bits if pins["enable_active_low"] else static | bits
        for h in pins["held"]:
            if h["pin"].sfr == sfr:
                static = static | h["pin"].mask if h["level"] else static & ~h["pin"].mask
        init = static | sum(m["patterns"][0] for m in group)
        coil_ports.append({"sfr": sfr, "var": f"p{sfr[1]}", "pins": mask, "static": static, "init": init, "init_coils": init & mask,
                           "motors": group, "names": ", ".join(m["name"] for m in group), "reg": reg})
    if coil_ports and board_lcd(config.board, [m.name for m in config.motors]) is not None:
        raise BuildError(f"board {config.board}: coil-driven motors with a display are not supported")
    tick_hz = mem["tick_hz"]
    pulse_ticks = math.ceil(config.step_pulse_us * tick_hz / 1e6 - 1e-9)
    # Several STEP ports rise 2 cycles apart and fall 2 cycles apart: the same high time on each.
    path = dict(PATH_TICKS)
    pads = {k: max(0, pulse_ticks - v) if step_ports else 0 for k, v in path.items()}
    if max(pads.values()) > MAX_PAD:
        raise BuildError(f"step_pulse_us = {config.step_pulse_us} is too long for the 8051 player "
                         f"(at most {MAX_PAD + min(path.values())} us)")
    tool = {**_pin_dict(pins["tool"]), "active_high": pins["tool_active_high"]}
    context = {
        "job_name": config.job_name, "job_file": config.job_file, "target": config.target, "board": config.board,
        "mcu": mem["mcu"], "f_cpu": mem["f_cpu"], "tick_hz": tick_hz, "clocks_per_tick": mem["f_cpu"] // tick_hz,
        "motors": motors, "step_ports": step_ports, "coil_ports": coil_ports, "tool": tool, "tool_flag": TOOL_BIT, "tool_bit": TOOL_FLAG_BIT,
        "enable_active_low": pins["enable_active_low"], "enable_ports": sorted(enables.items()),
        "step_clear": [(p["sfr"], p["pins"]) for p in step_ports],
        "held": [{**_pin_dict(h["pin"]), "level": h["level"], "what": h["what"]} for h in pins["held"]],
        "stop_ticks": STOP_TICKS, "start_ticks": START_TICKS, "step_pulse_us": config.step_pulse_us,
        "step_pulse_ticks": pulse_ticks, "step_path_ticks": min(path.values()), "pads": pads,
        "short_run_bytes": tables.SHORT_RUN_BYTES, "long_run_bytes": tables.LONG_RUN_BYTES,
        "short_block_bytes": tables.short_block_bytes(len(motors)),  # the longest: the player advances by what it read
        "long_block_bytes": tables.long_block_bytes(len(motors)),
    }
    context.update(homing_context(config, pins, motors, pulse_ticks))

    names = [m.name for m in config.motors]
    # Jog mode shows its speed in the field after the motors' (label F) where the display has one free.
    lcd = board_lcd(config.board, names + (["F"] if config.jog and len(names) < 4 else []))
    context.update(jog_context(config, motors, pulse_ticks, len(names) if lcd is not None else None))
    context.update(hold_context(config, board_data(config.board)[0], parse_pin, STOP_TICKS, tick_hz, stream))
    for m, start in zip(motors, config.start_steps or (0,) * len(motors)):
        m["start_steps"] = int(start) % 65536  # the display shows signed 16-bit positions
    # With a display (or a link, or feed hold's keys), main runs its code while the interrupt plays: the interrupt
    # saves what it uses, and keeps every motor's position at each block start for main to show (and report).
    context.update(busy_main=lcd is not None or stream or config.hold is not None, positions=lcd is not None or stream,
                   display=lcd is not None, stream=stream, block_regs=BLOCK_REGS, long_regs=LONG_REGS)
    return context, lcd


def _tidy_asm(text: str) -> str:
    """Drop the empty lines the template's macros leave in assembly, except before a label."""
    lines, out, in_asm = text.split("\n"), [], False
    for i, line in enumerate(lines):
        in_asm = (in_asm or line.strip() == "__asm") and line.strip() != "__endasm;"
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        if in_asm and not line.strip() and (not nxt.strip() or nxt.startswith(" ")):
            continue
        out.append(line)
    return "\n".join(out)


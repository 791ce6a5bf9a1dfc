"""8051 (AT89C52 / STC89C52RC class) firmware: render the step-table player for a board, build it with SDCC,
measure the fit.

The player (templates/mcs51/) plays the compact stream of codegen/tables/format.py from code memory with a Timer0
interrupt written in assembly (the streaming firmware, mcs51_stream.py, builds on this module). Everything here is
deterministic: the same schedule and config give byte-identical sources, and the same sources an identical
firmware.hex. Next to it, firmware.sym.json gives the simulator the addresses it needs (the timer start and
halt()), and firmware.map is SDCC's map of the image.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import codegen.tables.format as tables
from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig, board_socket
from codegen.firmware.avr.image import load_target
# The build (SDCC, its map and memory report) is mcs51_sdcc.py's; its names stay importable from here.
from codegen.firmware.mcs51.sdcc import (MAP_FILE, SYMBOLS_FILE, VECTOR_TIMER0, BuildPlan, build_image,  # noqa: F401
                                         flash_parts, read_map, read_mem)
from codegen.firmware.render import render
from codegen.tables.schedule import TOOL_BIT, Schedule

LINE_BYTES = 16  # table bytes per line of table.c
TOOL_FLAG_BIT = TOOL_BIT.bit_length() - 1
STOP_TICKS = 7  # cycles Timer0 stands still in the interrupt's `arm` sequence (calibrated in s51)
START_TICKS = 16  # from the timer start to tick 0 (main reaches idle before it)
# Shortest STEP high time of each path of the interrupt (machine cycles from the rise to the fall), before pads.
PATH_TICKS = {"same": 20, "run": 12, "block": 10}
# Where the interrupt finds the STEP pins of each port (in port order) when it raises them: set by the previous
# interrupt, left alone by main's idle loop.
RAISE_REGS = ("a", "r0", "r1", "b")
MAX_PAD = 511
BLOCK_REGS = (3, 4, 5, 6)  # bank 0 registers a block load uses (saved when main runs)
LONG_REGS = (2, 3, 4, 5, 6, 7)  # and a long wait
SFR = {0: 0x80, 1: 0x90, 2: 0xA0, 3: 0xB0}
# The 8-phase half-step sequence of a 4-wire coil drive over (coil 1, 2, 3, 4); + direction = the next phase.
HALF_STEPS = ((1, 0, 0, 0), (1, 1, 0, 0), (0, 1, 0, 0), (0, 1, 1, 0), (0, 0, 1, 0), (0, 0, 1, 1), (0, 0, 0, 1),
              (1, 0, 0, 1))


@dataclass(frozen=True)
class Pin:
    name: str  # P1.0
    port: int  # 1
    bit: int  # 0

    @property
    def sfr(self) -> str:
        return f"P{self.port}"

    @property
    def mask(self) -> int:
        return 1 << self.bit

    @property
    def var(self) -> str:
        return f"p{self.port}"


def parse_pin(text: str) -> Pin:
    match = re.fullmatch(r"P([0-3])\.([0-7])", str(text).strip())
    if not match:
        raise BuildError(f"bad 8051 pin `{text}` in a board file (expected e.g. P1.0)")
    return Pin(match.group(0), int(match.group(1)), int(match.group(2)))


def board_data(board: str) -> tuple[dict, dict]:
    """The board file and its MCU file (the same file for a one-file MCU+board such as at89c52)."""
    data = load_target(board)
    if data.get("target") != "mcs51":
        raise BuildError(f"board {board} is not an mcs51 board (target: {data.get('target')})")
    return data, load_target(data["mcu"])


def memories(board: str) -> dict[str, int | str]:
    """Code, internal RAM and XRAM sizes and the memory model (the board may add external RAM)."""
    data, mcu = board_data(board)
    xram = int(data.get("xram", mcu.get("xram", 0)))
    model = data.get("memory_model", mcu.get("memory_model", "large" if xram else "small"))
    return {"flash": int(mcu["flash"]), "iram": int(mcu["ram"]), "xram": xram, "model": model,
            "mcu": data["mcu"], "f_cpu": int(mcu["f_cpu"]), "tick_hz": int(mcu["tick_hz"])}


def board_pins(config: FirmwareConfig) -> dict:
    """Every pin the image drives, by role: motors (step, dir, enable, invert), tool, held pins."""
    board, _ = board_data(config.board)
    motors = []
    for m in config.motors:
        s = board_socket(config.board, board, m)
        if "coils" in s:
            coils = [parse_pin(c) for c in s["coils"] or []]
            if len(coils) != 4:
                raise BuildError(f"board {config.board}: socket {m.socket} needs 4 coil pins (has {len(coils)})")
            motors.append({"name": m.name, "socket": m.socket, "coils": coils, "step": None, "dir": None,
                           "enable": None, "invert": m.invert_dir})
            continue
        motors.append({"name": m.name, "socket": m.socket, "step": parse_pin(s["step"]), "dir": parse_pin(s["dir"]),
                       "enable": parse_pin(s["enable"]), "invert": m.invert_dir, "coils": None})
    held = [{"pin": parse_pin(h["pin"]), "level": 1 if h["level"] == "high" else 0, "what": h.get("what", "")}
            for h in board.get("held_pins") or []]
    tool = parse_pin(board["tool"]["pin"])
    # Every STEP, DIR, tool and held pin is its own (motors may share an enable pin).
    uses: dict[str, list[str]] = {}
    roles = [(f"{m['name']} {kind.upper()}", m[kind]) for kind in ("step", "dir") for m in motors if m[kind]]
    roles += [(f"{m['name']} coil {i + 1}", c) for m in motors for i, c in enumerate(m["coils"] or [])]
    for role, pin in roles + [("tool", tool)] + [("held", h["pin"]) for h in held]:
        uses.setdefault(pin.name, []).append(role)
    for m in motors:
        if m["enable"]:
            uses.setdefault(m["enable"].name, []).append("enable")
    clash = {name: roles for name, roles in uses.items() if len(roles) > 1 and set(roles) != {"enable"}}
    if clash:
        raise BuildError(f"board {config.board}: pins used twice: "
                         + "; ".join(f"{name} ({', '.join(roles)})" for name, roles in sorted(clash.items())))
    # A coil port is rewritten whole at each event: nothing else on it may change while the player runs.
    coil_ports = {c.port for m in motors for c in m["coils"] or []}
    moving = [(f"{m['name']} {kind.upper()}", m[kind]) for kind in ("step", "dir") for m in motors if m[kind]]
    moving.append(("tool", tool))
    lcd = board.get("lcd") or {}
    moving += [(f"LCD {k}", parse_pin(v)) for k, v in lcd.items() if k in ("rs", "e", "rw") and v]
    moving += [("LCD data", parse_pin(v)) for v in lcd.get("data") or []]
    bad = [f"{pin.name} ({role})" for role, pin in moving if pin.port in coil_ports]
    if bad:
        raise BuildError(f"board {config.board}: coil pins share their port with pins that change while the player "
                         f"runs: {', '.join(bad)} (coil ports: {', '.join(f'P{p}' for p in sorted(coil_ports))})")
    if coil_ports and config.homing:
        raise BuildError(f"board {config.board}: homing is not supported with coil-driven motors")
    return {"motors": motors, "tool": tool,
            "tool_active_high": bool(board["tool"]["active_high"]),
            "enable_active_low": bool(board["enable_active_low"]), "held": held}


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
    from codegen.firmware.mcs51.lcd import render_lcd  # here: that module builds on this one

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
    display (mcs51_lcd.Lcd) or None. `stream`: the streaming player's (codegen/firmware/mcs51/stream.py)."""
    from codegen.firmware.mcs51.lcd import board_lcd  # here: that module builds on this one

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
        "short_block_bytes": tables.short_block_bytes(len(motors)),
        "long_block_bytes": tables.long_block_bytes(len(motors)),
    }
    from codegen.firmware.mcs51.homing import homing_context  # here: that module builds on this one

    context.update(homing_context(config, pins, motors, pulse_ticks))

    names = [m.name for m in config.motors]
    # Jog mode shows its speed in the field after the motors' (label F) where the display has one free.
    lcd = board_lcd(config.board, names + (["F"] if config.jog and len(names) < 4 else []))
    from codegen.firmware.mcs51.jog import jog_context  # here: that module builds on this one

    context.update(jog_context(config, motors, pulse_ticks, len(names) if lcd is not None else None))
    from codegen.firmware.mcs51.hold import hold_context  # here: that module builds on this one

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


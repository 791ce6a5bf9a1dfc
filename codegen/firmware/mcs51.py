"""8051 (AT89C52 / STC89C52RC class) firmware: render the step-table player for a board, build it with SDCC,
measure the fit.

The player (templates/mcs51/) plays the compact stream of codegen/tables.py from code memory with a Timer0
interrupt written in assembly. Everything here is deterministic: the same schedule and config give
byte-identical sources, and the same sources give an identical firmware.hex. Next to the hex, firmware.sym.json gives the simulator the addresses it
needs (the timer start and halt()), and firmware.map is SDCC's map of the image.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path


from codegen import tables
from codegen.errors import BuildError
from codegen.firmware import FirmwareConfig, Image, board_socket, run_tool
from codegen.firmware.avr import load_target
from codegen.render import render
from codegen.schedule import TOOL_BIT, Schedule

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
VECTOR_TIMER0 = 0x000B
SYMBOLS_FILE = "firmware.sym.json"
MAP_FILE = "firmware.map"
SFR = {0: 0x80, 1: 0x90, 2: 0xA0, 3: 0xB0}
_ROM_FULL = "Insufficient ROM/EPROM/FLASH memory"
_XRAM_FULL = "Insufficient EXTERNAL RAM memory"
_IRAM_FULL = re.compile(r"Could not get (\d+) consecutive bytes in internal RAM for area (\w+)")
UNBOUNDED_CODE = 65536
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
    from codegen.firmware.mcs51_lcd import board_lcd, render_lcd  # here: that module builds on this one

    pins = board_pins(config)
    mem = memories(config.board)
    table = tables.encode(schedule)
    data = table.data
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
        "table_bytes": len(data), "blocks": schedule.n_blocks, "runs": schedule.n_runs, **table.counts(),
        "lines": tables.table_lines(table, schedule, LINE_BYTES),
    }
    sources = {name: render(f"mcs51/{name}.j2", **context) for name in ("config.h", "table.h", "table.c")}
    from codegen.firmware.mcs51_homing import homing_context  # here: that module builds on this one

    context.update(homing_context(config, pins, motors, pulse_ticks))

    lcd = board_lcd(config.board, [m.name for m in config.motors])
    for m, start in zip(motors, config.start_steps or (0,) * len(motors)):
        m["start_steps"] = int(start) % 65536  # the display shows signed 16-bit positions
    # With a display, main runs its code while the interrupt plays: the interrupt saves what it uses, and keeps
    # every motor's position at each block start for main to show.
    context.update(busy_main=lcd is not None, positions=lcd is not None, block_regs=BLOCK_REGS, long_regs=LONG_REGS)
    if lcd is not None:
        sources.update(render_lcd(lcd, context))
    sources["player.c"] = _tidy_asm(render("mcs51/player.c.j2", **context))
    if config.homing:
        sources["homing.c"] = render("mcs51/homing.c.j2", **context)
    return sources


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


def _sdcc_flags(mem: dict, code_size: int, xram_size: int) -> list[str]:
    return ["-mmcs51", "--Werror", f"--model-{mem['model']}", "--iram-size", str(mem["iram"]),
            "--xram-size", str(xram_size), "--code-size", str(code_size)]


def _run(cmd: list[str], cwd: Path, what: str) -> subprocess.CompletedProcess:
    return run_tool(cmd, cwd, what, "sdcc")


def _link(mem: dict, objects: list[str], code_size: int, xram_size: int, cwd: Path) -> subprocess.CompletedProcess:
    cmd = ["sdcc", *_sdcc_flags(mem, code_size, xram_size), "-o", "firmware.ihx", *objects]
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)


def read_mem(path: Path) -> dict[str, int]:
    """SDCC's .mem file: internal RAM bytes in use (registers, data, bits, overlays, idata), where the stack
    starts and how much it has, XRAM and code memory in use."""
    text = path.read_text(encoding="utf-8", errors="replace")
    used = 0
    for line in text.splitlines():
        if re.match(r"0x[0-9a-f]0:\|", line):
            used += sum(1 for cell in line.split("|")[1:17] if cell.strip() not in ("", "S"))
    out = {"iram": used}
    stack = re.search(r"Stack starts at: 0x([0-9a-fA-F]+) \(sp set to 0x[0-9a-fA-F]+\) with (\d+) bytes", text)
    if stack:
        out["stack_start"], out["stack_bytes"] = int(stack.group(1), 16), int(stack.group(2))
    for key, label in (("xram", "EXTERNAL RAM"), ("flash", "ROM/EPROM/FLASH")):
        m = re.search(rf"^\s*{re.escape(label)}\s+(?:0x[0-9a-f]+\s+0x[0-9a-f]+\s+)?(\d+)\s+(\d+)", text, re.M)
        out[key] = int(m.group(1)) if m else 0
    return out


def read_map(path: Path) -> tuple[dict[str, tuple[int, str]], dict[str, int]]:
    """Areas (name -> (bytes, attributes)) and global symbols (name -> address) from SDCC's .map file."""
    text = path.read_text(encoding="utf-8", errors="replace")
    areas = {m.group(1): (int(m.group(2), 16), m.group(3))
             for m in re.finditer(r"^(\w+)\s+[0-9A-F]{8}\s+([0-9A-F]{8}) =\s+\d+\. bytes \(([A-Z,]+)\)", text, re.M)}
    symbols = {m.group(2): int(m.group(1), 16) for m in re.finditer(r"^\s*C:\s+([0-9A-F]{8})\s+(\w+)", text, re.M)}
    return areas, symbols


def flash_parts(areas: dict[str, tuple[int, str]], table_bytes: int) -> dict[str, int]:
    """Every byte of code memory by what it holds: the step table, the player (the interrupt, which fills HOME from
    its vector on, and CSEG: halt, the start, main), SDCC's start-up (the reset and start-up jumps before the
    vector, GSINIT*, GSFINAL) and any other constants."""
    code = {name: size for name, (size, attrs) in areas.items() if "CODE" in attrs.split(",") and size}
    home = code.pop("HOME", 0)
    player = home - VECTOR_TIMER0 + code.pop("CSEG", 0)
    constants = code.pop("CONST", 0) - table_bytes
    return {"table": table_bytes, "player": player, "startup": VECTOR_TIMER0 + sum(code.values()),
            "constants": constants}


def _overflow(done: subprocess.CompletedProcess, mem: dict, objects: list[str], table_bytes: int,
              cwd: Path) -> BuildError:
    """A BuildError that says which memory overflowed, by how much when a bigger link can tell, and the limit."""
    out = done.stderr + done.stdout
    iram = _IRAM_FULL.search(out)
    if _ROM_FULL in out:
        again = _link(mem, objects, UNBOUNDED_CODE, max(int(mem["xram"]), 1), cwd)
        needed = read_mem(cwd / "firmware.mem")["flash"] if again.returncode == 0 else None
        size = f"it needs {needed} bytes" if needed else "it needs more than 64 KB"
        return BuildError(f"the image does not fit in code memory: {size} (table {table_bytes} bytes), "
                          f"{mem['flash']} available on the {mem['mcu']}; what helps: a larger machine.tolerance "
                          f"(fewer chords), a board without the display, or fewer moves")
    if _XRAM_FULL in out:
        again = _link(mem, objects, int(mem["flash"]), 65536, cwd)
        needed = read_mem(cwd / "firmware.mem")["xram"] if again.returncode == 0 else None
        size = f"it needs {needed} bytes" if needed else "it needs more"
        return BuildError(f"the image does not fit in external RAM: {size}, {mem['xram']} available")
    if iram:
        return BuildError(f"the image does not fit in internal RAM: its {iram.group(2)} area needs {iram.group(1)} "
                          f"consecutive bytes, more than are free of the {mem['iram']} bytes of the {mem['mcu']}")
    return BuildError(f"linking firmware.ihx failed:\n{out.strip()}")


def build_image(sources: dict[str, str], out_dir: Path, table_bytes: int) -> Image:
    """Write `sources` into out_dir and build firmware.hex (with firmware.map and firmware.sym.json); BuildError
    leaves no firmware.hex behind."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    hex_path = out_dir / "firmware.hex"
    for stale in (hex_path, out_dir / SYMBOLS_FILE, out_dir / MAP_FILE):
        stale.unlink(missing_ok=True)
    for name, text in sorted(sources.items()):
        (out_dir / name).write_text(text, encoding="utf-8")
    board = re.search(r'#define BOARD_NAME "([^"]+)"', sources.get("config.h", ""))
    if not board:
        raise BuildError("config.h does not name its board")
    mem = memories(board.group(1))
    with tempfile.TemporaryDirectory(prefix=".build-", dir=out_dir) as tmp:
        work = Path(tmp)
        for name, text in sorted(sources.items()):
            (work / name).write_text(text, encoding="utf-8")
        # main() is in player.c, which must come first on the link line.
        names = sorted((n for n in sources if n.endswith(".c")), key=lambda n: (n != "player.c", n))
        objects = []
        for name in names:
            objects.append(name[:-2] + ".rel")
            _run(["sdcc", *_sdcc_flags(mem, int(mem["flash"]), int(mem["xram"])), "-c", name], work,
                 f"sdcc on {name}")
        done = _link(mem, objects, int(mem["flash"]), int(mem["xram"]), work)
        if done.returncode != 0 or "?ASlink-Error" in done.stderr + done.stdout:
            raise _overflow(done, mem, objects, table_bytes, work)
        use = read_mem(work / "firmware.mem")
        areas, symbols = read_map(work / "firmware.map")
        missing = [s for s in ("_halt", "_timer_start", "_player_isr", "_table") if s not in symbols]
        if missing:
            raise BuildError(f"firmware.map lacks {', '.join(missing)}")
        if symbols["_player_isr"] != VECTOR_TIMER0:
            raise BuildError(f"the step interrupt is at 0x{symbols['_player_isr']:04X}, not at the Timer0 vector "
                             f"0x{VECTOR_TIMER0:04X} (SDCC's HOME area changed?)")
        hex_text = _run(["packihx", "firmware.ihx"], work, "packihx").stdout
        (work / "firmware.hex").write_text(hex_text, encoding="ascii")
        sym = {"halt": symbols["_halt"], "timer_start": symbols["_timer_start"], "isr": symbols["_player_isr"],
               "start_ticks": START_TICKS, "clocks_per_tick": mem["f_cpu"] // mem["tick_hz"]}
        (work / SYMBOLS_FILE).write_text(json.dumps(sym, indent=1, sort_keys=True) + "\n", encoding="utf-8")
        # The map and the symbols first, the hex (what gets flashed) last.
        (work / "firmware.map").replace(out_dir / MAP_FILE)
        (work / SYMBOLS_FILE).replace(out_dir / SYMBOLS_FILE)
        (work / "firmware.hex").replace(hex_path)
    # Code areas from the map; RAM from the .mem file (the map's data areas are the linker's reservations).
    sections = {name: size for name, (size, attrs) in sorted(areas.items()) if size and "CODE" in attrs.split(",")}
    sections.update({"iram_used": use["iram"], "xram_used": use["xram"], "stack_free": use.get("stack_bytes", 0)})
    return Image(hex_path=hex_path, elf_path=None, flash_bytes=use["flash"], ram_bytes=use["iram"],
                 table_bytes=table_bytes, flash_capacity=int(mem["flash"]), ram_capacity=int(mem["iram"]),
                 sections=sections, flash_parts=flash_parts(areas, table_bytes))

"""Building an 8051 image with SDCC (codegen/firmware/mcs51/image.py renders its sources): compile, link, read SDCC's
memory report and map, turn an overflow into a clear BuildError, and write firmware.hex with firmware.map and
firmware.sym.json (the addresses the simulator needs) beside it.
"""

from __future__ import annotations

import json
import re
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from codegen import progress
from codegen.errors import BuildError
from codegen.firmware.config import Image, run_tool
from codegen.firmware.mcs51.board import memories

VECTOR_TIMER0 = 0x000B
SYMBOLS_FILE = "firmware.sym.json"
MAP_FILE = "firmware.map"
START_TICKS = 16  # from the timer start to tick 0 (main reaches idle before it)
_ROM_FULL = "Insufficient ROM/EPROM/FLASH memory"
_XRAM_FULL = "Insufficient EXTERNAL RAM memory"
_IRAM_FULL = re.compile(r"Could not get (\d+) consecutive bytes in internal RAM for area (\w+)")
UNBOUNDED_CODE = 65536
FLASH_SYMBOLS = (("halt", "_halt"), ("timer_start", "_timer_start"), ("isr", "_player_isr"))


@dataclass(frozen=True)
class BuildPlan:
    """How build_image builds beyond a flashed player's defaults (the streaming player's: stream.py)."""

    model: str | None = None  # SDCC's memory model (None: the board's)
    xram: int | None = None  # XRAM bytes SDCC may place variables in (None: all the board has)
    iram: int | None = None  # internal RAM bytes SDCC may use from address 0, stack included (None: all of it)
    stack: int = 0  # stack bytes that must be free above the variables (SDCC starts the stack after them)
    symbols: tuple[tuple[str, str], ...] = FLASH_SYMBOLS  # firmware.sym.json key, map symbol (code or data)
    required: tuple[str, ...] = ("_table",)  # map symbols the image must also have
    sym_extra: dict = field(default_factory=dict)  # more firmware.sym.json entries
    parts: tuple[tuple[str, str], ...] = ()  # code areas that are flash parts of their own: (area, part)


def _sdcc_flags(mem: dict, code_size: int, xram_size: int) -> list[str]:
    return ["-mmcs51", "--Werror", f"--model-{mem['model']}", "--iram-size", str(mem["iram_limit"]),
            "--xram-size", str(xram_size), "--code-size", str(code_size)]


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


def read_map(path: Path, data: bool = False) -> tuple[dict[str, tuple[int, str]], dict[str, int]]:
    """Areas (name -> (bytes, attributes)) and global symbols (name -> address) from SDCC's .map file: code
    symbols, and with `data` those of internal RAM too."""
    text = path.read_text(encoding="utf-8", errors="replace")
    areas = {m.group(1): (int(m.group(2), 16), m.group(3))
             for m in re.finditer(r"^(\w+)\s+[0-9A-F]{8}\s+([0-9A-F]{8}) =\s+\d+\. bytes \(([A-Z,]+)\)", text, re.M)}
    prefix = r"(?:C:)?" if data else r"C:"  # data symbols have none
    symbols = {m.group(2): int(m.group(1), 16)
               for m in re.finditer(rf"^\s*{prefix}\s+([0-9A-F]{{8}})\s+(\w+)", text, re.M)}
    return areas, symbols


def flash_parts(areas: dict[str, tuple[int, str]], table_bytes: int, parts: tuple = ()) -> dict[str, int]:
    """Every byte of code memory by what it holds: the step table, the player (the interrupt, which fills HOME from
    its vector on, and CSEG: halt, the start, main), `parts` (code areas of their own), SDCC's start-up (the
    reset and start-up jumps before the vector, GSINIT*, GSFINAL) and any other constants."""
    code = {name: size for name, (size, attrs) in areas.items() if "CODE" in attrs.split(",") and size}
    home = code.pop("HOME", 0)
    player = home - VECTOR_TIMER0 + code.pop("CSEG", 0)
    constants = code.pop("CONST", 0) - table_bytes
    own = {part: code.pop(area, 0) for area, part in parts}
    return {"table": table_bytes, "player": player, **own, "startup": VECTOR_TIMER0 + sum(code.values()),
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
        limit = mem["iram_limit"]
        below = "" if limit == mem["iram"] else f", of which it may use those below 0x{limit:02X}"
        return BuildError(f"the image does not fit in internal RAM: its {iram.group(2)} area needs {iram.group(1)} "
                          f"consecutive bytes, more than are free of the {mem['iram']} bytes of the {mem['mcu']}"
                          f"{below}")
    return BuildError(f"linking firmware.ihx failed:\n{out.strip()}")


def build_image(sources: dict[str, str], out_dir: Path, table_bytes: int, plan: BuildPlan = BuildPlan()) -> Image:
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
    mem.update({"model": plan.model or mem["model"], "xram": mem["xram"] if plan.xram is None else plan.xram,
                "iram_limit": plan.iram or mem["iram"]})
    # main() is in player.c, which must come first on the link line.
    names = sorted((n for n in sources if n.endswith(".c")), key=lambda n: (n != "player.c", n))
    with (tempfile.TemporaryDirectory(prefix=".build-", dir=out_dir) as tmp,
          progress.stage("compile", len(names) + 1, "steps") as bar):
        work = Path(tmp)
        for name, text in sorted(sources.items()):
            (work / name).write_text(text, encoding="utf-8")
        objects = []
        for name in names:
            bar.set_postfix_str(name)
            objects.append(name[:-2] + ".rel")
            run_tool(["sdcc", *_sdcc_flags(mem, int(mem["flash"]), int(mem["xram"])), "-c", name], work,
                     f"sdcc on {name}", "sdcc")
            bar.update()
        bar.set_postfix_str("link and checks")
        done = _link(mem, objects, int(mem["flash"]), int(mem["xram"]), work)
        if done.returncode != 0 or "?ASlink-Error" in done.stderr + done.stdout:
            raise _overflow(done, mem, objects, table_bytes, work)
        use = read_mem(work / "firmware.mem")
        if use.get("stack_bytes", 0) < plan.stack:
            raise BuildError(f"the image's variables end at 0x{use.get('stack_start', 0):02X} in internal RAM, "
                             f"which leaves {use.get('stack_bytes', 0)} bytes of stack below 0x{mem['iram_limit']:02X} "
                             f"(the end of the internal RAM it may use), fewer than the {plan.stack} it needs")
        areas, symbols = read_map(work / "firmware.map", data=True)
        missing = [s for s in (*dict(plan.symbols).values(), *plan.required) if s not in symbols]
        if missing:
            raise BuildError(f"firmware.map lacks {', '.join(missing)}")
        if symbols["_player_isr"] != VECTOR_TIMER0:
            raise BuildError(f"the step interrupt is at 0x{symbols['_player_isr']:04X}, not at the Timer0 vector "
                             f"0x{VECTOR_TIMER0:04X} (SDCC's HOME area changed?)")
        hex_text = run_tool(["packihx", "firmware.ihx"], work, "packihx", "sdcc").stdout
        (work / "firmware.hex").write_text(hex_text, encoding="ascii")
        sym = {**{key: symbols[name] for key, name in plan.symbols}, **plan.sym_extra,
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
                 sections=sections, flash_parts=flash_parts(areas, table_bytes, plan.parts))

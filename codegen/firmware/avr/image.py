"""ATmega2560 firmware: render the step-table player for a board, build it with avr-gcc, measure the fit.

The player (templates/avr/) plays the compact record stream of codegen/tables/format.py from flash, its step interrupt
written in assembly (player_isr.S, laid out by codegen/firmware/avr/player.py); everything here is deterministic:
the same schedule and config give byte-identical sources, and the same sources give an identical firmware.hex.
"""

from __future__ import annotations

import math
import re
import subprocess
import tempfile
from pathlib import Path

import numpy as np

import codegen.tables.format as tables
from codegen import progress
from codegen.errors import BuildError
from codegen.firmware.avr.board import board_pins
from codegen.firmware.avr.heaters import heaters_context
from codegen.firmware.avr.hold import hold_context
from codegen.firmware.avr.homing import homing_context
from codegen.firmware.avr.interrupts_off import check_interrupts_off
from codegen.firmware.avr.jog import jog_context
from codegen.firmware.avr.laser import laser_context
from codegen.firmware.avr.player import isr_context, table_chunks
from codegen.firmware.avr.toolchain import ASFLAGS, CFLAGS, check_integer_only, run_avr
from codegen.firmware.config import FirmwareConfig, Image, load_target
from codegen.firmware.render import render
from codegen.tables.schedule import RT_PAUSE, TOOL_BIT, Schedule

STEP_ISR = "__vector_17"  # TIMER1_COMPA on the ATmega2560
# The objects whose functions and variables _memory_parts counts as each part of flash and RAM.
OBJECT_PARTS = {"player": ("player", "player_isr"), "homing": ("homing",), "link": ("stream", "link_rx", "link_tx"),
                "heaters": ("heaters", "heaters_hook"), "heater_tables": ("heaters_table",)}
# Pushes, calls, Y-relative frame slots and SP accesses (0x3d/0x3e) in the naked ISR.
_STACK_USE = re.compile(
    r"\b(push|pop|call|rcall|icall|eicall)\b|\b(ldd|std|ld|st)\b[^;]*\bY|\b(in|out)\b[^;]*0x3[de]\b")
_TEXT_FULL = re.compile(r"region [`']text'")  # ld: "will not fit in region `text'" / "region `text' overflowed"
UNBOUNDED_FLASH = 8 << 20  # a link that only measures an oversized image
MAX_STEP_PORTS = 4  # one PEND register each (the format has at most 4 motors)


def _ident(name: str) -> str:
    return re.sub(r"\W", "_", name).lower()


def render_sources(schedule: Schedule, config: FirmwareConfig) -> dict[str, str]:
    """The sources of the image (file name -> text): config.h, table.h, table.c, player.c, player_isr.S,
    homing.c when the config homes motors, heaters.h, heaters.c, heaters_table.c and heaters_hook.S when it has
    heaters."""
    if tuple(m.name for m in config.motors) != tuple(schedule.motors):
        raise BuildError(f"firmware motors {[m.name for m in config.motors]} differ from the schedule's "
                         f"{list(schedule.motors)}")
    context = player_context(config, stream=False)
    try:
        table = tables.encode(schedule)
    except ValueError as exc:
        raise BuildError(f"the schedule cannot be played by the {context['mcu']} player: {exc}") from exc
    settings = schedule.n_runtime - int(np.count_nonzero(schedule.runtime_command == RT_PAUSE))
    if settings and not config.heaters:
        raise BuildError("the tables carry heater or fan settings, but the image runs no heaters")
    if schedule.n_runtime > settings and config.hold is None:
        raise BuildError("the tables carry M0/M1 pauses, but the image has no feed hold (its resume key)")
    context.update({"table_bytes": len(table.data), "blocks": schedule.n_blocks, "runs": schedule.n_runs,
                    "chunks": table_chunks(table), "runtime_records": schedule.n_runtime})
    names = ("config.h", "table.h", "table.c", "player.c", "player_isr.S") + (("homing.c",) if config.homing else ())
    names += ("heaters.h", "heaters.c", "heaters_table.c", "heaters_hook.S") if config.heaters else ()
    names += ("laser.h",) if config.laser else ()
    names += ("jog.c",) if config.jog else ()
    sources = {name: render(f"avr/{name}.j2", **context) for name in names}
    check_interrupts_off(sources, config, stream=False)
    return sources


def player_context(config: FirmwareConfig, stream: bool) -> dict:
    """What the player's templates need besides the table: the board's pins by port, the step interrupt's
    registers (templates/avr/player_isr.S.j2, `stream`: reading the link's ring), homing."""
    pins = board_pins(config)
    mcu = load_target(pins.mcu)
    motors = []
    for index, w in enumerate(pins.motors):
        motors.append({"name": w.name, "socket": w.socket, "id": _ident(w.name).upper(), "var": _ident(w.name),
                       "index": index, "step": {**w.step.__dict__, "var": w.step.port.lower()},
                       "dir": w.dir.__dict__, "enable": w.enable.__dict__, "invert": w.invert_dir, "flag": 1 << index})
    step_ports = []
    for port in sorted({m["step"]["port"] for m in motors}):
        group = [m for m in motors if m["step"]["port"] == port]
        if len(step_ports) == MAX_STEP_PORTS:
            raise BuildError(f"board {config.board}: STEP pins on more than {MAX_STEP_PORTS} ports")
        step_ports.append({"port": port, "var": port.lower(), "motors": group,
                           "names": ", ".join(m["name"] for m in group)})
        for m in group:
            m["step_port"] = step_ports[-1]
    pin_ports: dict[str, list[dict]] = {}
    for m in motors:
        pin_ports.setdefault(m["dir"]["port"], []).append(
            {"flag_bit": m["index"], "pin": m["dir"]["name"], "what": f"DIR {m['name']}"})
    tool_entry = {"flag_bit": TOOL_BIT.bit_length() - 1, "pin": pins.tool.name, "what": "tool"}
    pin_ports.setdefault(pins.tool.port, []).append(tool_entry)
    dir_ports = [{"port": p, "entries": e} for p, e in sorted(pin_ports.items())]
    invert_mask = sum(m["flag"] for m in motors if m["invert"]) | (0 if pins.tool_active_high else TOOL_BIT)
    outputs: dict[str, list[str]] = {}
    enables: dict[str, list[str]] = {}
    for m in motors:
        for kind in ("step", "dir", "enable"):
            outputs.setdefault(m[kind]["port"], []).append(f"{m['id']}_{kind.upper()}_BIT")
        enables.setdefault(m["enable"]["port"], []).append(f"{m['id']}_ENABLE_BIT")
    outputs.setdefault(pins.tool.port, []).append("TOOL_BIT")
    f_cpu, tick_hz = int(mcu["f_cpu"]), int(mcu.get("tick_hz", mcu["f_cpu"]))
    pulse_cycles = math.ceil(config.step_pulse_us * f_cpu / 1e6)
    context = {
        "job_name": config.job_name, "job_file": config.job_file, "target": config.target, "board": config.board,
        "mcu": pins.mcu, "f_cpu": f_cpu, "tick_hz": tick_hz, "motors": motors, "step_ports": step_ports,
        "tool": {**pins.tool.__dict__, "active_high": pins.tool_active_high}, "tool_flag": TOOL_BIT,
        "enable_active_low": pins.enable_active_low,
        "output_ports": [(p, " | ".join(bits)) for p, bits in sorted(outputs.items())],
        "enable_ports": [(p, " | ".join(bits)) for p, bits in sorted(enables.items())],
        "step_pulse_us": config.step_pulse_us, "step_pulse_cycles": pulse_cycles, "dir_ports": dir_ports,
        "tool_port": {"port": pins.tool.port, "entries": [tool_entry]}, "pad_plan": pad_plan, "stream": stream,
    }
    context.update(isr_context(motors, step_ports, dir_ports + [context["tool_port"]], invert_mask, f_cpu,
                               tick_hz, pulse_cycles))
    context.update(homing_context(config, pins, motors, mcu))
    context.update(heaters_context(config, f_cpu, tick_hz, stream))
    context.update(laser_context(config))
    context.update(jog_context(config, motors))
    context.update(hold_context(config, motors, stream, tick_hz))
    return context


def pad_plan(cycles: int) -> dict:
    """Exactly `cycles` CPU cycles of waiting: loops of 3k cycles (LDI + k x (DEC, BRNE) less one), then RJMP .+0
    (2 cycles) and a NOP."""
    loops = []
    left = cycles
    while left >= 6:
        k = min(left // 3, 255)
        loops.append(k)
        left -= 3 * k
    return {"loops": loops, "rjmps": left // 2, "nops": left % 2}


def _section_sizes(elf: Path, cwd: Path) -> dict[str, int]:
    out = run_avr(["avr-size", "-A", elf.name], cwd, "avr-size").stdout
    sizes = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit():
            sizes[parts[0]] = int(parts[1])
    return sizes


def _check_table_contiguous(elf: Path, cwd: Path) -> None:
    """The player reads the chunks as one stream: each must start where the previous one ends."""
    out = run_avr(["avr-nm", "-S", elf.name], cwd, "avr-nm").stdout
    chunks = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[3].startswith("table_chunk_"):
            chunks[int(parts[3][len("table_chunk_"):])] = (int(parts[0], 16), int(parts[1], 16))
    for k in range(1, len(chunks)):
        addr, size = chunks[k - 1]
        if chunks.get(k, (None,))[0] != addr + size:
            raise BuildError(f"table chunks {k - 1} and {k} are not contiguous in flash ({elf.name})")


def _memory_parts(elf: Path, cwd: Path, sections: dict[str, int]) -> tuple[dict[str, int], dict[str, int]]:
    """Every byte of flash by what it is: the step table, the player's own code (the functions player.o and
    player_isr.o define), the homing code (homing.o's, in an image that homes), the link's (a streaming image's
    stream.o, link_rx.o and link_tx.o), the heaters' code (heaters.o's and heaters_hook.o's) and their ADC tables
    (heaters_table.o's), the initial values of RAM variables, and the rest (interrupt vectors, C start-up,
    libgcc, alignment); and every byte of RAM in use (.data and .bss) by the part whose variables it holds, the
    rest (libc's, alignment) as `other`."""
    flash_own: dict[str, set[str]] = {}
    ram_own: dict[str, set[str]] = {}
    for part, objects in OBJECT_PARTS.items():
        for obj in (name for name in objects if (cwd / f"{name}.o").exists()):
            symbols = [line.split() for line in run_avr(["avr-nm", "--defined-only", f"{obj}.o"], cwd,
                                                     "avr-nm").stdout.splitlines()]
            flash_own.setdefault(part, set()).update(s[-1] for s in symbols if s[-2] in "TtRr")
            ram_own.setdefault(part, set()).update(s[-1] for s in symbols if s[-2] in "DdBbRr")  # .rodata: in RAM
    flash, ram = dict.fromkeys(flash_own, 0), dict.fromkeys(ram_own, 0)
    table = 0
    for line in run_avr(["avr-nm", "-S", elf.name], cwd, "avr-nm").stdout.splitlines():
        parts = line.split()
        if len(parts) != 4 or parts[2] not in "TtDdBb":
            continue
        size, in_flash = int(parts[1], 16), parts[2] in "Tt"
        if parts[3].startswith("table_chunk_"):
            table += size
        for part, symbols in (flash_own if in_flash else ram_own).items():
            if parts[3] in symbols:
                (flash if in_flash else ram)[part] += size
                break
    text = sections.get(".text", 0)
    counted = {"table": table, "player": flash.get("player", 0), "ram_initial_values": sections.get(".data", 0),
               "vectors_startup_libgcc": text - table - sum(flash.values())}
    used = sections.get(".data", 0) + sections.get(".bss", 0)
    ram_parts = {part: size for part, size in ram.items() if size} | {"other": used - sum(ram.values())}
    return {**counted, **{part: size for part, size in flash.items() if part != "player"}}, ram_parts


def _check_isr_stackless(elf: Path, cwd: Path) -> None:
    """The step interrupt (assembly) saves nothing and has no frame: no push, call or stack access in it."""
    out = run_avr(["avr-objdump", "-d", "--no-show-raw-insn", elf.name], cwd, "avr-objdump").stdout
    body = out.split(f"<{STEP_ISR}>:", 1)[1].split("\n\n", 1)[0] if f"<{STEP_ISR}>:" in out else ""
    bad = [line.strip() for line in body.splitlines() if _STACK_USE.search(line)]
    if not body or bad:
        raise BuildError(f"the step interrupt {STEP_ISR} uses the stack, which it may not (it saves nothing): "
                         f"{'; '.join(bad[:3]) or 'not found'}")


def _link(arch: list[str], objects: list[str], elf: str, flash: int, ram: int,
          cwd: Path) -> subprocess.CompletedProcess:
    cmd = ["avr-gcc", *arch, f"-Wl,--defsym=__TEXT_REGION_LENGTH__={flash}",
           f"-Wl,--defsym=__DATA_REGION_LENGTH__={ram}", "-o", elf, *objects]
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)


def _link_unbounded(arch: list[str], objects: list[str], cwd: Path) -> str:
    done = _link(arch, objects, "unbounded.elf", UNBOUNDED_FLASH, UNBOUNDED_FLASH, cwd)
    if done.returncode != 0:
        raise BuildError(f"the image does not fit in flash, and even an unbounded link fails:\n{done.stderr.strip()}")
    return "unbounded.elf"


def build_image(sources: dict[str, str], out_dir: Path, table_bytes: int) -> Image:
    """Write `sources` into out_dir and build firmware.elf and firmware.hex; BuildError leaves neither behind."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    hex_path, elf_path = out_dir / "firmware.hex", out_dir / "firmware.elf"
    for stale in (hex_path, elf_path):
        stale.unlink(missing_ok=True)
    for name, text in sorted(sources.items()):
        (out_dir / name).write_text(text, encoding="utf-8")
    mcu = load_target("atmega2560")
    flash, ram = int(mcu["flash"]), int(mcu["ram"])
    arch = [f"-mmcu={mcu['name']}", f"-DF_CPU={int(mcu['f_cpu'])}UL"]
    compiled = sorted(n for n in sources if n.endswith((".c", ".S")))
    with (tempfile.TemporaryDirectory(prefix=".build-", dir=out_dir) as tmp,
          progress.stage("compile", len(compiled) + 1, "steps") as bar):
        work = Path(tmp)
        objects = []
        for name, text in sorted(sources.items()):
            (work / name).write_text(text, encoding="utf-8")
        for name in compiled:
            bar.set_postfix_str(name)
            objects.append(name[:-2] + ".o")
            flags = CFLAGS if name.endswith(".c") else ASFLAGS
            run_avr(["avr-gcc", *arch, *flags, "-c", name, "-o", objects[-1]], work, f"avr-gcc on {name}")
            bar.update()
        bar.set_postfix_str("link and checks")
        done = _link(arch, objects, "firmware.elf", flash, ram, work)
        if done.returncode != 0:
            if _TEXT_FULL.search(done.stderr):
                # Link again without the limit, only to measure what the job needs.
                sizes = _section_sizes(work / _link_unbounded(arch, objects, work), work)
                needed = sizes.get(".text", 0) + sizes.get(".data", 0)
                raise BuildError(f"the image does not fit in flash: it needs {needed} bytes (table {table_bytes} "
                                 f"bytes), {flash} available on the {mcu['name']}")
            raise BuildError(f"linking firmware.elf failed:\n{done.stderr.strip()}")
        elf = work / "firmware.elf"
        _check_table_contiguous(elf, work)
        _check_isr_stackless(elf, work)
        check_integer_only(elf, work)
        sections = {k: v for k, v in _section_sizes(elf, work).items() if k in (".text", ".data", ".bss")}
        flash_parts, ram_parts = _memory_parts(elf, work, sections)
        run_avr(["avr-objcopy", "-O", "ihex", "-R", ".eeprom", "firmware.elf", "firmware.hex"], work, "avr-objcopy")
        # Both files appear together, complete: the ELF first, the hex (what gets flashed) last.
        (work / "firmware.elf").replace(elf_path)
        (work / "firmware.hex").replace(hex_path)
    text, data, bss = (sections.get(s, 0) for s in (".text", ".data", ".bss"))
    return Image(hex_path=hex_path, elf_path=elf_path, flash_bytes=text + data, ram_bytes=data + bss,
                 table_bytes=table_bytes, flash_capacity=flash, ram_capacity=ram, sections=sections,
                 flash_parts=flash_parts, ram_parts=ram_parts)

"""The streaming ATmega2560 firmware: the flash image's player (templates/avr/player_isr.S.j2 with `stream`) reading
the compact record stream from a ring buffer in SRAM that the link (codegen/link/protocol.py) fills.

One image per machine: it holds no table, so it is built from the FirmwareConfig alone and plays any job of that
machine. SRAM, from its start: the variables (all of them declared in the assembly, so that `ring_layout` counts
them without building; build_stream_image checks the count against the linked image), the ring up to RING_END,
a mirror of its first RECORD_MAX bytes (a record is read linearly across the ring's end), the stack.
"""

from __future__ import annotations

import binascii
from dataclasses import dataclass
from pathlib import Path

from codegen.errors import BuildError
from codegen.firmware.avr.hold import HOLD_STREAM_VARIABLES, HOLD_VARIABLES
from codegen.firmware.avr.image import build_image, player_context
from codegen.firmware.avr.interrupts_off import check_interrupts_off
from codegen.firmware.avr.laser import LASER_HOLD_VARIABLES, LASER_VARIABLES
from codegen.firmware.avr.toolchain import run_avr
from codegen.firmware.config import FirmwareConfig, Image, load_target
from codegen.firmware.render import render
from codegen.link import protocol
from codegen.link.ring import link_budget

MCU = "atmega2560"
MAX_BAUD_ERROR = 0.02
UBRR_MAX = 4095  # 12 bits
BIT_CYCLES_U2X = 8  # CPU cycles per UBRR step and bit at double speed
LINE_BITS = 10  # 8N1: start, 8 data, stop
SRAM_START = 0x0200  # after the ATmega2560's registers and I/O space
RING_END = 0x2100  # 256-aligned: the receive interrupt tells the mirror by the address's high byte
POSITION_BIAS = 0x8000  # pl_pos holds position + this, so the top half seldom carries
MIN_STACK_BYTES = 160  # main's deepest calls, an interrupt's pushes, player_run's 18
CALLEE_SAVED = ("r2", "r3", "r4", "r5", "r6", "r7", "r8", "r9", "r10", "r11", "r12", "r13", "r14", "r15", "r16",
                "r17", "r28", "r29")
STREAM_NAMES = ("config.h", "link.h", "stream.c", "player_isr.S", "link_rx.S", "link_tx.S")
HEATER_NAMES = ("heaters.h", "heaters.c", "heaters_table.c", "heaters_hook.S")
MAX_HOMING_AXES = 4  # the HOMING_FAILED status holds the axis bits in its low nibble
IDENT_PAYLOAD = 8  # version u8, identity u32, ring bytes u16, motors u8
FRAME_HEAD = 3  # LEN SEQ TYPE, kept with a frame's payload
# Bytes of the variables link_rx.S and link_tx.S declare besides ident_frame and message_frame, and player_isr.S's
# per image, per motor and per STEP port (stream.c and homing.c declare none; jog.c its positions).
LINK_VARIABLES = 39
PLAYER_VARIABLES, PER_MOTOR, PER_PORT = 8, 8, 2
JOG_PER_MOTOR = 4  # jog.c's position count (int32) per jogged motor
# heaters.c's (RAM_PER_HEATER: its constants, state, reading and STATUS report; HEATER_VARIABLES: the runtime
# records' slots and flags, the period's stage, the fault's reason and heater, heaters_hook's copy of TIMSK1).
HEATER_VARIABLES, RAM_PER_HEATER = 14, 79  # 79: CONFIG 41 (.rodata is in RAM), state 32, reading 2, report 4
HEATER_CONFIG_BYTES = 41  # in .data, which the linker pads to an even length
CRC_LINE_BYTES = 16
WINDOW_UPDATES = True  # player_run ACKs unasked once the ring has room for a DATA frame again (link_tx.S: link_window)
STATE_NAMES = {"idle": "STATE_IDLE", "homing": "STATE_HOMING", "playing": "STATE_PLAYING",
               "finished": "STATE_FINISHED", "underrun": "STATE_UNDERRUN", "aborted": "STATE_ABORTED",
               "homing failed": "STATE_HOMING_FAILED", "fault": "STATE_FAULT"}


@dataclass(frozen=True)
class RingLayout:
    """Where the streaming image keeps its ring, and its link's rate: known before the image is built."""

    ring_start: int
    ring_bytes: int
    record_max: int  # the mirror after the ring
    variables_bytes: int
    stack_bytes: int
    baud: int  # wanted
    ubrr: int
    actual_baud: float  # F_CPU / (8 * (UBRR + 1)), double speed
    byte_cycles: int  # CPU cycles per byte on the line (10 bit times)

    @property
    def baud_error_pct(self) -> float:
        return 100 * (self.actual_baud / self.baud - 1)

    @property
    def where(self) -> str:
        return (f"SRAM 0x{self.ring_start:04X}-0x{RING_END - 1:04X} (its first {self.record_max} bytes mirrored "
                f"after it)")


@dataclass
class StreamImage(Image):
    """A streaming image: Image's figures (no table), its ring, and every SRAM byte by what holds it (ram_parts:
    variables, ring, mirror, stack)."""

    ring_address: int = 0
    ring_bytes: int = 0


def link_rate(f_cpu: int, baud: int) -> tuple[int, float]:
    """UBRR and the rate it makes at double speed for `baud`; BuildError when none comes within 2 %."""
    ubrr = round(f_cpu / (BIT_CYCLES_U2X * baud)) - 1
    if not 0 <= ubrr <= UBRR_MAX:
        raise BuildError(f"link baud rate {baud} is out of the USART's range at {f_cpu} Hz")
    actual = f_cpu / (BIT_CYCLES_U2X * (ubrr + 1))
    if abs(actual / baud - 1) > MAX_BAUD_ERROR:
        raise BuildError(f"link baud rate {baud} cannot be made within {MAX_BAUD_ERROR:.0%} at {f_cpu} Hz: the "
                         f"nearest is {actual:.0f} ({100 * (actual / baud - 1):+.1f} %)")
    return ubrr, actual


def ring_layout(config: FirmwareConfig) -> RingLayout:
    """The image's ring and link for `config` (FirmwareConfig.baud 0: the MCU file's link_baud)."""
    mcu = load_target(MCU)
    baud = config.baud or int(mcu["link_baud"])
    ubrr, actual = link_rate(int(mcu["f_cpu"]), baud)
    context = player_context(config, stream=True)
    variables = (LINK_VARIABLES + 2 * FRAME_HEAD + IDENT_PAYLOAD + protocol.MAX_ANSWER + PLAYER_VARIABLES
                 + PER_MOTOR * len(context["motors"]) + PER_PORT * len(context["step_ports"]))
    if config.heaters:
        n = len(config.heaters)
        variables += HEATER_VARIABLES + RAM_PER_HEATER * n + (HEATER_CONFIG_BYTES * n) % 2  # .data ends even
    variables += LASER_VARIABLES if config.laser else 0
    variables += JOG_PER_MOTOR * len(config.jog.motors) if config.jog else 0
    variables += HOLD_VARIABLES + HOLD_STREAM_VARIABLES if config.hold else 0
    variables += LASER_HOLD_VARIABLES if config.hold and config.laser else 0
    record_max = protocol.max_record_bytes(len(config.motors))
    start = SRAM_START + variables
    stack = SRAM_START + int(mcu["ram"]) - RING_END - record_max
    if stack < MIN_STACK_BYTES:
        raise BuildError(f"the {MCU}'s ring ends too high for {MIN_STACK_BYTES} bytes of stack")
    return RingLayout(start, RING_END - start, record_max, variables, stack, baud, ubrr, actual,
                      LINE_BITS * BIT_CYCLES_U2X * (ubrr + 1))


def crc_table_lines() -> tuple[list[str], list[str]]:
    """The CRC-16/CCITT-FALSE table (crc << 8 of each byte value) as .byte lines: its high bytes, its low bytes."""
    table = [binascii.crc_hqx(bytes([i]), 0) for i in range(256)]
    lines = []
    for shift in (8, 0):
        values = [f"0x{(t >> shift) & 0xFF:02X}" for t in table]
        lines.append([", ".join(values[i:i + CRC_LINE_BYTES]) for i in range(0, 256, CRC_LINE_BYTES)])
    return lines[0], lines[1]


def render_stream_sources(config: FirmwareConfig) -> dict[str, str]:
    """The streaming image's sources (file name -> text): config.h, link.h, stream.c, player_isr.S, link_rx.S,
    link_tx.S, homing.c when the config homes motors, the heaters' (as the flash image's) when it has them, laser.h
    for a laser, jog.c for jog keys."""
    if len(config.homing) > MAX_HOMING_AXES:
        raise BuildError(f"a streaming image homes at most {MAX_HOMING_AXES} axes, not {len(config.homing)}")
    layout = ring_layout(config)
    context = player_context(config, stream=True)
    status_payload = (7 + 4 * len(context["motors"]) + 4 * len(context["heaters"]) + (2 if config.laser else 0)
                      + (1 if config.hold else 0))
    if status_payload > protocol.MAX_ANSWER:
        raise BuildError(f"a STATUS of {len(config.motors)} motors, {len(config.heaters)} heaters and a laser "
                         f"takes {status_payload} bytes: the link's answers hold {protocol.MAX_ANSWER}")
    kinds = ("DATA", "HELLO", "START", "STATUS", "ABORT", "HOLD", "RESUME", "FEED_DOWN", "FEED_UP", "ACK", "IDENT", "STARTED", "FINISHED", "UNDERRUN",
             "STATUS_REPLY", "ABORTED", "HOMING_FAILED", "FAULT")
    crc_hi, crc_lo = crc_table_lines()
    context.update({
        "layout": layout, "actual_baud": f"{layout.actual_baud:.0f}", "rate_error": f"{layout.baud_error_pct:+.2f}",
        "version": protocol.VERSION, "identity": protocol.firmware_identity(config, context["f_cpu"],
                                                                              context["tick_hz"]),
        "frame": {"sync": protocol.SYNC, "max_payload": protocol.MAX_PAYLOAD, "rejected": protocol.REJECTED,
                  "kinds": [(name, getattr(protocol, name)) for name in kinds]},
        "states": [(STATE_NAMES[name], value) for value, name in sorted(protocol.STATES.items())],
        "ring_end": RING_END, "position_bias": POSITION_BIAS, "message_max": protocol.MAX_ANSWER,
        "ident_payload": IDENT_PAYLOAD,
        "status_payload": status_payload,
        "data_payload": link_budget(layout.baud, layout.ring_bytes, len(config.motors)).payload,
        "need_bits": ", ".join(str(m["need_bit"]) for m in context["motors"]),
        "callee_saved": CALLEE_SAVED, "crc_hi": crc_hi, "crc_lo": crc_lo,
    })
    names = STREAM_NAMES + (("homing.c",) if config.homing else ()) + (HEATER_NAMES if config.heaters else ())
    names += ("laser.h",) if config.laser else ()
    names += ("jog.c",) if config.jog else ()
    sources = {name: render(f"avr/{name}.j2", **context) for name in names}
    check_interrupts_off(sources, config, stream=True)
    return sources


def build_stream_image(sources: dict[str, str], out_dir: Path) -> StreamImage:
    """Build render_stream_sources' sources into out_dir (firmware.hex, firmware.elf) as build_image does, and
    check that the variables end where the ring begins; BuildError leaves neither image file behind."""
    image = build_image(sources, out_dir, 0)
    symbols = elf_symbols(image.elf_path)
    start, end, variables_end = symbols["ring_start"], symbols["ring_end"], symbols["_end"]
    if variables_end != start:
        for path in (image.hex_path, image.elf_path):
            path.unlink(missing_ok=True)
        raise BuildError(f"the streaming image's variables end at 0x{variables_end:04X}, its ring starts at "
                         f"0x{start:04X}: avr_stream.ring_layout counts them wrong")
    ram = image.ram_capacity
    mirror = symbols["ring_mirror"]
    parts = {"variables": start - SRAM_START, "ring": end - start, "mirror": mirror,
             "stack": SRAM_START + ram - end - mirror}
    fields = {name: getattr(image, name) for name in Image.__dataclass_fields__} | {"ram_parts": parts}
    return StreamImage(**fields, ring_address=start, ring_bytes=end - start)


def elf_symbols(elf: Path) -> dict[str, int]:
    """Every symbol's value in an ELF (data addresses without avr-ld's 0x800000)."""
    out = run_avr(["avr-nm", elf.name], elf.parent, "avr-nm").stdout
    return {parts[2]: int(parts[0], 16) & 0x7FFFFF for parts in (line.split() for line in out.splitlines())
            if len(parts) == 3}

"""The 8051 streaming firmware: the step player of codegen/firmware/mcs51.py with no table inside, playing the
records that come over the UART (codegen/link/protocol.py) from a ring buffer in XRAM.

One firmware per machine and board (`build --stream`): templates/mcs51/player.c.j2 rendered with `stream` (the
same interrupt, reading with MOVX @R1 from the ring instead of MOVC from code memory), link.c.j2 (the serial
interrupt and the session) and link.h.j2, homing.c.j2 (homing at START) and the board's display. The ring is one
256-byte page of XRAM read and written with MOVX @Ri only (so neither interrupt drives P2 with an address: the
seed board's display shares P2), its indexes wrapping by themselves: 255 bytes for the host to fill. Built like
the flashed image (mcs51_sdcc.build_image), with the map symbols the closed-loop simulation needs
(codegen/sim/mcs51_link.py) in firmware.sym.json.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from codegen.errors import BuildError
from codegen.firmware import FirmwareConfig, Image
from codegen.firmware.mcs51 import board_data, memories, player_context, render_player
from codegen.firmware.mcs51_sdcc import BuildPlan, build_image
from codegen.link import protocol

PAGE_BYTES = 256  # MOVX @Ri reaches one page; its indexes wrap at 256
RING_BYTES = PAGE_BYTES - 1  # a full ring and an empty one must differ
DEFAULT_BAUD = 9600
MAX_BAUD_ERROR_PCT = 2.5
T2_CLOCKS_PER_BAUD = 32  # Timer2 as baud generator: f_cpu / (32 x (65536 - RCAP2))
PLAYER_BANK_PSW = 0x10  # the step interrupt's registers: bank 2 (R0 = the ring's read index at 0x10)
MAX_STEP_PORTS = 3  # the step interrupt's head at 0x000B must end before the serial vector at 0x0023
STREAM_SYMBOLS = (("timer_start", "_timer_start"), ("isr", "_player_isr"), ("link_isr", "_link_isr"),
                  ("poll", "_link_poll"), ("tx_end", "_link_tx_end"), ("need_run", "_pl_need_run"),
                  ("need_block", "_pl_need_block"), ("need_brun", "_pl_need_brun"), ("link_head", "_link_head"),
                  ("committed", "_lk_committed"))
HOMING_SYMBOLS = (("homing_poll", "_homing_poll"), ("homing_fault", "_homing_fault"))
LINK_AREA = "LINK"  # link.c's code area (#pragma codeseg): its own flash part


@dataclass(frozen=True)
class RingLayout:
    """Where the ring is and how fast the link runs, for a board (and a baud rate)."""

    ring_bytes: int  # what the host may fill
    where: str
    on_chip: bool  # the MCU's own XRAM (MOVX @Ri ignores P2) or external RAM (P2's latch gives the page)
    page: int  # the ring's page: address bits 8.. (external RAM: its top page, P2's reset state)
    xram: int  # the board's XRAM bytes
    c_xram: int  # XRAM left to C's variables (below the ring)
    model: str  # SDCC's memory model
    baud: int
    reload: int  # RCAP2
    actual_baud: float
    baud_error_pct: float


def ring_layout(config: FirmwareConfig) -> RingLayout:
    """The ring in the board's XRAM and the UART's Timer2 reload for config.baud (0: 9600); BuildError for a board
    without XRAM, or a baud rate the crystal cannot make within MAX_BAUD_ERROR_PCT."""
    board, mcu = board_data(config.board)
    mem = memories(config.board)
    on_chip = int(mcu.get("xram", 0)) > 0
    xram = int(mem["xram"])
    if xram < PAGE_BYTES:
        raise BuildError(
            f"board {config.board} has no XRAM: the streaming player keeps its ring buffer ({RING_BYTES} bytes, one "
            f"MOVX page) in XRAM, and the {mem['iram']} bytes of internal RAM of the {mem['mcu']} already hold the "
            f"registers, the player's and the link's state and the stack (about 200 bytes on seed-51), too little "
            f"left for a ring of even two DATA frames and a record; use a board with XRAM: seed-51 (512 B of "
            f"external RAM) or stc89c52rc (256 B on-chip)")
    if xram & (xram - 1):
        raise BuildError(f"board {config.board}: {xram} bytes of XRAM is not a power of two (the ring takes the top "
                         f"256-byte page, whose address lines P2 holds high)")
    page = 0 if on_chip else xram // PAGE_BYTES - 1
    c_xram = xram - PAGE_BYTES
    f_cpu = int(mem["f_cpu"])
    baud = int(config.baud or DEFAULT_BAUD)
    counts = round(f_cpu / (T2_CLOCKS_PER_BAUD * baud))
    if not 1 <= counts <= 0xFFFF:
        raise BuildError(f"{baud} baud is out of Timer2's range at {f_cpu} Hz")
    actual = f_cpu / (T2_CLOCKS_PER_BAUD * counts)
    error = (actual / baud - 1) * 100
    if abs(error) > MAX_BAUD_ERROR_PCT:
        raise BuildError(f"{baud} baud: Timer2 at {f_cpu} Hz makes {actual:.0f} baud at best ({error:+.2f} %), more "
                         f"than {MAX_BAUD_ERROR_PCT} % off; choose another machine.link.baud (9600 is 0.16 % off at "
                         f"12 MHz) or an 11.0592 MHz crystal")
    start = page * PAGE_BYTES
    where = (f"on-chip XRAM 0x{start:04X}-0x{start + RING_BYTES:04X}, MOVX @Ri whatever P2" if on_chip else
             f"external RAM 0x{start:04X}-0x{start + RING_BYTES:04X}, the page P2's latch gives (high from reset)")
    return RingLayout(RING_BYTES, where, on_chip, page, xram, c_xram, "small" if c_xram == 0 else str(mem["model"]),
                      baud, 0x10000 - counts, actual, error)


def render_stream_sources(config: FirmwareConfig) -> dict[str, str]:
    """The C sources of the streaming firmware (file name -> text): config.h, link.h, link.c, player.c, and
    homing.c when the machine homes at START, lcd.c and lcd.h when the board has a display."""
    layout = ring_layout(config)
    context, lcd = player_context(config, stream=True)
    if any(m["coil"] for m in context["motors"]):
        raise BuildError(f"board {config.board}: the streaming player drives STEP/DIR sockets, not coils")
    if len(context["step_ports"]) > MAX_STEP_PORTS:
        raise BuildError(f"board {config.board}: the streaming player takes STEP pins on at most {MAX_STEP_PORTS} "
                         f"ports (its interrupt's head must end before the serial vector)")
    mem = memories(config.board)
    states = [(name.upper().replace(" ", "_"), value) for value, name in sorted(protocol.STATES.items())]
    ident = protocol.Ident(protocol.VERSION, protocol.firmware_identity(config, int(mem["f_cpu"]),
                                                                       int(mem["tick_hz"])),
                           layout.ring_bytes, len(config.motors)).payload()
    types = {name: getattr(protocol, name) for name in ("DATA", "HELLO", "START", "STATUS", "ABORT", "ACK", "IDENT",
                                                        "STARTED", "FINISHED", "UNDERRUN", "STATUS_REPLY",
                                                        "ABORTED", "HOMING_FAILED")}
    context.update(
        ring={"bytes": layout.ring_bytes, "where": layout.where},
        ring_need=protocol.max_record_bytes(len(config.motors)), player_bank_psw=PLAYER_BANK_PSW,
        link={"version": protocol.VERSION, "baud": layout.baud, "baud_error_pct": layout.baud_error_pct,
              "reload": layout.reload, "actual_baud": layout.actual_baud, "sync": protocol.SYNC,
              "max_payload": protocol.MAX_PAYLOAD, "max_answer": protocol.MAX_ANSWER, "types": types,
              "rejected": protocol.REJECTED, "states": states, "ident": list(ident)})
    return render_player(context, lcd, config, ("config.h", "link.h", "link.c"))


def build_stream_image(sources: dict[str, str], out_dir: Path) -> Image:
    """Build firmware.hex of render_stream_sources' sources in out_dir (mcs51_sdcc.build_image: the same files and
    report; table_bytes 0, flash part `link` for link.c's code, `ring_bytes` among the sections)."""
    board = re.search(r'#define BOARD_NAME "([^"]+)"', sources.get("config.h", ""))
    if not board:
        raise BuildError("config.h does not name its board")
    layout = ring_layout(FirmwareConfig("", "", "mcs51", board.group(1), ()))
    symbols = STREAM_SYMBOLS + (HOMING_SYMBOLS if "homing.c" in sources else ())
    plan = BuildPlan(model=layout.model, xram=layout.c_xram, symbols=symbols, required=(),
                     sym_extra={"ring_page": layout.page, "ring_bytes": layout.ring_bytes, "xram": layout.xram,
                                "on_chip_xram": layout.on_chip, "player_bank": PLAYER_BANK_PSW},
                     parts=((LINK_AREA, "link"),))
    image = build_image(sources, out_dir, 0, plan)
    image.sections["ring_bytes"] = PAGE_BYTES
    return image

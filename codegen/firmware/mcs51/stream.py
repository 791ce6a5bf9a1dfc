"""The 8051 streaming firmware: the step player of codegen/firmware/mcs51/image.py with no table inside, playing the
records that come over the UART (codegen/link/protocol.py) from a ring buffer in XRAM, or in internal RAM on a
board without XRAM.

One firmware per machine and board (`build --stream`): templates/mcs51/player.c.j2 rendered with `stream` (the
same interrupt, reading from the ring instead of with MOVC from code memory), link.c.j2 (the serial interrupt and
the session) and link.h.j2, homing.c.j2 (homing at START) and the board's display. The ring's indexes (the link's
head, the player's read index R0) are 8-bit counters wrapping by themselves, the ring's fill their difference:
- XRAM: the ring is one 256-byte page read and written with MOVX @Ri only (so neither interrupt drives P2 with an
  address: the seed board's display shares P2), an index its address: 255 bytes for the host to fill.
- Internal RAM (no XRAM): the top RING_SIZE bytes (128, 64 or 32: the largest that leaves room below it for the
  variables and a measured stack reserve; SDCC links them below it), read and written with MOV @Ri at the address
  index | RING_BASE (= RING_BASE + index mod RING_SIZE), RING_SIZE - 1 bytes for the host to fill.
Built like the flashed image (mcs51_sdcc.build_image), with the map symbols the closed-loop simulation needs
(codegen/sim/mcs51_link.py) in firmware.sym.json.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig, Image
from codegen.firmware.mcs51.board import board_data, memories
from codegen.firmware.mcs51.image import player_context, render_player
from codegen.firmware.mcs51.sdcc import BuildPlan, build_image
from codegen.link import protocol
from codegen.link.ring import MIN_PAYLOAD, link_budget

PAGE_BYTES = 256  # MOVX @Ri reaches one page; its indexes wrap at 256
RING_BYTES = PAGE_BYTES - 1  # a full ring and an empty one must differ
WINDOW_UPDATES = True  # main ACKs unasked once the ring has room for a DATA frame again (link.c.j2: window_update)
IRAM_RING_SIZES = (128, 64, 32)  # bytes: a power of two at the top of internal RAM, so index | base addresses it
# Where the streaming firmware's variables end in internal RAM, and SDCC starts the stack (below a ring there):
# under 0x20 the register banks 0-2 and the overlay; from 0x20 the bit variables, then data and idata (a port:
# the pending, masters' and raised STEP pins; a motor: 14 bytes of the player's and 4 of the link's positions, 4 of
# the answer; homing: its state). Measured on the at89c52 (the .mem file's "Stack starts at") for 1-4 motors with
# 0-3 homed axes; build_image checks the stack it leaves.
IRAM_BITS_START = 0x20
IRAM_BITS, IRAM_BITS_PER_MOTOR, IRAM_BITS_HOMING = 13, 1, 1
IRAM_DATA, IRAM_DATA_PER_MOTOR, IRAM_DATA_PER_PORT = 59, 18, 3
IRAM_HOMING, IRAM_HOMING_PER_AXIS = 11, 8
IRAM_HOLD = 23  # feed hold's (measured the same way): the dilated path's 19 bytes and 3 bits, hold.c's 2 bytes
# Stack bytes kept free below the ring: main's deepest calls (link_poll, stopped, exact_positions, position: 11
# bytes; 16 after a homing failure, when the player cannot run) + the serial interrupt (4) + the step interrupt
# on top of it (4), from SDCC 4.2's listings. The deepest stack seen in s51 (a write breakpoint on every byte
# above the variables): 11 bytes playing to the end, to an underrun or an abort; 15 homing; 17 after a homing
# failure.
STACK_RESERVE = 20
HOLD_STACK = 3  # with feed hold, the step interrupt's dilated path pushes B and DPTR too
DEFAULT_BAUD = 9600
MAX_BAUD_ERROR_PCT = 2.5
T2_CLOCKS_PER_BAUD = 32  # Timer2 as baud generator: f_cpu / (32 x (65536 - RCAP2))
STATUS_HEAD = 7  # STATUS_REPLY's payload before the positions (i32 per motor): state, played u32, fill u16
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
    page: int  # the ring's XRAM page: address bits 8.. (external RAM: its top page, P2's reset state)
    xram: int  # the board's XRAM bytes
    c_xram: int  # XRAM left to C's variables (below the ring)
    model: str  # SDCC's memory model
    baud: int
    reload: int  # RCAP2
    actual_baud: float
    baud_error_pct: float
    iram_base: int = 0  # an internal-RAM ring's first address (0: the ring is in XRAM)

    @property
    def size(self) -> int:
        """The ring's bytes of memory: one more than the host may fill."""
        return self.ring_bytes + 1


def iram_need(config: FirmwareConfig) -> int:
    """The first internal RAM address above the streaming firmware's variables (no display): where its stack
    starts below a ring in internal RAM."""
    context, _ = player_context(config, stream=True)
    motors, axes = len(context["motors"]), len(config.homing)
    bits = IRAM_BITS + IRAM_BITS_PER_MOTOR * motors + (IRAM_BITS_HOMING if axes else 0)
    data = (IRAM_DATA + IRAM_DATA_PER_MOTOR * motors + IRAM_DATA_PER_PORT * len(context["step_ports"])
            + (IRAM_HOMING + IRAM_HOMING_PER_AXIS * axes if axes else 0) + (IRAM_HOLD if config.hold else 0))
    return IRAM_BITS_START + -(-bits // 8) + data


def _iram_ring(config: FirmwareConfig, iram: int) -> tuple[int, int]:
    """(size, first address) of the largest ring of IRAM_RING_SIZES at the top of internal RAM that leaves room for
    the variables and the stack reserve below it; BuildError when it would not hold two DATA frames of the
    smallest payload and the longest record."""
    need = iram_need(config)
    stack = STACK_RESERVE + (HOLD_STACK if config.hold else 0)
    free = iram - need - stack
    size = next((n for n in IRAM_RING_SIZES if n <= free), 0)
    frames = 2 * (MIN_PAYLOAD + protocol.OVERHEAD_BYTES)
    record = protocol.max_record_bytes(len(config.motors))
    if size - 1 < frames + record:
        raise BuildError(
            f"board {config.board} has no XRAM, and its internal RAM leaves too little for the streaming player's "
            f"ring buffer: the ring must hold {frames + record} bytes (two DATA frames of {MIN_PAYLOAD} bytes + "
            f"{protocol.OVERHEAD_BYTES} of overhead each, and the longest record of {len(config.motors)} motors: "
            f"{record}); the largest ring of {', '.join(map(str, IRAM_RING_SIZES))} bytes that fits holds "
            f"{max(size - 1, 0)} ({free} of the {iram} bytes are free after the variables' {need} and a stack of "
            f"{stack}); use fewer motors or homed axes, or a board with XRAM (seed-51: 512 B external; "
            f"stc89c52rc: 256 B on-chip)")
    return size, iram - size


def ring_layout(config: FirmwareConfig) -> RingLayout:
    """The ring (the board's XRAM, else the top of its internal RAM) and the UART's Timer2 reload for config.baud
    (0: 9600); BuildError for a ring too small, or a baud rate the crystal cannot make within MAX_BAUD_ERROR_PCT."""
    board, mcu = board_data(config.board)
    mem = memories(config.board)
    on_chip = int(mcu.get("xram", 0)) > 0
    xram = int(mem["xram"])
    iram = int(mem["iram"])
    if 0 < xram < PAGE_BYTES or xram & (xram - 1):
        raise BuildError(f"board {config.board}: {xram} bytes of XRAM is not a power of two of at least a page "
                         f"(the ring takes the top 256-byte page, whose address lines P2 holds high)")
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
    link = {"baud": baud, "reload": 0x10000 - counts, "actual_baud": actual, "baud_error_pct": error}
    if xram == 0:
        size, base = _iram_ring(config, iram)
        where = f"internal RAM 0x{base:02X}-0x{iram - 1:02X} (MOV @Ri), the variables and the stack below it"
        return RingLayout(size - 1, where, False, 0, 0, 0, str(mem["model"]), **link, iram_base=base)
    page = 0 if on_chip else xram // PAGE_BYTES - 1
    c_xram = xram - PAGE_BYTES
    start = page * PAGE_BYTES
    where = (f"on-chip XRAM 0x{start:04X}-0x{start + RING_BYTES:04X}, MOVX @Ri whatever P2" if on_chip else
             f"external RAM 0x{start:04X}-0x{start + RING_BYTES:04X}, the page P2's latch gives (high from reset)")
    return RingLayout(RING_BYTES, where, on_chip, page, xram, c_xram, "small" if c_xram == 0 else str(mem["model"]),
                      **link)


def render_stream_sources(config: FirmwareConfig) -> dict[str, str]:
    """The C sources of the streaming firmware (file name -> text): config.h, link.h, link.c, player.c, and
    homing.c when the machine homes at START, lcd.c and lcd.h when the board has a display. BuildError for jog
    keys: seed-51's matrix is on P0, the bus to the external RAM that holds the ring (the serial interrupt writes
    it at any time, and a held key would join two of the bus's lines); on the other boards it is not built yet."""
    if config.jog:
        raise BuildError(f"machine.jog: the 8051 streaming firmware has no jog mode (seed-51's key matrix is on "
                         f"P0, the bus to the external RAM that holds its ring): the flash image has one; leave "
                         f"`jog:` out to stream to board {config.board}")
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
                                                        "ABORTED", "HOMING_FAILED", "HOLD", "FEED_UP")}
    context.update(
        ring={"bytes": layout.ring_bytes, "where": layout.where, "iram": layout.iram_base > 0,
              "base": layout.iram_base, "size": layout.size},
        ring_need=protocol.max_record_bytes(len(config.motors)), player_bank_psw=PLAYER_BANK_PSW,
        link={"version": protocol.VERSION, "baud": layout.baud, "baud_error_pct": layout.baud_error_pct,
              "reload": layout.reload, "actual_baud": layout.actual_baud, "sync": protocol.SYNC,
              "max_payload": protocol.MAX_PAYLOAD, "types": types, "rejected": protocol.REJECTED, "states": states,
              "payload": link_budget(layout.baud, layout.ring_bytes, len(config.motors)).payload,
              "ident": list(ident),
              "max_answer": max(len(ident), STATUS_HEAD + 4 * len(config.motors) + (config.hold is not None))})
    return render_player(context, lcd, config, ("config.h", "link.h", "link.c"))


def build_stream_image(sources: dict[str, str], out_dir: Path) -> Image:
    """Build firmware.hex of render_stream_sources' sources in out_dir (mcs51_sdcc.build_image: the same files and
    report; table_bytes 0, flash part `link` for link.c's code, `ring_bytes` among the sections: the ring's memory).
    An internal-RAM ring (link.h's RING_BASE) keeps SDCC's variables below it, with STACK_RESERVE bytes of stack."""
    board = re.search(r'#define BOARD_NAME "([^"]+)"', sources.get("config.h", ""))
    if not board:
        raise BuildError("config.h does not name its board")
    mem = memories(board.group(1))
    iram_ring = re.search(r"#define RING_BASE (0x[0-9A-F]+)", sources.get("link.h", ""))
    symbols = STREAM_SYMBOLS + (HOMING_SYMBOLS if "homing.c" in sources else ())
    sym_extra = {"player_bank": PLAYER_BANK_PSW}
    if iram_ring:
        base = int(iram_ring.group(1), 16)
        size = int(mem["iram"]) - base
        plan = BuildPlan(model=str(mem["model"]), xram=0, iram=base,
                         stack=STACK_RESERVE + (HOLD_STACK if "hold.c" in sources else 0))
        sym_extra.update(ring_base=base, ring_bytes=size - 1, xram=0, on_chip_xram=False)
    else:
        layout = ring_layout(FirmwareConfig("", "", "mcs51", board.group(1), ()))
        size = PAGE_BYTES
        plan = BuildPlan(model=layout.model, xram=layout.c_xram)
        sym_extra.update(ring_page=layout.page, ring_bytes=layout.ring_bytes, xram=layout.xram,
                         on_chip_xram=layout.on_chip)
    plan = replace(plan, symbols=symbols, required=(), sym_extra=sym_extra, parts=((LINK_AREA, "link"),))
    image = build_image(sources, out_dir, 0, plan)
    image.sections["ring_bytes"] = size
    if iram_ring:
        image.ram_bytes += size  # the variables, and the ring above them
    return image

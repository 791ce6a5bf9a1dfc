"""Jog keys in simavr: a key script (codegen/sim/keys.py) as the harness's key= options (simavr_keys.c: each
board key's pin held low while pressed), and the firmware's jog position counts read from its RAM at the end
(dump=, the ELF's jog_pos_* symbols: little-endian int32 per jogged motor)."""

from __future__ import annotations

from pathlib import Path

from codegen.errors import BuildError
from codegen.firmware.avr.board import parse_pin
from codegen.firmware.avr.jog import taken_pins
from codegen.firmware.avr.stream import elf_symbols
from codegen.firmware.config import FirmwareConfig, load_target
from codegen.motion.jog import board_keys
from codegen.sim.keys import KeyPress

POSITION_BYTES = 4


def key_args(config: FirmwareConfig, script: list[KeyPress], elf: Path,
             f_cpu: int) -> tuple[list[str], list[int], int]:
    """The harness options that press the script's keys and report the jog positions; the positions' addresses
    and the first of them (for jog_positions)."""
    board = load_target(config.board)
    wiring = board_keys(config.board, board, config.jog.keys, parse_pin, taken_pins(board))
    missing = sorted({k.key for k in script} - set(wiring.keys))
    if missing:
        raise BuildError(f"board {config.board} has no jog key {', '.join(missing)}")
    args = []
    for k in script:
        pin = wiring.keys[k.key]
        args.append(f"key={pin.port}{pin.bit},{int(round(k.press_s * f_cpu))},{int(round(k.release_s * f_cpu))}")
    symbols = elf_symbols(elf)
    names = [f"jog_pos_{config.motors[m].name}" for m in config.jog.motors]
    addresses = [symbols.get(n) for n in names]
    if None in addresses:
        raise BuildError(f"{elf} lacks {', '.join(n for n, a in zip(names, addresses) if a is None)}")
    first = min(addresses)
    if sorted(addresses) != [first + POSITION_BYTES * i for i in range(len(addresses))]:
        raise BuildError(f"{elf}: the jog positions are not side by side ({names}: {addresses})")
    return args + [f"dump={first},{POSITION_BYTES * len(addresses)}"], addresses, first


def jog_positions(dump: str, addresses: list[int], first: int) -> list[int]:
    """The jog positions (steps from power-up) from the harness's dump, in the jogged motors' order."""
    raw = bytes.fromhex(dump)
    out = []
    for a in addresses:
        value = int.from_bytes(raw[a - first:a - first + POSITION_BYTES], "little")
        out.append(value - (1 << 32) if value >= 1 << 31 else value)
    return out

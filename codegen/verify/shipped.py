"""The step table a flash image ships, read back from its hex file and decoded (codegen/tables/decode.py), against
the schedule the twin plays: verify's pulse comparison proves the schedule, this proves the bytes are that schedule.

Where the table is: the ATmega2560's table_chunk_0 and the chunks after it, back to back (the ELF's symbols); the
8051's `_table` (SDCC's map file). Intel HEX records 00 (data), 01 (end), 02 and 04 (address bases) are read.
"""

from __future__ import annotations

from pathlib import Path

from codegen.errors import BuildError
from codegen.firmware.avr.stream import elf_symbols
from codegen.firmware.mcs51.sdcc import MAP_FILE, read_map
from codegen.tables.decode import TableError, decode, differences
from codegen.tables.schedule import Schedule


def read_hex(path: Path) -> dict[int, int]:
    """Every byte of an Intel HEX file: address -> value."""
    memory: dict[int, int] = {}
    base = 0
    for number, line in enumerate(Path(path).read_text(encoding="ascii").splitlines(), 1):
        if not line.startswith(":"):
            continue
        raw = bytes.fromhex(line[1:])
        if len(raw) < 5 or len(raw) != raw[0] + 5 or sum(raw) & 0xFF:
            raise BuildError(f"{path}:{number}: not an Intel HEX record (length or checksum)")
        kind, address, payload = raw[3], raw[1] << 8 | raw[2], raw[4:-1]
        if kind == 0:
            memory.update((base + address + k, b) for k, b in enumerate(payload))
        elif kind == 2:
            base = int.from_bytes(payload, "big") << 4
        elif kind == 4:
            base = int.from_bytes(payload, "big") << 16
        elif kind == 1:
            break
    return memory


def table_address(image, target: str) -> int:
    if target == "avr":
        return elf_symbols(image.elf_path)["table_chunk_0"]
    return read_map(image.hex_path.with_name(MAP_FILE))[1]["_table"]


def shipped_table(image, target: str) -> bytes:
    """The table's bytes as they stand in the image's hex file."""
    memory = read_hex(image.hex_path)
    start = table_address(image, target)
    missing = [a for a in range(start, start + image.table_bytes) if a not in memory]
    if missing:
        raise BuildError(f"{image.hex_path}: the table's byte at {missing[0]:#x} is not in the image")
    return bytes(memory[a] for a in range(start, start + image.table_bytes))


def shipped_problems(image, target: str, schedule: Schedule) -> list[str]:
    """Verify's problems when the image's table is not the schedule the twin plays (none when it is)."""
    try:
        decoded = decode(shipped_table(image, target), len(schedule.motors))
    except TableError as exc:
        return [f"the image's table is not a table stream: {exc}"]
    return [f"the image's table is not the plan's: {p}" for p in differences(decoded, schedule)]

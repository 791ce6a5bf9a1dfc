"""verify reads the step table back from the image it checks (codegen/verify/shipped.py): an image whose table
bytes differ from the plan fails, with the record named, though its pulses may look fine."""

from __future__ import annotations

import json
import shutil

import pytest

from codegen.cli.main import main
from codegen.verify.shipped import read_hex, shipped_table, table_address
from tests.helpers import EXAMPLES


def patch_hex(path, address: int, flip: int) -> None:
    """XOR the byte at `address` with `flip` in an Intel HEX file (its record's checksum made again)."""
    lines = path.read_text().splitlines()
    base = 0
    for k, line in enumerate(lines):
        raw = bytearray.fromhex(line[1:])
        if raw[3] == 4:
            base = int.from_bytes(raw[4:6], "big") << 16
        start = base + (raw[1] << 8 | raw[2])
        if raw[3] == 0 and start <= address < start + raw[0]:
            raw[4 + address - start] ^= flip
            raw[-1] = -sum(raw[:-1]) & 0xFF
            lines[k] = ":" + raw.hex().upper()
            path.write_text("\n".join(lines) + "\n")
            return
    raise AssertionError(f"no byte at {address:#x}")


@pytest.mark.parametrize("name, target", [("line.yaml", "avr"), ("plotter-set-51.yaml", "mcs51")])
def test_an_image_whose_table_is_not_the_plan_fails_verify(tmp_path, capsys, name, target):
    if shutil.which("simavr" if target == "avr" else "s51") is None:
        pytest.skip("needs the simulator (scripts/setup.sh installs it)")
    job = EXAMPLES / name
    out = tmp_path / "out"
    assert main(["build", str(job), "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    image = type("Image", (), {"hex_path": out / "firmware.hex", "elf_path": out / "firmware.elf",
                               "table_bytes": report["image"]["table_bytes"]})
    table = shipped_table(image, target)
    assert table[-2:] in (b"\0\0", b"\x40\0")  # the end marker is where the table ends
    patch_hex(out / "firmware.hex", table_address(image, target) + len(table) - 2, 0x40)  # the tool on at the end
    assert read_hex(out / "firmware.hex")[table_address(image, target) + len(table) - 2] == table[-2] ^ 0x40
    capsys.readouterr()
    code = main(["verify", str(job), "--out", str(out), "--json"])
    result = json.loads(capsys.readouterr().out)
    assert code == 1 and not result["pass"]
    assert result["problems"][0] == ("the image's table is not the plan's: the end marker leaves the tool "
                                     f"{'on' if table[-2] == 0 else 'off'}, planned {'off' if table[-2] == 0 else 'on'}")

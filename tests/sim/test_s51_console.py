"""The s51 console driver of the 8051 stream harness (codegen/sim/mcs51_link.py _Console): s51 echoes its input
99 bytes at a time and runs a command between two reads, so a batch longer than a read once lost its sim_ticks
(CI: IndexError) and could read a piece of an echoed line as a number. Batches go in pieces whose echoes are whole
lines; these tests hold the numbers read back to exactly what the commands print, in real s51."""

from __future__ import annotations

import random

from codegen.sim.mcs51_link import GATE, PICK_BYTES, _Console, _pieces


def test_pieces_are_whole_lines_of_exactly_one_read():
    lines = [f"let tw={10 ** k}" for k in range(12)] + ["let uart0_check_often=1"] * 5
    pieces = _pieces(lines)
    assert all(len(p) == PICK_BYTES and p.endswith("\n") for p in pieces)
    assert [line.rstrip() for p in pieces for line in p.splitlines()] == lines


def test_batches_longer_than_a_read_give_exactly_the_numbers_printed(tmp_path):
    """300 batches of 60 to 400 bytes, with digit-ended commands before and after the marker (the echo pieces
    that once read as numbers): each batch returns exactly the values of its `then` commands."""
    rng = random.Random(27)
    console = _Console(["s51"], tmp_path)
    try:
        console.setup(["var tb", "var tw"], 30)
        for _ in range(300):
            before = [f"let tb={rng.randrange(10 ** 9)}" for _ in range(rng.randrange(0, 12))]
            values = [rng.randrange(-2 ** 31, 2 ** 31) for _ in range(rng.randrange(1, 4))]
            assert console.batch(before, [f"let {v}" for v in values], 10) == values
    finally:
        console.close()
    assert console.proc.returncode == 0


def test_the_gate_is_named_in_s51s_working_directory(tmp_path):
    console = _Console(["s51"], tmp_path)
    try:
        assert (tmp_path / GATE.split('"')[1]).exists()
    finally:
        console.close()

"""The table stream read back as a player reads it (codegen/tables/decode.py): every example's tables decode to
their schedule, and each kind of wrong byte is named with the record and the byte where it is."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from codegen.tables.decode import TableError, decode, differences
from codegen.tables.format import encode, stream_bytes
from tests.helpers import make_schedule

EXAMPLES = ["star.yaml", "kossel-mini.yaml", "gcode/laser-hiking.yaml", "plotter-set-51.yaml", "delta-seed.yaml"]


@pytest.mark.parametrize("name", EXAMPLES)
def test_every_example_decodes_to_its_schedule(planned_example, name):
    """Short and long blocks and runs, dwells, a laser's power records, runtime records (delta-seed homes)."""
    schedule = planned_example(name).schedule
    decoded = decode(encode(schedule).data, len(schedule.motors))
    assert differences(decoded, schedule) == []
    assert len(decoded.modulus) == schedule.n_blocks and len(decoded.runs) == schedule.n_runs


def test_a_wrong_byte_is_named_where_it_is(planned_example):
    schedule = planned_example("plotter-set-51.yaml").schedule  # x and y
    table = encode(schedule)
    data = bytearray(table.data)
    run = 5
    assert not table.block_long.all()
    block = int((~table.block_long).argmax())  # the first short block: flags, modulus, the slave's steps and init
    at = int(table.block_offsets[block])
    data[at + 3] ^= 1
    problems = differences(decode(bytes(data), len(schedule.motors)), schedule)
    assert len(problems) == 1 and problems[0].startswith(f"block {block} (byte {at}): Bresenham start")
    data = bytearray(table.data)
    decoded = decode(table.data, len(schedule.motors))
    at = decoded.run_at[run]
    data[at + 2] ^= 0x10  # run 5's interval, its middle byte
    problems = differences(decode(bytes(data), len(schedule.motors)), schedule)
    count, interval, add = (int(a[run]) for a in (schedule.run_count, schedule.run_interval, schedule.run_add))
    assert problems == [f"run {run} (byte {at}): count, interval, add {[count, interval ^ 0x1000, add]}, "
                        f"planned {[count, interval, add]}"]


def test_laser_power_and_the_end_markers_tool(planned_example):
    schedule = planned_example("gcode/laser-hiking.yaml").schedule
    table = encode(schedule)
    data = bytearray(table.data)
    at = int(table.power_offsets[3])
    data[at + 3] ^= 1
    data[-2] ^= 0x40  # the tool bit of the end marker
    problems = differences(decode(bytes(data), len(schedule.motors)), schedule)
    assert any(p.startswith("run ") and ": power " in p for p in problems)
    assert problems[-1].startswith("the end marker leaves the tool")


def test_bytes_that_are_no_table_stream(planned_example):
    schedule = planned_example("star.yaml").schedule
    data = encode(schedule).data
    with pytest.raises(TableError, match="ends inside a record"):
        decode(data[:len(data) // 2], len(schedule.motors))
    with pytest.raises(TableError, match="3 bytes after the end marker"):
        decode(data + b"\0\0\0", len(schedule.motors))


@settings(max_examples=120, deadline=None, derandomize=True)
@given(data=st.data())
def test_any_corrupted_table_is_named_never_a_traceback(planned_example, data):
    """Bytes changed anywhere (counts, runs, flags, the end marker): decode either reads a table, whose differences
    from the plan are named, or refuses it with a TableError; no other exception (numpy's included). (A change in
    bits no player reads, a long record's master bits, reads as the same table.)"""
    schedule = planned_example("star.yaml").schedule
    table = bytearray(encode(schedule).data)
    for _ in range(data.draw(st.integers(1, 4))):
        table[data.draw(st.integers(0, len(table) - 1))] = data.draw(st.integers(0, 255))
    try:
        decoded = decode(bytes(table), len(schedule.motors))
    except TableError as err:
        assert str(err)
        return
    assert all(isinstance(p, str) for p in differences(decoded, schedule))


def test_a_short_block_stores_the_start_of_its_bresenham_slaves_only():
    """Flags, modulus, every slave's steps, then the init of each slave that steps at some events and not all:
    4 motors, the master y (steps 9 = the modulus); x at 3 of 9 events, z idle, e at every event."""
    schedule = make_schedule(("x", "y", "z", "e"), [((1, -1, 1, 1), (3, 9, 0, 9), 9, (4, 0, 4, 0), False,
                                                      [(256 * 500, 0, 9)]),
                                                     ((1, 1, 1, 1), (2, 7, 5, 0), 7, (3, 0, 1, 3), False,
                                                      [(256 * 500, 0, 7)])])
    table = encode(schedule)
    first, second = (table.data[a:b] for a, b in zip(table.block_offsets, [*table.block_offsets[1:], None]))
    flags = schedule.block_flags()
    assert first[:6] == bytes([flags[0] | 1 << 4, 9, 3, 0, 9, 4])  # then the run
    assert second[:7] == bytes([flags[1] | 1 << 4, 7, 2, 5, 0, 3, 1])
    assert len(table.data) == stream_bytes(schedule) == 6 + 7 + 2 * 6 + 2
    assert differences(decode(table.data, 4), schedule) == []

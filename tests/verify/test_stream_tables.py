"""A stream's table bytes decoded window by window and held against each window's schedule
(codegen/verify/stream_tables.py): the bytes the planner writes pass, a changed byte is named with its window, its
record and its place, and bytes that are no table stream are refused without a traceback."""

from __future__ import annotations

import dataclasses

import pytest

from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.pipeline.streaming import stream_setup
from codegen.verify.stream_tables import StreamTableCheck
from tests.helpers import DATA


@pytest.fixture(scope="module")
def streamed_tables(tmp_path_factory):
    """The windows' table schedules and event counts of a job planned in several windows, and its table stream."""
    job = load_job(DATA / "mutants" / "windows.yaml")
    windows = []
    path = tmp_path_factory.mktemp("stream") / "table.bin"
    with open(path, "wb") as table:
        host_build(job, keep=False, tables=table, link=stream_setup(job).budget,
                   observe=lambda p: windows.append((p.table_schedule, p.events_count)))
    return windows, path.read_bytes(), len(job.machine.motor_names)


def checked(windows, data: bytes, motors: int, tmp_path) -> list[str]:
    path = tmp_path / "sent.bin"
    path.write_bytes(data)
    check = StreamTableCheck(path, motors)
    for schedule, events in windows:
        check.window(schedule, events)
    return check.close()


def test_the_planned_stream_passes_window_by_window(streamed_tables, tmp_path):
    windows, data, motors = streamed_tables
    assert len(windows) >= 3
    assert checked(windows, data, motors, tmp_path) == []


def test_a_changed_run_is_named_with_its_window(streamed_tables, tmp_path):
    windows, data, motors = streamed_tables
    second = windows[1][0]
    changed = dataclasses.replace(second, run_interval=second.run_interval + (second.run_count > 0))
    problems = checked([windows[0], (changed, windows[1][1]), *windows[2:]], data, motors, tmp_path)
    assert problems[0].startswith("the streamed table is not the plan's: window 1: run 0 (byte ")
    assert "count, interval, add" in problems[0]


@pytest.mark.parametrize("cut, message", [(-1, "ends inside a record"), (2, "bytes after the end marker")])
def test_bytes_that_are_no_table_stream(streamed_tables, tmp_path, cut, message):
    windows, data, motors = streamed_tables
    wrong = data[:cut] if cut < 0 else data + bytes(cut)
    problems = checked(windows, wrong, motors, tmp_path)
    assert len(problems) == 1 and message in problems[0] and "not a table stream" in problems[0]

"""Heater and fan settings at their place in the tables (codegen/tables/runtime.py, codegen/tables/format.py's runtime records):
the stream round-trips them and the twin ignores them; an AVR flash image plays them in simavr with the thermal
plants (a target mid-print without a pause, a mid-program M109 that holds the player, M106 / M107 on the fan
pin); the 8051 boards and the streaming firmware get none."""

from __future__ import annotations

import io
import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from codegen.cli.main import main
from codegen.job import load_job
from codegen.pipeline.host import host_build, runtime_outputs
from codegen.tables.format import RUNTIME_BYTES, RUNTIME_FLAGS, encode, record_events, stream_bytes
from codegen.tables.schedule import RT_FAN, RT_TARGET_BED, RT_TARGET_HOTEND, RT_WAIT
from codegen.tables.twin import predict
from codegen.targets import target_info
from tests.helpers import HEATERS_JOB, make_schedule
from tests.reference_player import play, play_stream

# A hot end that sits at 60 degC (the plant's ambient) at power-up: an M109 S62 holds the player for about 3 s.
WARM_HOTEND = "  heaters:\n    hotend: {plant: {ambient_c: 60}}\n"
MOVES = ["G1 X10 Y0 F6000", "G1 X20 Y5", "G1 X30 Y10", "G1 X40 Y0"]

needs_simavr = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                  reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


def job_file(folder: Path, name: str, lines: list[str], target: str = "avr", heaters: str = "") -> Path:
    (folder / f"{name}.gcode").write_text("G21\nG90\n" + "\n".join(lines) + "\n")
    path = folder / f"{name}.yaml"
    path.write_text(HEATERS_JOB.format(name=name, target=target, heaters=heaters))
    return path


def verify_json(capsys, path: Path) -> dict:
    code = main(["verify", str(path), "--out", str(path.parent / f"{path.stem}-out"), "--json"])
    out, _ = capsys.readouterr()
    result = json.loads(out)
    assert code == 0, result["problems"]
    return result


def test_runtime_records_round_trip_and_leave_the_twin_alone():
    """Records before blocks 0 (two in a row), 2, and the end marker: the stream holds each (0x90, command, value)
    at its place, the reference reader finds them before the right events, the pulses and the twin's prediction
    are those of the same tables without them, and the stream's size counts them."""
    plain = make_schedule(("x", "y"), [((1, 1), (40, 10), 40, (0, 20), False, [(800 * 256, 0, 40)]),
                                       ((1, -1), (300, 300), 300, (0, 0), False, [(600 * 256, 0, 300)]),
                                       ((-1, 1), (5, 0), 5, (0, 0), True, [(900 * 256, 3, 5)])])
    sched = replace(plain, runtime_block=np.array([0, 0, 2, 3]),
                    runtime_command=np.array([RT_TARGET_HOTEND, RT_WAIT, RT_FAN, RT_TARGET_BED]),
                    runtime_value=np.array([2050, 1, 128, 0]))
    sched.validate()
    table, bare = encode(sched), encode(plain)
    assert len(table.data) == stream_bytes(sched) == len(bare.data) + 4 * RUNTIME_BYTES
    offsets = [int(o) for o in table.runtime_offsets]
    assert [table.data[o:o + RUNTIME_BYTES] for o in offsets] == [
        bytes([RUNTIME_FLAGS, RT_TARGET_HOTEND, 0x02, 0x08]), bytes([RUNTIME_FLAGS, RT_WAIT, 1, 0]),
        bytes([RUNTIME_FLAGS, RT_FAN, 128, 0]), bytes([RUNTIME_FLAGS, RT_TARGET_BED, 0, 0])]
    assert offsets[:2] == [0, 4] and offsets[2] + RUNTIME_BYTES == table.block_offsets[2]
    assert offsets[3] + RUNTIME_BYTES == len(table.data) - 2  # before the end marker
    without = bytearray(table.data)
    for o in reversed(offsets):
        del without[o:o + RUNTIME_BYTES]
    assert bytes(without) == bare.data
    runtime: list = []
    pulses, _, _ = play_stream(table.data, 2, runtime)
    assert runtime == [(0, RT_TARGET_HOTEND, 2050), (0, RT_WAIT, 1), (340, RT_FAN, 128), (345, RT_TARGET_BED, 0)]
    assert pulses == play(plain)
    events, sizes = record_events(sched)
    assert list(sizes[:2]) == [RUNTIME_BYTES] * 2 and list(events[:3]) == [0, 0, 0]
    twin, bare_twin = predict(sched), predict(plain)
    assert np.array_equal(twin.tick, bare_twin.tick) and np.array_equal(twin.motor, bare_twin.motor)


def test_only_avr_flash_images_get_records(tmp_path):
    """The 8051 boards (no heater outputs) and the AVR's streaming firmware play no settings: no records, and a
    wait does not stop the plan; an AVR flash image's outputs are its board's heaters and the fan."""
    lines = [MOVES[0], "M109 S200", "M106 S255", MOVES[1]]
    mcs51 = host_build(load_job(job_file(tmp_path, "seed", lines, target="mcs51")))
    assert mcs51.schedule.n_runtime == 0 and not np.any(mcs51.segments.dwell > 0)
    avr = load_job(job_file(tmp_path, "avr", lines))
    assert runtime_outputs(avr, target_info(avr.board), streamed=True) == ()
    assert runtime_outputs(avr, target_info(avr.board), streamed=False) == ("hotend", "bed", "fan")


@needs_simavr
def test_target_and_fan_mid_print_without_a_pause(tmp_path, capsys):
    """M104 S200 between two moves, M106 S128 and M107 later: the plan is the same as without them (no rest, the
    same duration), the records come before the next moves' blocks (in `plan --tables`'s stream too), the pulses
    are the twin's with no hold, and the fan pin is at 50 % from M106's block to M107's, then off (each applied at
    the runtime's next control period)."""
    lines = MOVES[:2] + ["M104 S200"] + MOVES[2:3] + ["M106 S128"] + MOVES[3:] + ["M107", "G1 X50 Y0"]
    path = job_file(tmp_path, "mid", lines)
    host = host_build(load_job(path))
    bare = host_build(load_job(job_file(tmp_path, "bare", [l for l in lines if l[0] == "G"])))
    assert host.plan.total == pytest.approx(bare.plan.total, abs=1e-6)
    assert host.schedule.n_blocks == bare.schedule.n_blocks
    sched = host.schedule
    assert list(sched.runtime_command) == [RT_TARGET_HOTEND, RT_FAN, RT_FAN]
    assert list(sched.runtime_value) == [2000, 128, 0] and list(sched.runtime_block) == [2, 3, 4]
    written = io.BytesIO()  # `plan --tables`: the stream written window by window carries them too
    host_build(load_job(path), keep=False, tables=written)
    assert written.getvalue() == encode(sched).data

    result = verify_json(capsys, path)
    assert result["pass"] and result["holds"] == []
    assert result["duration_s"] == pytest.approx(result["planned_duration_s"], rel=1e-3)
    assert all(m["max_timing_error_us"] < 2 for m in result["motors"].values())
    first = np.concatenate([[0], np.cumsum(sched.events_per_block())])
    read_s = [result["table_start_s"] + host.pulses.event_tick[first[b] - 1] / host.target.tick_hz
              for b in sched.runtime_block[1:]]
    fan = result["fan"]
    print("fan", fan, "records read at", read_s)
    assert [f["duty"] for f in fan] == [0.5, 0.0]
    for change, at in zip(fan, read_s):
        assert at <= change["at_s"] <= at + 0.11  # the next control period applies it
    assert result["heaters"]["hotend"]["target_c"] == 200.0


@needs_simavr
def test_m109_mid_program_rests_the_plan_and_holds_the_player(tmp_path, capsys):
    """M109 S62 between two moves: the plan comes to rest there (a dwell of WAIT_REST_S), the player holds until
    the hot end has been within 2 degC for 3 s, the hold is in verify's output, and the pulses after it are the
    twin's from the resume."""
    path = job_file(tmp_path, "hold", MOVES[:2] + ["M109 S62"] + MOVES[2:], heaters=WARM_HOTEND)
    host = host_build(load_job(path))
    sched = host.schedule
    assert list(sched.runtime_command) == [RT_TARGET_HOTEND, RT_WAIT] and list(sched.runtime_value) == [620, 1]
    dwell = int(sched.block_segment[sched.runtime_block[1]])
    assert host.segments.dwell[dwell] > 0 and host.plan.v_entry[dwell] == 0 and host.plan.v_entry[dwell + 1] == 0

    result = verify_json(capsys, path)
    (hold,) = result["holds"]
    print("hold", hold, result["heaters"]["hotend"])
    assert hold["heaters"] == ["hotend"] and 2.9 <= hold["waited_s"] < 6.0  # 30 readings 0.1 s apart
    assert result["pass"] and all(m["max_timing_error_us"] < 2 for m in result["motors"].values())
    assert result["duration_s"] == pytest.approx(result["planned_duration_s"], rel=1e-3)  # on the twin's clock
    hot = result["heaters"]["hotend"]
    assert hot["target_c"] == 62.0 and hold["at_s"] < hot["settled_s"] <= hold["at_s"] + hold["waited_s"] + 0.01

"""benchmarks/klipper_decode.py on a synthetic out.serial (encoded here from Klipper's documented protocol: no
Klipper needed), the pairing of benchmarks/klipper_compare.py, and, where Klipper is set up beside the
repository, benchmarks/klipper_steps.py end to end on a few moves."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tests.helpers import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
from klipper_compare import Train, drift_of, nearest_pairs, occurrence_pairs  # noqa: E402
from klipper_decode import decode, homing_end, varints  # noqa: E402
from klipper_ref import find_klipper  # noqa: E402
from klipper_steps import klipper_config  # noqa: E402

IDS = {"identify_response offset=%u data=%.*s": 0, "config_stepper oid=%c step_pin=%c dir_pin=%c invert_step=%c "
       "step_pulse_ticks=%u": 23, "queue_step oid=%c interval=%u count=%hu add=%hi": 22,
       "set_next_step_dir oid=%c dir=%c": 21, "reset_step_clock oid=%c clock=%u": 20,
       "endstop_home oid=%c clock=%u trsync_oid=%c": 25, "stepper_stop_on_trigger oid=%c trsync_oid=%c": 18,
       "config_spi_shutdown oid=%c spi_oid=%c shutdown_msg=%*s": 34, "allocate_oids count=%c": -7}
PINS = {"PA0": [0, 8], "PF0": [40, 8]}  # PA4 = 4, PF0 = 40


def varint(value: int) -> list[int]:
    """Klipper's variable-length integer (docs/Protocol.md)."""
    out = []
    if value >= 0xC000000 or value < -0x4000000:
        out.append((value >> 28) & 0x7F | 0x80)
    if value >= 0x180000 or value < -0x80000:
        out.append((value >> 21) & 0x7F | 0x80)
    if value >= 0x3000 or value < -0x1000:
        out.append((value >> 14) & 0x7F | 0x80)
    if value >= 0x60 or value < -0x20:
        out.append((value >> 7) & 0x7F | 0x80)
    out.append(value & 0x7F)
    return out


def message(fmt: str, *params) -> list[int]:
    out = varint(IDS[fmt])
    for param in params:
        out += [len(param), *param] if isinstance(param, bytes) else varint(param if param < 2**31 else param - 2**32)
    return out


def serial_file(messages: list[list[int]]) -> bytes:
    """Messages in blocks of at most 64 bytes: length, sequence, payload, CRC (not checked: zeros), sync."""
    blocks, payload, seq = bytearray(), [], 0
    for msg in messages + [None]:
        if msg is None or len(payload) + len(msg) > 59:
            blocks += bytes([len(payload) + 5, 0x10 | seq, *payload, 0, 0, 0x7E])
            payload, seq = [], (seq + 1) % 16
        payload += msg or []
    return bytes(blocks)


def test_varints_decode_every_size_and_sign():
    values = [0, 1, 0x5F, 0x60, -1, -0x20, -0x21, 0x2FFF, 0x3000, -0x1001, 0x17FFFF, 0x180000, 2**31 - 1, -2**31]
    decoded, first, last = varints(np.array([b for v in values for b in varint(v)], dtype=np.uint8))
    assert decoded.tolist() == values and (last - first + 1 <= 5).all()


@pytest.fixture()
def synthetic(tmp_path):
    """Two steppers' commands (with a string message, a far step, a negative add, a homing pass and a 32-bit
    clock wrap), and every step time computed one by one, as the MCU would."""
    dictionary = tmp_path / "klipper.dict"
    dictionary.write_text(json.dumps({"commands": {k: v for k, v in IDS.items() if v}, "responses": {},
                                      "enumerations": {"pin": PINS}, "config": {"CLOCK_FREQ": 16000000}}))
    stream = [message("allocate_oids count=%c", 3),
              message("config_stepper oid=%c step_pin=%c dir_pin=%c invert_step=%c step_pulse_ticks=%u", 1, 40, 41,
                      0, 32),
              message("config_spi_shutdown oid=%c spi_oid=%c shutdown_msg=%*s", 2, 0, bytes([0x7E, 0x80, 3])),
              message("config_stepper oid=%c step_pin=%c dir_pin=%c invert_step=%c step_pulse_ticks=%u", 0, 4, 6,
                      0, 32)]
    expected, last = {0: [], 1: []}, {0: 0, 1: 0}
    direction = {0: -1, 1: -1}
    # (oid, what, value); x's clock passes 2^32 before its reset
    commands = [(1, "home", 4_000_000), (1, "dir", 1), (1, "q", (4_064_000, 1, 0)), (0, "dir", 1),
                (1, "q", (23_176, 2, -6_798)), (0, "q", (3_000_000_000, 1, 0)), (0, "q", (1_600_000_000, 3, 1_000)),
                (1, "home", 0), (1, "dir", 0), (1, "q", (3_200, 250, 0)), (1, "q", (4_000_000_000, 1, 0)),
                (1, "reset", 2**32 + 5_000_000), (1, "q", (1_000, 4, -3)), (0, "dir", 0), (0, "q", (40_000, 65_535, 0))]
    for oid, kind, value in commands:
        if kind == "dir":
            stream.append(message("set_next_step_dir oid=%c dir=%c", oid, value))
            direction[oid] = 1 if value else -1
        elif kind == "home":  # a homing pass of x's endstop (oid 3, trsync 4) starts, or ends (clock 0)
            stream.append(message("stepper_stop_on_trigger oid=%c trsync_oid=%c", oid, 4))
            stream.append(message("endstop_home oid=%c clock=%u trsync_oid=%c", 3, value, 4 if value else 0))
        elif kind == "reset":
            stream.append(message("reset_step_clock oid=%c clock=%u", oid, value % 2**32))
            last[oid] = value
        else:
            interval, count, add = value
            stream.append(message("queue_step oid=%c interval=%u count=%hu add=%hi", oid, interval, count, add))
            for _ in range(count):
                last[oid] += interval
                interval += add
                expected[oid].append((last[oid], direction[oid]))
    serial = tmp_path / "out.serial"
    serial.write_bytes(serial_file(stream))
    return serial, dictionary, expected


def test_decoded_step_times_are_the_mcus(synthetic):
    serial, dictionary, expected = synthetic
    steppers, messages = decode(serial, dictionary, {"stepper_x": ("PF0", False), "extruder": ("PA4", True)})
    x, e = steppers["stepper_x"], steppers["extruder"]
    assert (x.oid, e.oid) == (1, 0)
    assert list(zip(x.clock.tolist(), x.dir.tolist())) == expected[1]
    assert e.clock.tolist() == [c for c, _ in expected[0]]
    assert e.dir.tolist() == [-d for _, d in expected[0]]  # its dir pin inverted
    assert homing_end(messages, steppers) == expected[1][2][0]  # x's pass: its first 3 steps, one way


def test_pairs_survive_drift_and_an_extra_step_pair():
    """Ours: Klipper's steps 0.3 s later and slower by 2 %, with one extra step out and back mid-way."""
    theirs_dir = np.array([1] * 50 + [-1] * 30 + [1] * 40, dtype=np.int8)
    theirs = Train(np.arange(len(theirs_dir)) * 0.01, theirs_dir, 0)
    extra = 60
    ours_dir = np.concatenate([theirs_dir[:extra], [1, -1], theirs_dir[extra:]]).astype(np.int8)
    ours_time = np.concatenate([theirs.time[:extra], theirs.time[extra - 1] + [0.003, 0.006], theirs.time[extra:]])
    ours = Train(0.3 + ours_time * 1.02, ours_dir, 0)
    mine, other = occurrence_pairs(ours, theirs)
    drift = drift_of(ours.time[mine], ours.time[mine] - theirs.time[other], 1.0)
    mine, other = nearest_pairs(ours, theirs, drift)
    assert len(mine) == len(theirs.time) and len(ours.time) - len(mine) == 2
    assert (ours.position[mine] == theirs.position[other]).all() and (ours.dir[mine] == theirs.dir[other]).all()
    assert np.abs(ours.time[mine] - theirs.time[other] - drift(ours.time[mine])).max() < 0.01


def test_klippers_config_follows_the_files_advance_changes_only_with_advance(tmp_path):
    """With pressure advance Klipper gets M900 K / M572 S as macros (it answers them "Unknown command"); without
    it, neither the advance nor the macros."""
    plain = klipper_config(tmp_path, {}, None, 1.0, None).read_text()
    assert "gcode_macro" not in plain and "pressure_advance:" not in plain
    text = klipper_config(tmp_path, {"x": ("mzv", 50.0, None)}, (0.05, None), 1.0, None).read_text()
    assert "shaper_type_x: mzv\nshaper_freq_x: 50\n" in text and "pressure_advance: 0.05\n" in text
    assert "[gcode_macro M900]" in text and "SET_PRESSURE_ADVANCE ADVANCE={params.K}" in text
    assert "[gcode_macro M572]" in text and "SET_PRESSURE_ADVANCE ADVANCE={params.S}" in text


@pytest.mark.skipif(find_klipper() is None, reason="Klipper is not set up beside the repository (CI has none)")
def test_a_few_moves_step_for_step_with_klipper(tmp_path):
    gcode = tmp_path / "few.gcode"
    gcode.write_text("G28\nG90\nM83\nG1 X20 Y10 F6000\nG1 X60 Y10 E2 F3000\nG1 Z1 F600\nG1 X20 Y20 F9000\n")
    job = tmp_path / "few.yaml"
    job.write_text((ROOT / "examples" / "printers" / "benchy-mini.yaml").read_text().replace(
        "../../tests/data/gcode/slicer/benchy-prusaslicer.gcode", str(gcode)))
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "klipper_steps.py"), str(job), "--json"],
                         capture_output=True, text=True, check=True, cwd=ROOT)
    motors = json.loads(out.stdout)["motors"]
    for name, motor in motors.items():
        assert motor["steps"]["ours"] == motor["steps"]["klipper"], name
        assert motor["final"]["ours"] == motor["final"]["klipper"], name
        assert motor["unpaired"] == {"ours": 0, "klipper": 0}, name

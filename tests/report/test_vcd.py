"""verify --vcd (codegen/verify/waveform.py): the simulated pins as a VCD waveform, read back with pyvcd's tokenizer and
held against verify's JSON and its --trace CSV: each motor's rising STEP edges are its steps, the first and last at the
CSV's times, DIR at every pulse as the CSV says; flash images and streamed jobs, on the ATmega2560 and the 8051.
No file where the job's input is bad."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from vcd.reader import TokenKind, tokenize

from codegen.cli.main import main
from codegen.verify.waveform import nanoseconds
from tests.helpers import ROOT

STAR, ARC = ROOT / "examples" / "star.yaml", ROOT / "examples" / "arc.yaml"
LASER = ROOT / "examples" / "laser" / "power.yaml"

needs_simavr = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                  reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")
needs_s51 = pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None,
                               reason="needs sdcc and s51 (scripts/setup.sh installs them)")


def read_vcd(path: Path) -> tuple[str, dict[str, list[tuple[int, int]]]]:
    """The timescale, and every signal's changes (time, value) by its path ("star.a.step"), its value at 0 first:
    a small reader of the subset of VCD the writer uses (pyvcd's tokenizer agrees: pyvcd_read; it takes seconds
    where this takes a fraction of one)."""
    scopes, names, waves, now, timescale = [], {}, {}, 0, None
    with open(path, encoding="utf-8") as file:
        header = iter(file.readline, "")
        for line in header:
            words = line.split()
            if words[0] == "$timescale":
                timescale = " ".join(words[1:-1])
            elif words[0] == "$scope":
                scopes.append(words[2])
            elif words[0] == "$upscope":
                scopes.pop()
            elif words[0] == "$var":
                names[words[3]] = ".".join([*scopes, words[4]])
                waves[names[words[3]]] = []
            elif words[0] == "$enddefinitions":
                break
        for line in file:
            if line[0] == "#":
                now = int(line[1:])
            elif line[0] in "01":
                waves[names[line[1:].strip()]].append((now, int(line[0])))
            elif line[0] == "b":
                value, code = line[1:].split()
                waves[names[code]].append((now, int(value, 2)))
    return timescale, waves


def pyvcd_read(path: Path) -> tuple[str, dict[str, list[tuple[int, int]]]]:
    """read_vcd, by pyvcd's tokenizer."""
    scopes, names, waves, now, timescale = [], {}, {}, 0, None
    with open(path, "rb") as file:
        for token in tokenize(file):
            if token.kind is TokenKind.TIMESCALE:
                timescale = str(token.timescale)
            elif token.kind is TokenKind.SCOPE:
                scopes.append(token.scope.ident)
            elif token.kind is TokenKind.UPSCOPE:
                scopes.pop()
            elif token.kind is TokenKind.VAR:
                names[token.var.id_code] = ".".join([*scopes, token.var.reference])
                waves[names[token.var.id_code]] = []
            elif token.kind is TokenKind.CHANGE_TIME:
                now = token.time_change
            elif token.kind is TokenKind.CHANGE_SCALAR:
                waves[names[token.scalar_change.id_code]].append((now, int(token.scalar_change.value)))
            elif token.kind is TokenKind.CHANGE_VECTOR:
                waves[names[token.vector_change.id_code]].append((now, int(token.vector_change.value)))
    return timescale, waves


def verify(capsys, tmp_path: Path, job: Path, *options) -> tuple[dict, list[dict], dict]:
    """verify --json --trace --vcd: its JSON, the CSV's rows and the waveform's signals (all checked for a pass)."""
    vcd, trace = tmp_path / "pins.vcd", tmp_path / "steps.csv"
    code = main(["verify", str(job), *options, "--out", str(tmp_path / "out"), "--json", "--trace", str(trace),
                 "--vcd", str(vcd)])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and result["pass"], result["problems"]
    assert not list(tmp_path.glob(".*.partial"))
    timescale, waves = read_vcd(vcd)
    assert timescale == "1 ns"
    with open(trace, encoding="utf-8") as rows:
        return result, list(csv.DictReader(rows)), waves


def assert_matches(result: dict, rows: list[dict], waves: dict, job: str) -> None:
    """Each motor's STEP rises from the player's start are its steps, at the CSV's times (within the 0.5 ns each
    rounds by), with DIR at each as the CSV's dir (no motor of these jobs inverts it)."""
    (run_at, _), = [c for c in waves[f"{job}.player.run"] if c[1] == 1]
    for name, motor in result["motors"].items():
        step, direction = waves[f"{job}.{name}.step"], waves[f"{job}.{name}.dir"]
        rises = np.array([t for (t, v), (_, before) in zip(step[1:], step) if v == 1 and before == 0])
        rises = rises[rises >= run_at]
        mine = [r for r in rows if r["motor"] == name and r["phase"] == "run"]
        assert len(rises) == motor["steps"] == len(mine) > 100
        csv_ns = np.array([round(float(r["time_s"]) * 1e9) for r in mine])
        assert np.abs(rises[[0, -1]] - csv_ns[[0, -1]]).max() <= 1
        assert np.abs(rises - csv_ns).max() <= 1
        dir_t = np.array([t for t, _ in direction])
        level = np.array([v for _, v in direction])[np.searchsorted(dir_t, rises, side="right") - 1]
        assert np.array_equal(np.where(level == 1, 1, -1), [int(r["dir"]) for r in mine])
        assert len(set(level)) == 2  # the motor turns at least once: DIR changes are checked too


@needs_simavr
def test_a_flash_image_on_the_atmega2560(capsys, tmp_path):
    result, rows, waves = verify(capsys, tmp_path, STAR)
    assert_matches(result, rows, waves, "star")
    assert {"star.a.enable", "star.b.enable", "star.tool"} <= set(waves)


@needs_s51
def test_a_flash_image_on_the_8051(capsys, tmp_path):
    result, rows, waves = verify(capsys, tmp_path, ARC, "--target", "mcs51")
    assert_matches(result, rows, waves, "arc")
    assert waves["arc.x.step"][0] == (0, 1)  # an 8051's latches are high after reset
    assert pyvcd_read(tmp_path / "pins.vcd") == ("1 ns", waves)


@needs_simavr
def test_a_stream_to_the_atmega2560(capsys, tmp_path):
    result, rows, waves = verify(capsys, tmp_path, ARC, "--stream")
    assert_matches(result, rows, waves, "arc")


@needs_s51
def test_a_stream_to_the_8051(capsys, tmp_path):
    result, rows, waves = verify(capsys, tmp_path, ARC, "--stream", "--target", "mcs51")
    assert_matches(result, rows, waves, "arc")


def test_no_waveform_where_the_job_is_bad(capsys, tmp_path):
    job = tmp_path / "bad.yaml"
    job.write_text(STAR.read_text(encoding="utf-8").replace("feed: 18000", "feed: fast"), encoding="utf-8")
    code = main(["verify", str(job), "--out", str(tmp_path / "out"), "--vcd", str(tmp_path / "pins.vcd")])
    assert code == 2 and "bad.yaml" in capsys.readouterr().err
    assert not (tmp_path / "pins.vcd").exists() and not list(tmp_path.glob(".*"))


def test_times_are_whole_nanoseconds_exactly_for_long_runs():
    cycles = np.array([0, 1, 2, 3, 12_345, 1 << 40, (1 << 44) + 3])  # 2**44 cycles: 12 days at 16 MHz
    for f_cpu in (16_000_000, 11_059_200):
        expected = [(int(c) * 10**9 + f_cpu // 2) // f_cpu for c in cycles]
        assert nanoseconds(cycles, f_cpu).tolist() == expected


@needs_simavr
def test_the_page_and_the_waveform_are_written_as_the_run_is_compared(capsys, tmp_path, monkeypatch):
    """verify --report --vcd of an ATmega2560's image (a laser's: its PWM's duty too) takes the bounded path
    (codegen/verify/bounded.py): neither the whole run's waveform nor the whole run's samples are made; the page has
    its plots and the waveform every motor's STEP rises, as many as the result's steps (homing's before the player's
    start)."""
    def whole(*_):
        raise AssertionError("the whole run was kept")

    monkeypatch.setattr("codegen.verify.waveform.write_vcd", whole)  # main.py imports them as verify runs
    monkeypatch.setattr("codegen.verify.report_samples.whole_run_samples", whole)
    page, vcd = tmp_path / "laser.html", tmp_path / "laser.vcd"
    code = main(["verify", str(LASER), "--out", str(tmp_path / "out"), "--json", "--report", str(page), "--vcd",
                 str(vcd)])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and result["pass"], result["problems"]
    _, waves = read_vcd(vcd)
    (run_at, _), = [c for c in waves["laser_power.player.run"] if c[1] == 1]
    for name, motor in result["motors"].items():
        step = waves[f"laser_power.{name}.step"]
        rises = [t for (t, v), (_, before) in zip(step[1:], step) if v == 1 and before == 0 and t >= run_at]
        assert len(rises) == motor["steps"] > 100
    assert len(waves["laser_power.laser.duty"]) > 10
    text = page.read_text(encoding="utf-8")
    for plot in ("path", "motion", "timing"):
        assert f"data-plot='{plot}'" in text
    assert "data-missing=" not in text
    assert not list(tmp_path.glob(".*.partial"))

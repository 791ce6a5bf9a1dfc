"""The streaming examples end to end, through the command line users run (`verify --stream --json`): the laser
engraving and the Benchy's first three layers streamed to a RAMPS board in simavr, and the seed plotter set at the
default tolerance, too big for the AT89C52's flash, streamed to the seed-51 board in s51.
"""

import json
import re
import shutil
from pathlib import Path

import pytest

from codegen.tables.compress import TimingWindow
from tests.helpers import ROOT
from tests.helpers import run_cli as run

BENCHY = ROOT / "examples" / "printers" / "benchy-mini.yaml"
BENCHY_GCODE = ROOT / "tests" / "data" / "gcode" / "slicer" / "benchy-prusaslicer.gcode"
LASER = ROOT / "examples" / "gcode" / "laser-hiking.yaml"
SEED_PLOTTER = ROOT / "examples" / "stream" / "plotter-set-seed51.yaml"

needs_avr = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                               reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")
needs_mcs51 = pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None,
                                 reason="needs sdcc and s51 (scripts/setup.sh installs them)")


def verify_stream(capsys, job: Path, out: Path) -> dict:
    code, stdout, _ = run(capsys, "verify", job, "--stream", "--json", "--out", out)
    result = json.loads(stdout)
    assert code == 0, result["problems"]
    return result


def assert_streamed_as_planned(result: dict, baud: int) -> None:
    """PASS over a clean line: every byte in time, the ring never dry, the positions and the duration the plan's."""
    assert result["pass"] is True
    assert result["problems"] == [] and result["not_compared"] == []  # a problem too: end positions the firmware
    # reports over the link that are not the twin's
    link = result["link"]
    assert link["baud"] == baud
    assert link["retransmits"] == 0 and link["underruns"] == 0 and link["lost_bytes"] == 0
    assert link["min_ring_fill_bytes"] >= link["planned_min_ring_fill_bytes"] > 0  # the plan's lowest fill holds
    assert link["link_slowdown_s"] == 0.0  # the line carries every stretch of these jobs unslowed
    assert 0 < link["prefill_bytes"] < link["bytes"]
    for name, motor in result["motors"].items():
        assert motor["final"] == motor["expected_final"], name
        assert motor["end_position"] == motor["expected_end_position"], name
    # The twin's events stand within the run fitter's window of the plan's, the simulated pulses within
    # max_timing_error_us of the twin's: at each end of the run.
    worst_us = TimingWindow().max_us + max(m["max_timing_error_us"] for m in result["motors"].values())
    assert abs(result["duration_s"] - result["planned_duration_s"]) <= 2 * worst_us * 1e-6


def first_layers(gcode: str, layers: int) -> str:
    """The start code and the first `layers` layers: the lines before PrusaSlicer's (layers + 1)-th ;LAYER_CHANGE."""
    lines = gcode.splitlines(keepends=True)
    changes = [i for i, line in enumerate(lines) if line.startswith(";LAYER_CHANGE")]
    return "".join(lines[:changes[layers]])


@needs_avr
def test_the_laser_engravings_first_strokes_stream_to_ramps(tmp_path, capsys):
    """The engraving's first 900 lines (its first strokes, 13 minutes of engraving, 29 KB on the line: the ring
    filled almost four times; the whole engraving is 50 minutes, examples/gcode/laser-hiking.yaml). The firmware's
    window updates spare the host its pings (without them: 182 KB in 28,465 frames)."""
    gcode = (ROOT / "tests" / "data" / "gcode" / "laser" / "hiking.gcode").read_text().splitlines(keepends=True)
    (tmp_path / "hiking-part.gcode").write_text("".join(gcode[:900]))
    job, replaced = re.subn(r"(?m)^  gcode: .*$", "  gcode: hiking-part.gcode", LASER.read_text())
    assert replaced == 1
    (tmp_path / "hiking-part.yaml").write_text(job)
    result = verify_stream(capsys, tmp_path / "hiking-part.yaml", tmp_path / "out")
    assert_streamed_as_planned(result, baud=250_000)
    assert result["image"]["table_bytes"] == 0  # the program came over the line, none of it in flash
    ring = json.loads((tmp_path / "out" / "report.json").read_text())["link"]["ring_bytes"]
    assert 3 * ring < result["link"]["bytes"] < 4 * ring
    assert result["laser"]["max_power_error_pct"] <= 1.0
    assert (tmp_path / "out" / "firmware.hex").is_file()


@needs_avr
def test_the_benchys_first_three_layers_stream_to_ramps(tmp_path, capsys):
    (tmp_path / "benchy-3-layers.gcode").write_text(first_layers(BENCHY_GCODE.read_text(), 3))
    job, replaced = re.subn(r"(?m)^  gcode: .*$", "  gcode: benchy-3-layers.gcode", BENCHY.read_text())
    assert replaced == 1  # the machine is benchy-mini.yaml's, the program the cut file
    (tmp_path / "benchy-3-layers.yaml").write_text(job.replace("name: benchy-mini", "name: benchy-3-layers"))
    result = verify_stream(capsys, tmp_path / "benchy-3-layers.yaml", tmp_path / "out")
    assert_streamed_as_planned(result, baud=250_000)
    assert sorted(result["motors"]) == ["e", "x", "y", "z"]
    assert result["motors"]["z"]["expected_final"] == 360  # the third layer's top, 0.9 mm at 400 steps/mm


@needs_mcs51
def test_the_seed_plotter_set_at_the_default_tolerance_streams_to_seed51(tmp_path, capsys):
    code, _, err = run(capsys, "build", SEED_PLOTTER, "--out", tmp_path / "flash")
    assert code == 1 and "does not fit in flash" in err and "8192" in err
    assert not (tmp_path / "flash" / "firmware.hex").exists()
    result = verify_stream(capsys, SEED_PLOTTER, tmp_path / "stream")
    assert_streamed_as_planned(result, baud=9600)
    assert result["board"] == "seed-51"
    assert result["max_path_error_mm"] <= result["path_limit_mm"]


@needs_mcs51
def test_the_seed_delta_streams_after_homing_and_shows_its_steps_since_the_start(tmp_path, capsys):
    """The streaming firmware does not know where a job puts the machine: its LCD shows each carriage's steps
    since START (after homing), the numbers it reports over the link."""
    result = verify_stream(capsys, ROOT / "examples" / "delta-seed-51.yaml", tmp_path)
    assert result["pass"] is True and result["problems"] == []
    finals = [result["motors"][m]["final"] for m in "abc"]
    assert finals == [result["motors"][m]["expected_final"] for m in "abc"]
    assert result["display"] == [f"A{finals[0]:6d} B{finals[1]:6d} ", f"C{finals[2]:6d}         "]

"""A build that fails leaves no firmware behind, not even an earlier build's (issue 28, "nothing stale")."""

import shutil

import pytest

from codegen.cli.outputs import job_name_guess
from tests.helpers import ROOT
from tests.helpers import run_cli as run

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None, reason="needs gcc-avr (scripts/setup.sh)")

BUILT = {"firmware.hex", "firmware.elf", "report.json", "config.h", "player.c", "player_isr.S", "table.c", "table.h"}
LINE = (ROOT / "examples" / "line.yaml").read_text()


def _failing_jobs(tmp_path):
    """(job file, expected exit code): bad input in the YAML, in the G-code, and a job too big for the chip."""
    misspelt = tmp_path / "misspelt.yaml"
    misspelt.write_text(LINE.replace("max_accel: 2000, range", "max_acel: 2000, range", 1))
    gcode = tmp_path / "gcode.yaml"
    gcode.write_text(LINE[:LINE.index("program:")] + "program:\n  gcode: |\n    G1 X10 F600\n    G1 X#\n")
    return [(misspelt, 2), (gcode, 2), (ROOT / "examples" / "plotter-set.yaml", 1)]


def test_each_failing_build_clears_the_earlier_image_and_keeps_the_users_files(tmp_path, capsys):
    out = tmp_path / "out"
    for job, expected in _failing_jobs(tmp_path):
        code, _, _ = run(capsys, "build", ROOT / "examples" / "line.yaml", "--out", out)
        assert code == 0 and BUILT <= {p.name for p in out.iterdir()}
        (out / "notes.txt").write_text("mine")
        target = ["--target", "mcs51"] if expected == 1 else []
        code, _, err = run(capsys, "build", job, "--out", out, *target)
        assert code == expected, err
        assert {p.name for p in out.iterdir()} == {"notes.txt"}, job.name


def test_a_failed_build_without_out_clears_build_slash_its_name(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    job = tmp_path / "job.yaml"
    job.write_text(LINE)
    assert run(capsys, "build", job)[0] == 0
    folder = tmp_path / "build" / "line"  # examples/line.yaml names itself "line"
    assert (folder / "firmware.hex").is_file()
    job.write_text(LINE.replace("max_accel: 2000, range", "max_acel: 2000, range", 1))
    assert run(capsys, "build", job)[0] == 2
    assert not (folder / "firmware.hex").exists() and not (folder / "report.json").exists()


def test_a_failed_stream_build_clears_the_earlier_streaming_firmware(tmp_path, capsys):
    out = tmp_path / "stream"
    assert run(capsys, "build", ROOT / "examples" / "line.yaml", "--stream", "--out", out)[0] == 0
    assert (out / "firmware.hex").is_file()
    bad = tmp_path / "bad.yaml"
    bad.write_text(LINE.replace("kinematics: cartesian", "kinematics: polar", 1))
    code, _, err = run(capsys, "build", bad, "--stream", "--out", out)
    assert code == 2 and "polar" in err
    assert not (out / "firmware.hex").exists() and not (out / "report.json").exists()


@pytest.mark.parametrize("text, name", [
    ("name: plotter\nmachine: {}\n", "plotter"),
    ("# a comment\nname: 'pen one'  # quoted\n", "pen one"),
    ("name: ../../etc\n", "job"),   # a name that is no folder name: the loader's default, the stem
    ("machine: {}\n", "job"),
])
def test_the_folder_of_a_job_too_broken_to_load_comes_from_its_name_line(tmp_path, text, name):
    path = tmp_path / "job.yaml"
    path.write_text(text)
    assert job_name_guess(path) == name

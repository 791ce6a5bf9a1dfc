"""`printer-codegen flash`: the programmer's exact command for each chip, and every refusal before anything runs
(no image, a stale image, no port, no programmer installed). Real builds (avr-gcc, SDCC) of the small star
job; no simulator, no board: a stand-in avrdude records what it was given."""

import json
import stat
from pathlib import Path

import pytest

from codegen.cli.flash import flash_command
from tests.helpers import STAR
from tests.helpers import run_cli as run

AVRDUDE = "avrdude -p atmega2560 -c wiring -P /dev/ttyACM0 -b 115200 -D -U flash:w:build/star/firmware.hex:i"
STALE = ("error: build/star/firmware.hex is stale: it was built from another version of star.yaml (the job, its "
         "G-code, the board file, --target, --stream or printer-codegen changed since): run `printer-codegen build "
         "star.yaml` first")


@pytest.fixture
def star(tmp_path, monkeypatch) -> Path:
    """The star job in a fresh folder, which is the working directory (so its build goes to build/star/)."""
    monkeypatch.chdir(tmp_path)
    Path("star.yaml").write_text(STAR)
    return Path("star.yaml")


def build(capsys, *argv: str) -> None:
    assert run(capsys, "build", *argv)[0] == 0


def test_avrdude_for_the_atmega2560(capsys, star):
    build(capsys, str(star))
    assert run(capsys, "flash", str(star), "--port", "/dev/ttyACM0", "--dry-run") == (0, AVRDUDE + "\n", "")


def test_stcgal_for_the_stc89c52rc(capsys, star):
    star.write_text(star.read_text().replace("name: star\n", "name: star\ntarget: mcs51\nboard: stc89c52rc\n"))
    build(capsys, str(star))
    assert run(capsys, "flash", str(star), "--port", "/dev/ttyUSB0", "--dry-run") == (
        0, "stcgal -P stc89 -p /dev/ttyUSB0 build/star/firmware.hex\n", "")


def test_minipro_for_the_at89c52_out_of_its_board(capsys, star):
    """No serial bootloader: the chip goes into a TL866II+ / T48 on USB, which minipro programs (no --port)."""
    build(capsys, str(star), "--target", "mcs51")
    assert run(capsys, "flash", str(star), "--target", "mcs51", "--dry-run") == (
        0, "minipro -p AT89C52 -w build/star/firmware.hex\n", "")
    for board in ("seed-51", "coil-51"):  # their own wiring, the same chip
        assert flash_command(board, None, Path("firmware.hex")) == ["minipro", "-p", "AT89C52", "-w", "firmware.hex"]


def test_a_serial_bootloader_needs_the_port(capsys, star):
    build(capsys, str(star))
    assert run(capsys, "flash", str(star), "--dry-run") == (
        2, "", "error: flash: avrdude programs board ramps-1.4 through its serial port: give --port (e.g. "
               "/dev/ttyACM0)\n")


def test_no_image_yet(capsys, star):
    assert run(capsys, "flash", str(star), "--port", "/dev/ttyACM0", "--dry-run") == (
        1, "", "error: no firmware image at build/star/firmware.hex: run `printer-codegen build star.yaml` first\n")
    assert run(capsys, "flash", str(star), "--port", "p", "--out", "elsewhere", "--target", "mcs51")[2] == (
        "error: no firmware image at elsewhere/firmware.hex: run `printer-codegen build star.yaml --target mcs51 "
        "--out elsewhere` first\n")


def test_an_edited_job_makes_the_image_stale(capsys, star):
    build(capsys, str(star))
    star.write_text(star.read_text().replace("feed: 18000 ", "feed: 17000 "))
    assert run(capsys, "flash", str(star), "--port", "/dev/ttyACM0", "--dry-run") == (1, "", STALE + "\n")
    code, _, err = run(capsys, "flash", str(star), "--target", "mcs51", "--port", "/dev/ttyACM0", "--dry-run")
    assert (code, "is stale" in err, "--target mcs51" in err) == (1, True, True)  # built for the other target
    build(capsys, str(star))
    assert run(capsys, "flash", str(star), "--port", "/dev/ttyACM0", "--dry-run")[0] == 0


def test_an_edited_gcode_file_makes_the_image_stale(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Path("part.gcode").write_text("G21 G90\nG1 X10 Y0 F1200\nG1 X10 Y10\n")
    Path("part.yaml").write_text("machine:\n  kinematics: cartesian\n  steppers:\n"
                                 "    x: {steps_per_mm: 80, max_velocity: 100, max_accel: 1000}\n"
                                 "    y: {steps_per_mm: 80, max_velocity: 100, max_accel: 1000}\n"
                                 "program:\n  gcode: part.gcode\n")
    build(capsys, "part.yaml")
    assert run(capsys, "flash", "part.yaml", "--port", "/dev/ttyACM0", "--dry-run")[0] == 0
    Path("part.gcode").write_text("G21 G90\nG1 X10 Y0 F1200\nG1 X10 Y20\n")
    code, _, err = run(capsys, "flash", "part.yaml", "--port", "/dev/ttyACM0", "--dry-run")
    assert (code, "build/part/firmware.hex is stale" in err) == (1, True)


def test_a_report_without_a_job_fingerprint(capsys, star):
    build(capsys, str(star))
    report = Path("build/star/report.json")
    report.write_text(json.dumps({k: v for k, v in json.loads(report.read_text()).items() if k != "job_fingerprint"}))
    assert run(capsys, "flash", str(star), "--port", "/dev/ttyACM0", "--dry-run")[2] == (
        "error: build/star/firmware.hex was built by an older printer-codegen (its report.json has no job "
        "fingerprint): run `printer-codegen build star.yaml` first\n")


def test_the_streaming_firmware_is_the_machines(capsys, star):
    build(capsys, str(star), "--stream")
    command = AVRDUDE.replace("build/star/", "build/star/stream/")
    assert run(capsys, "flash", str(star), "--stream", "--port", "/dev/ttyACM0", "--dry-run") == (0, command + "\n", "")
    assert run(capsys, "flash", str(star), "--port", "/dev/ttyACM0", "--dry-run")[0] == 1  # no flash image
    star.write_text(star.read_text().replace("feed: 18000 ", "feed: 17000 "))  # another program: the same firmware
    assert run(capsys, "flash", str(star), "--stream", "--port", "/dev/ttyACM0", "--dry-run")[0] == 0
    star.write_text(star.read_text().replace("junction_deviation: 0.02\n",
                                             "junction_deviation: 0.02\n  link: {baud: 500000}\n"))
    code, _, err = run(capsys, "flash", str(star), "--stream", "--port", "/dev/ttyACM0", "--dry-run")
    assert (code, "build/star/stream/firmware.hex is stale" in err) == (1, True)  # another link: another firmware
    assert err.endswith("run `printer-codegen build star.yaml --stream` first\n")


def test_runs_avrdude_or_names_the_package(capsys, star, tmp_path, monkeypatch):
    build(capsys, str(star))
    tools = tmp_path / "bin"
    tools.mkdir()
    monkeypatch.setenv("PATH", str(tools))
    assert run(capsys, "flash", str(star), "--port", "/dev/ttyACM0") == (
        1, "", f"error: avrdude not found: install avrdude (Debian: apt-get install avrdude), or run it yourself: "
               f"{AVRDUDE}\n")
    fake = tools / "avrdude"
    fake.write_text(f'#!/bin/sh\nprintf "%s\\n" "$@" > {tmp_path / "args"}\n')
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    assert run(capsys, "flash", str(star), "--port", "/dev/ttyACM0") == (
        0, "flashed build/star/firmware.hex to /dev/ttyACM0\n", AVRDUDE + "\n")
    assert (tmp_path / "args").read_text().splitlines() == AVRDUDE.split()[1:]
    fake.write_text("#!/bin/sh\nexit 3\n")
    assert run(capsys, "flash", str(star), "--port", "/dev/ttyACM0")[2].endswith(
        f"error: avrdude failed (exit 3): {AVRDUDE}\n")


def test_a_bad_job_is_bad_input(capsys, star):
    star.write_text(star.read_text().replace("max_accel: 8000}", "max_accel: fast}", 1))
    code, out, err = run(capsys, "flash", str(star), "--port", "/dev/ttyACM0", "--dry-run")
    assert (code, out) == (2, "")
    assert err.splitlines()[0] == ("star.yaml:5:57: error: machine.steppers.a.max_accel: expected a number")
    assert err.splitlines()[2] == " " * 56 + "^"

"""Progress bars (codegen/progress.py): the command line, run as a subprocess with its stderr on a pseudo-terminal,
shows a bar per long stage (plan, compile, simulate, the simulated stream) with the stage's name and an ETA;
none when stderr is a pipe or with --quiet. PRINTER_CODEGEN_PROGRESS_DELAY=0 shows every bar at once (a stage
shorter than 2 s shows none otherwise). The plan's bar counts the share of the program read and cut."""

from __future__ import annotations

import fcntl
import os
import re
import select
import shutil
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest

from codegen.gcode import GcodeStream
from codegen.job import load_job
from codegen.kinematics import make_kinematics
from codegen.motion.pieces import pieces
from codegen.pipeline.settings import front_end_settings, homing_settings
from codegen.program.program import Program
from codegen.progress import DELAY_ENV
from tests.helpers import ROOT

ARC = ROOT / "examples" / "arc.yaml"
HIKING = ROOT / "examples" / "gcode" / "laser-hiking.yaml"
ENV = {**os.environ, DELAY_ENV: "0"}
BAR = re.compile(r"(?P<stage>[a-z ()]+): +(?P<percent>\d+)%\|[^|\r\n]*\|[^\[\r\n]*\[\d\d:\d\d<(\d\d:\d\d|\?)")

needs_s51 = pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None,
                               reason="needs sdcc and s51 (scripts/setup.sh installs them)")
needs_simavr = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                  reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


def on_terminal(*args) -> tuple[int, str]:
    """The command's exit code and what it wrote to stderr, a pseudo-terminal of 120 columns."""
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))  # tqdm draws nothing 0 wide
    process = subprocess.Popen([sys.executable, "-m", "codegen", *map(str, args)], cwd=ROOT, env=ENV,
                               stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=slave)
    os.close(slave)
    err = b""
    while True:
        if select.select([master], [], [], 0.2)[0]:
            try:
                chunk = os.read(master, 1 << 16)
            except OSError:  # EIO: the command has closed its end
                break
            if not chunk:
                break
            err += chunk
        elif process.poll() is not None:
            break
    os.close(master)
    return process.wait(), err.decode(errors="replace")


def bars(err: str) -> dict[str, list[int]]:
    """Every drawing of a bar on the terminal: the percentages each stage showed, in order."""
    out: dict[str, list[int]] = {}
    for m in BAR.finditer(err):
        out.setdefault(m["stage"].strip(), []).append(int(m["percent"]))
    return out


@pytest.fixture(scope="module")
def out51(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("arc51")


@needs_s51
def test_build_shows_the_plan_and_the_compile(out51):
    code, err = on_terminal("build", ARC, "--target", "mcs51", "--out", out51)
    assert code == 0, err
    shown = bars(err)
    assert {"plan", "compile"} <= set(shown), err
    assert shown["plan"][-1] == 100
    assert "steps" in err and "table.c" in err  # the compile counts its steps and names the file at hand


@needs_s51
def test_verify_shows_the_simulation_moving_with_simulated_time(out51):
    code, err = on_terminal("verify", ARC, "--target", "mcs51", "--out", out51)
    assert code == 0, err
    shown = bars(err)
    assert {"plan", "simulate"} <= set(shown), err
    assert any(0 < p < 100 for p in shown["simulate"]), shown  # s51's output read as it runs, not only at the end
    assert "s simulated" in err


@needs_s51
def test_quiet_shows_no_bar(out51):
    code, err = on_terminal("verify", ARC, "--target", "mcs51", "--out", out51, "--quiet")
    assert code == 0, err
    assert bars(err) == {} and "\r" not in err, err


@needs_s51
def test_no_bar_on_a_pipe(out51):
    done = subprocess.run([sys.executable, "-m", "codegen", "verify", ARC, "--target", "mcs51", "--out", out51],
                          cwd=ROOT, env=ENV, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert bars(done.stderr) == {} and "\r" not in done.stderr, done.stderr


@needs_simavr
def test_verify_stream_shows_the_simulated_stream(tmp_path):
    code, err = on_terminal("verify", ARC, "--stream", "--out", tmp_path)
    assert code == 0, err
    shown = bars(err)
    assert {"plan", "compile", "stream (simulated)"} <= set(shown), err
    assert "bytes" in err


@needs_simavr
def test_a_held_stream_shows_its_simulated_streams(tmp_path):
    """verify --stream --hold simulates the stream twice (where tick 0 falls, then with the requests): a bar each."""
    code, err = on_terminal("verify", ROOT / "examples" / "star.yaml", "--stream", "--hold", "1.0", "--out", tmp_path)
    assert code == 0, err
    assert len(bars(err).get("stream (simulated)", [])) >= 2 and err.count("stream (simulated):   0%") >= 2, err


def test_the_plan_counts_the_share_of_the_gcode_read_and_cut():
    job = load_job(HIKING, None)
    stream = GcodeStream(job)
    read = [stream.read_share for _ in stream.batches(size=512)]
    assert len(read) > 3 and read == sorted(read) and 0 < read[0] < 0.5 and read[-1] == 1.0
    kin = make_kinematics(job.machine)
    program = Program(job, kin, homing_settings(job))
    front = front_end_settings(job)
    handed = [program.handed_on for _ in pieces(front, kin, program)]  # the parts of one batch share its share
    assert len(set(handed)) > 5 and handed == sorted(handed) and handed[0] < 0.5 and handed[-1] > 0.99
    assert program.handed_on == 1.0  # once the last part is planned


def test_the_library_draws_no_bar(capfd):
    """Bars are off unless the command line turns them on: tests and scripts that call the library stay silent."""
    from codegen.pipeline.host import host_build

    host_build(load_job(HIKING, None), keep=False)
    assert capfd.readouterr().err == ""

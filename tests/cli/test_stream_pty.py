"""`printer-codegen stream` end to end: the real command, as a subprocess, opens a pseudo-terminal as its serial
port (pyserial) and streams a job in real time to the streaming firmware running in simavr, which a bridge
(codegen/sim/pty_bridge.py) paces to the wall clock. The pulses the simulated machine made are compared with the
twin's, as `verify --stream` does; a firmware of another machine is refused; Ctrl-C stops the machine mid-job
where the command says it stopped.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import struct
import subprocess
import sys
import termios
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from codegen.cli.stream import streamed_host
from codegen.job import load_job
from codegen.link import protocol
from codegen.link.host import LinkFigures
from codegen.pipeline.streaming import StreamSetup, build_stream_firmware, stream_setup
from codegen.sim.avr import SimTrace
from codegen.sim.avr_link import StreamSim
from codegen.sim.pty_bridge import PtyBridge
from codegen.verify.compare import compare, simulated_switches
from tests.helpers import ROOT

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")

# A dense wave: about 9 KB of records in 5.6 s, more than the 7.8 KB ring, so the stream runs on the firmware's
# credit while the machine moves.
WAVE = """\
name: wave
target: avr
board: ramps-1.4
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 80, max_velocity: 150, max_accel: 2000, range: [0, 200]}
    y: {steps_per_mm: 80, max_velocity: 150, max_accel: 2000, range: [0, 200]%s}
program:
  feed: 6000
  shapes:
    - sine: {origin: [20, 40], amplitude: 5, omega: 3, phase: 0, length: 30}
"""
DEADLINE_S = 20.0  # wall time for one session, the command's start included
INTERRUPT_AFTER_S = 2.0  # Ctrl-C this long after the firmware started playing: drawing the wave
ABORT_STOP_S = 0.25  # SIGINT to the last pulse: the command's reaction, the bridge's slice, the line's bytes ahead


@dataclass
class Machine:
    """A job file and the streaming firmware built for a machine (its own, or another)."""

    job_path: Path
    setup: StreamSetup
    hex_path: Path


@dataclass
class Streamed:
    """One run of the command against the simulated machine."""

    code: int
    out: str
    err: str
    trace: SimTrace
    figures: LinkFigures
    bridge: PtyBridge


def write_machine(folder: Path, y_extra: str = "") -> Machine:
    folder.mkdir()
    job_path = folder / "wave.yaml"
    job_path.write_text(WAVE % y_extra)
    setup = stream_setup(load_job(job_path, None))
    image, _ = build_stream_firmware(setup, folder / "stream")
    return Machine(job_path, setup, image.hex_path)


@pytest.fixture(scope="module")
def wave(tmp_path_factory):
    return write_machine(tmp_path_factory.mktemp("pty") / "wave")


@pytest.fixture(scope="module")
def wave_host(wave):
    job = load_job(wave.job_path, None)
    return streamed_host(job, wave.setup, strict=False, keep=True)


def stream(job_path: Path, firmware: Machine, interrupt: tuple[int, float] | None = None,
           quiet: bool = True, terminal: bool | None = None) -> Streamed:
    """`printer-codegen stream job_path --port <pty> [--quiet]` against `firmware` in simavr, until it exits;
    `interrupt` as PtyBridge's: Ctrl-C that long after a frame of the firmware. Its stderr is a terminal (a
    pseudo-terminal, read as it writes) with `terminal`, by default without `quiet`: a bar shows only there."""
    config = firmware.setup.config
    f_cpu = firmware.setup.target.f_cpu
    terminal = Terminal() if (not quiet if terminal is None else terminal) else None
    with StreamSim(firmware.hex_path, config) as sim, \
            PtyBridge(len(config.motors), DEADLINE_S, interrupt) as bridge:
        process = subprocess.Popen([sys.executable, "-m", "codegen", "stream", str(job_path), "--port", bridge.port,
                                    *(["--quiet"] if quiet else [])], cwd=ROOT, stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE if terminal is None else terminal.slave, text=True)
        try:
            bridge.attach(process)
            trace, figures = sim.session(bridge, int((DEADLINE_S + 1) * f_cpu))  # the bridge's deadline first
            out, err = process.communicate(timeout=10)
        finally:
            if process.poll() is None:
                process.kill()
                process.communicate()
    if terminal is not None:
        err = terminal.close()
    return Streamed(process.returncode, out, err, trace, figures, bridge)


class Terminal:
    """A pseudo-terminal of 120 columns for a child's stderr, drained by a thread (a full one would block it)."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        fcntl.ioctl(self.slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))  # tqdm draws nothing 0 wide
        self.chunks: list[bytes] = []
        self.reader = threading.Thread(target=self._drain, daemon=True)
        self.reader.start()

    def _drain(self) -> None:
        while True:
            try:
                chunk = os.read(self.master, 1 << 16)
            except OSError:  # EIO: every writer has closed its end
                return
            if not chunk:
                return
            self.chunks.append(chunk)

    def close(self) -> str:
        os.close(self.slave)
        self.reader.join(timeout=5)
        os.close(self.master)
        return b"".join(self.chunks).decode(errors="replace")


def net_steps(trace: SimTrace, motors: int) -> list[int]:
    run = trace.run_only()
    return [int(run.step_dir[run.step_motor == m].sum()) for m in range(motors)]


def test_stream_plays_the_job_as_planned(wave, wave_host):
    assert wave_host.link_plan.stream_bytes > wave.setup.layout.ring_bytes  # the job's point: it needs credit
    run = stream(wave.job_path, wave)
    expected = [int(v) for v in wave_host.expected_final - wave_host.start_steps]
    assert (run.code, run.err) == (0, "")
    match = re.fullmatch(rf"streamed wave to {re.escape(run.bridge.port)}: {wave_host.link_plan.stream_bytes} "
                         rf"stream bytes in (\d+\.\d) s, (\d+) frames retransmitted; positions "
                         rf"{re.escape(str(expected))} as planned\n", run.out)
    assert match, run.out
    took, retransmits = float(match[1]), int(match[2])
    planned = wave_host.plan.total
    assert planned - 0.1 <= took <= planned + 1.0  # real time: the handshake and prefill on top of the motion
    assert retransmits == run.figures.retransmits  # none on an idle machine; a loaded one may be late
    assert (run.bridge.outcome, list(run.bridge.position)) == ("finished", expected)
    assert net_steps(run.trace, 2) == expected
    verdict = compare(wave_host, run.trace, simulated_switches(wave_host))
    assert verdict.problems == []
    assert (run.figures.underruns, run.figures.lost_bytes) == (0, 0)


def test_stream_refuses_a_firmware_built_for_another_machine(wave, tmp_path):
    other = write_machine(tmp_path / "other", ", invert_dir: true")  # y's motor turns the other way
    assert other.setup.identity != wave.setup.identity
    run = stream(wave.job_path, other)
    assert run.code == 1
    assert run.err == (
        f"error: wave: the stream ended refused: the firmware on the line was built for another machine, board or "
        f"format (identity {other.setup.identity:08x}, protocol 1, 2 motors; this job needs "
        f"{wave.setup.identity:08x}, protocol 1, 2 motors): build and flash `printer-codegen build --stream`\n")
    assert run.out == ""
    assert len(run.trace.step_cycle) == 0 and run.bridge.outcome is None


def test_ctrl_c_aborts_mid_job_where_the_machine_stopped(wave, wave_host):
    run = stream(wave.job_path, wave, interrupt=(protocol.STARTED, INTERRUPT_AFTER_S))
    stopped = net_steps(run.trace, 2)
    assert run.code == 1
    assert run.err == f"error: interrupted: sent ABORT; the machine stopped at positions {stopped}\n"
    assert run.out == ""
    assert (run.bridge.outcome, list(run.bridge.position)) == ("aborted", stopped)
    final = [int(v) for v in wave_host.expected_final - wave_host.start_steps]
    assert 0 < stopped[0] < final[0]  # x only goes forward: mid-job
    last_pulse_s = run.trace.step_cycle.max() / run.trace.f_cpu
    assert last_pulse_s < run.bridge.interrupted_at + ABORT_STOP_S
    twin = wave_host.pulses
    made = len(run.trace.run_only().step_cycle)  # the first pulse not made was due after the Ctrl-C, not before
    next_s = (run.trace.timer_start_cycle / run.trace.f_cpu + twin.tick[made] / wave_host.target.tick_hz)
    assert next_s > run.bridge.interrupted_at
    for m in range(2):  # the pulses so far are the twin's first ones
        made = run.trace.run_only().step_dir[run.trace.run_only().step_motor == m]
        np.testing.assert_array_equal(made, twin.of_motor(m)[1][:len(made)])


def test_ctrl_c_before_the_job_starts_reports_no_motion(wave):
    """Ctrl-C as the firmware answers HELLO: ABORT reaches an idle firmware that has played nothing."""
    run = stream(wave.job_path, wave, interrupt=(protocol.IDENT, 0.0))
    assert len(run.trace.step_cycle) == 0
    assert (run.code, run.err) == (1, "error: interrupted: sent ABORT; the machine stopped at positions [0, 0]\n")


def test_ctrl_c_as_the_job_ends_reports_the_finished_job(wave):
    """Ctrl-C just as the firmware reports FINISHED: the ABORT comes after the end, and the job is done."""
    line = ROOT / "examples" / "line.yaml"  # another job for the same machine: the same firmware plays it
    run = stream(line, wave, interrupt=(protocol.FINISHED, 0.0))
    assert run.bridge.interrupted_at is not None
    assert (run.code, run.err) == (0, "")
    assert re.fullmatch(rf"streamed line to {re.escape(run.bridge.port)}: 185 stream bytes in \d+\.\d s, \d+ frames "
                        rf"retransmitted; positions \[7200, 4400\] as planned\n", run.out), run.out
    assert net_steps(run.trace, 2) == [7200, 4400]


def test_no_progress_bar_when_stderr_is_not_a_terminal(wave):
    run = stream(wave.job_path, wave, quiet=False, terminal=False)
    assert run.code == 0 and run.out.startswith("streamed wave")
    assert "streaming:" not in run.err and "playing, ring" not in run.err and "\r" not in run.err, run.err[-300:]


def test_the_progress_bar_shows_the_firmwares_status_as_it_plays(wave, wave_host):
    """Without --quiet: the bar of acknowledged bytes, and beside it the firmware's STATUS, asked for twice a
    second once the job has started: playing, the ring's fill, each motor's steps since START (x only goes
    forward, so its count grows from one answer to the next), then the end's positions."""
    run = stream(wave.job_path, wave, quiet=False)
    assert run.code == 0 and run.out.startswith("streamed wave")
    shown = re.findall(r"playing, ring (\d+) B, x ([+-]\d+) y ([+-]\d+)", run.err)
    assert len(shown) >= 5, run.err[-600:]  # 5.6 s of motion, an answer every 0.5 s (the bar redraws them)
    xs = [int(x) for _, x, _ in shown]
    assert xs == sorted(xs) and xs[-1] > xs[0] >= 0
    final = int(wave_host.expected_final[0] - wave_host.start_steps[0])
    assert all(0 < int(fill) <= wave.setup.layout.ring_bytes for fill, _, _ in shown) and xs[-1] <= final

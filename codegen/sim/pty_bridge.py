"""A pseudo-terminal between a real `printer-codegen stream` process and the simulated streaming firmware: the
end-to-end test of the command users run against a board (tests/cli/test_stream_pty.py).

    with StreamSim(hex_path, config) as sim, PtyBridge(motors=2) as bridge:    # codegen/sim/avr_link.py
        process = subprocess.Popen([..., "stream", job, "--port", bridge.port, "--quiet"])
        bridge.attach(process)
        trace, figures = sim.session(bridge, cycle_budget)

The simulator boots before the process starts: the process gives up after a few HELLOs unanswered.

The bridge opens a pseudo-terminal pair; the process opens the slave by its path (pyserial takes it for a serial
port; a PTY ignores the baud rate) and the bridge keeps the master. To the simulator the bridge is a host with
HostLink's interface (codegen/link/host.py): transmit(now) hands over what the process wrote to the PTY since
the last call, receive(data, now) writes the firmware's bytes back, wake_at() asks for the simulator again a
slice later, and `done` says the process has exited (or the deadline has passed).

The process's timers (ACK timeouts, pings) run on its wall clock, the firmware on simulated time, and simavr is
several times faster than a real part: so the bridge paces simulated time to wall time, never letting the
simulation run ahead of the wall clock since the session began. The simulated UART already spends 10 bit times on
every byte each way, so the line's rate holds without the PTY's help. A slice of 2 ms keeps the process's view
of the firmware within a few milliseconds of a real board's.

`interrupt` plays an operator's Ctrl-C at a chosen point of the session: SIGINT to the process a given time
(simulated) after the firmware sent a given frame; at 0 s, before the process has read that frame. The bridge
reads both directions as a HostLink would, for StreamSim's figures and the test's own account: `stats` counts
the process's frames (a retransmission: a sequence number that goes back), `outcome` and `position` are what
the firmware's last frame said (FINISHED, UNDERRUN, ABORTED, HOMING_FAILED).
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
import tty

from codegen.link import protocol
from codegen.link.host import LinkStats

SLICE_S = 0.002  # simulated time between the simulator's returns to the bridge
SIGNAL_GRACE_S = 0.02  # wall time for the process to take a SIGINT before the firmware's frame that follows it
READ_BYTES = 65536
UNTRACKED = (protocol.HELLO, protocol.ABORT)  # frames that take no sequence number of their own
ENDINGS = {protocol.FINISHED: "finished", protocol.UNDERRUN: "underrun", protocol.ABORTED: "aborted",
           protocol.HOMING_FAILED: "homing failed"}


class PtyBridge:
    in_tail = False  # as a HostLink that is not told the stream's length: StreamSim's lowest fill counts it all

    def __init__(self, motors: int, deadline_s: float = 60.0, interrupt: tuple[int, float] | None = None):
        """`interrupt`: (a firmware frame's kind, seconds): SIGINT to the process that long after the frame."""
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line discipline: bytes pass as they are
        os.set_blocking(self.master, False)
        self.port = os.ttyname(self._slave)
        self.deadline_s = deadline_s
        self.interrupt = interrupt
        self.interrupted_at: float | None = None  # simulated time of the SIGINT
        self.motors = motors
        self.stats = LinkStats()
        self.outcome: str | None = None
        self.position: tuple[int, ...] | None = None
        self.process: subprocess.Popen | None = None
        self._now = 0.0
        self._wall_origin: float | None = None  # the wall clock's reading at simulated time 0
        self._from_host = protocol.Parser()
        self._from_firmware = protocol.Parser(protocol.MAX_ANSWER)
        self._next_seq = 0
        self._interrupt_due: float | None = None

    def __enter__(self) -> PtyBridge:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        os.close(self.master)
        os.close(self._slave)

    def attach(self, process: subprocess.Popen) -> None:
        """The streaming process whose port is `self.port`: the session lasts as long as it runs."""
        self.process = process

    @property
    def done(self) -> bool:
        if self.process is None:
            raise RuntimeError("attach the streaming process before the session")
        past_deadline = self._wall_origin is not None and time.monotonic() - self._wall_origin > self.deadline_s
        return self.process.poll() is not None or past_deadline

    def wake_at(self) -> float:
        return self._now + SLICE_S

    def transmit(self, now: float) -> bytes:
        self._now = now
        self._pace(now)
        self._interrupt_when_due(now, grace_s=0.0)  # the process answers the signal in its own time
        data = self._read_master()
        self._count(data)
        return data

    def receive(self, data: bytes, now: float) -> None:
        self._pace(now)  # the last byte has arrived by `now`: not before, on the wall clock
        for f in self._from_firmware.feed(data):
            if self.interrupt is not None and f.kind == self.interrupt[0] and self._interrupt_due is None:
                self._interrupt_due = now + self.interrupt[1]
            if f.kind in ENDINGS:
                self.outcome = ENDINGS[f.kind]
                if f.kind != protocol.HOMING_FAILED:
                    self.position = protocol.positions(f.payload, self.motors)
        self._interrupt_when_due(now, grace_s=SIGNAL_GRACE_S)  # the signal first, then these bytes
        view = memoryview(data)
        while view:  # the PTY's buffer is far larger than the firmware's answers: this hardly loops
            try:
                view = view[os.write(self.master, view):]
            except BlockingIOError:
                time.sleep(0.001)

    def _interrupt_when_due(self, now: float, grace_s: float) -> None:
        if self._interrupt_due is not None and self.interrupted_at is None and now >= self._interrupt_due:
            self.process.send_signal(signal.SIGINT)
            self.interrupted_at = now
            time.sleep(grace_s)

    def _pace(self, now: float) -> None:
        if self._wall_origin is None:
            self._wall_origin = time.monotonic() - now
        ahead = self._wall_origin + now - time.monotonic()
        if ahead > 0:
            time.sleep(ahead)

    def _read_master(self) -> bytes:
        out = bytearray()
        while True:
            try:
                chunk = os.read(self.master, READ_BYTES)
            except BlockingIOError:  # nothing more written yet
                return bytes(out)
            if not chunk:
                return bytes(out)
            out += chunk

    def _count(self, data: bytes) -> None:
        self.stats.bytes += len(data)
        for f in self._from_host.feed(data):
            self.stats.frames += 1
            if f.kind == protocol.HELLO:
                self._next_seq = (f.seq + 1) & 0xFF
            elif f.kind not in UNTRACKED:
                if f.seq != self._next_seq:  # go-back-N: an earlier frame again
                    self.stats.retransmits += 1
                else:
                    self._next_seq = (f.seq + 1) & 0xFF

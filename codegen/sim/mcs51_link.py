"""The 8051 streaming firmware in s51, in a closed loop with the host's own protocol code (codegen/link/host.py):
the host's bytes reach the simulated UART at the simulated baud rate, the firmware's answers reach the host with
their simulated time, and the host's next bytes depend on them.

How s51 0.6.4 is driven (each point measured here):
- Its command console, on a pipe. A batch of commands ends with `run`: the simulation goes on until a breakpoint
  stops it, then the batch's last commands print sim_ticks and a marker. Breakpoints that print a record and
  `run` on do not stop it. Stopped with nothing to read, s51 sleeps 100 ms before it looks again (its
  loop_delay), and its input often ran dry before the next batch came: so each batch ends with `file` of a FIFO,
  whose open waits for a writer, and the next batch goes in before we open the FIFO. s51 echoes its input: a
  batch goes in pieces whose echoes are whole lines (_Console). A stop costs about a
  millisecond.
- Host to firmware: a FIFO given to `-S in=`. Bytes written while s51 stands still are taken by its UART at its
  next serial tick once `uart0_check_often` is 1, then one every 10 bit times of Timer2 (the firmware's own baud
  rate). With check_often on and nothing to read, s51 polls the FIFO at every instruction (about 4x slower), so
  it is on only while bytes wait. No flow control: like a real UART, a byte that completes before the firmware
  has read the one before is lost (s51 keeps the newer one).
- Firmware to host: `-S out=` a file, where s51 writes each byte as its stop bit ends. A breakpoint where the
  serial interrupt sends a frame's last byte stops the simulation; the frame reaches the host at a stop set for
  when that byte has gone.
- The host's time: breakpoints `if sim_ticks-tb>=tw` on the firmware's polling loops (main's link_poll, homing's
  Timer1 wait) and its two interrupt vectors stop the simulation at the host's wake-up time, or within a turn of
  a loop after it (on a board with a display main's turn may include a refresh: up to 2 ms).
- The host starts once the firmware's main loop runs (its UART set up).
- Lost bytes: every read of SBUF prints its time; a byte that completed on a real 8N1 line at the firmware's
  rate before the byte ahead of it was read would have been lost.
- Records of the pins, the timer start, the ring's fill where the player goes for a record (with the stream
  bytes taken so far), homing's fault: breakpoints that print and run on, as in codegen/sim/mcs51.py.
"""

from __future__ import annotations

import array
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig
from codegen.firmware.homing import homing_ticks_bound
from codegen.firmware.mcs51.board import SFR, board_pins, memories
from codegen.firmware.mcs51.homing import decode_status
from codegen.firmware.mcs51.lcd import board_lcd
from codegen.firmware.mcs51.sdcc import SYMBOLS_FILE
from codegen.firmware.mcs51.stream import PAGE_BYTES, T2_CLOCKS_PER_BAUD, ring_layout
from codegen.link.host import LinkFigures
from codegen.sim.avr import HOMING_FAILED, SimTrace, _homing_fault, switch_thresholds
from codegen.sim.hd44780 import decode as decode_display
from codegen.sim.mcs51 import slow_pins, switch_model, trace_of
from codegen.sim.mcs51_edges import EdgeRecords, KeptRecords
from codegen.sim.mcs51_line import UartLine

TAG_TIMER, TAG_FAULT, TAG_RX, TAG_FILL = 16, 19, 21, 22  # record tags beyond the port tags 0..3
SBUF = 0x99
VECTOR_SERIAL = 0x0023  # the serial interrupt's vector (a jump to link.c's interrupt: player.c)
PICK_BYTES = 99  # s51 reads its console this many bytes at a time (ucsim's cl_f::pick)
GATE_NAME = "gate"
GATE = f'file "{GATE_NAME}"'  # in s51's working directory
MARK_A, MARK_A_PRINTS = "let /x 2748", b"\nabc\n"  # the end of what a batch's `before` printed
MARK_B, MARK_B_PRINTS = "let /x 4077", b"\nfed\n"  # the end of a batch
SYNC, SYNC_PRINTS = "let /x 12648430", b"c0ffee\n"  # the end of the setup
MAX_WAIT = 1 << 30  # clocks: sim_ticks is 32-bit; a stop at least this often keeps the wrap unambiguous
SIM_CLOCKS_PER_S = 5e6  # a pessimistic s51 speed with the FIFO polled, for the wall-clock watchdog
BITS_PER_BYTE = 10


class _Console:
    """s51 driven through its console: batches of commands, the number lines each prints. Each batch ends on
    `file` of a FIFO, the gate: s51 waits in its open until the next batch is in its input (see the top).

    s51 echoes its console's input as it reads it, 99 bytes at a time (ucsim's cl_f::pick), and runs a command
    between two reads: a piece of a line echoed between two outputs could read as a number, or glue one to its
    own line (measured: 1 batch in about 60,000). So a batch's bytes go in whole-line pieces of exactly 99
    bytes (padded with spaces) ahead of a last piece of at most 99, into an empty pipe at once: every echo is of
    whole lines. Markers print hex words (`abc`), which neither an echo nor a record (decimal) can print."""

    def __init__(self, args: list[str], cwd: Path):
        self.barrier = cwd / GATE_NAME
        os.mkfifo(self.barrier)
        self.proc = subprocess.Popen(args, cwd=cwd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL)
        self.buffer = b""
        self.waiting = False  # s51 waits at the gate

    def _release(self) -> None:
        """s51's open of the gate returns (it finds an empty file and goes on); s51 gone: nothing to do."""
        deadline = time.monotonic() + 30
        while self.waiting and self.proc.poll() is None:
            try:
                os.close(os.open(self.barrier, os.O_WRONLY | os.O_NONBLOCK))
                self.waiting = False
            except OSError:  # ENXIO: s51 is not in its open yet (its output must not fill the pipe meanwhile)
                if select.select([self.proc.stdout], [], [], 1e-3)[0]:
                    self.buffer += os.read(self.proc.stdout.fileno(), 1 << 16)
                if time.monotonic() > deadline:
                    tail = self.buffer[-3000:].decode(errors="replace")
                    raise BuildError(f"s51 does not come to its gate; it printed last:\n{tail}")

    def _read_until(self, end: bytes, wall_s: float) -> bytes:
        """What s51 prints up to `end` (consumed with it)."""
        deadline, seen = time.monotonic() + wall_s, 0
        while self.buffer.find(end, seen) < 0:
            seen = max(0, len(self.buffer) - len(end))
            ready, _, _ = select.select([self.proc.stdout], [], [], max(0.0, deadline - time.monotonic()))
            chunk = os.read(self.proc.stdout.fileno(), 1 << 16) if ready else b""
            if not chunk:
                raise BuildError("s51 stopped answering" if ready else
                                 f"s51 ran {wall_s:.0f} s without reaching a stop (a firmware stuck outside its "
                                 f"polling loops?)")
            self.buffer += chunk
        text, self.buffer = self.buffer.split(end, 1)
        return text

    def setup(self, commands: list[str], wall_s: float) -> None:
        """The commands before the first batch, what they print dropped. Their lines may be longer than a read:
        all of them are read before s51 waits at the gate, which lets it go at once (it then looks at its input
        again within its 100 ms loop delay, once)."""
        self.proc.stdin.write(("\n".join([*commands, SYNC, GATE]) + "\n").encode())
        self.proc.stdin.flush()
        self._read_until(SYNC_PRINTS, wall_s)  # not at a line start: it may follow a piece of an echoed line
        self.waiting = True
        self._release()

    def batch(self, before: list[str], then: list[str], wall_s: float) -> list[int]:
        """Run `before` (what it prints is dropped), then `then` (`run`: the simulation to its next stop): the
        number lines printed meanwhile (by `then`, and the records of breakpoints that ran on)."""
        last = [MARK_A, *then, MARK_B, GATE] if before else [*then, MARK_B, GATE]
        ahead = list(before)
        while ahead and len(ahead[-1]) + 1 + _length(last) <= PICK_BYTES:
            last.insert(0, ahead.pop())
        pieces = [*_pieces(ahead), "\n".join(last) + "\n"]
        data = "".join(pieces).encode()
        if _length(last) > PICK_BYTES or len(data) > select.PIPE_BUF:
            raise BuildError(f"s51 batch too long to be read whole: {pieces!r}")
        self.proc.stdin.write(data)
        self.proc.stdin.flush()
        self._release()
        text = self._read_until(MARK_B_PRINTS, wall_s)
        self.waiting = True
        after = text.decode(errors="replace").split(MARK_A_PRINTS.decode(), 1)[-1]
        return [int(line) for line in after.splitlines() if line.strip().lstrip("-").isdigit()]

    def close(self) -> None:
        try:
            self.proc.stdin.write(b"quit\n")
            self.proc.stdin.flush()
            self._release()
            self.proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()


def _length(lines: list[str]) -> int:
    return sum(len(line) + 1 for line in lines)


def _pieces(lines: list[str]) -> list[str]:
    """`lines` in pieces of exactly PICK_BYTES bytes, whole lines each, the last line of each padded."""
    pieces, current = [], []
    for line in lines:
        if len(line) + 1 > PICK_BYTES:
            raise BuildError(f"s51 command longer than a read of its console: {line!r}")
        if _length(current) + len(line) + 1 > PICK_BYTES:
            pieces.append(current)
            current = []
        current.append(line)
    if current:
        pieces.append(current)
    return ["\n".join(p) + " " * (PICK_BYTES - _length(p)) + "\n" for p in pieces]


def _committed(sym: dict) -> str:
    """The expression of the stream bytes the firmware has taken since HELLO (its u32 in internal RAM)."""
    return "+".join(f"iram[{sym['committed'] + i:#x}]*{1 << 8 * i}" for i in range(4))


def _setup(hex_path: Path, sym: dict, config: FirmwareConfig, pins: dict, switches: dict) -> list[str]:
    """The commands before the first run: the hex, the board's XRAM, the endstop keys, the breakpoints."""
    cmds = [f'file "{hex_path}"']
    # XRAM as the board decodes it: its bytes repeat over the 64 KB (external RAM sees only its address lines;
    # the on-chip XRAM of MOVX @Ri ignores P2).
    size = max(int(sym["xram"]), PAGE_BYTES)
    cmds.append(f"memory create chip boardxram {size} 8")
    cmds += [f"memory create addressdecoder xram {a:#x} {a + size - 1:#x} boardxram 0" for a in range(0, 65536, size)]
    prelude, on_write = switch_model(config, pins, switches) if config.homing else ((), {})
    cmds += [*prelude, "var tb", "var tw", "expression tb=0", "expression tw=1"]
    watched = [p for m in pins["motors"] for p in (m["step"], m["dir"])] + [pins["tool"]]
    watched += [p for _, p in slow_pins(pins)]
    lcd = board_lcd(config.board, [m.name for m in config.motors])
    if lcd is not None:
        w = lcd.wiring
        watched += [p for p in (w.rs, w.e, w.rw, *w.data) if p is not None]
    ports = sorted({p.port for p in watched})
    bits = sorted({SFR[p.port] + p.bit for p in watched})
    effects = {port: expr + "," for port, expr in on_write.items()}
    count = 0

    def brk(spec: str, prints: list[str] | None) -> None:
        nonlocal count
        count += 1
        cmds.append(f"break {spec}")
        if prints is not None:
            # no /u: s51 0.6.4 leaks memory at every /u it evaluates (about 5 KB a record, measured); a clock
            # printed as a negative int32 is unwrapped all the same (_Run._unwrap)
            cmds.append(f"commands {count} " + " ; ".join(f"expression {p}" for p in prints) + " ; run")

    for port in ports:
        brk(f"sfr w {SFR[port]:#x}", ["sim_ticks", f"{effects.get(port, '')}{port * 256}+P{port}"])
    for bit in bits:
        port = (bit - 0x80) >> 4
        brk(f"bits w {bit:#x}", ["sim_ticks", f"{effects.get(port, '')}{port * 256}+P{port}"])
    brk(f"{sym['timer_start']:#x}", ["sim_ticks", str(TAG_TIMER * 256)])
    brk(f"sfr r {SBUF:#x}", ["sim_ticks", str(TAG_RX * 256)])
    fill = f"(iram[{sym['link_head']:#x}]-iram[{sym['player_bank']:#x}])&255"
    for site in ("need_run", "need_block", "need_brun"):
        brk(f"{sym[site]:#x}", ["sim_ticks", f"{TAG_FILL * 256}+({fill})", _committed(sym)])
    if "homing_fault" in sym:
        brk(f"{sym['homing_fault']:#x}", ["sim_ticks", f"{TAG_FAULT * 256}+DPL"])
    brk(f"{sym['tx_end']:#x}", None)  # a frame's last byte goes out: a stop before the host's time (_Run.go)
    polls = [sym["poll"], sym["isr"], sym["link_isr_vector"]] + ([sym["homing_poll"]] if "homing_poll" in sym else [])
    for address in polls:
        brk(f"{address:#x} if sim_ticks-tb>=tw", None)
    return cmds


def simulate_stream(hex_path: Path, config: FirmwareConfig, host, cycle_budget: int,
                    switches: dict[int, int | None] | None = None,
                    edges: Path | None = None) -> tuple[SimTrace, LinkFigures]:
    """Run the streaming firmware `hex_path` (built by codegen.firmware.mcs51.stream) against `host` (HostLink's
    interface: transmit, receive, wake_at, done) until the host's session ends; BuildError past `cycle_budget`
    CPU clocks (an image that homes gets its homing time on top) or when s51 misbehaves. `switches`: the endstop
    keys as codegen.sim.mcs51.simulate takes them. The trace's tick 0 is the player's after the first START.
    With `edges`, the pins' records go to that file as they come (codegen/sim/mcs51_edges.py EdgeRecords: verify
    reads it beside the run, codegen/verify/bounded.py) and the trace has no pulses and no pins, only the
    session's state, clock, homing's fault, display and ring fills."""
    if shutil.which("s51") is None:
        raise BuildError("s51 not found: install sdcc-ucsim")
    began = time.monotonic()
    hex_path = Path(hex_path).resolve()
    sym = json.loads(hex_path.with_name(SYMBOLS_FILE).read_text(encoding="utf-8"))
    if "link_isr" not in sym:
        raise BuildError(f"{hex_path} is not a streaming firmware (build it with codegen.firmware.mcs51.stream)")
    sym["link_isr_vector"] = VECTOR_SERIAL
    pins = board_pins(config)
    mem = memories(config.board)
    f_cpu, layout = int(mem["f_cpu"]), ring_layout(config)
    if switches is None:
        switches = {k: 0 for k in range(len(config.homing))}
    budget = int(cycle_budget)
    if config.homing:
        budget += homing_ticks_bound(config, switch_thresholds(config, switches), int(mem["tick_hz"])) * int(
            sym["clocks_per_tick"])
    byte_clocks = BITS_PER_BYTE * T2_CLOCKS_PER_BAUD * (0x10000 - layout.reload)  # a byte on a real 8N1 line
    with tempfile.TemporaryDirectory(prefix="printer-codegen-s51link-") as tmp:
        work = Path(tmp)
        fifo, out_path = work / "rx.fifo", work / "tx.bin"
        os.mkfifo(fifo)
        out_path.touch()
        feed = os.open(fifo, os.O_RDWR)  # opened first: s51's open for reading does not wait then
        setup = _setup(hex_path, sym, config, pins, switches)
        s51 = _Console(["s51", "-X", str(f_cpu), "-S", f"in={fifo},out={out_path}"], work)
        try:
            with open(out_path, "rb") as answers:
                run = _Run(s51, host, answers, feed, f_cpu, byte_clocks, budget,
                           KeptRecords() if edges is None else EdgeRecords(edges, config))
                try:
                    run.go(setup)
                finally:
                    run.records.close()
                final_committed = run.committed(sym)
        finally:
            s51.close()
            os.close(feed)
    rec = run.records.array()
    clocks = int(sym["clocks_per_tick"])
    starts = rec[rec[:, 1] == TAG_TIMER, 0]
    timer_start = int(starts[0]) + clocks * (1 + int(sym["start_ticks"])) if len(starts) else None
    if edges is None:
        trace = trace_of(rec, pins, f_cpu, run.now, timer_start, int(starts[0]) if len(starts) else None)
    else:
        motors = len(config.motors)
        trace = SimTrace("done", run.now, f_cpu, timer_start, *(np.zeros(0, np.int64) for _ in range(3)),
                         [None] * motors, [None] * motors, [])
    faults = rec[rec[:, 1] == TAG_FAULT]
    if len(faults):
        axis_bits, phase = decode_status(int(faults[0, 2]))
        trace.homing_failed, trace.homing_fault = True, _homing_fault(config, HOMING_FAILED, axis_bits, phase)
    lcd = board_lcd(config.board, [m.name for m in config.motors])
    if lcd is not None:
        trace.display = decode_display(rec, lcd.wiring, f_osc=f_cpu) if edges is None else run.records.display.display()
    link = getattr(host, "link", host)  # a HostLink, or a wrapper of one (link.faults.Faulty, a test's)
    # As the plan counts it: a finished job's last ring of the stream drains the ring, and does not count.
    finished = link.outcome == "finished"
    fills = np.frombuffer(run.fills, dtype=np.int64).reshape(-1, 3)  # ring bytes, bytes taken, clock
    drained = finished & (fills[:, 1] - fills[:, 0] > final_committed - layout.ring_bytes)
    counted = fills[~drained, 0]
    trace.ring_fill = fills[:, [2, 0]].copy()
    figures = LinkFigures(baud=layout.baud, bytes=link.stats.bytes, frames=link.stats.frames,
                          retransmits=link.stats.retransmits,
                          min_ring_fill_bytes=int(counted.min()) if len(counted) else None,
                          underruns=int(link.outcome == "underrun"), lost_bytes=run.line.lost_bytes(run.now),
                          wall_s=time.monotonic() - began)
    return trace, figures


class _Run:
    """The loop: at each stop the host hears what the firmware sent and answers, and the next stop is set."""

    def __init__(self, s51: _Console, host, answers, feed: int, f_cpu: int, byte_clocks: int, budget: int,
                 records: KeptRecords | EdgeRecords):
        self.s51, self.host, self.answers, self.feed = s51, host, answers, feed
        self.f_cpu, self.byte_clocks, self.budget = f_cpu, byte_clocks, budget
        self.now = 0  # CPU clocks, unwrapped
        self.records = records  # (clock, tag, value) rows: pins, timer start, fault
        self.fills = array.array("q")  # at each record the player reads: ring bytes, bytes taken, clock
        self.line = UartLine(byte_clocks)
        self.tx_due: int | None = None  # when the frame going out will have gone
        self.polling = False  # uart0_check_often

    def go(self, setup: list[str]) -> None:
        # Bytes sent before the UART is set up are lost on a real board (the host's HELLO only tries again).
        self.s51.setup(setup, 30)
        *numbers, ticks = self.s51.batch([], ["run", "let sim_ticks"], 10 + MAX_WAIT / SIM_CLOCKS_PER_S)
        self._take(numbers)
        self.now = self._unwrap(ticks)
        pending: list[str] = []
        while True:
            data = self.answers.read()
            if data:
                self.host.receive(data, self.now / self.f_cpu)
            if self.host.done:
                return
            out = self.host.transmit(self.now / self.f_cpu)
            if out:
                os.write(self.feed, out)
                self.line.send(len(out), self.now)
            # The FIFO holds bytes until the UART starts on the last one, which is before the firmware reads the
            # one ahead of it: then polling it is of no more use.
            waiting = self.line.waiting()
            if waiting != self.polling:
                self.polling = waiting
                pending.append(f"let uart0_check_often={int(waiting)}")
            targets = [self.budget + 1, self.now + MAX_WAIT]
            wake = self.host.wake_at()
            if wake is not None:
                targets.append(int(np.ceil(wake * self.f_cpu)))
            if self.tx_due is not None:
                targets.append(self.tx_due)
            if waiting:
                targets.append(max(self.line.last_arrival, self.now + self.byte_clocks))
            wait = max(1, min(targets) - self.now)
            pending += ["let tb=sim_ticks", f"let tw={wait}"]
            *numbers, ticks = self.s51.batch(pending, ["run", "let sim_ticks"], 10 + wait / SIM_CLOCKS_PER_S)
            pending = []
            target = self.now + wait
            self._take(numbers)
            self.now = self._unwrap(ticks)
            self.line.judge(self.now)
            if self.tx_due is not None and self.now >= self.tx_due:
                self.tx_due = None
            if self.now < target:  # not the host's time: the only other stop is a frame's last byte going out
                self.tx_due = self.now + self.byte_clocks + 2 * self.byte_clocks // BITS_PER_BYTE
            if self.now > self.budget:
                raise BuildError(f"the streamed job did not end within {self.budget} clocks "
                                 f"({self.budget / self.f_cpu:.3f} s simulated; the host's session: "
                                 f"{getattr(self.host, 'outcome', None) or 'going on'})")

    def _unwrap(self, ticks: int) -> int:
        """sim_ticks is 32-bit: the clock nearest to `now` (stops and records are less than 2**31 clocks apart)."""
        return self.now + ((ticks - self.now + (1 << 31)) % (1 << 32)) - (1 << 31)

    def _take(self, numbers: list[int]) -> None:
        records: list[tuple[int, int, int]] = []
        i = 0
        while i < len(numbers):
            clock, code = self._unwrap(numbers[i]), numbers[i + 1]
            self.now = max(self.now, clock)
            tag, value = code >> 8, code & 0xFF
            i += 2
            if tag == TAG_FILL:
                self.fills.extend((value, numbers[i], clock))
                i += 1
            elif tag == TAG_RX:
                self.line.reading(clock)
            else:
                records.append((clock, tag, value))
        if records:
            self.records.add(np.array(records, dtype=np.int64))

    def committed(self, sym: dict) -> int:
        """Stream bytes the firmware has taken since the last HELLO, as it counts them now."""
        return self.s51.batch([], [f"let /u {_committed(sym)}"], 10)[-1]

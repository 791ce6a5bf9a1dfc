"""How fast the 8051 streaming player steps with its link busy at 9600 baud, and what the link costs, in s51.

The player costs: firmware_rate_51.py's schedules and criterion (every pulse of a motor one scheduled gap after
the one before, within +-TOLERANCE clocks and the jitter of the instructions the step interrupt may have to wait
for: main's and the serial interrupt's, at most LINK_JITTER machine cycles), streamed into the streaming firmware
(templates/mcs51/link.c.j2) in the closed-loop simulation (codegen/sim/mcs51_link.py), and the line kept busy
from START to the end by DATA frames out of sequence, of the host's payload for the ring (codegen/link/ring.py:
31 bytes for a 255-byte ring, 8 for 63): the serial interrupt takes every byte (CRC, state) and answers each
frame with an ACK (9 bytes). The whole table goes into the ring before START where the ring holds it (the cases
are cut to fit: 30 run loads, 6 blocks; a 63-byte ring holds 3 to 7 run loads); 6 blocks that it does not hold
stream as they play, the host's own session (codegen/link/host.py) between the filler frames. A case counts only
if no received byte came too late for a real UART.

The link's own cost: HELLO then DATA frames in sequence (of that payload, as many as the ring holds, and again),
back to back at 9600 baud into an idle streaming firmware; the serial interrupt timed from its vector to its exit,
CPU clocks per received byte (the ACKs' bytes included), and its share of the CPU.

It prints the figures and, with --write, puts them under `stream_player_costs:` in the board's file: by default
targets/stc89c52rc.yaml (the ring in its on-chip XRAM), with --board seed-51 (external RAM, the display, SDCC's
large model) targets/seed-51.yaml, with --board at89c52 (no XRAM: the ring in internal RAM, read and written
with MOV @Ri at index | base) targets/at89c52.yaml, the MCU file of coil-51 too (whose coil sockets do not
stream). CPU clocks, 12 per machine cycle, like every cost there.

    python benchmarks/stream_rate_51.py [--board B] [--write]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from firmware_rate_51 import CLOCKS, TICK_HZ, TOLERANCE, _note, config, latencies, schedule  # noqa: E402
from shortest import shortest  # noqa: E402 - beside this script

import codegen.tables.format as tables  # noqa: E402
from codegen.firmware.mcs51.sdcc import MAP_FILE, SYMBOLS_FILE, read_map  # noqa: E402
from codegen.firmware.mcs51.stream import build_stream_image, render_stream_sources, ring_layout  # noqa: E402
from codegen.link import protocol  # noqa: E402
from codegen.link.host import HostLink, LinkStats  # noqa: E402
from codegen.link.ring import link_budget  # noqa: E402
from codegen.paths import targets_dir  # noqa: E402
from codegen.sim.mcs51_link import simulate_stream  # noqa: E402

LINK_JITTER = 4  # machine cycles: the instruction running when the timer overflows, one more after a RETI
DEFAULT_BOARD = "stc89c52rc"
EVENTS = {"run": 2000, "accel": 2000, "runs": 30, "block": 6 * 256}  # at most: the ring must hold each whole
PREFILL_FRAMES = 4  # DATA frames before START of a table streamed as it plays
FILLER_SEQ = 200  # the sequence number of the filler frames: never the one expected (the tables take fewer)
TAG = 4_000_000_000  # a record's second line: TAG + 1 entry, 2 exit, 3 a byte read (above any sim_ticks here)
ISR_ENTRY, ISR_EXIT = 2, 6  # machine cycles before the vector's fetch (the hardware's LCALL), after the exit label


class Flood:
    """A host (HostLink's interface) that sends HELLO, the table, START, and then out-of-sequence DATA frames
    back to back until `until` (seconds), all at once; done at the firmware's report or at `until`."""

    def __init__(self, data: bytes, until: float, baud: int, payload: int):
        frames = [protocol.frame(protocol.HELLO, 0)]
        chunks = [data[i:i + payload] for i in range(0, len(data), payload)]
        frames += [protocol.frame(protocol.DATA, 1 + k, c) for k, c in enumerate(chunks)]
        frames.append(protocol.frame(protocol.START, 1 + len(chunks)))
        filler = protocol.frame(protocol.DATA, FILLER_SEQ, bytes(payload))
        frames += [filler] * int(until * baud / 10 / len(filler) + 1)
        self.script, self.until = b"".join(frames), until
        self.stats = LinkStats(bytes=len(self.script), frames=len(frames))
        self.outcome, self.now = None, 0.0
        self._parser = protocol.Parser(protocol.MAX_ANSWER)

    @property
    def done(self) -> bool:
        return self.outcome is not None or self.now >= self.until

    def transmit(self, now: float) -> bytes:
        self.now, out, self.script = now, self.script, b""
        return out

    def receive(self, data: bytes, now: float) -> None:
        self.now = now
        for f in self._parser.feed(data):
            if f.kind in (protocol.FINISHED, protocol.UNDERRUN):
                self.outcome = protocol.NAMES[f.kind].lower()

    def wake_at(self) -> float:
        return self.until


class Busy:
    """A host for a table the ring cannot hold whole (6 blocks, a ring of internal RAM): the host's own session
    (HostLink) streams it, and from STARTED on the line is kept busy between its frames by out-of-sequence DATA
    frames of the same size, as Flood's; done at the firmware's report or at `until`."""

    def __init__(self, link: HostLink, until: float, baud: int):
        self.link, self.until, self.byte_s = link, until, 10 / baud
        self.stats = link.stats
        self.filler = protocol.frame(protocol.DATA, FILLER_SEQ, bytes(link.payload))
        self.line_free = self.now = 0.0  # when the bytes sent so far have gone

    @property
    def outcome(self) -> str | None:
        return self.link.outcome

    @property
    def done(self) -> bool:
        return self.link.done or self.now >= self.until

    def transmit(self, now: float) -> bytes:
        self.now = now
        out = self.link.transmit(now)
        blocked = self.link._credit() < self.link.payload  # HostLink waits for ring space: the line is free
        if not out and blocked and self.link.started_at is not None and now >= self.line_free:
            out = self.filler
        self.line_free = max(self.line_free, now) + len(out) * self.byte_s
        return out

    def receive(self, data: bytes, now: float) -> None:
        self.now = now
        self.link.receive(data, now)

    def wake_at(self) -> float:
        busy = self.line_free if self.link.started_at is not None else None
        return min(t for t in (self.link.wake_at(), busy, self.until) if t is not None)


def stream_bytes(n_motors: int, events: int, mode: str) -> int:
    return len(tables.encode(schedule(n_motors, 1000, events, mode)).data + protocol.tail_padding(n_motors))


def case_events(n_motors: int, mode: str, board: str) -> int:
    """The events of a case: EVENTS, but only as many run loads as the board's ring holds (a run load at every
    event cannot be streamed while it plays)."""
    ring = ring_layout(config(n_motors, board)).ring_bytes
    events = EVENTS[mode]
    while mode == "runs" and stream_bytes(n_motors, events, mode) > ring:
        events -= 1
    return events


def play(n_motors: int, interval: int, mode: str, work: Path, board: str):
    sched = schedule(n_motors, interval, case_events(n_motors, mode, board), mode)
    cfg = config(n_motors, board)
    key = f"{board}-{n_motors}"
    if not (work / key / "firmware.hex").is_file():
        build_stream_image(render_stream_sources(cfg), work / key)
    data = tables.encode(sched).data + protocol.tail_padding(n_motors)
    duration = (2000 + interval * int(sched.run_count.sum())) / TICK_HZ + 0.6  # the handshake and prefill
    layout = ring_layout(cfg)
    payload = link_budget(layout.baud, layout.ring_bytes, n_motors).payload
    if len(data) <= layout.ring_bytes:
        host = Flood(data, duration, layout.baud, payload)
    else:
        identity = protocol.firmware_identity(cfg, TICK_HZ * CLOCKS, TICK_HZ)
        # Frames of a quarter of the ring: before START it takes four (the records of tick 0 and of the first
        # block, RING_NEED bytes before each); 16-byte frames would fill 48 bytes of 63.
        payload = layout.ring_bytes // PREFILL_FRAMES
        host = Busy(HostLink([data], n_motors, identity, 10 / layout.baud, PREFILL_FRAMES * payload,
                             payload=payload), duration, layout.baud)
    trace, figures = simulate_stream(work / key / "firmware.hex", cfg, host, int(duration * 12e6) + 24_000_000)
    return sched, trace, figures, host


def on_time(n_motors: int, interval: int, mode: str, work: Path, board: str) -> bool:
    sched, trace, figures, host = play(n_motors, interval, mode, work, board)
    late = latencies(sched, trace, n_motors) if host.outcome == "finished" else None
    skip = 2 if mode in ("run", "accel") else 1
    return (late is not None and figures.lost_bytes == 0
            and all(int(np.abs(np.diff(m[skip:])).max()) <= TOLERANCE + CLOCKS * LINK_JITTER for m in late))


def motor_counts(board: str) -> tuple[int, ...]:
    return (1, 3) if board == "seed-51" else (1, 3, 4)


def suffix(n: int) -> str:
    return "1_motor" if n == 1 else f"{n}_motors"


def measure(work: Path, board: str) -> dict[str, int]:
    """Every figure of stream_player_costs, in machine cycles."""
    out: dict[str, int] = {}
    for n in motor_counts(board):
        for kind, mode, hi in (("event", "run", 400), ("accel_event", "accel", 400), ("run_event", "runs", 800),
                               ("block_event", "block", 1200)):
            out[f"{kind}_cycles_{suffix(n)}"] = shortest(lambda c: on_time(n, c, mode, work, board), 10, hi,
                                                         f"{n} motor(s), mode {mode}")
    sched, trace, _, _ = play(1, 2000, "run", work, board)
    out["isr_latency_cycles"] = min(int(np.median(m)) for m in latencies(sched, trace, 1)) // CLOCKS
    highs = [h for mode in ("run", "runs", "block") for h in play(1, 2000, mode, work, board)[1].pulse_high_min_cycles]
    out["step_high_min_cycles"] = min(h for h in highs if h is not None) // CLOCKS
    n = motor_counts(board)[-1]
    worst = out[f"block_event_cycles_{suffix(n)}"]
    sched, trace, _, _ = play(n, worst, "block", work, board)
    out["block_dir_write_cycles"] = max(worst * CLOCKS + int(np.median(m)) - s for m, s in
                                        zip(latencies(sched, trace, n), trace.dir_setup_min_cycles)) // CLOCKS
    out["min_event_cycles"] = worst + 1  # + 1 us of margin
    return out


def link_cost(work: Path, board: str, rounds: int = 6) -> tuple[float, int]:
    """The serial interrupt with the line full of DATA frames: (machine cycles per received byte, bytes)."""
    cfg = config(1, board)
    out = work / f"{board}-1"
    if not (out / "firmware.hex").is_file():
        build_stream_image(render_stream_sources(cfg), out)
    layout = ring_layout(cfg)
    payload = link_budget(layout.baud, layout.ring_bytes, 1).payload
    script = b""
    for _ in range(rounds):  # each round fills the ring (7 x 31 bytes of 255; 3 x 16 of 63) and HELLO empties it
        script += protocol.frame(protocol.HELLO, 0)
        script += b"".join(protocol.frame(protocol.DATA, 1 + k, bytes(range(k, k + payload)))
                           for k in range(layout.ring_bytes // payload))
    (work / "rx.bin").write_bytes(script)
    sym = json.loads((out / SYMBOLS_FILE).read_text())
    exit_label = read_map(out / MAP_FILE)[1]["_link_isr_exit"]
    end = int((len(script) * 10 / layout.baud + 0.2) * 12e6)
    size = max(int(sym["xram"]), 256)
    lines = [f'file "{out / "firmware.hex"}"', f"memory create chip boardxram {size} 8",
             *[f"memory create addressdecoder xram {a:#x} {a + size - 1:#x} boardxram 0"
               for a in range(0, 65536, size)],
             "expression uart0_check_often=1",
             "break 0x23", f"commands 1 expression /u sim_ticks ; expression /u {TAG + 1} ; run",
             f"break {exit_label:#x}", f"commands 2 expression /u sim_ticks ; expression /u {TAG + 2} ; run",
             "break sfr r 0x99", f"commands 3 expression /u sim_ticks ; expression /u {TAG + 3} ; run",
             f"break {sym['poll']:#x} if sim_ticks>{end}", "run", "quit"]
    (work / "cost.cmd").write_text("\n".join(lines) + "\n")
    done = subprocess.run(["timeout", "120", "s51", "-X", "12M", "-S", f"in={work / 'rx.bin'},out=/dev/null",
                           "-C", str(work / "cost.cmd")], stdin=subprocess.DEVNULL, capture_output=True, text=True)
    numbers = [int(x) for x in done.stdout.splitlines() if x.strip().isdigit()]
    rec = np.array([(t, tag - TAG) for t, tag in zip(numbers, numbers[1:]) if tag > TAG])
    entries, exits = rec[rec[:, 1] == 1, 0], rec[rec[:, 1] == 2, 0]
    spent = (exits[:len(entries)] - entries[:len(exits)]).sum() / CLOCKS + (ISR_ENTRY + ISR_EXIT) * len(exits)
    received = int((rec[:, 1] == 3).sum())
    return spent / received, received


def write_costs(figures: dict[str, int], link_cycles: float, board: str) -> None:
    """Replace (or append) the `stream_player_costs:` block of the board's file: CPU clocks, cycles in comments."""
    command = "python benchmarks/stream_rate_51.py" + (f" --board {board}" if board != DEFAULT_BOARD else "")
    iram = ring_layout(config(1, board)).iram_base > 0
    block = ["# Measured costs of the streaming player (templates/mcs51/player.c.j2 with `stream`: records read with",
             "# MOV from the link's ring in internal RAM), the link busy at 9600 baud, from" if iram else
             "# MOVX from the link's ring), the link busy at 9600 baud, from",
             f"# `{command} --write`.",
             f"# CPU clocks, machine cycles in the comments; every pulse within +-{LINK_JITTER} machine cycles (the",
             "# instructions of main and of the serial interrupt that the step interrupt may wait for), no received",
             "# byte late. codegen/targets.py merges them over the flashed player's costs.",
             "stream_player_costs:"]
    for key, cycles in figures.items():
        block.append(f"  {key}: {cycles * CLOCKS}".ljust(36) + f"# {cycles} machine cycles{_note(key)}")
    share = link_cycles * 960 / 1e4  # % of the machine cycles of a second at 960 bytes a second
    block.append(f"  link_isr_cycles: {round(link_cycles * CLOCKS)}".ljust(36)
                 + f"# {link_cycles:.1f} machine cycles per byte received, ACKs included: {share:.1f} % at 9600 baud")
    path = targets_dir() / f"{board}.yaml"
    text = re.sub(r"\n(# Measured costs of the streaming player.*?\n)?stream_player_costs:\n(  .*\n)*", "\n",
                  path.read_text(encoding="utf-8"), flags=re.S)
    path.write_text(text.rstrip("\n") + "\n\n" + "\n".join(block) + "\n", encoding="utf-8")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--board", default=DEFAULT_BOARD, help=f"a streaming mcs51 board (default: {DEFAULT_BOARD})")
    parser.add_argument("--write", action="store_true", help="write the figures into the target files")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="stream-rate-51-") as tmp:
        link_cycles, received = link_cost(Path(tmp), args.board)
        figures = measure(Path(tmp), args.board)
    print(f"board {args.board}: the streaming player at 12 MHz in s51, the link busy at 9600 baud; within "
          f"+-{TOLERANCE} clocks and {LINK_JITTER} machine cycles of jitter, no byte late")
    for n in motor_counts(args.board):
        for kind, what in (("event", "sustained, constant rate"), ("accel_event", "sustained, accelerating"),
                           ("run_event", "a run load at every event"), ("block_event", "a block load at every event")):
            cycles = figures[f"{kind}_cycles_{suffix(n)}"]
            print(f"  {n} motor(s), {what}: {cycles} machine cycles per event, {TICK_HZ / cycles:,.0f} events/s")
    for key in ("isr_latency_cycles", "step_high_min_cycles", "block_dir_write_cycles", "min_event_cycles"):
        print(f"  {key}: {figures[key]} machine cycles")
    print(f"  the link: {link_cycles:.1f} machine cycles per received byte ({received} bytes, the ACKs' bytes "
          f"included), {link_cycles * 960 / 1e4:.1f} % of the CPU with the line full at 9600 baud")
    if args.write:
        write_costs(figures, link_cycles, args.board)
        print(f"written into targets/{args.board}.yaml")


if __name__ == "__main__":
    main()

"""How fast the 8051 streaming player steps with its link busy at 9600 baud, and what the link costs, in s51.

The player costs: firmware_rate_51.py's schedules and criterion (every pulse of a motor one scheduled gap after
the one before, within +-TOLERANCE clocks and the jitter of the instructions the step interrupt may have to wait
for: main's and the serial interrupt's, at most LINK_JITTER machine cycles), streamed into the streaming firmware
(templates/mcs51/link.c.j2) in the closed-loop simulation (codegen/sim/mcs51_link.py), the whole table in the ring
before START (the cases are cut to fit: 30 run loads, 6 blocks), and the line kept busy from HELLO to the end by
DATA frames of 31 bytes out of sequence: the serial interrupt takes every byte (CRC, state) and answers each
frame with an ACK (9 bytes). A case counts only if no received byte came too late for a real UART.

The link's own cost: HELLO then DATA frames in sequence (31 bytes each, 7 to the ring's fill, and again), back to
back at 9600 baud into an idle streaming firmware; the serial interrupt timed from its vector to its exit, CPU
clocks per received byte (the ACKs' bytes included), and its share of the CPU.

It prints the figures and, with --write, puts them under `stream_player_costs:` in targets/at89c52.yaml and
stc89c52rc.yaml (measured on the stc89c52rc: the same core, the ring in its on-chip XRAM), or with --board seed-51
(the display, SDCC's large model) in targets/seed-51.yaml. CPU clocks, 12 per machine cycle, like every cost there.

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

from codegen import tables  # noqa: E402
from codegen.firmware.mcs51 import MAP_FILE, SYMBOLS_FILE, read_map  # noqa: E402
from codegen.firmware.mcs51_stream import build_stream_image, render_stream_sources, ring_layout  # noqa: E402
from codegen.link import protocol  # noqa: E402
from codegen.link.host import LinkStats  # noqa: E402
from codegen.paths import targets_dir  # noqa: E402
from codegen.sim.mcs51_link import simulate_stream  # noqa: E402
from firmware_rate_51 import CLOCKS, TICK_HZ, TOLERANCE, _note, config, latencies, schedule  # noqa: E402
from shortest import shortest  # noqa: E402 - beside this script

LINK_JITTER = 4  # machine cycles: the instruction running when the timer overflows, one more after a RETI
BOARDS = ("at89c52", "stc89c52rc")  # the stc89c52rc's figures; the at89c52 has no XRAM to stream with
EVENTS = {"run": 2000, "accel": 2000, "runs": 30, "block": 6 * 256}  # the ring holds each whole
FILLER_PAYLOAD = 31  # bytes: the DATA frames of a 255-byte ring (codegen/link/ring.py: an eighth)
TAG = 4_000_000_000  # a record's second line: TAG + 1 entry, 2 exit, 3 a byte read (above any sim_ticks here)
ISR_ENTRY, ISR_EXIT = 2, 6  # machine cycles before the vector's fetch (the hardware's LCALL), after the exit label


class Flood:
    """A host (HostLink's interface) that sends HELLO, the table, START, and then out-of-sequence DATA frames
    back to back until `until` (seconds), all at once; done at the firmware's report or at `until`."""

    def __init__(self, data: bytes, until: float, baud: int):
        frames = [protocol.frame(protocol.HELLO, 0)]
        chunks = [data[i:i + FILLER_PAYLOAD] for i in range(0, len(data), FILLER_PAYLOAD)]
        frames += [protocol.frame(protocol.DATA, 1 + k, c) for k, c in enumerate(chunks)]
        frames.append(protocol.frame(protocol.START, 1 + len(chunks)))
        filler = protocol.frame(protocol.DATA, 128 + len(chunks), bytes(FILLER_PAYLOAD))  # never the one expected
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


def play(n_motors: int, interval: int, mode: str, work: Path, board: str):
    sched = schedule(n_motors, interval, EVENTS[mode], mode)
    cfg = config(n_motors, board)
    key = f"{board}-{n_motors}"
    if not (work / key / "firmware.hex").is_file():
        build_stream_image(render_stream_sources(cfg), work / key)
    data = tables.encode(sched).data + protocol.tail_padding(n_motors)
    duration = (2000 + interval * int(sched.run_count.sum())) / TICK_HZ + 0.6  # the handshake and prefill
    host = Flood(data, duration, ring_layout(cfg).baud)
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


def measure(work: Path, board: str) -> dict[str, int]:
    """Every figure of stream_player_costs, in machine cycles."""
    out: dict[str, int] = {}
    for n in motor_counts(board):
        suffix = "1_motor" if n == 1 else f"{n}_motors"
        for kind, mode, hi in (("event", "run", 400), ("accel_event", "accel", 400), ("run_event", "runs", 800),
                               ("block_event", "block", 1200)):
            out[f"{kind}_cycles_{suffix}"] = shortest(lambda c: on_time(n, c, mode, work, board), 10, hi,
                                                      f"{n} motor(s), mode {mode}")
    sched, trace, _, _ = play(1, 2000, "run", work, board)
    out["isr_latency_cycles"] = min(int(np.median(m)) for m in latencies(sched, trace, 1)) // CLOCKS
    highs = [h for mode in ("run", "runs", "block") for h in play(1, 2000, mode, work, board)[1].pulse_high_min_cycles]
    out["step_high_min_cycles"] = min(h for h in highs if h is not None) // CLOCKS
    n = motor_counts(board)[-1]
    worst = out[f"block_event_cycles_{n}_motors"]
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
    script = b""
    for _ in range(rounds):  # each round fills the ring (7 x 31 bytes) and HELLO empties it again
        script += protocol.frame(protocol.HELLO, 0)
        script += b"".join(protocol.frame(protocol.DATA, 1 + k, bytes(range(k, k + FILLER_PAYLOAD))) for k in range(7))
    (work / "rx.bin").write_bytes(script)
    sym = json.loads((out / SYMBOLS_FILE).read_text())
    exit_label = read_map(out / MAP_FILE)[1]["_link_isr_exit"]
    end = int((len(script) * 10 / ring_layout(cfg).baud + 0.2) * 12e6)
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


def write_costs(figures: dict[str, int], link_cycles: float, boards: tuple[str, ...]) -> None:
    """Replace (or append) the `stream_player_costs:` block of each board file: CPU clocks, cycles in comments."""
    command = "python benchmarks/stream_rate_51.py" + (" --board seed-51" if boards == ("seed-51",) else "")
    block = ["# Measured costs of the streaming player (templates/mcs51/player.c.j2 with `stream`: records read with",
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
    for board in boards:
        path = targets_dir() / f"{board}.yaml"
        text = re.sub(r"\n(# Measured costs of the streaming player.*?\n)?stream_player_costs:\n(  .*\n)*", "\n",
                      path.read_text(encoding="utf-8"), flags=re.S)
        path.write_text(text.rstrip("\n") + "\n\n" + "\n".join(block) + "\n", encoding="utf-8")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--board", default="stc89c52rc", help="a streaming mcs51 board (default: stc89c52rc)")
    parser.add_argument("--write", action="store_true", help="write the figures into the target files")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="stream-rate-51-") as tmp:
        link_cycles, received = link_cost(Path(tmp), args.board)
        figures = measure(Path(tmp), args.board)
    print(f"board {args.board}: the streaming player at 12 MHz in s51, the link busy at 9600 baud; within "
          f"+-{TOLERANCE} clocks and {LINK_JITTER} machine cycles of jitter, no byte late")
    for n in motor_counts(args.board):
        suffix = "1_motor" if n == 1 else f"{n}_motors"
        for kind, what in (("event", "sustained, constant rate"), ("accel_event", "sustained, accelerating"),
                           ("run_event", "a run load at every event"), ("block_event", "a block load at every event")):
            cycles = figures[f"{kind}_cycles_{suffix}"]
            print(f"  {n} motor(s), {what}: {cycles} machine cycles per event, {TICK_HZ / cycles:,.0f} events/s")
    for key in ("isr_latency_cycles", "step_high_min_cycles", "block_dir_write_cycles", "min_event_cycles"):
        print(f"  {key}: {figures[key]} machine cycles")
    print(f"  the link: {link_cycles:.1f} machine cycles per received byte ({received} bytes, the ACKs' bytes "
          f"included), {link_cycles * 960 / 1e4:.1f} % of the CPU with the line full at 9600 baud")
    if args.write:
        write_costs(figures, link_cycles, BOARDS if args.board == "stc89c52rc" else (args.board,))
        print("written into targets/" + ("{at89c52,stc89c52rc}" if args.board == "stc89c52rc" else args.board)
              + ".yaml")


if __name__ == "__main__":
    main()

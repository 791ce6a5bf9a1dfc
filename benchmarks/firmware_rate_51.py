"""How fast the 8051 player steps, measured pulse by pulse in s51.

Schedules are built by hand: events a constant interval apart, on the at89c52 board (x, y, z, e on sockets X, Y, Z,
E0). Motor 0 is the block's master (steps == modulus, as the host makes it: it steps at every event without any
Bresenham arithmetic); the others step at (nearly) every event through the 16-bit Bresenham, the path that costs
most. For each case the benchmark finds the
shortest interval, in machine cycles (= timer ticks, 12 CPU clocks each), at which every pulse still comes at its
scheduled tick plus one constant latency, within +-TOLERANCE clocks:
  - "run":    one long rate run with add = 0 (the sustained rate, constant speed);
  - "accel":  one long rate run with add != 0 (the sustained rate while accelerating: interval += add is done);
  - "runs":   a new rate run at every event (a run load from code memory each time);
  - "block":  a new block every 256 events, in the long form, its first event a new run (block and run load: the
              worst case, which gives min_event_cycles with four motors), all DIR pins flipping.
It prints the figures and, with --write, puts them into targets/at89c52.yaml and stc89c52rc.yaml (in CPU clocks =
12 x machine cycles, the unit the host's formula expects). A board with a display (seed-51) runs main's display code
while the interrupt plays, so its interrupt saves main's registers: `--board seed-51` measures that player (with up to
3 motors, and within +-MAIN_JITTER machine cycles: an interrupt waits for main's instruction to end) and writes the
figures under the board's `player_costs:`.

    python benchmarks/firmware_rate_51.py [--board B] [--write]
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from shortest import shortest  # noqa: E402 - beside this script

from codegen.errors import BuildError  # noqa: E402
from codegen.firmware.config import FirmwareConfig, MotorPins, load_target  # noqa: E402
from codegen.firmware.mcs51.image import build_image, render_sources  # noqa: E402
from codegen.paths import targets_dir  # noqa: E402
from codegen.sim.mcs51 import SimTrace, simulate  # noqa: E402
from codegen.tables.format import stream_bytes  # noqa: E402
from codegen.tables.schedule import Schedule  # noqa: E402
from codegen.tables.twin import predict  # noqa: E402

TICK_HZ = 1_000_000
CLOCKS = 12  # CPU clocks per machine cycle (timer tick)
TOLERANCE = 1  # clocks around the constant latency
SOCKETS = (("x", "X"), ("y", "Y"), ("z", "Z"), ("e", "E0"))
MOTOR_COUNTS = (1, 3, 4)
BOARDS = ("at89c52", "stc89c52rc")  # seed-51 names at89c52 as its MCU: it uses those figures
ACCEL_ADD = 1  # 1/256 tick per event: the accelerating case adds it (and the interval stays as good as constant)


MAIN_JITTER = 3  # machine cycles: main's longest instruction (MUL, DIV) less one


def config(n_motors: int, board: str = "at89c52") -> FirmwareConfig:
    motors = tuple(MotorPins(name, socket) for name, socket in SOCKETS[:n_motors])
    return FirmwareConfig("firmware_rate_51", "benchmarks/firmware_rate_51.py", "mcs51", board, motors)


def schedule(n_motors: int, interval: int, events: int, mode: str) -> Schedule:
    """A lead event 2000 ticks after tick 0 (clear of tick 0's block load), then `events` events `interval` ticks
    apart (mode: run, accel, runs, block). Motor 0 is the master (steps == modulus: it steps at every event with
    no Bresenham); the others step at (nearly) every event through the full Bresenham path."""
    lead = (1, 1, 1, 0, [(2000 * 256, 0, 1)])  # (dir, modulus, other motors' steps, init, runs)
    if mode in ("run", "accel"):
        add = ACCEL_ADD if mode == "accel" else 0
        first = interval * 256 - add * (events - 1) // 2  # centred on the nominal interval
        blocks = [lead, (1, events, events - 1, 0, [(first, add, events)])]
    elif mode == "runs":
        blocks = [lead, (1, events, events - 1, 0, [(interval * 256, 0, 1)] * events)]
    else:  # long blocks (modulus 256), each starting with a run of its own
        blocks = [lead] + [(-1 if k % 2 == 0 else 1, 256, 255, 0, [(interval * 256, 0, 1), (interval * 256, 0, 255)])
                           for k in range(max(events // 256, 1))]
    runs = [r for b in blocks for r in b[4]]
    block_events = np.array([sum(r[2] for r in b[4]) for b in blocks], dtype=np.int64)
    modulus = np.array([b[1] for b in blocks], dtype=np.int64)
    steps = np.repeat(np.array([b[2] for b in blocks], dtype=np.int64)[:, None], n_motors, axis=1)
    steps[:, 0] = modulus
    return Schedule(
        motors=tuple(name for name, _ in SOCKETS[:n_motors]), tick_hz=TICK_HZ,
        block_dirs=np.repeat(np.array([b[0] for b in blocks], dtype=np.int8)[:, None], n_motors, axis=1),
        block_steps=steps, block_modulus=modulus,
        block_init=np.repeat(np.array([b[3] for b in blocks], dtype=np.int64)[:, None], n_motors, axis=1),
        block_tool=np.zeros(len(blocks), dtype=bool), 
        block_segment=np.zeros(len(blocks), dtype=np.int64),
        run_interval=np.array([r[0] for r in runs], dtype=np.int64),
        run_add=np.array([r[1] for r in runs], dtype=np.int64),
        run_count=np.array([r[2] for r in runs], dtype=np.int64), block_events=block_events)


def play(n_motors: int, interval: int, events: int, mode: str, workdir: Path, board: str = "at89c52",
         ) -> tuple[Schedule, SimTrace]:
    sched = schedule(n_motors, interval, events, mode)
    cfg = config(n_motors, board)
    image = build_image(render_sources(sched, cfg), workdir, stream_bytes(sched))
    total = int(sched.run_count.sum())
    return sched, simulate(image.hex_path, cfg, (2000 + interval * total) * CLOCKS * 2 + 1_000_000)


def latencies(sched: Schedule, trace: SimTrace, n_motors: int) -> list[np.ndarray] | None:
    """Per motor: edge clock - (tick 0 + 12 x the twin's tick) for each pulse; None if pulses are missing."""
    twin = predict(sched)
    out = []
    for m in range(n_motors):
        ticks, edges = twin.tick[twin.motor == m], trace.step_cycle[trace.step_motor == m]
        if len(ticks) != len(edges):
            return None
        out.append(edges - trace.timer_start_cycle - CLOCKS * ticks)
    return out


def on_time(n_motors: int, interval: int, events: int, mode: str, workdir: Path, board: str = "at89c52") -> bool:
    """Every gap between two pulses of a motor after the lead event is the scheduled one within TOLERANCE
    clocks (the gap from the lead into a long run, a run load, is left out in the modes run and accel)."""
    try:
        sched, trace = play(n_motors, interval, events, mode, workdir, board)
    except BuildError:  # too fast: a delta already past waits a whole timer period, past the budget
        return False
    late = latencies(sched, trace, n_motors)
    skip = 2 if mode in ("run", "accel") else 1
    tolerance = TOLERANCE + (CLOCKS * MAIN_JITTER if load_target(board).get("lcd") else 0)
    return late is not None and all(int(np.abs(np.diff(m[skip:])).max()) <= tolerance for m in late)


def fastest(n_motors: int, events: int, mode: str, workdir: Path, board: str, lo: int = 10, hi: int = 1000) -> int:
    """The shortest interval (machine cycles) that plays on time; assumes anything slower also does."""
    return shortest(lambda cycles: on_time(n_motors, cycles, events, mode, workdir, board), lo, hi,
                    f"{n_motors} motor(s), mode {mode}")


def coil_board(board: str) -> bool:
    """A board with 4-wire coil sockets (coil-51: sockets X and Y only)."""
    return any("coils" in s for s in (load_target(board).get("steppers") or {}).values())


def motor_counts(board: str) -> tuple[int, ...]:
    if coil_board(board):
        return (1, 2)
    return MOTOR_COUNTS if board in BOARDS else MOTOR_COUNTS[:2]


def measure(work: Path, board: str) -> dict[str, int]:
    """Every figure of the target files, in machine cycles."""
    out: dict[str, int] = {}
    for n in motor_counts(board):
        suffix = "1_motor" if n == 1 else f"{n}_motors"
        out[f"event_cycles_{suffix}"] = fastest(n, 2000, "run", work, board)
        out[f"accel_event_cycles_{suffix}"] = fastest(n, 2000, "accel", work, board)
        out[f"run_event_cycles_{suffix}"] = fastest(n, 300, "runs", work, board)
        out[f"block_event_cycles_{suffix}"] = fastest(n, 2560, "block", work, board)
    sched, trace = play(1, 2000, 100, "run", work, board)
    out["isr_latency_cycles"] = min(int(np.median(m)) for m in latencies(sched, trace, 1)) // CLOCKS
    if coil_board(board):  # no STEP pulse, no DIR pin: the coil port is written once per event
        out["min_event_cycles"] = out[f"block_event_cycles_{motor_counts(board)[-1]}_motors"] + 1
        return out
    # The STEP high time of every path: same run, run load, block load (the shortest is a run load's).
    highs = [h for mode in ("run", "runs", "block")
             for h in play(1, 2000, 20, mode, work, board)[1].pulse_high_min_cycles]
    out["step_high_min_cycles"] = min(h for h in highs if h is not None) // CLOCKS
    n = motor_counts(board)[-1]
    worst = out[f"block_event_cycles_{n}_motors"]
    sched, trace = play(n, worst, 2560, "block", work, board)
    late = latencies(sched, trace, n)
    # DIR changes right after the previous event's pulses: overflow to the last DIR write.
    out["block_dir_write_cycles"] = max(worst * CLOCKS + int(np.median(m)) - s
                                        for m, s in zip(late, trace.dir_setup_min_cycles)) // CLOCKS
    out["min_event_cycles"] = worst + 1  # + 1 us of margin
    return out


def write_targets(figures: dict[str, int], boards: tuple[str, ...]) -> None:
    """Replace the cost lines (key: value  # comment) of each board file: value in clocks, cycles in the comment."""
    for board in boards:
        path = targets_dir() / f"{board}.yaml"
        text = path.read_text(encoding="utf-8")
        for key, cycles in figures.items():
            text, n = re.subn(rf"^( *){key}: *\d+( *#[^\n]*)?$",
                              lambda m, k=key, c=cycles: f"{m.group(1)}{k}: {c * CLOCKS}".ljust(36)
                              + f"# {c} machine cycles{_note(k)}", text, flags=re.M)
            if n == 0:
                raise SystemExit(f"{path}: has no line `{key}:` to update")
        path.write_text(text, encoding="utf-8")


def _note(key: str) -> str:
    notes = {"min_event_cycles": "; the worst block load + 1 us; also from tick 0 to the first event",
             "isr_latency_cycles": "; overflow to the first STEP rising edge",
             "block_dir_write_cycles": "; overflow to the last DIR write of a block load (all motors)",
             "step_high_min_cycles": "; shortest STEP high time (a run load); longer pulses pad the interrupt"}
    if key.startswith("event_cycles"):
        return "; sustained, one long constant-rate run"
    if key.startswith("accel_event"):
        return "; sustained, one long accelerating run"
    if key.startswith("run_event"):
        return "; a new rate run at every event"
    if key.startswith("block_event"):
        return "; a new block at every event, DIR flipping"
    return notes.get(key, "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--board", default=BOARDS[0], help="an mcs51 board (default: at89c52)")
    parser.add_argument("--write", action="store_true", help="write the figures into the mcs51 target files")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="firmware-rate-51-") as tmp:
        figures = measure(Path(tmp), args.board)
    print(f"board {args.board}")
    jitter = "" if not load_target(args.board).get("lcd") else f" and +-{MAIN_JITTER} machine cycles of main's instructions"
    print(f"8051 player at 12 MHz (1 MHz timer ticks) in s51; every pulse on its tick within +-{TOLERANCE} clocks{jitter}; "
          f"motor 0 the master, every other motor stepping through Bresenham at (nearly) every event")
    for n in motor_counts(args.board):
        suffix = "1_motor" if n == 1 else f"{n}_motors"
        for kind, what in (("event", "sustained, constant rate"), ("accel_event", "sustained, accelerating"),
                           ("run_event", "a run load at every event"), ("block_event", "a block load at every event")):
            cycles = figures[f"{kind}_cycles_{suffix}"]
            rate = TICK_HZ / cycles
            print(f"  {n} motor(s), {what}: {cycles} machine cycles per event, {rate:,.0f} steps/s per motor, "
                  f"{rate * n:,.0f} steps/s in total")
    for key in ("isr_latency_cycles", "step_high_min_cycles", "block_dir_write_cycles", "min_event_cycles"):
        if key in figures:
                print(f"  {key}: {figures[key]} machine cycles")
    if args.write:
        boards = BOARDS if args.board in BOARDS else (args.board,)
        write_targets(figures, boards)
        print(f"written into targets/{{{','.join(boards)}}}.yaml (in CPU clocks)")


if __name__ == "__main__":
    main()

"""How fast the ATmega2560 player steps, measured pulse by pulse in simavr.

Schedules are built by hand in the compact stream (codegen/tables/format.py: runs that cross block starts), on a
cartesian RAMPS 1.4 (x, y, z, e on sockets X, Y, Z, E0): a lead event 2000 ticks after tick 0 (clear of tick
0's block load), then events a constant interval apart. Motor 0 is the block's master (steps == modulus: it steps
at every event without Bresenham); the others step at (nearly) every event through the 16-bit Bresenham, the path
that costs most. For each case the benchmark finds the shortest interval at which every pulse still comes at its
scheduled tick plus one constant latency (per motor), within +-TOLERANCE cycles:
  - "run":        one long rate run (the sustained rate);
  - "runs":       a new rate run at every event (a run load from flash each time);
  - "block":      a new short block at every event (modulus 1, every motor stepping, DIR flipping), each with a
                  new rate run: block and run load at every event;
  - "long_block": long blocks (modulus 256), each starting with a long rate run record, DIR flipping: the
                  block-start event is the worst case (the long forms).
The player's timer ticks are 8 CPU cycles (tick_hz 2 MHz); to give the interrupt's cost to the cycle, the cases
run on a build whose Timer1 counts CPU cycles (prescaler 1: the same code but the clock select bits), and each
figure is checked again at the real tick (the interval rounded up to whole ticks must play on time).
Also measured: compare match to the first STEP edge, compare match to the last DIR write of a block load, the
shortest STEP high time, and homing at power-up (templates/avr/homing.c.j2): the shortest step interval shared
by 1..4 homed motors whose switches close at different distances, at which every homing step comes one interval
after the one before within +-TOLERANCE cycles (in each phase), with the DIR setup of the default 1 us kept.
With --write the figures go into targets/atmega2560.yaml.

    python benchmarks/firmware_rate.py [--write]
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from shortest import shortest  # noqa: E402 - beside this script

from codegen.errors import BuildError  # noqa: E402
from codegen.firmware.avr.image import build_image, render_sources  # noqa: E402
from codegen.firmware.config import FirmwareConfig, MotorPins, load_target  # noqa: E402
from codegen.paths import targets_dir  # noqa: E402
from codegen.program.homing import HomingAxis  # noqa: E402
from codegen.sim.avr import SimTrace, simulate  # noqa: E402
from codegen.tables.format import stream_bytes  # noqa: E402
from codegen.tables.schedule import Schedule  # noqa: E402
from codegen.tables.twin import predict  # noqa: E402

MCU = "atmega2560"
F_CPU = 16_000_000
TOLERANCE = 2  # cycles around the constant latency
SOCKETS = (("x", "X"), ("y", "Y"), ("z", "Z"), ("e", "E0"))
MOTOR_COUNTS = (1, 3, 4)
LEAD_TICKS = 2000
LONG_ADD = 40_000  # an add beyond i16 makes a run record long (with count 1 it changes no time)
HOMING_SWITCHES = ("x_min", "y_min", "z_min", "x_max")  # any free switch will do for E0
HOMING_BACKOFF = 20  # steps
MARGIN_CYCLES = 16  # 1 us on top of the worst block load: min_event_cycles
BUDGET_FACTOR = 2
PAD_MARGIN = 1  # cycles the interrupt holds STEP high beyond step_pulse_us (templates/avr/player_isr.S.j2)
MAX_LATENCY = 200  # cycles from the compare match to a STEP edge: more is a missed compare (a timer period late)


@contextmanager
def prescaler(scale: int):
    """Build and simulate with Timer1 at F_CPU / scale (the MCU file's tick_hz, changed in its cached copy)."""
    mcu = load_target(MCU)
    saved = mcu["tick_hz"]
    mcu["tick_hz"] = F_CPU // scale
    try:
        yield mcu["tick_hz"]
    finally:
        mcu["tick_hz"] = saved


def config(n_motors: int) -> FirmwareConfig:
    motors = tuple(MotorPins(name, socket) for name, socket in SOCKETS[:n_motors])
    return FirmwareConfig("firmware_rate", "benchmarks/firmware_rate.py", "avr", "ramps-1.4", motors)


def schedule(n_motors: int, interval: int, events: int, mode: str, tick_hz: int) -> Schedule:
    """The lead event, then `events` events `interval` ticks apart (see the module docstring). In the modes run
    and runs they are the events of one block after one more event LEAD_TICKS after the lead (the block load
    before it is not what they measure)."""
    fx = interval * 256
    lead = (1, 1, 1, [(LEAD_TICKS * 256, 0, 1)])  # (dir, modulus, the other motors' steps, runs)
    first = [(LEAD_TICKS * 256, 0, 1)]
    if mode == "run":  # interval += add is done at every event, whatever the add: 0 here
        blocks = [lead, (1, events + 1, events, first + [(fx, 0, events)])]
    elif mode == "runs":
        blocks = [lead, (1, events + 1, events, first + [(fx, 0, 1)] * events)]
    elif mode == "block":
        blocks = [lead] + [(-1 if k % 2 == 0 else 1, 1, 1, [(fx, 0, 1)]) for k in range(events)]
    else:  # long_block
        blocks = [lead] + [(-1 if k % 2 == 0 else 1, 256, 255, [(fx, LONG_ADD, 1), (fx, 0, 255)])
                           for k in range(max(events // 256, 1))]
    runs = [r for b in blocks for r in b[3]]
    modulus = np.array([b[1] for b in blocks], dtype=np.int64)
    steps = np.repeat(np.array([b[2] for b in blocks], dtype=np.int64)[:, None], n_motors, axis=1)
    steps[:, 0] = modulus
    return Schedule(
        motors=tuple(name for name, _ in SOCKETS[:n_motors]), tick_hz=tick_hz,
        block_dirs=np.repeat(np.array([b[0] for b in blocks], dtype=np.int8)[:, None], n_motors, axis=1),
        block_steps=steps, block_modulus=modulus, block_init=np.zeros((len(blocks), n_motors), dtype=np.int64),
        block_tool=np.zeros(len(blocks), dtype=bool), 
        block_segment=np.zeros(len(blocks), dtype=np.int64),
        run_interval=np.array([r[0] for r in runs], dtype=np.int64),
        run_add=np.array([r[1] for r in runs], dtype=np.int64),
        run_count=np.array([r[2] for r in runs], dtype=np.int64),
        block_events=np.array([sum(r[2] for r in b[3]) for b in blocks], dtype=np.int64))


def play(n_motors: int, interval: int, events: int, mode: str, workdir: Path, tick_hz: int,
         ) -> tuple[Schedule, SimTrace]:
    sched = schedule(n_motors, interval, events, mode, tick_hz)
    image = build_image(render_sources(sched, config(n_motors)), workdir, stream_bytes(sched))
    cycles = (LEAD_TICKS + interval * int(sched.run_count.sum())) * (F_CPU // tick_hz)
    return sched, simulate(image.hex_path, config(n_motors), BUDGET_FACTOR * cycles + 1_000_000)


def latencies(sched: Schedule, trace: SimTrace, tick_hz: int) -> list[np.ndarray] | None:
    """Per motor: edge cycle - (tick 0 + the twin's tick in cycles) of each pulse; None if pulses are missing."""
    twin, out = predict(sched), []
    for m in range(len(sched.motors)):
        ticks, edges = twin.tick[twin.motor == m], trace.step_cycle[trace.step_motor == m]
        if len(ticks) != len(edges) or not np.array_equal(twin.dir[twin.motor == m], trace.step_dir[trace.step_motor == m]):
            return None
        out.append(edges - trace.timer_start_cycle - ticks * (F_CPU // tick_hz))
    return out


def on_time(n_motors: int, interval: int, events: int, mode: str, workdir: Path, tick_hz: int) -> bool:
    """Every pulse at its tick + the motor's constant latency within TOLERANCE (no later than MAX_LATENCY: not a
    timer period late); in the mode run, every gap between two pulses of a motor after the first run load of the
    measured run is the scheduled one within TOLERANCE."""
    try:
        sched, trace = play(n_motors, interval, events, mode, workdir, tick_hz)
    except BuildError:  # too fast: a compare set in the past waits a whole timer period, past the budget
        return False
    late = latencies(sched, trace, tick_hz)
    if late is None:
        return False
    if mode == "run":  # the lead, the event LEAD_TICKS later and the one after it load records
        return all(int(np.abs(np.diff(m[3:])).max()) <= TOLERANCE for m in late)
    return all(int(np.abs(m - np.median(m)).max()) <= TOLERANCE and np.median(m) < MAX_LATENCY for m in late)


def fastest(n_motors: int, events: int, mode: str, workdir: Path, lo: int = 20, hi: int = 2000) -> int:
    """The shortest interval in CPU cycles that plays on time (Timer1 at prescaler 1); then checked at the real
    tick, the interval rounded up to whole ticks."""
    with prescaler(1) as tick_hz:
        hi = shortest(lambda cycles: on_time(n_motors, cycles, events, mode, workdir, tick_hz), lo, hi,
                      f"{n_motors} motor(s), mode {mode}")
    tick_hz = load_target(MCU)["tick_hz"]
    scale = F_CPU // tick_hz
    if not on_time(n_motors, -(-hi // scale), events, mode, workdir, tick_hz):
        raise BuildError(f"{n_motors} motor(s), mode {mode}: {hi} cycles play on time at prescaler 1, but not "
                         f"{-(-hi // scale)} ticks at prescaler {scale}")
    return hi


def homing_config(n_motors: int, interval: int) -> FirmwareConfig:
    axes = tuple(HomingAxis((m,), (1,), HOMING_SWITCHES[m], 1, 500, interval, interval, HOMING_BACKOFF)
                 for m in range(n_motors))
    return FirmwareConfig("homing_rate", "benchmarks/firmware_rate.py", "avr", "ramps-1.4",
                          config(n_motors).motors, homing=axes)


def homing_on_time(n_motors: int, interval: int, workdir: Path, tick_hz: int) -> bool:
    """Home n motors (switches 40, 50, ... steps away) at `interval` ticks per step, then play a one-event table."""
    sched = schedule(n_motors, 2000, 1, "run", tick_hz)
    cfg = homing_config(n_motors, interval)
    mcu = load_target(MCU)
    limit, mcu["homing_event_cycles"] = mcu["homing_event_cycles"], [0] * 5  # measure below the checked minimum
    try:
        sources = render_sources(sched, cfg)
    finally:
        mcu["homing_event_cycles"] = limit
    scale = F_CPU // tick_hz
    try:
        image = build_image(sources, workdir, stream_bytes(sched))
        trace = simulate(image.hex_path, cfg, 400 * interval * scale * 4 + 1_000_000,
                         switches={m: 40 + 10 * m for m in range(n_motors)})
    except BuildError:
        return False
    if trace.homing_failed or any(s is None or s < F_CPU // 1_000_000 for s in trace.dir_setup_min_cycles):
        return False
    for m in range(n_motors):
        home = (trace.step_motor == m) & (trace.step_phase == "home")
        cycles, dirs = trace.step_cycle[home], trace.step_dir[home]
        if len(cycles) != 40 + 10 * m + 2 * HOMING_BACKOFF:
            return False
        same_phase = dirs[1:] == dirs[:-1]  # the phases alternate directions
        if np.abs(np.diff(cycles)[same_phase] - interval * scale).max() > TOLERANCE + 1:  # + the polling loop
            return False
    return True


def homing_fastest(n_motors: int, workdir: Path, lo: int = 10, hi: int = 4000) -> int:
    """The shortest homing step interval in CPU cycles (Timer1 at prescaler 1, as the player's cases)."""
    with prescaler(1) as tick_hz:
        return shortest(lambda cycles: homing_on_time(n_motors, cycles, workdir, tick_hz), lo, hi,
                        f"homing {n_motors} motor(s)")


def suffix(n: int) -> str:
    return "1_motor" if n == 1 else f"{n}_motors"


def measure(work: Path) -> dict:
    """Every figure of targets/atmega2560.yaml, in CPU cycles."""
    out: dict = {}
    for n in MOTOR_COUNTS:
        out[f"event_cycles_{suffix(n)}"] = fastest(n, 2000, "run", work)
        out[f"run_event_cycles_{suffix(n)}"] = fastest(n, 300, "runs", work)
        short, long = fastest(n, 300, "block", work), fastest(n, 1024, "long_block", work)
        out[f"short_block_cycles_{suffix(n)}"], out[f"long_block_cycles_{suffix(n)}"] = short, long
        out[f"block_event_cycles_{suffix(n)}"] = max(short, long)
    tick_hz = load_target(MCU)["tick_hz"]
    scale = F_CPU // tick_hz
    sched, trace = play(1, 250, 100, "run", work, tick_hz)
    out["isr_latency_cycles"] = min(int(np.median(m)) for m in latencies(sched, trace, tick_hz))
    highs = [h for n in MOTOR_COUNTS for mode in ("run", "runs", "block", "long_block")
             for h in play(n, 250, 512, mode, work, tick_hz)[1].pulse_high_min_cycles if h is not None]
    out["step_high_time_cycles"] = min(highs)
    # What the host counts on: every path padded to step_pulse_us, + 1 cycle the interrupt adds (a write lands
    # at the end of a 2-cycle instruction on a real part): a longer pulse grows the padded paths by the difference.
    out["step_high_min_cycles"] = min(highs) - PAD_MARGIN
    n = MOTOR_COUNTS[-1]
    worst = max(out[f"block_event_cycles_{suffix(n)}"] for n in MOTOR_COUNTS)
    ticks = -(-worst // scale)
    dir_write = 0
    for mode in ("block", "long_block"):
        sched, trace = play(n, ticks, 1024, mode, work, tick_hz)
        late = latencies(sched, trace, tick_hz)
        # DIR changes right after the previous event's pulses: compare match to the last DIR write.
        dir_write = max(dir_write, max(ticks * scale + int(np.median(m)) - s
                                       for m, s in zip(late, trace.dir_setup_min_cycles)))
    out["block_dir_write_cycles"] = dir_write
    out["min_event_cycles"] = worst + MARGIN_CYCLES
    pulse = int(np.ceil(2.0 * F_CPU / 1e6))
    out["homing_event_cycles"] = [homing_fastest(k, work) - pulse + MARGIN_CYCLES for k in range(1, 5)]
    return out


def write_target(figures: dict) -> None:
    """Replace the value of each `key: value  # comment` line of targets/atmega2560.yaml."""
    path = targets_dir() / f"{MCU}.yaml"
    text = path.read_text(encoding="utf-8")
    for key, value in figures.items():
        if key.startswith(("short_block", "long_block", "step_high_time")):
            continue
        text, n = re.subn(rf"^{key}: *(\[[^\]]*\]|\d+)", lambda m, v=value: f"{m.group(0).split(':')[0]}: {v}"
                          .replace("'", ""), text, flags=re.M)
        if n == 0:
            raise SystemExit(f"{path}: has no line `{key}:` to update")
    path.write_text(text, encoding="utf-8")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--write", action="store_true", help="write the figures into targets/atmega2560.yaml")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="firmware-rate-") as tmp:
        figures = measure(Path(tmp))
    print(f"ATmega2560 player at {F_CPU / 1e6:g} MHz in simavr (Timer1 ticks: {load_target(MCU)['tick_hz']:,} Hz); "
          f"every pulse on its tick within +-{TOLERANCE} cycles; motor 0 the master, the others stepping through "
          f"Bresenham at (nearly) every event")
    for n in MOTOR_COUNTS:
        for kind, what in (("event", "sustained"), ("run_event", "a run load at every event"),
                           ("short_block", "a short block (and run) load at every event"),
                           ("long_block", "a long block and long run load (every 256 events)")):
            cycles = figures[f"{kind}_cycles_{suffix(n)}"]
            rate = F_CPU / cycles
            print(f"  {n} motor(s), {what}: {cycles} cycles per event, {rate:,.0f} steps/s per motor, "
                  f"{rate * n:,.0f} steps/s in total")
    for key in ("isr_latency_cycles", "step_high_time_cycles", "step_high_min_cycles", "block_dir_write_cycles",
                "min_event_cycles",
                "homing_event_cycles"):
        print(f"  {key}: {figures[key]}")
    if args.write:
        write_target(figures)
        print(f"written into targets/{MCU}.yaml")


if __name__ == "__main__":
    main()

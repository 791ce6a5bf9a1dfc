"""Run an ATmega2560 firmware.hex in simavr and decode its STEP, DIR and tool pins with exact cycle times.

simavr 1.6 has no usable trace output, so a small C harness (simavr_harness.c, linked with libsimavr) is built
on first use into a cache directory and logs every real pin level change as binary records. For an image that
homes, the harness also plays the endstop switches: it follows each homed motor's position from its STEP and
DIR edges and closes each axis's switch where `simulate(..., switches=)` puts it (a corexy's x and y switches
from both belts' positions).
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from codegen import progress
from codegen.errors import BuildError
from codegen.firmware.avr.board import Pin, board_pins
from codegen.firmware.avr.laser import LASER_TOP_ADDRESS, laser_ocr_address
from codegen.firmware.avr.player import START_TICKS
from codegen.firmware.config import FirmwareConfig, load_target
from codegen.firmware.homing import homing_ticks_bound
from codegen.sim.avr_edges import EDGE_RECORD, EdgeDecoder, PinWave, read_edges
from codegen.sim.avr_keys import jog_positions, key_args
from codegen.sim.keys import session

HARNESS_SOURCE = Path(__file__).with_name("simavr_harness.c")
PLANT_SOURCE = HARNESS_SOURCE.with_name("simavr_plant.c")  # compiled beside the harness
HARNESS_SOURCES = (HARNESS_SOURCE, HARNESS_SOURCE.with_name("simavr_link.c"),  # #included by the first ...
                   HARNESS_SOURCE.with_name("simavr_keys.c"),  # ... as this one
                   PLANT_SOURCE, PLANT_SOURCE.with_suffix(".h"))
HARNESS_BUILD = ("gcc", "-O2", "-I/usr/include/simavr", f"-I{HARNESS_SOURCE.parent}")
HARNESS_LIBS = ("-lsimavr", "-lelf", "-lm")
EXIT_STATES = {0: "done", 1: "crashed", 2: "budget", 4: "held"}  # held: a plant run's `held=` (avr_plant.py)
PHASE_HOME, PHASE_RUN = "home", "run"  # SimTrace.step_phase values
HOMING_FAILED = 0x02  # GPIOR0 bit set by homing.c's error state (GPIOR1: the motor bits, GPIOR2: the phase)
HOMING_PHASES = {1: "fast approach", 2: "back off", 3: "slow approach"}


@dataclass
class SimTrace:
    """What the simulated firmware did with its pins; step pulses in time order (motors: config order).

    The step arrays hold every pulse, homing included; `step_phase` tells them apart and `run_only()` keeps the
    step table's (what the twin predicts)."""

    state: str  # done | crashed | budget | held (still running a while after the table: heaters held)
    cycles: int  # total simulated cycles
    f_cpu: int
    timer_start_cycle: int | None  # the player's tick 0: START_TICKS ticks after it started Timer1; None if never
    step_cycle: np.ndarray  # (P,) int64, STEP rising edge
    step_motor: np.ndarray  # (P,) int index into config.motors
    step_dir: np.ndarray  # (P,) +1 / -1, DIR at the rising edge with invert_dir undone
    pulse_high_min_cycles: list[int | None]  # per motor, homing included; None without pulses
    dir_setup_min_cycles: list[int | None]  # per motor: DIR change to the next STEP rise; None if never
    tool_edges: list[tuple[int, int]]  # (cycle, 1 tool on / 0 off), active level undone
    step_phase: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype="<U4"))  # (P,) "home" | "run"
    homing_failed: bool = False  # the image stopped in homing's error state (and played no table)
    homing_fault: str | None = None  # which motors and phase, when homing_failed
    display: Any = None  # a board's status display, decoded (codegen.sim.hd44780.Display); None without one
    resumes: tuple[int, ...] = ()  # tick 0 of each restart of the player's timer after a hold (a WAIT record)
    laser_duty: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))  # (K, 2) cycle, counts
    laser_top: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))  # (K, 2) its TOP's writes
    ring_fill: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))  # (K, 2) cycle, bytes held
    # Every recorded pin as it was, by signal name: "x.step", "x.dir", "tool", and where recorded "x.enable",
    # "endstop.x_min", an 8051's "x.coil1".. and "lcd.e".. (codegen/verify/waveform.py writes them for GTKWave).
    pins: dict[str, PinWave] = field(default_factory=dict)
    dir_watches: tuple = ()  # a run read a chunk at a time: its DIR timing, watched as it came (codegen/verify/pins.py)

    def run_only(self) -> SimTrace:
        """The same trace with the step table's pulses only (phase "run")."""
        run = self.step_phase == PHASE_RUN
        return replace(self, step_cycle=self.step_cycle[run], step_motor=self.step_motor[run],
                       step_dir=self.step_dir[run], step_phase=self.step_phase[run])


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "printer-codegen"


def harness_binary() -> Path:
    """The compiled harness, keyed by a hash of its sources and build command; built atomically if missing."""
    source = b"".join(path.read_bytes() for path in HARNESS_SOURCES)
    key = hashlib.sha256(source + " ".join(HARNESS_BUILD[:-1] + HARNESS_LIBS).encode()).hexdigest()[:16]
    binary = _cache_dir() / f"simavr-harness-{key}"
    if binary.is_file():
        return binary
    binary.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=binary.name + ".", dir=binary.parent)
    os.close(fd)
    cmd = [*HARNESS_BUILD, str(HARNESS_SOURCE), str(PLANT_SOURCE), *HARNESS_LIBS, "-o", tmp]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True)
    except FileNotFoundError as exc:
        os.unlink(tmp)
        raise BuildError("gcc not found: the simavr harness needs gcc, libsimavr-dev and libelf-dev") from exc
    if done.returncode != 0:
        os.unlink(tmp)
        raise BuildError(f"building the simavr harness failed (install simavr, libsimavr-dev, libelf-dev):\n"
                         f"{done.stderr.strip()}")
    os.replace(tmp, binary)
    return binary


def switch_thresholds(config: FirmwareConfig, switches: dict[int, int | None]) -> dict[int, int | None]:
    """Each homing axis's switch position counted towards it (steps of each of its motors), from `switches`
    (axis index -> signed position in machine coordinates; None or missing: never closes)."""
    stray = sorted(set(switches) - set(range(len(config.homing))))
    if stray:
        raise ValueError(f"switches for axes {stray} that the config does not home (it homes {len(config.homing)})")
    return {k: None if switches.get(k) is None else int(switches[k]) * h.direction
            for k, h in enumerate(config.homing)}


def switch_args(config: FirmwareConfig, switches: dict[int, int | None]) -> list[str]:
    """The harness's switch=... arguments, one per homing axis: closed once the sum over its motors of (their
    direction towards it x their position) reaches (the switch's distance towards it x the number of motors)."""
    pins = board_pins(config)
    args = []
    for k, towards in switch_thresholds(config, switches).items():
        h = config.homing[k]
        endstop = pins.endstop(h.switch)
        if endstop is None:
            raise BuildError(f"board {config.board} has no endstop `{h.switch}`")
        at = "never" if towards is None else str(towards * len(h.motors))
        terms = "".join(f",{2 * m},{2 * m + 1},{int(pins.motors[m].invert_dir)},{d}"
                        for m, d in zip(h.motors, h.motor_directions))
        args.append(f"switch={endstop.pin.port}{endstop.pin.bit},{int(endstop.closed_high)},{at}{terms}")
    return args


def _homing_fault(config: FirmwareConfig, status: int, axis_bits: int, phase: int) -> str | None:
    """What homing.c's status bytes say (GPIOR0, GPIOR1, GPIOR2); None unless homing failed."""
    if not status & HOMING_FAILED:
        return None
    names = [m.name for m in config.motors]
    axes = ", ".join(f"{'motor' if len(h.motors) == 1 else 'axis'} {h.label(names)} (switch {h.switch})"
                     for k, h in enumerate(config.homing) if axis_bits >> k & 1) or "an unknown axis"
    verb = "did not open within its back off limit" if phase == 2 else "did not close within max_steps"
    return f"homing failed in the {HOMING_PHASES.get(phase, f'phase {phase}')}: {axes}: the switch {verb}"


def simulate(hex_path: Path, config: FirmwareConfig, cycle_budget: int,
             switches: dict[int, int | None] | None = None, keys: list | None = None,
             presses: list[tuple[str, int, int]] = (), beside: Callable | None = None) -> SimTrace:
    """Run `hex_path` until the firmware sleeps with interrupts off; BuildError on a crash or the budget.

    `switches` maps a homing axis's index (config.homing) to the position, in steps (of each of its motors) from
    where the simulation starts, signed in machine coordinates, at which its switch closes: the switch reads
    closed while the axis is there or beyond it in its homing direction, open otherwise. An axis without an
    entry (or with None) has a switch that never closes. Without `switches` at all, the machine starts on its switches
    (every one at position 0: where a job that homes says the machine starts), so homing backs off and comes
    back. `cycle_budget` is for the step table: an image that homes gets a bound on its homing time on top.
    A failed homing is not an error here: see `homing_failed`. `keys`: a jog image's key script
    (codegen/sim/keys.py; it must press start; without one, start alone; firmware.elf beside the hex), its time
    on top of the budget; the trace then has `jog_positions` (the firmware's counts at the end). `presses`: keys
    to ground held down, (pin such as PL2, from cycle, to cycle): the feed hold keys (codegen/verify/hold.py).
    `beside(edges, ended)` reads the records while the harness writes them (run_harness); the trace then has none
    of them, only the run's state, clock and homing fault."""
    pins = board_pins(config)
    mcu = load_target(pins.mcu)
    f_cpu = int(mcu["f_cpu"])
    if switches is None:
        switches = {k: 0 for k in range(len(config.homing))}
    tick_hz = int(mcu.get("tick_hz", f_cpu))
    if config.homing:
        bound = homing_ticks_bound(config, switch_thresholds(config, switches), tick_hz)
        cycle_budget = int(cycle_budget) + bound * (f_cpu // tick_hz)
    keyed: tuple = ([], [], 0)
    keys = session(config, keys)
    if keys is not None:
        keyed = key_args(config, keys, Path(hex_path).with_name("firmware.elf"), f_cpu)
        cycle_budget = int(cycle_budget) + int(max(k.release_s for k in keys) * f_cpu)
    with tempfile.TemporaryDirectory(prefix="printer-codegen-sim-") as tmp:
        edges_path = Path(tmp) / "edges.bin"
        cmd = [str(harness_binary()), pins.mcu, str(f_cpu), str(hex_path), str(edges_path), str(int(cycle_budget)),
               *switch_args(config, switches), *keyed[0], *(f"key={pin[1:]},{a},{b}" for pin, a, b in presses),
               *watched_pins(config)]
        with progress.stage("simulate", cycle_budget / f_cpu, "s simulated", 1) as bar:
            done = run_harness(cmd, bar, edges_path, f_cpu, beside)
        if done.returncode not in EXIT_STATES:
            raise BuildError(f"simavr harness failed on {hex_path}:\n{(done.stderr + done.stdout).strip()}")
        rec = read_edges(edges_path) if beside is None else np.zeros(0, EDGE_RECORD)
    fields = dict(kv.split("=", 1) for kv in done.stdout.strip().splitlines()[-1].split())
    state, cycles = EXIT_STATES[done.returncode], int(fields["cycles"])
    if state == "crashed":
        raise BuildError(f"the firmware crashed in simavr after {cycles} cycles ({hex_path})")
    if state == "budget" and beside is None:  # (compared beside the run, what went wrong on the way is named)
        raise BuildError(f"the firmware did not finish within {cycle_budget} cycles "
                         f"({cycle_budget / f_cpu:.3f} s simulated; {hex_path})")

    # The harness notes the cycle that starts Timer1; tick 0 is the compare match START_TICKS ticks later.
    timer_start = int(fields.get("timer_start", "-1"))
    tick0 = timer_start + START_TICKS * (f_cpu // tick_hz) if timer_start >= 0 else None
    status = [int(fields.get(k, "0")) for k in ("status", "status1", "status2")]
    trace = decode_edges(rec, config, state, cycles, tick0, _homing_fault(config, *status))
    if keys is not None:
        trace.jog_positions = jog_positions(fields["dump"], *keyed[1:])
    return trace


def run_harness(cmd: list[str], bar, edges: Path, f_cpu: int, beside: Callable | None) -> subprocess.CompletedProcess:
    """The harness run to its end (progress.run_watched); with `beside`, beside(edges, ended) runs in this process
    while it does (ended(): the harness has exited)."""
    if beside is None:
        return progress.run_watched(cmd, bar, lambda _: simulated_s(edges, f_cpu))
    process = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)  # it prints one line at its end
    try:
        beside(edges, lambda: process.poll() is not None)
        out, err = process.communicate()
    finally:
        if process.poll() is None:  # an exception here (Ctrl-C, a failed comparison): the harness goes too
            process.kill()
            process.wait()
    return subprocess.CompletedProcess(cmd, process.returncode, out, err)


def timer_ticks0(fields: dict, f_cpu: int, tick_hz: int) -> list[int]:
    """Tick 0 of every start of the player's timer (the harness's `starts`): the first, then each resume."""
    starts = fields.get("starts", "-")
    return [] if starts == "-" else [int(c) + START_TICKS * (f_cpu // tick_hz) for c in starts.split(",")]


def simulated_s(path: Path, f_cpu: int) -> float | None:
    """Simulated seconds at the last whole record of the edges file the harness is writing (None before one)."""
    try:
        with open(path, "rb") as edges:
            count = edges.seek(0, os.SEEK_END) // EDGE_RECORD.itemsize
            if not count:
                return None
            edges.seek((count - 1) * EDGE_RECORD.itemsize)
            return int(np.frombuffer(edges.read(EDGE_RECORD.itemsize), EDGE_RECORD)["cycle"][0]) / f_cpu
    except OSError:
        return None


def decode_edges(rec: np.ndarray, config: FirmwareConfig, state: str, cycles: int, tick0: int | None,
                 fault: str | None, since: int = 0) -> SimTrace:
    """The trace of the harness's pin records (watched pins: STEP and DIR of each motor, then the tool) from cycle
    `since` on (levels before it count: DIR at a pulse, the tool's edges); pulses from tick 0 on are the run's."""
    pins = board_pins(config)
    names = [name for name, _ in watched(config)]
    decoder = EdgeDecoder([w.invert_dir for w in pins.motors], names[2 * len(pins.motors):], since)
    steps = decoder.feed(rec)
    tool = decoder.waves()["tool"]
    after = tool.cycle >= since
    tool_on = tool.level[after].astype(int) ^ (0 if pins.tool_active_high else 1)
    run = steps.cycle >= tick0 if tick0 is not None else np.zeros(len(steps.cycle), dtype=bool)
    return SimTrace(state=state, cycles=cycles, f_cpu=int(load_target(pins.mcu)["f_cpu"]), timer_start_cycle=tick0,
                    step_cycle=steps.cycle, step_motor=steps.motor, step_dir=steps.dir,
                    pulse_high_min_cycles=decoder.width_min, dir_setup_min_cycles=decoder.setup_min,
                    tool_edges=[(int(c), int(v)) for c, v in zip(tool.cycle[after], tool_on)],
                    step_phase=np.where(run, PHASE_RUN, PHASE_HOME).astype("<U4"),
                    homing_failed=fault is not None, homing_fault=fault, laser_duty=decoder.duty(),
                    laser_top=decoder.top(), pins=pin_waves(rec, names))


def pin_waves(rec: np.ndarray, names: list[str]) -> dict[str, PinWave]:
    """Each watched pin's levels from the harness's records, by name (in the order of the harness's PIN list; pins
    are low after reset)."""
    order = np.argsort(rec["pin"], kind="stable")
    bounds = np.searchsorted(rec["pin"][order], np.arange(len(names) + 1))
    return {name: PinWave(0, rec["cycle"][order[a:b]].astype(np.int64), rec["level"][order[a:b]])
            for name, a, b in zip(names, bounds[:-1], bounds[1:])}


def watched(config: FirmwareConfig) -> list[tuple[str, Pin]]:
    """The pins the harness records, by name: STEP and DIR of each motor, then the tool (decode_edges counts on
    these places), then each motor's enable and the homed axes' endstops."""
    pins = board_pins(config)
    named = [(f"{w.name}.{role}", p) for w in pins.motors for role, p in (("step", w.step), ("dir", w.dir))]
    named += [("tool", pins.tool)] + [(f"{w.name}.enable", w.enable) for w in pins.motors]
    switches = dict.fromkeys(h.switch for h in config.homing)  # each once, in homing's order
    return named + [(f"endstop.{e.name}", e.pin) for e in map(pins.endstop, switches) if e is not None]


def watched_pins(config: FirmwareConfig) -> list[str]:
    """The harness's PIN arguments (`watched`); before them, a laser's duty= and top= options (its compare
    register's writes and its TOP register's)."""
    laser = [f"duty={laser_ocr_address(config.laser.pin)}", f"top={LASER_TOP_ADDRESS}"] if config.laser else []
    return laser + [f"{p.port}{p.bit}" for _, p in watched(config)]

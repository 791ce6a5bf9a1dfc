"""Run an 8051 firmware.hex in s51 (ucsim) and decode its STEP, DIR and tool pins with exact clock times.

s51 runs a command script: it loads the hex, sets a breakpoint on every byte write to a port that carries a watched
pin (`break sfr w 0x90`: MOV/ORL/ANL/XRL) and on every bit write to a watched pin (`break bits w 0x91`: SETB, CLR,
MOV bit,C), each of which prints `sim_ticks` (oscillator clocks, 12 per machine cycle) and the port latch, then
runs on. Fetch breakpoints on `_timer_start` (the SETB TR0 of player_start) and `_halt` (from firmware.sym.json,
written next to the hex by codegen.firmware.mcs51.image) mark tick 0 and the end; a conditional fetch breakpoint on the
Timer0 vector stops a run that outlives its cycle budget, and `timeout` bounds the wall time.

Tick 0 of the table is the Timer0 overflow START_TICKS ticks after the timer starts: timer_start_cycle is the
clock count at the end of SETB TR0 (its fetch + 12) + START_TICKS x 12. Pins come out of reset high (port latches
0xFF); edges are level changes of the latch.

Endstop keys (an image that homes): ucsim keeps a port's latch (`P3`, what the firmware writes) apart from the
levels outside circuits put on its pins (the variable `pin3`, alias `port3_pin`; the firmware reads latch AND
pins). The script keeps each homed motor's position in a simulator variable (`var hq0`, in ucsim's own variable
memory, not the 8051's) and, in the commands of the write breakpoints of its STEP port, one expression adds +-1
at each rising STEP edge (the latch against its last value, `hl1`, with the DIR latch giving the way) and puts
each key its motor moves on `pin<port>`: closed from the switch position on, open short of it (a corexy's x key
from the sum of both belts' positions, its y key from their difference). The firmware's fault routine
(`_homing_fault`, from firmware.map) gets a fetch breakpoint that prints the status it is called with (DPL).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from codegen import progress
from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig
from codegen.firmware.homing import homing_ticks_bound
from codegen.firmware.mcs51.board import SFR, board_pins, memories
from codegen.firmware.mcs51.homing import decode_status, endstops
from codegen.firmware.mcs51.image import HALF_STEPS
from codegen.firmware.mcs51.lcd import board_lcd
from codegen.firmware.mcs51.sdcc import MAP_FILE, SYMBOLS_FILE, VECTOR_TIMER0, read_map
from codegen.sim.avr import HOMING_FAILED, PHASE_HOME, PHASE_RUN, SimTrace, _homing_fault, switch_thresholds
from codegen.sim.avr_edges import PinWave
from codegen.sim.hd44780 import decode as decode_display
from codegen.sim.keys import KeyPress, script_end_s, session
from codegen.sim.mcs51_keys import (POSITION_BYTES, TAG_HOLD_POLL, TAG_JOG_POS, TAG_SCAN, hold_key_model, jog_positions,
                                    key_model)

TAG_TIMER, TAG_HALT, TAG_BUDGET, TAG_FAULT = 16, 17, 18, 19  # record tags beyond the port tags 0..3
MAX_CONDITION = (1 << 32) - 1  # sim_ticks is 32-bit: longer budgets rely on the wall-clock timeout
SIM_CLOCKS_PER_S = 5e6  # a pessimistic s51 speed with breakpoints on a busy machine, for the wall-clock timeout
#   (20e6 timed the seed delta out on 2 cores shared with another simulation: it needed 17.6 s of 18)
POSITION_BIAS = 1 << 28  # s51 compares unsigned: positions (steps) are kept this far above 0
SWITCH_REACH = 1 << 26  # switch positions beyond +-this many steps are as good as never reached


def _script(hex_path: Path, ports: list[int], bits: list[int], sym: dict, budget: int, *,
            prelude: tuple[str, ...] = (), on_write: dict[int, str] | None = None,
            fault: int | None = None, breaks: tuple = (), at_halt: tuple = ()) -> str:
    """The s51 command script: every record prints two lines, sim_ticks and tag * 256 + value.

    `prelude`: commands after loading the hex (none may print a line of digits alone); `on_write`: per port, an
    expression (no spaces) evaluated at every write to the port before its record; `fault`: the address of a
    routine whose fetch ends the run with a TAG_FAULT record of DPL; `breaks`: (fetch breakpoint spec, tag
    expression) pairs that log a record and run on; `at_halt`: tag expressions logged when halt() is reached."""
    lines = [f'file "{hex_path}"', *prelude]
    effects = {port: expr + "," for port, expr in (on_write or {}).items()}
    n = 0

    def brk(spec: str, tag_expr: str, resume: bool, more: tuple = ()) -> None:
        nonlocal n
        n += 1
        lines.append(f"break {spec}")
        lines.append(f"commands {n} " + " ; ".join(f"expression /u sim_ticks ; expression /u {e}"
                                                     for e in (tag_expr, *more)) + (" ; run" if resume else ""))

    for port in ports:
        brk(f"sfr w {SFR[port]:#x}", f"{effects.get(port, '')}{port * 256}+P{port}", True)
    for bit in bits:
        port = (bit - 0x80) >> 4
        brk(f"bits w {bit:#x}", f"{effects.get(port, '')}{port * 256}+P{port}", True)
    for spec, tag_expr in breaks:
        brk(spec, tag_expr, True)
    brk(f"{sym['timer_start']:#x}", str(TAG_TIMER * 256), True)
    brk(f"{sym['halt']:#x}", str(TAG_HALT * 256), False, at_halt)
    if fault is not None:
        brk(f"{fault:#x}", f"{TAG_FAULT * 256}+DPL", False)
    if budget <= MAX_CONDITION:
        brk(f"{VECTOR_TIMER0:#x} if sim_ticks>{budget}", str(TAG_BUDGET * 256), False)
    lines += ["run", "quit", ""]
    return "\n".join(lines)


class _PrintedClock:
    """Simulated seconds at the latest clock count in s51's output so far (progress.run_watched's `done`): the
    largest number in its tail (the tags beside the clocks are far smaller), its 32-bit wraps counted."""

    def __init__(self, f_cpu: int):
        self.f_cpu, self.last, self.wraps = f_cpu, 0, 0

    def __call__(self, stdout: Path) -> float | None:
        numbers = [int(line) for line in progress.tail(stdout).split(b"\n")[1:-1] if line.strip().isdigit()]
        if not numbers:
            return None
        clock = max(numbers)
        self.wraps += clock < self.last - (1 << 31)
        self.last = clock
        return (clock + (self.wraps << 32)) / self.f_cpu


def _records(stdout: str) -> np.ndarray:
    """(clock, tag, value) rows from the pairs of number lines the breakpoints print; 32-bit clocks unwrapped."""
    numbers = [int(line) for line in stdout.splitlines() if line.strip().isdigit()]
    pairs = np.array(numbers[: len(numbers) // 2 * 2], dtype=np.int64).reshape(-1, 2)
    clocks = pairs[:, 0].copy()
    if len(clocks) > 1:  # records come in time order, far less than 2**32 clocks apart
        clocks += np.concatenate([[0], np.cumsum(np.diff(clocks) < 0)]) << 32
    return np.stack([clocks, pairs[:, 1] >> 8, pairs[:, 1] & 0xFF], axis=1)


def _levels(rec: np.ndarray, port: int, bit: int) -> tuple[np.ndarray, np.ndarray]:
    """Changes of one pin: (clock, new level), from its port's records (the latch starts at 1 after reset)."""
    mine = rec[rec[:, 1] == port]
    level = (mine[:, 2] >> bit) & 1
    changed = np.diff(np.concatenate([[1], level])) != 0
    return mine[changed, 0], level[changed]


def switch_model(config: FirmwareConfig, pins: dict, switches: dict[int, int | None],
                  ) -> tuple[tuple[str, ...], dict[int, str]]:
    """The script's prelude and per-port expressions that play the endstop keys (see the top of this file):
    axis k's key closes once the axis has made `switches[k]` steps (signed, machine coordinates) from where the
    run starts; None: it never closes. Each motor's position is B + its steps (B = POSITION_BIAS); an axis's
    key is closed while the sum over its motors of B + (direction towards the key) x steps reaches n B + n x
    the key's distance (n motors; a term with direction -1 is 2 B - the position, keeping every value >= 0)."""
    keys = endstops(config.board)
    prelude, updates, levels = [], {}, {}
    pin_levels = {}  # port -> the pins' level at the start
    homed = sorted({m for h in config.homing for m in h.motors})
    for m in homed:
        wiring, q = pins["motors"][m], f"hq{m}"
        step, dirp = wiring["step"], wiring["dir"]
        prelude += [f"var {q}", f"expression /X {q}={POSITION_BIAS}"]
        rise = f"P{step.port}&~hl{step.port}&{step.mask}"
        plus_high = not wiring["invert"]  # the DIR level of a step in the motor's + direction
        way = f"(P{dirp.port}&{dirp.mask})?{2 if plus_high else 0}:{0 if plus_high else 2}"
        updates.setdefault(step.port, []).append(f"{q}={q}+(({rise})?({way}):1)-1")
    for k, towards in switch_thresholds(config, switches).items():
        h, key = config.homing[k], keys[config.homing[k].switch]
        port, closed = key.pin.port, key.pin.mask if key.closed_high else 0
        start = pin_levels.get(port, 0xFF) & ~key.pin.mask
        if towards is None:  # never closes
            pin_levels[port] = start | (key.pin.mask ^ closed)
            continue
        n = len(h.motors)
        threshold = n * (POSITION_BIAS + max(-SWITCH_REACH, min(SWITCH_REACH, towards)))
        pin_levels[port] = start | (closed if towards <= 0 else key.pin.mask ^ closed)
        total = "+".join(f"hq{m}" if d > 0 else f"({2 * POSITION_BIAS}-hq{m})" for m, d in zip(h.motors,
                                                                                                h.motor_directions))
        level = f"pin{port}=(pin{port}&{0xFF & ~key.pin.mask})|((({total})>={threshold})?{closed}:{key.pin.mask ^ closed})"
        for step_port in sorted({pins["motors"][m]["step"].port for m in h.motors}):
            levels.setdefault(step_port, []).append(level)
    for port in sorted(updates):
        prelude += [f"var hl{port}", f"expression /X hl{port}=255"]  # the latch after reset
    prelude += [f"expression /X pin{port}={level}" for port, level in sorted(pin_levels.items())]
    on_write = {port: ",".join(updates[port] + [f"hl{port}=P{port}"] + levels.get(port, [])) for port in updates}
    return tuple(prelude), on_write


def simulate(hex_path: Path, config: FirmwareConfig, cycle_budget: int,
             switches: dict[int, int | None] | None = None, keys: list[KeyPress] | None = None,
             hold_keys: list[tuple[str, int, int]] | None = None) -> SimTrace:
    """Run `hex_path` until the firmware reaches halt() (or homing's fault state); BuildError on a crash or past
    the budget (CPU clocks).

    `switches` maps a homing axis's index (config.homing) to the position, in steps (of each of its motors) from
    where the simulation starts, signed in machine coordinates, at which its key closes: closed while the axis
    is there or beyond it in its homing direction, open otherwise. An axis without an entry (or with None) has a
    key that never closes. Without `switches` at all, the machine starts on its keys (every one at position 0). `cycle_budget`
    is for the step table: an image that homes gets a bound on its homing time on top. A failed homing is not an
    error here: see SimTrace.homing_failed. `keys`: a jog image's key script (codegen/sim/keys.py; it must press
    start; without one, start alone), its time on top of the budget; the trace then has `jog_positions` (the
    firmware's counts at the end) and `key_scans` (the clock of every key scan). `hold_keys`: a feed hold image's
    presses (function, first clock, last clock; codegen/sim/mcs51_keys.py); the trace then has `hold_polls` (clock,
    index of the latest change seen) and `hold_changes`."""
    if shutil.which("s51") is None:
        raise BuildError("s51 not found: install sdcc-ucsim")
    hex_path = Path(hex_path).resolve()
    sym_path = hex_path.with_name(SYMBOLS_FILE)
    if not sym_path.is_file():
        raise BuildError(f"{sym_path} is missing: build the image with codegen.firmware.mcs51.image")
    sym = json.loads(sym_path.read_text(encoding="utf-8"))
    pins = board_pins(config)
    mem = memories(config.board)
    f_cpu = int(mem["f_cpu"])
    if switches is None:
        switches = {k: 0 for k in range(len(config.homing))}
    towards = switch_thresholds(config, switches)  # ValueError for an axis the image does not home
    extra: dict = {}
    if config.homing:
        cycle_budget = int(cycle_budget) + homing_ticks_bound(config, towards, int(mem["tick_hz"])) * int(
            sym["clocks_per_tick"])
        prelude, on_write = switch_model(config, pins, switches)
        fault = read_map(hex_path.with_name(MAP_FILE))[1].get("_homing_fault")
        if fault is None:
            raise BuildError(f"{hex_path.with_name(MAP_FILE)} lacks _homing_fault: the image does not home")
        extra = {"prelude": prelude, "on_write": on_write, "fault": fault}
    keyed: dict = {}
    keys = session(config, keys)
    if keys is not None:
        keyed = key_model(config, keys, read_map(hex_path.with_name(MAP_FILE), data=True)[1], f_cpu)
        cycle_budget = int(cycle_budget) + int(script_end_s(keys) * f_cpu)
        on_write = dict(extra.get("on_write") or {})
        for port, expr in keyed["on_write"].items():
            on_write[port] = ",".join(filter(None, [on_write.get(port), expr]))
        extra = {**extra, "prelude": (*extra.get("prelude", ()), *keyed["prelude"]), "on_write": on_write,
                 "breaks": tuple(keyed["breaks"]), "at_halt": tuple(keyed["at_halt"])}
    held: dict = {}
    if config.hold is not None:
        held = hold_key_model(config, hold_keys or [], read_map(hex_path.with_name(MAP_FILE), data=True)[1])
        on_write = dict(extra.get("on_write") or {})
        for port, expr in held["on_write"].items():
            on_write[port] = ",".join(filter(None, [on_write.get(port), expr]))
        extra = {**extra, "prelude": (*extra.get("prelude", ()), *held["prelude"]), "on_write": on_write,
                 "breaks": (*extra.get("breaks", ()), *held["breaks"])}
    watched = [p for m in pins["motors"] for p in (m["step"], m["dir"]) if p is not None] + [pins["tool"]]
    watched += [c for m in pins["motors"] for c in m["coils"] or []] + [p for _, p in slow_pins(pins)]
    lcd = board_lcd(config.board, [m.name for m in config.motors])
    if lcd is not None:
        w = lcd.wiring
        watched += [p for p in (w.rs, w.e, w.rw, *w.data) if p is not None]
    ports = sorted({p.port for p in watched} | set(keyed.get("on_write", {})) | set(held.get("on_write", {})))
    bits = sorted({SFR[p.port] + p.bit for p in watched} | set(keyed.get("bits", ())) | set(held.get("bits", ())))
    with tempfile.TemporaryDirectory(prefix="printer-codegen-s51-") as tmp:
        script = Path(tmp) / "run.cmd"
        script.write_text(_script(hex_path, ports, bits, sym, int(cycle_budget), **extra), encoding="utf-8")
        wall = 30 + cycle_budget / SIM_CLOCKS_PER_S
        try:
            with progress.stage("simulate", cycle_budget / f_cpu, "s simulated", 1) as bar:
                done = progress.run_watched(["timeout", f"{wall:.0f}", "s51", "-X", str(f_cpu), "-C", str(script)],
                                            bar, _PrintedClock(f_cpu))
        except FileNotFoundError as exc:
            raise BuildError("timeout or s51 not found") from exc
    rec = _records(done.stdout)
    tags = {*ports, TAG_TIMER, TAG_HALT, TAG_BUDGET, TAG_FAULT} | ({TAG_HOLD_POLL} if held else set())
    if keys is not None:
        tags |= {TAG_SCAN, *range(TAG_JOG_POS, TAG_JOG_POS + POSITION_BYTES * len(config.jog.motors))}
    stray = set(np.unique(rec[:, 1]).tolist()) - tags
    if stray:
        raise BuildError(f"unexpected s51 output (record tags {sorted(stray)}) for {hex_path}")
    ends = rec[np.isin(rec[:, 1], (TAG_HALT, TAG_BUDGET, TAG_FAULT))]
    cycles = int(rec[-1, 0]) if len(rec) else 0
    if len(ends) == 0 and done.returncode == 124:
        raise BuildError(f"s51 did not finish within {wall:.0f} s of wall time ({hex_path})")
    if len(ends) == 0:
        raise BuildError(f"the firmware stopped in s51 without reaching halt() after {cycles} clocks ({hex_path}):\n"
                         f"{(done.stderr + done.stdout)[-2000:].strip()}")
    if ends[0, 1] == TAG_BUDGET:
        raise BuildError(f"the firmware did not finish within {cycle_budget} cycles "
                         f"({cycle_budget / f_cpu:.3f} s simulated; {hex_path})")
    fault = None
    if ends[0, 1] == TAG_FAULT:
        axis_bits, phase = decode_status(int(ends[0, 2]))
        fault = _homing_fault(config, HOMING_FAILED, axis_bits, phase)
    clocks = int(sym["clocks_per_tick"])
    starts = rec[rec[:, 1] == TAG_TIMER, 0]
    timer_start = int(starts[0]) + clocks * (1 + int(sym["start_ticks"])) if len(starts) else None
    trace = trace_of(rec, pins, f_cpu, cycles, timer_start, int(starts[0]) if len(starts) else None)
    trace.homing_failed, trace.homing_fault = fault is not None, fault
    # Coil ports: every write (clock, latch), to check the exact patterns (an attribute only coil boards have).
    coil_ports = sorted({c.port for m in pins["motors"] for c in m["coils"] or []})
    if coil_ports:
        trace.coil_writes = {f"P{p}": rec[rec[:, 1] == p][:, [0, 2]] for p in coil_ports}
    if lcd is not None:
        trace.display = decode_display(rec, lcd.wiring, f_osc=f_cpu)
        w = lcd.wiring
        named = [("lcd.rs", w.rs), ("lcd.e", w.e), ("lcd.rw", w.rw)]
        named += [(f"lcd.d{k + 8 - len(w.data)}", d) for k, d in enumerate(w.data)]  # D4-D7 or D0-D7
        trace.pins.update(pin_waves(rec, [(name, pin) for name, pin in named if pin is not None]))
    if held:
        trace.hold_polls, trace.hold_changes = rec[rec[:, 1] == TAG_HOLD_POLL][:, [0, 2]], held["changes"]
    if keys is not None:
        trace.jog_positions = jog_positions(rec, len(config.jog.motors))
        trace.key_scans = rec[rec[:, 1] == TAG_SCAN][:, [0, 2]]
    return trace


def coil_phases(rec: np.ndarray, coils: list) -> tuple[np.ndarray, np.ndarray]:
    """Every write to the coils' port: (clock, half-step phase 0..7 of the 4 coil pins, -1 for no phase)."""
    mine = rec[rec[:, 1] == coils[0].port]
    code = sum(((mine[:, 2] >> c.bit) & 1) << (3 - i) for i, c in enumerate(coils))
    lookup = np.full(16, -1, dtype=np.int64)
    for phase, bits in enumerate(HALF_STEPS):
        lookup[sum(b << (3 - i) for i, b in enumerate(bits))] = phase
    return mine[:, 0], lookup[code] if len(mine) else np.zeros(0, np.int64)


def coil_steps(rec: np.ndarray, coils: list) -> tuple[np.ndarray, np.ndarray]:
    """The steps of a coil-driven motor: (clock, +1 / -1 in phase order) at each change of its 4 coil bits to the
    next or previous half-step pattern. Changes before the first pattern (reset: all coils on, then main's
    phase 0) are not steps; BuildError on a change that skips a phase or leaves the sequence."""
    t, phase = coil_phases(rec, coils)
    clock, way, last = [], [], -1
    for c, ph in zip(t.tolist(), phase.tolist()):
        if last < 0 or ph == last:
            last = ph
            continue
        delta = (ph - last) % 8 if ph >= 0 else None
        if delta not in (1, 7):
            raise BuildError(f"coils {', '.join(p.name for p in coils)}: phase {last} -> "
                             f"{'no phase' if ph < 0 else ph} at clock {c} (not one half-step)")
        clock.append(c)
        way.append(1 if delta == 1 else -1)
        last = ph
    return np.array(clock, dtype=np.int64), np.array(way, dtype=np.int64)


def trace_of(rec: np.ndarray, pins: dict, f_cpu: int, cycles: int, timer_start: int | None,
           run_from: int | None) -> SimTrace:
    """The trace of the records; steps from clock `run_from` on (the player's timer start) are the table's."""
    step_cycle, step_motor, step_dir, high_min, setup_min = [], [], [], [], []
    for m, wiring in enumerate(pins["motors"]):
        if wiring["coils"] is not None:
            rise, way = coil_steps(rec, wiring["coils"])
            step_cycle.append(rise)
            step_motor.append(np.full(len(rise), m, dtype=np.int64))
            step_dir.append(way * (-1 if wiring["invert"] else 1))
            high_min.append(None)
            setup_min.append(None)
            continue
        t, level = _levels(rec, wiring["step"].port, wiring["step"].bit)
        rise, fall = t[level == 1], t[level == 0]
        dir_t, dir_level = _levels(rec, wiring["dir"].port, wiring["dir"].bit)
        # DIR at each rising edge: the last change before it (the latch is 1 after reset).
        at = np.concatenate([[1], dir_level])[np.searchsorted(dir_t, rise, side="right")]
        step_cycle.append(rise)
        step_motor.append(np.full(len(rise), m, dtype=np.int64))
        step_dir.append(np.where(at ^ int(wiring["invert"]), 1, -1).astype(np.int64))
        nxt = np.searchsorted(fall, rise, side="right")  # the fall that ends each pulse
        ended = nxt < len(fall)
        high_min.append(int((fall[nxt[ended]] - rise[ended]).min()) if ended.any() else None)
        after = np.searchsorted(rise, dir_t, side="right")  # DIR change to the next STEP rise
        followed = after < len(rise)
        setup_min.append(int((rise[after[followed]] - dir_t[followed]).min()) if followed.any() else None)
    cyc, mot, dirs = (np.concatenate(a) if a else np.zeros(0, np.int64) for a in (step_cycle, step_motor, step_dir))
    order = np.lexsort((mot, cyc))
    tool_t, tool_level = _levels(rec, pins["tool"].port, pins["tool"].bit)
    tool_on = tool_level ^ (0 if pins["tool_active_high"] else 1)
    run = cyc[order] >= run_from if run_from is not None else np.zeros(len(order), dtype=bool)
    named = [(f"{m['name']}.{role}", m[role]) for m in pins["motors"] for role in ("step", "dir") if m[role]]
    named += [(f"{m['name']}.coil{k + 1}", c) for m in pins["motors"] for k, c in enumerate(m["coils"] or [])]
    named += slow_pins(pins)
    return SimTrace(state="done", cycles=cycles, f_cpu=f_cpu, timer_start_cycle=timer_start,
                    step_cycle=cyc[order], step_motor=mot[order], step_dir=dirs[order],
                    pulse_high_min_cycles=high_min, dir_setup_min_cycles=setup_min,
                    tool_edges=[(int(c), int(v)) for c, v in zip(tool_t, tool_on)],
                    step_phase=np.where(run, PHASE_RUN, PHASE_HOME).astype("<U4"),
                    pins=pin_waves(rec, named + [("tool", pins["tool"])]))


def slow_pins(pins: dict) -> list[tuple[str, object]]:
    """The pins codegen/verify/pins.py holds to a level, by name: each motor's enable ("x.enable") and the board's
    held pins ("held.P1_6" for P1.6)."""
    named = [(f"{m['name']}.enable", m["enable"]) for m in pins["motors"] if m["enable"] is not None]
    return named + [(f"held.P{h['pin'].port}_{h['pin'].bit}", h["pin"]) for h in pins["held"]]


def pin_waves(rec: np.ndarray, named: list[tuple[str, object]]) -> dict[str, PinWave]:
    """Each named pin's levels from its port's records, by name (latches are 1 after reset)."""
    return {name: PinWave(1, *_levels(rec, pin.port, pin.bit)) for name, pin in named}

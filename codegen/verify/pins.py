"""The pins no pulse comparison sees: drivers enabled, held pins at their level, the tool off until the table, DIR
held after each STEP edge, and homing's pace.

Each check is a function of recorded levels (PinWave: the level at reset, then each change's cycle and level) and
a few scalars: the first and last STEP rise (homing's included), the player's tick 0, the run's end. The DIR and
homing checks take one motor's edges as arrays and a small carried state (DirCarry, HomingCarry), so that a caller
may feed them a chunk of edges at a time. `pin_problems` applies them all to a simulated trace.

What the board says (targets/<board>.yaml): `enable_active_low`, each socket's `enable`, `held_pins` (an 8051
board's L297 HALF/FULL), the tool's `active_high`, and `driver` (its part and DIR setup and hold times, ns). A
held pin's wave is named `held.P1_6` (codegen/sim/mcs51.py records it so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from codegen.firmware.homing import PHASE_PAUSE_US, homing_steps, stepping_motors
from codegen.program.homing import HomingAxis
from codegen.sim.avr import PHASE_HOME, PinWave

HOMING_PHASES = ("fast approach", "back off", "slow approach")


@dataclass(frozen=True)
class Driver:
    """A stepper driver's DIR timing around the STEP rising edge, in CPU cycles."""

    part: str
    setup_cycles: int
    hold_cycles: int


def board_driver(board: dict, f_cpu: int) -> Driver | None:
    """The board's `driver: {part, dir_setup_ns, dir_hold_ns}`; None for a board without one (coil drive)."""
    spec = board.get("driver")
    if not spec:
        return None
    cycles = (lambda ns: math.ceil(float(ns) * f_cpu / 1e9))
    return Driver(str(spec["part"]), cycles(spec["dir_setup_ns"]), cycles(spec["dir_hold_ns"]))


def held_wave_name(pin: str) -> str:
    """The trace's name of a held pin (P1.6 -> held.P1_6)."""
    return "held." + pin.replace(".", "_")


def level_at(wave: PinWave, cycles: np.ndarray) -> np.ndarray:
    """The wave's level at each cycle (a change at a cycle counts from that cycle on)."""
    levels = np.concatenate([[wave.initial], np.asarray(wave.level, dtype=np.int64)])
    return levels[np.searchsorted(wave.cycle, cycles, side="right")]


def first_off_level(wave: PinWave, level: int, start: int, end: int) -> int | None:
    """The first cycle in [start, end] at which the wave is not at `level`; None if it stays there."""
    if int(level_at(wave, np.array([start]))[0]) != level:
        return start
    cycle, levels = np.asarray(wave.cycle), np.asarray(wave.level)
    inside = (cycle > start) & (cycle <= end) & (levels != level)
    return int(cycle[inside][0]) if inside.any() else None


def edges(wave: PinWave) -> tuple[np.ndarray, np.ndarray]:
    """(rising, falling) cycles: the wave's changes to 1 and to 0 (repeated levels dropped)."""
    levels = np.asarray(wave.level, dtype=np.int64)
    changed = levels != np.concatenate([[wave.initial], levels[:-1]])
    cycle = np.asarray(wave.cycle, dtype=np.int64)
    return cycle[changed & (levels == 1)], cycle[changed & (levels == 0)]


def changes(wave: PinWave) -> np.ndarray:
    """The cycles at which the wave changes level."""
    rise, fall = edges(wave)
    return np.sort(np.concatenate([rise, fall]))


def ms(cycle: int, f_cpu: int) -> str:
    return f"{cycle / f_cpu * 1e3:.3f} ms"


def level_problems(waves: dict[str, PinWave], wanted: list[tuple[str, int, str]], start: int, end: int,
                   why: str, f_cpu: int) -> list[str]:
    """Each (wave name, level, what it is) at its level over [start, end] (`why` says what that span is)."""
    problems = []
    for name, level, what in wanted:
        wave = waves.get(name)
        if wave is None:
            problems.append(f"{what}: its pin was not recorded, so its level cannot be checked")
            continue
        off = first_off_level(wave, level, start, end)
        wrong, right = ("low", "high") if level else ("high", "low")
        if off is not None:
            when = f"when the first STEP rises ({ms(off, f_cpu)})" if off == start else f"at {ms(off, f_cpu)}"
            problems.append(f"{what} is {wrong} {when}; it must stay {right} {why} ({ms(start, f_cpu)} to "
                            f"{ms(end, f_cpu)})")
    return problems


def tool_off_problems(tool: PinWave, on_level: int, duty: np.ndarray, tick0: int | None, end: int,
                      f_cpu: int) -> list[str]:
    """The tool off, and a PWM laser's power (duty: (cycle, counts) writes) 0, from reset until the table starts
    at tick 0 (through homing); without a tick 0, until the end."""
    until = end if tick0 is None else tick0 - 1
    problems = []
    on = first_off_level(tool, 1 - on_level, 0, until)
    if on is not None:
        problems.append(f"the tool is on at {ms(on, f_cpu)}, before the table starts (at "
                        f"{'no tick 0' if tick0 is None else ms(tick0, f_cpu)}): reset and homing must keep it off")
    lit = np.flatnonzero((duty[:, 0] <= until) & (duty[:, 1] != 0)) if len(duty) else []
    if len(lit):
        problems.append(f"the laser's PWM holds {int(duty[lit[0], 1])} counts at {ms(int(duty[lit[0], 0]), f_cpu)}, "
                        f"before the table starts: reset and homing must keep it at 0")
    return problems


@dataclass(frozen=True)
class DirCarry:
    """One motor's latest STEP rise before a chunk, and its fall (None: none yet, or still high)."""

    rise: int | None = None
    fall: int | None = None


def dir_hold_chunk(rise: np.ndarray, fall: np.ndarray, dir_change: np.ndarray, hold_cycles: int,
                   carry: DirCarry = DirCarry()) -> tuple[np.ndarray, DirCarry]:
    """The DIR changes (cycles, in order) that come while STEP is high or within `hold_cycles` of the rise
    before them; and the state to carry into the next chunk of the same motor's edges (each array in order, every
    edge after those of earlier chunks)."""
    if carry.rise is not None:
        rise = np.concatenate([[carry.rise], rise]).astype(np.int64)
        fall = np.concatenate([[carry.fall], fall]).astype(np.int64) if carry.fall is not None else fall
    before = np.searchsorted(rise, dir_change, side="right") - 1  # the last rise at or before each change
    moved, pulse = dir_change[before >= 0], rise[before[before >= 0]]
    high_until = np.append(fall, np.iinfo(np.int64).max)[np.searchsorted(fall, pulse, side="right")]
    late = moved[(moved < high_until) | (moved - pulse < hold_cycles)]
    if not len(rise):
        return late, carry
    last = int(rise[-1])
    ends = np.searchsorted(fall, last, side="right")
    return late, DirCarry(last, int(fall[ends]) if ends < len(fall) else None)


def dir_setup_short(rise: np.ndarray, dir_change: np.ndarray, setup_cycles: int) -> np.ndarray:
    """The DIR changes followed by a STEP rise of the same motor sooner than `setup_cycles` (a rise at the
    change's own cycle is the hold check's)."""
    nxt = np.searchsorted(rise, dir_change, side="right")
    followed = nxt < len(rise)
    return dir_change[followed][rise[nxt[followed]] - dir_change[followed] < setup_cycles]


class DirWatch:
    """One motor's DIR against its driver, its edges fed a chunk at a time (`add`): held after each STEP rise (and
    while STEP is high), set up before; `problems` once the run has ended."""

    def __init__(self, motor: str, driver: Driver, f_cpu: int):
        self.motor, self.driver, self.f_cpu = motor, driver, f_cpu
        self.carry = DirCarry()
        self.late: tuple[int, int] | None = None  # the first DIR change too soon after a rise: it, the rise
        self.late_count = 0
        self.early: int | None = None  # the first DIR change too soon before a rise
        self.early_count = 0

    def add(self, rise: np.ndarray, fall: np.ndarray, moved: np.ndarray) -> None:
        """The chunk's STEP rises and falls and DIR changes (cycles, each after the chunks before)."""
        before = self.carry.rise
        late, self.carry = dir_hold_chunk(rise, fall, moved, self.driver.hold_cycles, self.carry)
        if len(late) and self.late is None:
            at = int(late[0])
            rises = np.concatenate([[before], rise]) if before is not None else rise
            self.late = (at, int(rises[np.searchsorted(rises, at, side="right") - 1]))
        self.late_count += len(late)
        early = dir_setup_short(rise, moved, self.driver.setup_cycles)
        if len(early) and self.early is None:
            self.early = int(early[0])
        self.early_count += len(early)

    def problems(self) -> list[str]:
        f_cpu, driver, problems = self.f_cpu, self.driver, []
        if self.late is not None:
            at, pulse = self.late
            problems.append(f"motor {self.motor}: DIR changes {(at - pulse) / f_cpu * 1e6:.3f} us after a STEP rise "
                            f"(at {ms(at, f_cpu)}; {self.late_count} in all): the {driver.part} needs DIR held "
                            f"{driver.hold_cycles / f_cpu * 1e6:.3f} us after the rise and while STEP is high")
        if self.early is not None:
            problems.append(f"motor {self.motor}: DIR changes less than {driver.setup_cycles / f_cpu * 1e6:.3f} us "
                            f"before a STEP rise (at {ms(self.early, f_cpu)}; {self.early_count} in all): the "
                            f"{driver.part}'s DIR setup time")
        return problems


def dir_timing_problems(motor: str, step: PinWave, direction: PinWave, driver: Driver, f_cpu: int) -> list[str]:
    """One motor's DIR against its driver, its whole run at once (DirWatch)."""
    watch = DirWatch(motor, driver, f_cpu)
    watch.add(*edges(step), changes(direction))
    return watch.problems()


@dataclass(frozen=True)
class HomingPhase:
    """One phase of homing as one motor makes it."""

    axis: str  # for messages: "axis x (switch x_min)"
    name: str  # fast approach, back off, slow approach
    steps: int
    interval_cycles: int  # from one step to the next (the first comes a pause and an interval after the phase's start)


@dataclass(frozen=True)
class HomingCarry:
    """How many of a motor's homing steps came before a chunk, and the last one's cycle."""

    seen: int = 0
    last: int | None = None


def homing_pace_chunk(rises: np.ndarray, phases: list[HomingPhase], pause_cycles: int, tolerance: int, f_cpu: int,
                      carry: HomingCarry = HomingCarry()) -> tuple[list[str], HomingCarry]:
    """One motor's homing STEP rises (in order, after those of earlier chunks) against its phases: inside a phase
    one interval apart (within `tolerance` cycles), a phase's first step at least a pause and an interval after
    the step before. One problem per phase that keeps neither; steps beyond the phases' count are not judged."""
    cycles = np.concatenate([[carry.last], rises]) if carry.last is not None else np.asarray(rises)
    first = carry.seen - (carry.last is not None)  # the index of cycles[0] among the motor's homing steps
    bounds = np.cumsum([p.steps for p in phases])
    index = first + np.arange(1, len(cycles))  # each gap's later step
    judged = index < (bounds[-1] if len(bounds) else 0)
    gaps, index = np.diff(cycles)[judged], index[judged]
    phase = np.searchsorted(bounds, index, side="right")
    opens = np.isin(index, np.concatenate([[0], bounds[:-1]]))
    want = np.array([p.interval_cycles for p in phases], dtype=np.int64)[phase] if len(phase) else np.zeros(0)
    bad = np.where(opens, gaps < pause_cycles + want - tolerance, np.abs(gaps - want) > tolerance)
    problems = []
    for k in np.unique(phase[bad]):
        mine = bad & (phase == k)
        g = int(np.flatnonzero(mine & ~opens)[0] if (mine & ~opens).any() else np.flatnonzero(mine)[0])
        p, us = phases[k], (lambda c: f"{c / f_cpu * 1e6:.1f} us")
        want = f"at least {us(pause_cycles + p.interval_cycles - tolerance)}" if opens[g] else us(p.interval_cycles)
        problems.append(f"homing {p.axis}, {p.name}: its step {index[g] - (bounds[k] - p.steps)} comes {us(gaps[g])} "
                        f"after the one before, where the homing settings give {want} (within {us(tolerance)}; "
                        f"{int(mine.sum())} steps of the phase are off)")
    return problems, HomingCarry(carry.seen + len(rises), int(cycles[-1]) if len(cycles) else carry.last)


def settings_axis(host, h: HomingAxis) -> HomingAxis:
    """The axis with its intervals (ticks, unrounded) and back off read again from the job's homing settings (mm/s,
    mm), so that homing is held to the job, not to program/homing.py's reading of it."""
    homing = host.settings.homing
    spm = homing.steppers[host.kin.motors[h.motors[0]]].steps_per_mm
    per_step = host.target.tick_hz / spm
    return replace(h, fast_interval=per_step / homing.speed, slow_interval=per_step / homing.slow_speed,
                   backoff_steps=max(1, round(homing.backoff * spm)))


def motor_phases(host, switches: dict[int, int | None], motor: int, axes) -> list[HomingPhase]:
    """The homing phases one motor makes, round by round, with `axes` (host.homing, or those the settings give),
    where the simulated switches close (towards each axis's switch, in steps); [] if one of its axes has a switch
    that never closes."""
    phases = []
    names, cycles_per_tick = host.kin.motors, host.target.f_cpu // host.target.tick_hz
    for k, h in sorted(enumerate(axes), key=lambda kh: kh[1].round):
        if motor not in h.motors:
            continue
        if switches.get(k) is None:
            return []
        counts = homing_steps(h, int(switches[k]) * h.direction)
        intervals = (h.fast_interval, h.fast_interval, h.slow_interval)
        axis = f"{'motor' if len(h.motors) == 1 else 'axis'} {h.label(names)} (switch {h.switch})"
        phases += [HomingPhase(axis, name, n, round(i * cycles_per_tick))
                   for name, n, i in zip(HOMING_PHASES, counts, intervals) if n]
    return phases


def homing_pace_problems(host, trace, switches: dict[int, int | None]) -> list[str]:
    """Every homed motor's steps against the job's homing settings, phase by phase: their intervals, and their
    count where program/homing.py's axes (which the firmware and homing_report follow) give another."""
    if not host.homing or trace.homing_failed:
        return []
    f_cpu, cycles_per_tick = host.target.f_cpu, host.target.f_cpu // host.target.tick_hz
    pause = math.ceil(PHASE_PAUSE_US * host.target.tick_hz / 1e6) * cycles_per_tick
    work = host.target.mcu_data["homing_event_cycles"]
    pulse = math.ceil(host.job.machine.step_pulse_us * f_cpu / 1e6)
    config = host.firmware_config()
    tolerance = int(work[min(stepping_motors(config), len(work)) - 1]) + pulse + cycles_per_tick
    home = np.asarray(trace.step_phase) == PHASE_HOME
    job_axes = [settings_axis(host, h) for h in host.homing]
    problems = []
    for m in sorted({m for h in host.homing for m in h.motors}):
        phases = motor_phases(host, switches, m, job_axes)
        rises = trace.step_cycle[home & (trace.step_motor == m)]
        made, want = len(rises), sum(p.steps for p in phases)
        if phases and 0 < made <= want:  # (a run cut short, by its budget: the steps it made)
            problems += homing_pace_chunk(rises, phases, pause, tolerance, f_cpu)[0]
        elif phases and made == sum(p.steps for p in motor_phases(host, switches, m, host.homing)):
            problems.append(f"homing motor {host.kin.motors[m]}: {made} steps as program/homing.py's axes say, where "
                            f"the job's homing settings (back off {host.settings.homing.backoff:g} mm) give {want}")
    return problems


def held_levels(host) -> list[tuple[str, int, str]]:
    """(wave name, level, what it is) of every pin the board holds while the motors step: each enable pin at its
    active level (once, named by the first motor it drives), each of `held_pins` at its level."""
    board = host.target.board_data
    active = 0 if board["enable_active_low"] else 1
    enables: dict[str, list[str]] = {}  # an enable pin -> the motors it drives
    for m in host.kin.motors:
        pin = board["steppers"][host.kin.socket(m)].get("enable")
        if pin:
            enables.setdefault(str(pin), []).append(m)
    wanted = [(f"{motors[0]}.enable", active, f"ENABLE {pin} (driver{'s' if len(motors) > 1 else ''} of "
               f"{', '.join(motors)}, active {'high' if active else 'low'})") for pin, motors in enables.items()]
    return wanted + [(held_wave_name(h["pin"]), int(h["level"] == "high"), f"held pin {h['pin']} ({h.get('what', '')})")
                     for h in board.get("held_pins") or []]


def pin_problems(host, trace, switches: dict[int, int | None], span: tuple[int, int] | None = None) -> list[str]:
    """The simulated trace's slow pins and DIR timing against the board and the job (see the top; homing's pace:
    homing_pace_problems).
    `span`: the first and the last STEP rise (homing's included), for a trace that does not hold every pulse (a
    run compared a chapter at a time: codegen/verify/bounded.py; its STEP and DIR pins are not in trace.pins)."""
    board, f_cpu, waves = host.target.board_data, trace.f_cpu, trace.pins
    problems = []
    if span is None and len(trace.step_cycle):
        span = int(trace.step_cycle.min()), int(trace.step_cycle.max())
    if span is not None:
        first, last = span
        problems += level_problems(waves, held_levels(host), first, last,
                                   "from the first STEP (homing's included) to the last", f_cpu)
    on_level = int(bool(board["tool"]["active_high"]))
    problems += tool_off_problems(waves["tool"], on_level, trace.laser_duty, trace.timer_start_cycle, trace.cycles,
                                  f_cpu)
    driver = board_driver(board, f_cpu)
    for m in host.kin.motors:
        if driver is not None and f"{m}.step" in waves and f"{m}.dir" in waves:
            problems += dir_timing_problems(m, waves[f"{m}.step"], waves[f"{m}.dir"], driver, f_cpu)
    for watch in getattr(trace, "dir_watches", ()):  # a run read a chunk at a time watched its DIR as it came
        problems += watch.problems()
    return problems

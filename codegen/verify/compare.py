"""Simulator against twin: does the firmware do what the tables say, and does the motion it makes hold up?

Pulses are matched per motor in order (the k-th pulse of motor x in the simulator against the k-th the twin
predicted). The twin's ticks count from the moment the firmware started its timer, which the simulator
reports; every difference in time, the interrupt's latency included, is a timing error. The tool pin must be
at the level of each pulse's block, and off at the end.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from codegen.pipeline.host import HostBuild, trains_from
from codegen.sim.avr_edges import Steps
from codegen.tables.checks import Checker, Findings, corners_after
from codegen.tables.hold import Dilation
from codegen.tables.twin import Pulses
from codegen.toolpath.segments import concat
from codegen.verify.advance import advance_check
from codegen.verify.chapters import Chapter, whole_chapter
from codegen.verify.homing import homing_report
from codegen.verify.laser import LaserVerdict, laser_verdict, merge_laser
from codegen.verify.pins import homing_pace_problems, pin_problems
from codegen.verify.plan_checks import PlanChecks
from codegen.verify.program_check import ProgramCheck
from codegen.verify.resonance import AxisResonance
from codegen.verify.vibration import vibration_check

MAX_TIMING_ERROR_US = 5.0
DURATION_AGREEMENT = 0.01
SWITCH_DISTANCE_MM = (20.0, 35.0, 50.0)  # where the simulated machine starts: this far short of each switch


def simulated_switches(host: HostBuild) -> dict[int, int]:
    """Each homing axis's switch (host.homing[k]), in steps from where the simulation starts, signed in machine
    coordinates (the machine starts some way short of its switches, each axis at another distance)."""
    spm = host.kin.limits.steps_per_mm
    return {k: h.direction * round(SWITCH_DISTANCE_MM[k % len(SWITCH_DISTANCE_MM)] * spm[h.motors[0]])
            for k, h in enumerate(host.homing)}


@dataclass
class Verdict:
    findings: Findings
    duration_s: float
    planned_duration_s: float
    latency_us: float
    timing_error_us: dict[str, float]
    pulse_width_us: dict[str, float]
    dir_setup_us: dict[str, float | None]
    problems: list[str] = field(default_factory=list)
    homing: dict = field(default_factory=dict)
    display: list[str] | None = None  # the status display's text at the end (None: the board has none)
    not_compared: list[str] = field(default_factory=list)  # figures that could not be measured, and why
    laser: LaserVerdict | None = None  # a PWM laser's power (codegen/verify/laser.py)
    gcode_checked: dict | None = None  # what was held against the G-code read again (None: no G-code)
    vibration: dict | None = None  # per resonating axis, the toolhead's residual vibration (verify/vibration.py)
    advance_steps: float | None = None  # the simulated extruder's largest distance from the pressure advance formula

    @property
    def path_measured(self) -> bool:
        """The path error needs every simulated event matched to the twin's (and so to its segment)."""
        return not any(reason.startswith("path error") for reason in self.not_compared)

    @property
    def ok(self) -> bool:
        return not self.problems and self.findings.ok


class Comparison:
    """The simulated run against the twin a chapter at a time (codegen/verify/chapters.py): `add` each chapter with
    the simulated pulses that pair with its own (per motor, the next as many), then `finish`. What it keeps of the
    chapters before is a few figures per motor and the checks' carried state, whatever the run's length.

    A streaming firmware (`streamed`) counts positions from the job's start: it does not know where a job puts the
    machine. A held or overridden run (codegen/verify/hold.py) is compared with its dilated twin; `warp` maps the
    plan's times onto its clock (seconds to seconds; it may know only the chapter being added's: it is called there);
    `dilation` (codegen/tables/hold.py) has its feed factors. `resonance`: verify --resonance's axes."""

    def __init__(self, host: HostBuild, levels, streamed: bool = False, warp=None, dilation=None,
                 resonance: tuple[AxisResonance, ...] = ()):
        """`levels`: the run's clock and slow outputs so far (timer_start_cycle, f_cpu, tool_edges, laser_duty: a
        SimTrace, or what the caller keeps up to date as it reads the run)."""
        self.host, self.levels, self.f_cpu = host, levels, levels.f_cpu
        self.streamed, self.warp, self.dilation = streamed, warp, dilation
        motors = len(host.kin.motors)
        self.checker = Checker(host.kin, host.start_steps, host.settings.stages.tolerance_mm)
        self.program = ProgramCheck(host)  # the tables against a second reading of the G-code
        self.made = np.zeros(motors, dtype=np.int64)
        self.predicted = np.zeros(motors, dtype=np.int64)
        self.timing = np.zeros(motors)
        self.prefix_timing: list[float | None] = [None] * motors  # over each chapter's pairs, counts agreeing or not
        self.wrong_dir: list[tuple[int, int] | None] = [None] * motors  # first wrong step, how many
        self.position = np.zeros(motors, dtype=np.int64)  # the simulated steps' sum so far
        self.twin_final = np.zeros(motors, dtype=np.int64)
        self.paired = True  # every chapter so far had, per motor, as many simulated pulses as the twin's
        self.span_s: list[float] = []  # the first and the last simulated run pulse (on the twin's clock)
        self.span_cycles: list[int] = []  # and as simulated
        self.planned: list[float] = []  # the first and the last stepping event's planned time (warped)
        self.events = 0  # simulated events so far
        self.problems: list[str] = []
        self.laser_parts: list[LaserVerdict] = []
        self.open_cut = None  # the laser's cut the last chapter left on
        self.gap_cycles = (host.target.run_gap_ticks(motors, host.settings.stages.step_pulse_us) * self.f_cpu
                           // host.target.tick_hz // 2)
        self.plan_checks = PlanChecks(host, timing=warp is None)  # corner speeds, the rate runs' window
        self.vibration, self.vibration_notes = vibration_check(host, resonance, held=warp is not None)
        self.advance = None if warp is not None else advance_check(host)  # the extruder against the formula

    def add(self, chapter: Chapter, sim: Steps, clock: np.ndarray) -> None:
        """`sim`: the chapter's simulated pulses in time order (cycles as simulated: the tool's and the laser's
        levels are read there); `clock`: the same pulses' cycles on the twin's clock (a held run's moved by its
        holds, codegen/verify/heaters.py)."""
        self.problems += self.plan_checks.add(chapter)
        host, twin, names = self.host, chapter.pulses, self.host.kin.motors
        sim_s = (clock - self.tick0) / self.f_cpu
        twin_s = twin.tick / host.target.tick_hz
        matched, counts_agree = self.paired, True
        limit = MAX_TIMING_ERROR_US + host.target.isr_latency_us
        for m, name in enumerate(names):
            mine, theirs = sim.motor == m, twin.motor == m
            got, want = int(mine.sum()), int(theirs.sum())
            counts_agree = counts_agree and got == want
            err, wrong = self._pair(m, sim_s[mine], sim.dir[mine], twin_s[theirs], twin.dir[theirs])
            matched = matched and not wrong
            if matched and got == want and len(err) and err.max() > self.timing[m]:
                self.timing[m] = float(err.max())
                if self.timing[m] > limit:
                    self.problems.append(f"motor {name}: step {int(self.made[m] + np.argmax(err))} comes "
                                         f"{self.timing[m]:.2f} us away from its predicted time (limit "
                                         f"{limit:.2f} us: {MAX_TIMING_ERROR_US} us beyond the player's latency)")
            self.made[m] += got
            self.predicted[m] += want
        self.paired = self.paired and counts_agree
        matched = matched and self.paired
        if self.advance is not None:
            theirs = twin.motor == self.advance.motor
            planned = chapter.events.time[twin.event[theirs]] if matched else None
            self.advance.add(sim_s, sim.motor, sim.dir, chapter.advance, planned)
        if len(twin.event_position):
            self.twin_final = twin.event_position[-1].copy()  # not a view: the chapter's arrays go
        if len(twin.event):  # pulses come in event order: the first and the last event that steps
            times = chapter.events.time[twin.event[[0, -1]]]
            times = times if self.warp is None else self.warp(times)  # a held run's chapter's clock: now
            self.planned = [self.planned[0] if self.planned else float(times[0]), float(times[1])]
        if len(sim_s):
            self.span_s = [self.span_s[0] if self.span_s else float(sim_s[0]), float(sim_s[-1])]
            self.span_cycles = [self.span_cycles[0] if self.span_cycles else int(sim.cycle[0]), int(sim.cycle[-1])]
        self._motion(chapter, sim, sim_s, matched)
        self.program.add(chapter)
        if self.vibration is not None:
            self.vibration.add(chapter, sim_s, sim.motor, sim.dir)

    def _pair(self, m: int, sim_s: np.ndarray, sim_dir: np.ndarray, twin_s: np.ndarray,
              twin_dir: np.ndarray) -> tuple[np.ndarray, bool]:
        """Motor m's simulated pulses against the twin's first as many (all of a paired chapter's; what a run the
        heaters' protection stopped made before the trip: trip_figures): each pair's timing error (us), and
        whether a direction differs. Nothing once an earlier chapter's counts disagreed."""
        n = min(len(sim_s), len(twin_s))
        if not n or not self.paired:
            return np.zeros(0), False
        err = np.abs(sim_s[:n] - twin_s[:n]) * 1e6
        self.prefix_timing[m] = max(self.prefix_timing[m] or 0.0, float(err.max()))
        wrong = np.flatnonzero(sim_dir[:n] != twin_dir[:n])
        if len(wrong):
            first, count = self.wrong_dir[m] or (int(self.made[m] + wrong[0]), 0)
            self.wrong_dir[m] = (first, count + len(wrong))
        return err, bool(len(wrong))

    def extra(self, sim: Steps) -> None:
        """Simulated pulses after the twin's last chapter: counted (the twin predicted none)."""
        self.made += np.bincount(sim.motor, minlength=len(self.made))
        self.paired = self.paired and not len(sim.motor)

    def trip_figures(self) -> tuple[dict, list[str]]:
        """Per motor, the pulses a run made before a trip against the twin's first as many: the same directions,
        each within the timing limit of its predicted time (codegen/verify/heaters.py trip_result)."""
        limit = MAX_TIMING_ERROR_US + self.host.target.isr_latency_us
        motors, problems = {}, []
        for m, name in enumerate(self.host.kin.motors):
            made, planned = int(self.made[m]), int(self.predicted[m])
            worst = self.prefix_timing[m]
            motors[name] = {"steps": made, "planned_steps": planned,
                            "max_timing_error_us": None if worst is None or made > planned else round(worst, 3)}
            if made > planned:
                problems.append(f"motor {name}: {made} steps before the trip, the twin predicted {planned} in all")
                continue
            if self.wrong_dir[m] is not None:
                first, count = self.wrong_dir[m]
                problems.append(f"motor {name}: step {first} goes the wrong way ({count} steps differ)")
            if worst is not None and worst > limit:
                problems.append(f"motor {name}: a step before the trip comes {worst:.2f} us away from its predicted "
                                f"time (limit {limit:.2f} us)")
        return motors, problems

    def _motion(self, chapter: Chapter, sim: Steps, sim_s: np.ndarray, matched: bool) -> None:
        """Events, positions and the path, the motors' rates and accelerations, the tool and the laser."""
        host, names = self.host, self.host.kin.motors
        new_event = np.concatenate([[True], np.diff(sim.cycle) > self.gap_cycles])[:len(sim.cycle)]
        group = np.cumsum(new_event) - 1
        positions = np.zeros((int(group[-1]) + 1 if len(group) else 0, len(names)), dtype=np.int64)
        np.add.at(positions, (group, sim.motor), sim.dir)  # each event's steps, then their running sum in place
        np.cumsum(positions, axis=0, out=positions)
        positions += self.position
        if len(positions):
            self.position = positions[-1].copy()
        twin_event = None
        if matched:  # each simulated event belongs to the segment of the twin event its first pulse matched
            rank = np.empty(len(sim.cycle), dtype=np.int64)
            for m in range(len(names)):
                rank[sim.motor == m] = np.flatnonzero(chapter.pulses.motor == m)
            twin_event = chapter.pulses.event[rank[new_event]]
            segment = chapter.event_segments()[twin_event]
        parts = [p for p in (chapter.before, chapter.segments, chapter.after) if p is not None]
        shift = 0 if chapter.before is None else 1
        corners_t, jumps = corners_after(chapter.plan, chapter.segments, chapter.before, host.kin)
        if self.warp is not None:
            corners_t = self.warp(corners_t)
        trains = trains_from(sim_s, sim.motor, sim.dir, len(names))
        self.checker.add(trains, positions if matched else positions[:0], segment + shift if matched else
                         np.zeros(0, np.int64), concat(*parts), corners_t, jumps, chapter.last)
        event_cycle = sim.cycle[new_event]
        view = chapter_view(host, chapter)
        self.tool_events(view, event_cycle, twin_event)
        laser = laser_verdict(view, self.levels, event_cycle, twin_event, _chapter_dilation(self.dilation, chapter),
                              chapter.laser_before, self.open_cut, chapter.last)
        if laser is not None:  # a cut left on goes on into the next chapter
            self.laser_parts.append(laser)
            self.open_cut = laser.open_cut
        self.events += len(event_cycle)

    def tool_events(self, view: HostBuild, event_cycle: np.ndarray, twin_event: np.ndarray | None) -> None:
        """The tool pin's level at every simulated event (its first pulse) against its block's tool flag."""
        if twin_event is None or not len(event_cycle):
            return
        edges = np.array(self.levels.tool_edges, dtype=np.int64).reshape(-1, 2)
        levels = np.concatenate([[0], edges[:, 1]])
        at = levels[np.searchsorted(edges[:, 0], event_cycle, side="right")]
        want = view.schedule.block_tool[view.pulses.event_block[twin_event]].astype(np.int64)
        wrong = np.flatnonzero(at != want)
        if len(wrong) and not any(p.startswith("the tool pin is") for p in self.problems):
            self.problems.append(f"the tool pin is {'on' if at[wrong[0]] else 'off'} at simulated event "
                                 f"{self.events + wrong[0]} ({len(wrong)} events of "
                                 f"{len(event_cycle)} there differ from the tables)")

    def finish(self, trace, switches: dict[int, int]) -> Verdict:
        """The verdict once every chapter has been added; `trace`: the run's SimTrace without its pulses (state,
        cycles, homing, pulse widths, display, slow pins)."""
        host, names, f_cpu = self.host, self.host.kin.motors, self.f_cpu
        homing, homing_problems = homing_report(host, trace, switches)
        problems: list[str] = []
        pace = homing_pace_problems(host, trace, switches)
        if trace.state == "budget":  # what went wrong on the way comes first: running out of time follows from it
            homing_problems = pace + self.problems + [
                f"the firmware did not finish within {trace.cycles} cycles ({trace.cycles / f_cpu:.3f} s simulated; "
                f"the plan takes {self.planned_s():.3f} s)"] + homing_problems
            pace, self.problems = [], []
        elif trace.state not in ("done", "held"):  # held: the table played, the image holds its heaters
            problems.append(f"the simulation ended in state '{trace.state}' after {trace.cycles} cycles")
        not_compared, timing = self.plan_checks.not_compared + self.vibration_notes, {}
        for m, name in enumerate(names):
            got, want = int(self.made[m]), int(self.predicted[m])
            if got != want:
                problems.append(f"motor {name}: the simulator made {got} steps, the twin predicted {want}")
                not_compared.append(f"timing of motor {name}: its steps cannot be paired ({got} simulated, "
                                    f"{want} predicted)")
                continue
            timing[name] = float(self.timing[m])
            if self.wrong_dir[m] is not None:
                first, count = self.wrong_dir[m]
                problems.append(f"motor {name}: step {first} goes the wrong way ({count} steps differ)")
        problems += self.problems + self.program.finish() + (self.advance.problems() if self.advance else [])
        if not self.paired:
            not_compared.append("path error: the simulated steps do not pair with the twin's, so they cannot be "
                                "placed on the path's segments")
        findings = self.checker.findings(host.expected_final)
        duration = self.span_s[1] - self.span_s[0] if self.span_s else 0.0
        planned = self.planned_s()
        if planned > 0 and abs(duration - planned) > DURATION_AGREEMENT * planned:
            problems.append(f"simulated duration {duration:.4f} s differs from the planned {planned:.4f} s by more "
                            f"than {100 * DURATION_AGREEMENT:.0f} %")
        cfg = host.firmware_config()
        width = {n: c / f_cpu * 1e6 for n, c in zip(names, trace.pulse_high_min_cycles) if c is not None}
        setup = {n: (None if c is None else c / f_cpu * 1e6) for n, c in zip(names, trace.dir_setup_min_cycles)}
        for name, us in width.items():
            if us < cfg.step_pulse_us:
                problems.append(f"motor {name}: a STEP pulse is {us:.2f} us high (needs {cfg.step_pulse_us} us)")
        for name, us in setup.items():
            if us is not None and us < cfg.dir_setup_us:
                problems.append(f"motor {name}: DIR changes {us:.2f} us before a step (needs {cfg.dir_setup_us} us)")
        edges = np.array(trace.tool_edges, dtype=np.int64).reshape(-1, 2)
        if len(edges) and edges[-1, 1]:
            problems.append("the tool pin is still on when the program ends")
        problems.extend(pin_problems(host, trace, switches, self.step_span(trace)))  # enables, held pins, DIR hold
        problems.extend(pace)
        problems.extend(display_problems(host, trace, self.twin_final, self.streamed))
        laser = merge_laser(self.laser_parts, trace.laser_duty, trace.laser_top, host.laser.top) \
            if host.laser is not None else None
        problems.extend(laser.problems if laser else [])
        display = None if trace.display is None else list(trace.display.lines)
        return Verdict(findings, duration, planned, self.tick0 / f_cpu * 1e6, timing, width, setup,
                       homing_problems + problems, homing, display, not_compared, laser,
                       self.program.checked if self.program.active else None,
                       None if self.vibration is None else self.vibration.figures(),
                       None if self.advance is None else self.advance.worst[0])

    def step_span(self, trace) -> tuple[int, int] | None:
        """The first and the last STEP rise of the run, homing's (in `trace`) included."""
        cycles = [int(trace.step_cycle.min()), int(trace.step_cycle.max())] if len(trace.step_cycle) else []
        cycles += self.span_cycles
        return (min(cycles), max(cycles)) if cycles else None

    @property
    def tick0(self) -> int:
        return self.levels.timer_start_cycle or 0

    def planned_s(self) -> float:
        """The plan's time from its first step to its last (on a held run's clock with `warp`)."""
        if not self.planned:
            return 0.0
        first, last = self.planned
        return last - first


def chapter_view(host: HostBuild, chapter: Chapter) -> HostBuild:
    """The host build with the chapter's program in place of the whole's (what the laser's and the tool's checks
    read)."""
    return replace(host, segments=chapter.segments, plan=chapter.plan, events=chapter.events,
                   compressed=chapter.compressed, pulses=chapter.pulses)


def _chapter_dilation(dilation: Dilation | None, chapter: Chapter) -> Dilation | None:
    """A held run's dilation over the chapter's events and the one after it (a laser's power lasts until then),
    counted from the chapter's first."""
    if dilation is None:
        return None
    return dilation.window(chapter.first_event, chapter.first_event + len(chapter.pulses.event_tick) + 1)


def compare(host: HostBuild, full_trace, switches: dict[int, int], streamed: bool = False,
            dilated: Pulses | None = None, warp=None, dilation=None,
            resonance: tuple[AxisResonance, ...] = ()) -> Verdict:
    """A whole simulated run (the table's steps, after any homing) against a kept host build's twin (`dilated`: a
    held run's), as one chapter; homing on its own."""
    trace = full_trace.run_only()
    comparison = Comparison(host, trace, streamed, warp, dilation, resonance)
    order = np.argsort(trace.step_cycle, kind="stable")
    sim = Steps(trace.step_cycle[order], trace.step_motor[order], trace.step_dir[order])
    comparison.add(whole_chapter(host, dilated), sim, sim.cycle)
    return comparison.finish(full_trace, switches)


def planned_stepping_s(host: HostBuild, warp=None) -> float:
    """The plan's time from its first step to its last (on a held run's clock with `warp`)."""
    stepping = np.unique(host.pulses.event)
    if not len(stepping):
        return 0.0
    first, last = host.events.time[stepping[[0, -1]]]
    return float(warp(last) - warp(first)) if warp else float(last - first)


def display_problems(host: HostBuild, trace, twin_final: np.ndarray, streamed: bool = False) -> list[str]:
    """A board's status display: its decoded text at the end shows every motor's final position (`twin_final`, the
    twin's; a streaming firmware's: its steps since the job's start), and the firmware drove it within the
    display's timing."""
    if trace.display is None:
        return []
    from codegen.firmware.mcs51.lcd import board_lcd

    lcd = board_lcd(host.target.board, host.kin.motors)
    final = twin_final + (0 if streamed else host.start_steps)
    expected = lcd.expected_text([int(v) for v in final])
    problems = [f"display at clock {p.clock}: {p.message}" for p in trace.display.problems[:5]]
    if tuple(trace.display.lines) != tuple(expected):
        problems.append(f"the display ends showing {list(trace.display.lines)}, expected {list(expected)}")
    return problems

"""Simulator against twin: does the firmware do what the tables say, and does the motion it makes hold up?

Pulses are matched per motor in order (the k-th pulse of motor x in the simulator against the k-th the twin
predicted). The twin's ticks count from the moment the firmware started its timer, which the simulator
reports; every difference in time, the interrupt's latency included, is a timing error. The tool pin must be
at the level of each pulse's block, and off at the end.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from codegen.firmware.homing import homing_steps
from codegen.pipeline.host import HostBuild, trains_from
from codegen.tables.checks import Findings, check
from codegen.tables.twin import Pulses
from codegen.verify.laser import LaserVerdict, laser_verdict
from codegen.verify.pins import pin_problems

MAX_TIMING_ERROR_US = 5.0
DURATION_AGREEMENT = 0.01
SWITCH_DISTANCE_MM = (20.0, 35.0, 50.0)  # where the simulated machine starts: this far short of each switch


def simulated_switches(host: HostBuild) -> dict[int, int]:
    """Each homing axis's switch (host.homing[k]), in steps from where the simulation starts, signed in machine
    coordinates (the machine starts some way short of its switches, each axis at another distance)."""
    spm = host.kin.limits.steps_per_mm
    return {k: h.direction * round(SWITCH_DISTANCE_MM[k % len(SWITCH_DISTANCE_MM)] * spm[h.motors[0]])
            for k, h in enumerate(host.homing)}


def homing_report(host: HostBuild, trace, switches: dict[int, int | None]) -> tuple[dict, list[str]]:
    """Homing steps per motor against what the switch positions imply: per axis that moves it, fast + back
    off + slow approach steps, ending at the switch (a corexy's belts home in x and again in y). A switch at
    None never closes."""
    problems = [f"homing failed: {trace.homing_fault}"] if trace.homing_failed else []
    home = np.asarray(trace.step_phase) == "home"
    expected: dict[int, dict] = {}
    for k, h in enumerate(host.homing):
        switch = switches.get(k)
        towards = None if switch is None else int(switch) * h.direction
        for m, d in zip(h.motors, h.motor_directions):
            mine = expected.setdefault(m, {"steps": 0, "net": 0, "switches": []})
            mine["steps"] += h.max_steps if towards is None else sum(homing_steps(h, abs(towards)))
            mine["net"] += 0 if towards is None else d * towards
            mine["switches"].append(h.switch)
    report = {}
    for m, want in expected.items():
        name = host.kin.motors[m]
        mine = home & (trace.step_motor == m)
        steps, net = int(mine.sum()), int(trace.step_dir[mine].sum())
        report[name] = {"steps": steps, "expected_steps": want["steps"], "net": net, "expected_net": want["net"],
                        "switch": ", ".join(want["switches"])}
        if not trace.homing_failed and (steps != want["steps"] or net != want["net"]):
            problems.append(f"motor {name} homed in {steps} steps ending {net} from its start; its switches "
                            f"({report[name]['switch']}) imply {want['steps']} steps ending {want['net']}")
    return report, problems


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

    @property
    def path_measured(self) -> bool:
        """The path error needs every simulated event matched to the twin's (and so to its segment)."""
        return not any(reason.startswith("path error") for reason in self.not_compared)

    @property
    def ok(self) -> bool:
        return not self.problems and self.findings.ok


def compare(host: HostBuild, full_trace, switches: dict[int, int], streamed: bool = False,
            dilated: Pulses | None = None, warp=None, dilation=None) -> Verdict:
    """The simulated run (the table's steps, after any homing) against the twin; homing on its own. A streaming
    firmware (`streamed`) counts positions from the job's start: it does not know where a job puts the machine.
    A held or overridden run (codegen/verify/hold.py) is compared with the `dilated` twin; `warp` maps the
    plan's times onto its clock (seconds to seconds); `dilation` (codegen/tables/hold.py) has its feed factors."""
    homing, homing_problems = homing_report(host, full_trace, switches)
    trace = full_trace.run_only()
    names = host.kin.motors
    f_cpu, tick_hz = trace.f_cpu, host.target.tick_hz
    twin = dilated or host.pulses
    problems: list[str] = []
    if trace.state not in ("done", "held"):  # held: the table played, the image holds its heaters
        problems.append(f"the simulation ended in state '{trace.state}' after {trace.cycles} cycles")
    order = np.argsort(trace.step_cycle, kind="stable")
    cycle, motor, direction = trace.step_cycle[order], trace.step_motor[order], trace.step_dir[order]

    twin_s = twin.tick / tick_hz
    start = trace.timer_start_cycle or 0
    sim_s = (cycle - start) / f_cpu  # on the twin's clock
    timing: dict[str, float] = {}
    not_compared: list[str] = []
    matched = True
    for m, name in enumerate(names):
        mine, theirs = motor == m, twin.motor == m
        got, want = int(mine.sum()), int(theirs.sum())
        if got != want:
            problems.append(f"motor {name}: the simulator made {got} steps, the twin predicted {want}")
            not_compared.append(f"timing of motor {name}: its steps cannot be paired ({got} simulated, "
                                f"{want} predicted)")
            matched = False
            continue
        wrong_dir = np.flatnonzero(direction[mine] != twin.dir[theirs])
        if len(wrong_dir):
            problems.append(f"motor {name}: step {wrong_dir[0]} goes the wrong way ({len(wrong_dir)} steps differ)")
            matched = False
        err = np.abs(sim_s[mine] - twin_s[theirs]) * 1e6
        timing[name] = float(err.max()) if len(err) else 0.0
        limit = MAX_TIMING_ERROR_US + host.target.isr_latency_us
        if timing[name] > limit:
            problems.append(f"motor {name}: a step comes {timing[name]:.2f} us away from its predicted time "
                            f"(limit {limit:.2f} us: {MAX_TIMING_ERROR_US} us beyond the player's latency)")

    # Group simultaneous pulses (one interrupt) into events; a new event starts after a gap.
    gap = np.diff(cycle)
    new_event = np.concatenate([[True], gap > host.target.run_gap_ticks(len(names), host.job.machine.step_pulse_us) * f_cpu // tick_hz // 2])
    new_event = new_event[:len(cycle)]
    group = np.cumsum(new_event) - 1
    positions = np.zeros((int(group[-1]) + 1 if len(group) else 0, len(names)), dtype=np.int64)
    np.add.at(positions, (group, motor), direction)  # each event's steps, then their running sum in place
    np.cumsum(positions, axis=0, out=positions)
    if matched:
        # Each simulated event belongs to the segment of the twin event its first pulse matched.
        rank = np.empty(len(cycle), dtype=np.int64)
        for m in range(len(names)):
            rank[motor == m] = np.flatnonzero(twin.motor == m)
        twin_event = twin.event[rank[new_event]]
        segment = host.event_segments()[twin_event]
    else:
        segment = np.zeros(len(positions), dtype=np.int64)
        not_compared.append("path error: the simulated steps do not pair with the twin's, so they cannot be "
                            "placed on the path's segments")
    trains = trains_from(sim_s, motor, direction, len(names))
    findings = check(trains, positions if matched else positions[:0], segment, host.segments, host.plan,
                     host.kin, host.expected_final, host.start_steps, host.job.machine.tolerance, warp)

    duration = float(sim_s[-1] - sim_s[0]) if len(sim_s) else 0.0
    planned = planned_stepping_s(host, warp)
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
    problems.extend(tool_problems(host, trace, cycle[new_event], twin_event if matched else None))
    problems.extend(pin_problems(host, full_trace, switches))  # enables, held pins, DIR hold, homing pace
    problems.extend(display_problems(host, trace, streamed))
    laser = laser_verdict(host, trace, cycle[new_event], twin_event if matched else None, dilation)
    problems.extend(laser.problems if laser else [])
    display = None if trace.display is None else list(trace.display.lines)
    return Verdict(findings, duration, planned, start / f_cpu * 1e6, timing, width, setup,
                   homing_problems + problems, homing, display, not_compared, laser)


def planned_stepping_s(host: HostBuild, warp=None) -> float:
    """The plan's time from its first step to its last (on a held run's clock with `warp`)."""
    stepping = np.unique(host.pulses.event)
    if not len(stepping):
        return 0.0
    first, last = host.events.time[stepping[[0, -1]]]
    return float(warp(last) - warp(first)) if warp else float(last - first)


def display_problems(host: HostBuild, trace, streamed: bool = False) -> list[str]:
    """A board's status display: its decoded text at the end shows every motor's final position (a streaming
    firmware's: its steps since the job's start), and the firmware drove it within the display's timing."""
    if trace.display is None:
        return []
    from codegen.firmware.mcs51.lcd import board_lcd

    lcd = board_lcd(host.target.board, host.kin.motors)
    final = host.pulses.final_positions() + (0 if streamed else host.start_steps)
    expected = lcd.expected_text([int(v) for v in final])
    problems = [f"display at clock {p.clock}: {p.message}" for p in trace.display.problems[:5]]
    if tuple(trace.display.lines) != tuple(expected):
        problems.append(f"the display ends showing {list(trace.display.lines)}, expected {list(expected)}")
    return problems


def tool_problems(host: HostBuild, trace, event_cycle: np.ndarray, twin_event: np.ndarray | None) -> list[str]:
    """The tool pin's level at every simulated event (its first pulse) against its block's tool flag; off at
    the end."""
    edges = np.array(trace.tool_edges, dtype=np.int64).reshape(-1, 2)
    levels = np.concatenate([[0], edges[:, 1]])
    problems = []
    if twin_event is not None and len(event_cycle):
        at = levels[np.searchsorted(edges[:, 0], event_cycle, side="right")]
        want = host.schedule.block_tool[host.pulses.event_block[twin_event]].astype(np.int64)
        wrong = np.flatnonzero(at != want)
        if len(wrong):
            problems.append(f"the tool pin is {'on' if at[wrong[0]] else 'off'} at simulated event {wrong[0]} "
                            f"({len(wrong)} events differ from the tables)")
    if levels[-1] != int(host.schedule.final_tool):
        problems.append("the tool pin is still on when the program ends")
    return problems

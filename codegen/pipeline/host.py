"""The host side of a build, stage by stage: job -> toolpath items -> segments -> lookahead windows -> events
-> schedule -> twin and checks, a batch or window at a time.

Each stage is a function with a typed result; this module only composes them (and knows no CLI).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import BinaryIO, Callable

import numpy as np

from codegen import progress
from codegen.errors import BuildError, Diagnostic, SourceRef
from codegen.firmware.avr.heaters import job_heaters, stream_heaters
from codegen.firmware.config import FirmwareConfig, HeaterFirmware, MotorPins
from codegen.kinematics import make_kinematics
from codegen.kinematics.base import Kinematics
from codegen.link.ring import LinkBudget, LinkPlan, link_plan
from codegen.motion.blocks import Events
from codegen.motion.jog import jog_plan
from codegen.motion.lookahead import Lookahead, Window
from codegen.motion.pieces import front_end
from codegen.motion.planner import Plan, PlannerLimits, plan
from codegen.pipeline.join import join_compressed, join_events, join_plan, join_pulses, join_schedule, join_segments
from codegen.pipeline.settings import JobSettings, ShapingEras, job_settings, planner_limits
from codegen.pipeline.windows import Played, Stages, Totals
from codegen.program.heater_settings import heater_settings
from codegen.program.heaters import HeaterProgram, heater_diagnostics
from codegen.program.homing import HomingAxis, homes, homing_axes
from codegen.program.program import Program
from codegen.stopwatch import Stopwatch
from codegen.tables.checks import Findings, MotorTrain
from codegen.tables.compress import Compressed
from codegen.tables.format import RUNTIME_BYTES
from codegen.tables.hold import HoldPlan, hold_plan
from codegen.tables.laser import LaserPwm, laser_pwm
from codegen.tables.runtime import RuntimeRecords, played_outputs, runtime_records, with_runtime
from codegen.tables.schedule import HEATER_COMMANDS, RT_WAIT, WAIT_MASKS
from codegen.tables.twin import Pulses
from codegen.targets import TargetInfo, target_info
from codegen.toolpath.segments import Flattener, Segments


@dataclass
class HostBuild:
    job: object  # for the firmware's names and pins (firmware_config), the heaters and the reports
    settings: JobSettings  # the stages' settings, made once from the job (codegen/pipeline/settings.py)
    target: TargetInfo
    kin: Kinematics
    start: np.ndarray  # (4,) mm: where the program starts
    end: np.ndarray  # (4,) mm: where it ends
    totals: Totals
    findings: Findings
    start_steps: np.ndarray
    expected_final: np.ndarray
    warnings: list[Diagnostic]
    homing: tuple[HomingAxis, ...]  # the motors the firmware homes at power-up
    heater_program: HeaterProgram  # the program's heater settings (codegen/program/heaters.py)
    # The whole program's results, when the build keeps them (None otherwise):
    segments: Segments | None = None
    plan: Plan | None = None
    events: Events | None = None
    compressed: Compressed | None = None
    pulses: Pulses | None = None
    link_plan: LinkPlan | None = None  # a streamed job's link (host_build's `link`)
    runtime: RuntimeRecords | None = None  # the heater and fan settings the image plays (codegen/tables/runtime.py)
    laser: LaserPwm | None = None  # a PWM laser's (codegen/tables/laser.py)
    planned: tuple[Segments, Plan] | None = None  # a shaped job's segments and plan before shaping, when kept
    shapings: tuple = ()  # each era's input shapers (ShapingSettings or None: unshaped), M593s between them
    shaper_specs: tuple = ()  # each era's shapers of x, y, z as (type, freq, damping) or None: what set them

    @property
    def shaped(self) -> bool:
        """Some stretch of the program is played as shaped motion (the machine's shapers or an M593's, or pressure
        advance: its extruder advanced)."""
        return any(s is not None for s in self.shapings)

    @property
    def schedule(self):
        return self.compressed.schedule

    def firmware_config(self) -> FirmwareConfig:
        steppers = self.job.machine.steppers
        return FirmwareConfig(
            job_name=self.job.name,
            job_file=self.job.path.name,
            target=self.target.target,
            board=self.target.board,
            motors=tuple(MotorPins(m, self.kin.socket(m), bool(steppers[m].invert_dir)) for m in self.kin.motors),
            step_pulse_us=self.job.machine.step_pulse_us,
            dir_setup_us=self.job.machine.dir_setup_us,
            homing=self.homing,
            start_steps=tuple(int(v) for v in self.start_steps),
            heaters=self.heaters,
            laser=self.laser,
            jog=jog_plan(self.settings.jog, self.kin.motors, self.target.tick_hz) if self.settings.jog else None,
            hold=self.hold_plan,
            hold_override=self.settings.hold.override if self.settings.hold else 100,
        )

    @cached_property
    def hold_plan(self) -> HoldPlan | None:
        """The feed hold of the image (codegen/tables/hold.py); BuildError where the player cannot hold."""
        if self.settings.hold is None:
            return None
        return hold_plan(self.settings.hold, self.target.tick_hz, self.target.board, self.target.board_data,
                         streamed=self.link_plan is not None)

    @cached_property
    def heaters(self) -> tuple[HeaterFirmware, ...]:
        """The heaters of an AVR flash image (codegen/firmware/avr/heaters.py job_heaters) or streaming firmware
        (stream_heaters); none elsewhere."""
        if self.target.target != "avr":
            return ()
        if self.link_plan is not None:
            return stream_heaters(self.job, self.target.heater_pins)
        return job_heaters(self.job, self.target.heater_pins, self.heater_program)

    def runtime_settings(self, heater: str) -> RuntimeRecords:
        """The runtime records of one heater: its targets, and the waits for it."""
        r = self.runtime or runtime_records([], ())
        mine = (r.command == HEATER_COMMANDS[heater]) | ((r.command == RT_WAIT) & (r.value & WAIT_MASKS[heater] > 0))
        return RuntimeRecords(r.item[mine], r.command[mine], r.value[mine])

    def event_segments(self) -> np.ndarray:
        """The segment every event belongs to."""
        block = np.searchsorted(self.events.block_first, np.arange(len(self.events.time)), side="right") - 1
        return self.events.block_segment[block]


def trains_from(pulse_time: np.ndarray, motor: np.ndarray, direction: np.ndarray, motors: int) -> list[MotorTrain]:
    return [MotorTrain(pulse_time[motor == m], direction[motor == m]) for m in range(motors)]


def host_build(job, strict: bool = False, watch: Stopwatch | None = None, keep: bool | str = True,
               tables: BinaryIO | None = None, link: LinkBudget | None = None,
               observe: Callable[[Played], None] | None = None) -> HostBuild:
    """Everything up to the twin and its checks against the plan: no compiler, no simulator. The program
    is read, planned and played a window at a time (codegen/motion/lookahead.py, codegen/pipeline/windows.py); `keep` joins
    the windows' results into the whole program's (for an image and its verification), otherwise only their
    totals are kept and memory stays bounded whatever the program's size; keep="tables" joins only the schedule
    (an image's tables, which flash bounds: codegen/verify/bounded.py verifies it planning again). `tables` gets the table stream as
    its windows are made. With `link`, the job is planned for the streaming player: its costs, and a ring that
    the link keeps fed (host.link_plan). `observe` gets each final window (codegen/report/plan_samples.py). A bar shows
    the share of the program planned (codegen/progress.py)."""
    with progress.stage("plan", 1.0) as bar:
        return _host_build(job, strict, watch or Stopwatch(), keep, tables, link, bar, observe)


def _host_build(job, strict: bool, watch: Stopwatch, keep: bool, tables: BinaryIO | None, link: LinkBudget | None,
                bar, observe) -> HostBuild:
    try:
        target = target_info(job.board, stream=link is not None, laser=job.machine.laser is not None,
                             hold=job.machine.feed_hold is not None)
    except FileNotFoundError:
        raise BuildError(f"the {job.target} target is not supported yet: targets/ has no board '{job.board}'") \
            from None
    settings = job_settings(job)
    hold = None
    if settings.hold is not None:  # its errors before any planning
        hold = hold_plan(settings.hold, target.tick_hz, target.board, target.board_data, streamed=link is not None)
    kin = make_kinematics(job.machine)
    program = Program(job, kin, settings.homing, strict)
    played_out = runtime_outputs(job, target, link is not None)
    program.plays_runtime = bool(played_out)
    runtime = (lambda: runtime_records(program.settings, played_out)) if played_out else None
    limits = planner_limits(job, kin, target, bool(played_out))
    laser = laser_pwm(settings.laser, job.board, target.board_data, target.f_cpu)
    ahead = Lookahead(kin, limits)
    eras = ShapingEras(job, program)
    stages: Stages | None = None
    played: list[Played] = []
    chunks = front_end(settings.front_end, kin, program, watch)
    while True:
        with watch("front end (waiting for it)"):
            chunk = next(chunks, None)
        if stages is None:
            start_steps = kin.to_steps(program.start[None, :])[0]
            stages = Stages(settings.stages, kin, target, limits, start_steps, ahead, keep is True, watch, tables, link,
                            runtime, laser, hold, observe, eras)
        with watch("plan"):
            windows = ahead.close() if chunk is None else ahead.push(*chunk)
        while True:
            with watch("plan"):  # each window planned once the one before is played (and maybe slowed)
                window = next(windows, None)
            if window is None:
                break
            after = ahead.next_segment()  # at the program's end too: of a window that ends at an M593
            final = stages.play(window, after, chunk is None and after is None)
            if keep == "tables":
                played += [_tables_only(p) for p in final]
            elif keep:
                played += final
        progress.move_to(bar, program.handed_on)
        bar.set_postfix_str(f"{stages.totals.duration_s:.1f} s of motion", refresh=False)
        if chunk is None:
            break
    homing: tuple[HomingAxis, ...] = ()
    if homes(settings.homing, program.homes_first):
        homing = homing_axes(settings.homing, kin, target.tick_hz)
    start_steps = stages.checker.start_steps
    expected_final = kin.to_steps(np.asarray(program.end, float)[None, :])[0]
    if stages.totals.events == 0 and not played:  # nothing moves: an empty program
        played = stages.play(_no_window(kin, program, settings.front_end.tolerance_mm, limits), None, True)
    stages.finish()
    machine_heaters = None if job.machine.heaters is None else tuple(job.machine.heaters)
    heater_notes = heater_diagnostics(job.board, machine_heaters, target.heater_pins, program.heater_program,
                                      link is not None and not played_out)
    host = HostBuild(job, settings, target, kin, program.start, program.end, stages.totals,
                     stages.checker.findings(expected_final), start_steps, expected_final,
                     program.warnings + heater_notes + _advance_notes(stages.totals, program), homing,
                     program.heater_program, laser=laser, shapings=tuple(eras.all()),
                     shaper_specs=tuple(eras.specs()))
    if link is not None:
        host.link_plan = link_plan(link, stages.carried.ring, stages.totals)
    if runtime is not None:
        host.runtime = runtime()
        stages.totals.table_bytes += RUNTIME_BYTES * len(host.runtime)
    if keep == "tables":
        host.compressed = Compressed(join_schedule(played, False), *(np.zeros(0) for _ in range(3)))
        if runtime is not None:
            items = np.concatenate([p.window.segments.item for p in played]) if played else np.zeros(0, np.int64)
            host.compressed.schedule = with_runtime(host.compressed.schedule, runtime(), items)
    elif keep:
        bar.set_postfix_str("joining the windows")
        with watch("join"):
            host.segments, host.plan, host.events = join_segments(played), join_plan(played), join_events(played)
            if any(p.planned is not None for p in played):
                host.planned = join_segments(played, planned=True), join_plan(played, planned=True)
            host.pulses = join_pulses(played)
            host.compressed = join_compressed(played, False, host.pulses)
            if runtime is not None:
                host.compressed.schedule = with_runtime(host.compressed.schedule, runtime(), host.segments.item)
    return host


def _advance_notes(totals: Totals, program: Program) -> list[Diagnostic]:
    """A note where the plan was slowed to keep the advanced extruder within its limits (the first place)."""
    if not totals.advance_slowed:
        return []
    line = totals.advance_slowed_line
    where = SourceRef(program.gcode_file, line, 1) if line and program.gcode_file else SourceRef(str(program.job.path))
    return [Diagnostic(where, f"pressure advance: the plan was slowed {totals.advance_slowed} times to keep motor e "
                              "within its max_velocity and max_accel (K times the extruder's acceleration adds to "
                              "its speed), the first here", "note")]


def _tables_only(played: Played) -> Played:
    """A final window with only what its tables need (its schedule, its segments' items for the runtime records)."""
    empty = np.zeros(0)
    return replace(played, compressed=Compressed(played.compressed.schedule, empty, empty, empty), events=None,
                   pulses=None)


def runtime_outputs(job, target: TargetInfo, streamed: bool) -> tuple[str, ...]:
    """The outputs whose settings the image plays at their place: an AVR flash image's heaters (the job's
    that its board has), a streaming firmware's (stream_heaters), and the board's fan beside them (unless a
    heater uses its pin); with feed_hold, the program's pauses (M0/M1) too (an 8051's only ones); none elsewhere
    (codegen/tables/runtime.py)."""
    pauses = ("pause",) if job.machine.feed_hold is not None else ()
    if target.target != "avr":
        return pauses
    if not target.heater_pins:
        return pauses
    if streamed:
        heaters = tuple(h.name for h in stream_heaters(job, target.heater_pins))
        if not heaters:
            return pauses
    else:
        heaters = tuple(name for name in heater_settings(job) if name in target.heater_pins)
    fan = target.board_data.get("fan")
    played = played_outputs(heaters, bool(fan) and fan not in {pwm for pwm, _ in target.heater_pins.values()})
    return played + pauses if played else pauses


def _no_window(kin: Kinematics, program: Program, tolerance_mm: float, limits: PlannerLimits) -> Window:
    """The window of a program that does not move."""
    segments = Flattener(program.start, tolerance_mm)([])
    steps = np.zeros((0, len(kin.motors)), dtype=np.int64)
    return Window(0, segments, steps, plan(segments, kin, steps, PlannerLimits(limits.junction_deviation)))

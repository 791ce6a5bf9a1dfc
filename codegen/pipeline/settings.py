"""Each stage's settings, made once from the job at the top of a build (codegen/pipeline/host.py, streaming.py).

A stage takes the few numbers it needs in a small frozen type of its own, defined beside it, and never sees the
job object: the front end (codegen/motion/pieces.py FrontEndSettings), the planner (codegen/motion/planner.py
PlannerLimits), the stages after it (codegen/pipeline/windows.py StageSettings), homing
(codegen/program/homing.py HomingSettings), jog mode (codegen/motion/jog.py JogSettings), the feed hold
(codegen/tables/hold.py HoldSettings) and the laser (codegen/tables/laser.py LaserSettings). This module is the
one place that reads them out of the job. The makers raise nothing: a setting a stage cannot play is that stage's
error, raised where it was before.
"""

from __future__ import annotations

from dataclasses import dataclass

from codegen.kinematics.base import Kinematics, StepperLimits
from codegen.motion.advance import AdvanceSettings
from codegen.motion.jog import JogSettings
from codegen.motion.pieces import FrontEndSettings
from codegen.motion.planner import PlannerLimits
from codegen.motion.shaped_motion import ShapingSettings, shaping_of
from codegen.pipeline.windows import StageSettings
from codegen.program.homing import HomedStepper, HomingSettings
from codegen.tables.hold import RAMP_SHARE, HoldSettings, plans_ramp_share
from codegen.tables.laser import LaserSettings
from codegen.targets import TargetInfo

ADVANCE_FIT_STEPS = 0.05  # how far the advanced extruder's quadratic pieces may stray from Klipper's formula


@dataclass(frozen=True)
class JobSettings:
    """The settings of every stage that does not depend on the target (planner_limits does)."""

    front_end: FrontEndSettings
    stages: StageSettings
    homing: HomingSettings
    jog: JogSettings | None  # None: no jog mode
    hold: HoldSettings | None  # None: no feed hold
    laser: LaserSettings | None  # None: the tool pin is only on or off


def job_settings(job) -> JobSettings:
    return JobSettings(front_end_settings(job), stage_settings(job), homing_settings(job), jog_settings(job),
                       hold_settings(job), laser_settings(job))


def front_end_settings(job) -> FrontEndSettings:
    machine = job.machine
    advance = machine.pressure_advance
    return FrontEndSettings(machine.tolerance, {name: s.range for name, s in machine.steppers.items()},
                            0.0 if advance is None else advance.k, 0.0 if advance is None else advance.smooth_time)


def stage_settings(job) -> StageSettings:
    machine = job.machine
    return StageSettings(machine.tolerance, machine.step_pulse_us, machine.dir_setup_us, shaping_settings(job))


def shaping_settings(job) -> ShapingSettings | None:
    """The input shaper of each axis x, y, z (None where it has none) and the extruder's pressure advance; None
    when the machine shapes no axis and advances no extruder."""
    shaper = job.machine.input_shaper
    return shaping_of(shaper_specs(job), None if shaper is None else shaper.max_smoothing, advance_settings(job))


def shaper_specs(job) -> tuple:
    """The machine's input shaper of x, y, z as (type, freq, damping); None where it shapes none."""
    axes = {} if job.machine.input_shaper is None else job.machine.input_shaper.axes
    return tuple((axes[a].type, axes[a].freq, axes[a].damping) if a in axes else None for a in ("x", "y", "z"))


def advance_settings(job) -> AdvanceSettings | None:
    """The pressure advance's smoothing time, and its fit: within ADVANCE_FIT_STEPS extruder steps of the formula."""
    advance = job.machine.pressure_advance
    if advance is None:
        return None
    return AdvanceSettings(advance.smooth_time, ADVANCE_FIT_STEPS / job.machine.steppers["e"].steps_per_mm)


class ShapingEras:
    """The input shapers of each era of the program (codegen/toolpath/segments.py `shaping`): era 0 the machine's,
    era k what the k-th M593 of `program.shapings` set (as the front end hands them on), with the machine's
    max_smoothing and the job's pressure advance in every era (K travels per segment: Segments.advance), so that
    a stretch after `M593 F0` is still played as shaped motion, its xyz unshaped, while the extruder is advanced."""

    def __init__(self, job, program):
        self.program = program
        self.max_smoothing = None if job.machine.input_shaper is None else job.machine.input_shaper.max_smoothing
        self.advance = advance_settings(job)
        self.known = {0: shaping_settings(job)}
        self.machine_specs = shaper_specs(job)

    def __call__(self, era: int) -> ShapingSettings | None:
        if era not in self.known:
            self.known[era] = shaping_of(self.program.shapings[era - 1].shapers, self.max_smoothing, self.advance)
        return self.known[era]

    def all(self) -> list[ShapingSettings | None]:
        """Every era's, in order."""
        return [self(era) for era in range(len(self.program.shapings) + 1)]

    def specs(self) -> list[tuple]:
        """Every era's shapers of x, y, z as (type, freq, damping) or None (unshaped), in order."""
        return [self.machine_specs] + [change.shapers for change in self.program.shapings]


def homing_settings(job) -> HomingSettings:
    """A machine homes whatever its program says when it is a delta or its program says `home: true` (a
    streaming firmware's job file may have no program)."""
    machine, program = job.machine, job.program
    homing = machine.homing
    return HomingSettings(
        kinematics=machine.kinematics,
        always=machine.kinematics == "delta" or bool(program is not None and program.home),
        speed=homing.speed, slow_speed=homing.slow_speed, backoff=homing.backoff,
        steppers={name: HomedStepper(s.steps_per_mm, s.range, s.steps_source) for name, s in machine.steppers.items()})


def jog_settings(job) -> JogSettings | None:
    jog = job.machine.jog
    if jog is None:
        return None
    return JogSettings(job.machine.kinematics, tuple(jog.speeds), jog.accel, jog.keys, stepper_limits(job))


def hold_settings(job) -> HoldSettings | None:
    hold = job.machine.feed_hold
    if hold is None:
        return None
    return HoldSettings(hold.override, hold.max_override, tuple(stepper_limits(job).values()), ramp_share(job))


def laser_settings(job) -> LaserSettings | None:
    laser = job.machine.laser
    if laser is None:
        return None
    return LaserSettings(laser.pwm_hz, follows_feed=job.machine.feed_hold is not None)


def stepper_limits(job) -> dict[str, StepperLimits]:
    """Every stepper's limits, by name (the values as the job gives them: no rounding on the way)."""
    return {name: StepperLimits(s.steps_per_mm, s.max_velocity, s.max_accel)
            for name, s in job.machine.steppers.items()}


def ramp_share(job) -> bool:
    """The plan keeps the feed hold's RAMP_SHARE of every motor's acceleration (codegen/tables/hold.py)."""
    return plans_ramp_share(job.machine.feed_hold is not None, job.machine.kinematics, job.target)


def planner_limits(job, kin: Kinematics, target: TargetInfo, heaters: bool = False) -> PlannerLimits:
    """`heaters`: the image runs heater stages beside the player (their check may delay a pulse). A laser's
    machine does not stop where the tool switches (Grbl's laser mode): its power records land at their step."""
    pulse_us, setup_us, motors = job.machine.step_pulse_us, job.machine.dir_setup_us, len(kin.motors)
    return PlannerLimits(job.machine.junction_deviation, max_event_rate=target.max_event_rate(motors, pulse_us),
                         block_overhead=target.block_overhead_s(motors, pulse_us, setup_us),
                         block_load=target.block_load_s(pulse_us, setup_us),
                         pulse_jitter_s=target.pulse_jitter_s(heaters), tool_stops=job.machine.laser is None,
                         accel_share=1.0 - RAMP_SHARE if ramp_share(job) else 1.0)

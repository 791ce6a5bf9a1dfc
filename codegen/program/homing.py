"""Homing: which axes find their switches at power-up, how, and where the tool is afterwards.

Delta machines always home, every carriage up to its tower's max switch. Cartesian and corexy machines home when
the job says so (`program.home: true`) or when their G-code starts with G28: x, y and z go down to their min
switches, where each axis is at the low end of its `range` (0 without one; a corexy's x and y at 0: its ranges
are the belts'). A corexy moves both belts for either axis, so it homes as Marlin and Klipper do, one axis at a
time: x (with z) first, then y. The firmware does the motion; the host gives it the speeds and the travel after
which a switch that never closed is a fault. Where the tool then is, is the machine's `home_point`
(codegen/job/schema/machine.py), where the G-code's G28 leaves it too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

from codegen.errors import Diagnostic, JobError, SourceRef
from codegen.kinematics.base import Kinematics

# kinematics -> its homed axes: (board endstop, the axis's direction towards it, {motor: its direction}, round)
AXES = {
    "cartesian": (("x_min", -1, {"x": -1}, 0), ("y_min", -1, {"y": -1}, 0), ("z_min", -1, {"z": -1}, 0)),
    "corexy": (("x_min", -1, {"a": -1, "b": -1}, 0), ("z_min", -1, {"z": -1}, 0),
               ("y_min", -1, {"a": -1, "b": 1}, 1)),  # A = X + Y, B = X - Y
    "delta": (("x_max", 1, {"a": 1}, 0), ("y_max", 1, {"b": 1}, 0), ("z_max", 1, {"c": 1}, 0)),
}
TRAVEL_MARGIN = 1.2  # a switch may be this much further than the machine's travel before it is a fault
DEFAULT_TRAVEL_MM = 1000.0  # an axis without a `range` (a corexy's x and y)


@dataclass(frozen=True)
class HomingAxis:
    """How one axis homes: its motors step together towards its switch fast, back off, towards it again
    slowly. A cartesian or delta axis is one motor; a corexy x or y moves both belts (a and b)."""

    motors: tuple[int, ...]  # indices into FirmwareConfig.motors, stepping at the same events
    motor_directions: tuple[int, ...]  # per motor, +1 / -1: the way it steps (its own coordinate) towards the switch
    switch: str  # the board's endstop name: x_min, x_max, y_min, y_max, z_min, z_max
    direction: int  # +1 / -1: the way the axis moves (in machine coordinates) to reach the switch
    max_steps: int  # a switch that has not closed after this many steps stops the machine in an error state
    fast_interval: int  # timer ticks between steps on the first approach
    slow_interval: int  # timer ticks between steps on the second approach
    backoff_steps: int  # steps away from the switch between the approaches
    round: int = 0  # rounds home one after another (corexy: x, then y), the axes of one round together

    def label(self, motor_names) -> str:
        """The axis in messages and generated names: its motor's name, or for several its switch's axis (x)."""
        return motor_names[self.motors[0]] if len(self.motors) == 1 else self.switch.split("_")[0]


@dataclass(frozen=True)
class HomedStepper:
    """What homing needs of one stepper."""

    steps_per_mm: float
    range: tuple[float, float] | None  # mm of motor travel; None: none given
    steps_source: SourceRef  # where the job file gives steps_per_mm (an error about it points there)


@dataclass(frozen=True)
class HomingSettings:
    """`machine.homing`, the machine's steppers, and whether it homes whatever its program says."""

    kinematics: str
    always: bool  # the machine homes at power-up: a delta, or `program.home: true`
    speed: float  # mm/s of motor travel on the first approach
    slow_speed: float  # mm/s on the second
    backoff: float  # mm away from the switches between them
    steppers: Mapping[str, HomedStepper]  # by name


def homes(settings: HomingSettings, leading_g28: bool) -> bool:
    return settings.always or leading_g28


def homing_axes(settings: HomingSettings, kin: Kinematics, tick_hz: int) -> tuple[HomingAxis, ...]:
    """The firmware's homing of every axis whose motors the machine has."""
    axes = []
    for switch, direction, motor_directions, round_ in AXES[settings.kinematics]:
        if not all(name in kin.motors for name in motor_directions):
            continue
        motors = tuple(kin.motors.index(name) for name in motor_directions)
        stepper, *others = (settings.steppers[name] for name in motor_directions)
        spm = stepper.steps_per_mm
        for name, other in zip(list(motor_directions)[1:], others):
            if other.steps_per_mm != spm:  # one homing step of each belt must move the tool straight along the axis
                raise JobError([Diagnostic(other.steps_source, (
                    f"machine.steppers.{name}.steps_per_mm: homing {switch[0]} steps "
                    f"{' and '.join(motor_directions)} together, so they need the same steps_per_mm "
                    f"({next(iter(motor_directions))} has {spm:g}, {name} {other.steps_per_mm:g})"))])
        if len(motors) == 1 and stepper.range:
            travel = stepper.range[1] - stepper.range[0]
        elif settings.kinematics == "delta":
            travel = float(kin.to_motor(kin.home()[None, :])[0, motors[0]])  # the carriage from the bed to the top
        else:
            travel = DEFAULT_TRAVEL_MM
        axes.append(HomingAxis(
            motors=motors,
            motor_directions=tuple(motor_directions.values()),
            switch=switch,
            direction=direction,
            max_steps=math.ceil(TRAVEL_MARGIN * travel * spm),
            fast_interval=max(1, round(tick_hz / (settings.speed * spm))),
            slow_interval=max(1, round(tick_hz / (settings.slow_speed * spm))),
            backoff_steps=max(1, round(settings.backoff * spm)),
            round=round_,
        ))
    return tuple(axes)

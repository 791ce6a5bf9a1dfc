"""Homing: which motors find their switches at power-up, how, and where the tool is afterwards.

Delta machines always home, every carriage up to its tower's max switch. Cartesian machines home when the job
says so (`program.home: true`) or when their G-code starts with G28: x, y and z go down to their min switches,
where each axis is at the low end of its `range` (0 without one). The firmware does the motion; the host gives
it the speeds, the travel after which a switch that never closed is a fault, and the position it then has.
"""

from __future__ import annotations

import math

import numpy as np

from codegen.errors import BuildError
from codegen.firmware import HomingAxis
from codegen.kinematics.base import Kinematics

SWITCHES = {  # kinematics -> motor -> (board endstop, direction towards it)
    "cartesian": {"x": ("x_min", -1), "y": ("y_min", -1), "z": ("z_min", -1)},
    "delta": {"a": ("x_max", 1), "b": ("y_max", 1), "c": ("z_max", 1)},
}
TRAVEL_MARGIN = 1.2  # a switch may be this much further than the machine's travel before it is a fault
DEFAULT_TRAVEL_MM = 1000.0  # a cartesian axis without a `range`


def homes(job, leading_g28: bool) -> bool:
    return job.machine.kinematics == "delta" or bool(job.program.home) or leading_g28


def home_position(job, kin: Kinematics) -> np.ndarray:
    """Where the tool is once homed (4-vector, mm)."""
    if job.machine.kinematics == "delta":
        return kin.home()
    if job.machine.kinematics != "cartesian":
        raise BuildError(f"homing a {job.machine.kinematics} machine is not supported yet")
    position = np.zeros(4)
    for axis, name in enumerate("xyz"):
        stepper = job.machine.steppers.get(name)
        if stepper is not None and stepper.range:
            position[axis] = stepper.range[0]
    return position


def homing_axes(job, kin: Kinematics, tick_hz: int) -> tuple[HomingAxis, ...]:
    """The firmware's homing of every motor that has a switch."""
    settings = job.machine.homing
    switches = SWITCHES.get(job.machine.kinematics, {})
    home_steps = kin.to_steps(home_position(job, kin)[None, :])[0]
    axes = []
    for m, name in enumerate(kin.motors):
        if name not in switches:
            continue
        switch, direction = switches[name]
        spm = float(kin.limits.steps_per_mm[m])
        stepper = job.machine.steppers[name]
        if stepper.range:
            travel = stepper.range[1] - stepper.range[0]
        elif job.machine.kinematics == "delta":
            travel = float(kin.to_motor(kin.home()[None, :])[0, m])  # the carriage from the bed to the top
        else:
            travel = DEFAULT_TRAVEL_MM
        axes.append(HomingAxis(
            motor=m,
            switch=switch,
            direction=direction,
            max_steps=math.ceil(TRAVEL_MARGIN * travel * spm),
            fast_interval=max(1, round(tick_hz / (settings.speed * spm))),
            slow_interval=max(1, round(tick_hz / (settings.slow_speed * spm))),
            backoff_steps=max(1, round(settings.backoff * spm)),
            home_steps=int(home_steps[m]),
        ))
    return tuple(axes)

"""Kinematics: machine axes [x, y, z, e] (mm) to motor positions (mm of motor travel), one module per variant."""

from __future__ import annotations

from codegen.kinematics.base import Kinematics, MotorLimits
from codegen.kinematics.cartesian import Cartesian
from codegen.kinematics.corexy import CoreXY
from codegen.kinematics.delta import Delta

VARIANTS = {"cartesian": Cartesian, "corexy": CoreXY, "delta": Delta}


def make_kinematics(machine) -> Kinematics:
    """The kinematics of a validated `job.machine`."""
    names = tuple(machine.motor_names)
    limits = MotorLimits.from_steppers(names, machine.steppers)
    try:
        variant = VARIANTS[machine.kinematics]
    except KeyError:
        raise NotImplementedError(f"kinematics '{machine.kinematics}' is not supported yet") from None
    if variant is Delta:
        geometry = machine.delta
        return Delta(limits, geometry.radius, geometry.diagonal_rod, geometry.height, geometry.tower_angles,
                     ranges=[getattr(machine.steppers[n], "range", None) for n in names])
    return variant(limits)


__all__ = ["Kinematics", "MotorLimits", "make_kinematics", "Cartesian", "CoreXY", "Delta"]

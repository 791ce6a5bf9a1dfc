"""Cartesian machines: each motor drives one axis (x, y, z, e)."""

from codegen.kinematics.base import LinearKinematics


class Cartesian(LinearKinematics):
    name = "cartesian"
    sockets = {"x": "X", "y": "Y", "z": "Z", "e": "E0"}
    axis_rows = {
        "x": (1.0, 0.0, 0.0, 0.0),
        "y": (0.0, 1.0, 0.0, 0.0),
        "z": (0.0, 0.0, 1.0, 0.0),
        "e": (0.0, 0.0, 0.0, 1.0),
    }

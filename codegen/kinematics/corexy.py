"""CoreXY machines: belts A and B move A = X + Y and B = X - Y; z and e are direct."""

from codegen.kinematics.base import LinearKinematics


class CoreXY(LinearKinematics):
    name = "corexy"
    sockets = {"a": "X", "b": "Y", "z": "Z", "e": "E0"}
    axis_rows = {
        "a": (1.0, 1.0, 0.0, 0.0),
        "b": (1.0, -1.0, 0.0, 0.0),
        "z": (0.0, 0.0, 1.0, 0.0),
        "e": (0.0, 0.0, 0.0, 1.0),
    }

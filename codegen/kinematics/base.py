"""The interface every kinematics variant implements, and the linear case shared by cartesian and corexy."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StepperLimits:
    """One stepper's limits as the job gives them (mm of motor travel), for the stages that need a few of them
    without the kinematics (jog mode, the feed hold's ramp)."""

    steps_per_mm: float
    max_velocity: float  # mm/s
    max_accel: float  # mm/s^2


@dataclass(frozen=True)
class MotorLimits:
    names: tuple[str, ...]
    steps_per_mm: np.ndarray  # (M,)
    max_velocity: np.ndarray  # (M,) mm/s of motor travel
    max_accel: np.ndarray  # (M,) mm/s^2 of motor travel
    invert_dir: tuple[bool, ...]

    @classmethod
    def from_steppers(cls, names, steppers) -> "MotorLimits":
        get = lambda attr: np.array([float(getattr(steppers[n], attr)) for n in names])  # noqa: E731
        return cls(
            names=tuple(names),
            steps_per_mm=get("steps_per_mm"),
            max_velocity=get("max_velocity"),
            max_accel=get("max_accel"),
            invert_dir=tuple(bool(getattr(steppers[n], "invert_dir", False)) for n in names),
        )

    @property
    def max_rate(self) -> np.ndarray:
        """Steps per second each motor may make."""
        return self.max_velocity * self.steps_per_mm


class Kinematics:
    """Maps axis positions to motor positions (and back). Every variant implements the methods below; the
    linear ones (cartesian, corexy) through a fixed matrix, delta through its geometry."""

    name = "abstract"
    sockets: dict[str, str] = {}  # motor name -> board stepper socket

    def __init__(self, limits: MotorLimits):
        self.limits = limits

    def motor_factors(self, directions: np.ndarray, points: np.ndarray) -> np.ndarray:
        """|d motor / d path| (motor mm per mm of tool travel) along unit directions (N, 4) at points (N, 4)."""
        raise NotImplementedError

    def step_reach(self) -> np.ndarray:
        """(M,) the largest tool displacement (mm, xyz) one step of each motor can make in the workspace."""
        raise NotImplementedError

    def motor_bend(self, directions: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(N, M) |d^2 motor / ds^2| along straight lines: motor acceleration per (mm/s)^2 of constant speed."""
        return np.zeros((len(points), len(self.motors)))

    def chord_kinks(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """(n - 1, M) at each vertex between consecutive straight pieces (`start[j + 1]` is `end[j]`): how much each
        motor's velocity changes there, per mm/s of path speed, beyond what the path's own turn makes it (the
        motors move linearly along every piece). Nothing where motors are linear in the axes."""
        return np.zeros((max(len(start) - 1, 0), len(self.motors)))

    def path_quantum(self) -> float:
        """How far (mm) from the path stepping itself may put the tool: one step of the coarsest motor."""
        return float(self.step_reach().max())

    linear = False  # motor positions are a fixed linear map of the axes

    def subdivide(self, segments, tolerance: float):
        """Cut straight segments so that moving the motors linearly between the cuts keeps the tool within
        `tolerance` of the straight line (nothing to do where motors are linear in the axes)."""
        return segments

    def unreachable(self, points: np.ndarray) -> np.ndarray:
        """(N,) True where the machine cannot put the tool at the point (N, 4)."""
        return np.zeros(len(points), dtype=bool)

    def home(self) -> np.ndarray:
        """Where the tool is once every motor has homed (4-vector)."""
        return np.zeros(4)

    @property
    def motors(self) -> tuple[str, ...]:
        return self.limits.names

    def socket(self, motor: str) -> str:
        return self.sockets[motor]

    def to_motor(self, axes: np.ndarray) -> np.ndarray:
        """(N, 4) axis mm -> (N, M) motor mm."""
        raise NotImplementedError

    def to_axes(self, motor_mm: np.ndarray, like: np.ndarray) -> np.ndarray:
        """(N, M) motor mm -> (N, 4) axis mm; axes no motor drives are taken from `like` (N, 4)."""
        raise NotImplementedError

    def to_steps(self, axes: np.ndarray) -> np.ndarray:
        """Motor positions in whole steps: round once from the exact coordinates (JOB-FORMAT.md)."""
        return np.round(self.to_motor(axes) * self.limits.steps_per_mm).astype(np.int64)


class LinearKinematics(Kinematics):
    """Motor positions are a fixed linear map of the axes: motor = matrix @ axes."""

    linear = True
    axis_rows: dict[str, tuple[float, float, float, float]] = {}

    def __init__(self, limits: MotorLimits):
        super().__init__(limits)
        self.matrix = np.array([self.axis_rows[n] for n in limits.names], dtype=float)
        self.driven_axes = np.flatnonzero(np.any(self.matrix != 0.0, axis=0))
        self.inverse = np.linalg.pinv(self.matrix[:, self.driven_axes])  # driven axes from motor mm

    def to_motor(self, axes: np.ndarray) -> np.ndarray:
        return np.asarray(axes, dtype=float) @ self.matrix.T

    def to_axes(self, motor_mm: np.ndarray, like: np.ndarray) -> np.ndarray:
        out = np.array(like, dtype=float, copy=True)
        out[:, self.driven_axes] = np.asarray(motor_mm, dtype=float) @ self.inverse.T
        return out

    def motor_factors(self, directions: np.ndarray, points: np.ndarray | None = None) -> np.ndarray:
        return np.abs(directions @ self.matrix.T)

    def step_reach(self) -> np.ndarray:
        return np.linalg.norm(self.to_axes(np.diag(1.0 / self.limits.steps_per_mm),
                                           np.zeros((len(self.motors), 4)))[:, :3], axis=1)

"""Delta machines: three carriages ride vertical towers and hold the effector by diagonal rods of equal length.

Tower i stands at T_i = radius * (cos angle_i, sin angle_i). A carriage's coordinate is its height above the
bed plane, c_i = z + sqrt(rod^2 - |(x, y) - T_i|^2) (JOB-FORMAT.md): the effector hangs `rise_i` below it.
Motors a, b, c drive the carriages of the towers in `tower_angles` order; e (the extruder) is linear.
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from codegen.kinematics.base import Kinematics, MotorLimits
from codegen.toolpath.segments import Segments

MAX_ARM_RATIO = 12.0  # horizontal : vertical span of a rod beyond which the arm is too flat (Klipper's limit)
SLACK = 1e-9  # mm: carriages exactly at their top (home) or a range end stay reachable despite rounding
REACH_GRID = 201  # points per side of the grid that looks for the largest effector motion per carriage mm
REACH_ZOOMS = 8  # finer grids around each best point, each 1/5 the size of the previous
REACH_SAFETY = 1.01  # on top of the maximum found: grid resolution, steps that graze the region's edge
CURVATURE_SAMPLES = 16  # intervals along a segment at which the carriages' curvature is sampled
CHECK_POINTS = 16  # each piece is measured at the interior points k / CHECK_POINTS
AIM = 0.9  # share of the tolerance the cuts aim at: the estimate is second-order
ACCEPT = 0.97  # share of the tolerance a piece may measure: its peak may fall between the measured points
ROUNDS = 24  # rounds of splitting the pieces still too coarse before giving up


class Delta(Kinematics):
    name = "delta"
    sockets = {"a": "X", "b": "Y", "c": "Z", "e": "E0"}

    def __init__(self, limits: MotorLimits, radius: float, diagonal_rod: float, height: float,
                 tower_angles=(210.0, 330.0, 90.0), ranges=None):
        """`ranges`: per motor (in `limits.names` order) its (min, max) carriage coordinate, or None."""
        super().__init__(limits)
        if limits.names[:3] != ("a", "b", "c"):
            raise ValueError(f"delta motors are a, b, c (and e), not {', '.join(limits.names)}")
        angles = np.radians(np.asarray(tower_angles, dtype=float))
        self.radius = float(radius)
        self.towers = radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)  # (3, 2)
        spans = 2.0 * (self.towers[1:] - self.towers[0])
        if abs(np.linalg.det(spans)) < 1e-9 * radius * radius:
            raise ValueError("delta tower_angles must be three different directions")
        self._plane = np.linalg.inv(spans)  # see _effector
        self.rod2 = float(diagonal_rod) ** 2
        self.height = float(height)
        self.top = self.height + math.sqrt(self.rod2 - radius * radius)  # every carriage's coordinate at home
        self.min_rise = diagonal_rod / math.hypot(1.0, MAX_ARM_RATIO)  # the flattest arm allowed
        bounds = [r if r is not None else (-np.inf, np.inf) for r in (ranges or [None] * len(limits.names))]
        self.low = np.array([b[0] for b in bounds[:3]], dtype=float)
        self.high = np.minimum(np.array([b[1] for b in bounds[:3]], dtype=float), self.top)
        self.has_e = "e" in limits.names

    # ---- positions ----

    def _arms(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, 3) each: the effector's offsets (x, y) from every tower, and how far each carriage is above it
        (nan where a rod cannot reach)."""
        dx = xy[:, :1] - self.towers[:, 0]
        dy = xy[:, 1:2] - self.towers[:, 1]
        with np.errstate(invalid="ignore"):
            return dx, dy, np.sqrt(self.rod2 - dx * dx - dy * dy)

    def to_motor(self, axes: np.ndarray) -> np.ndarray:
        """Carriage coordinates (nan where a rod cannot reach the point); e passes through."""
        axes = np.asarray(axes, dtype=float)
        carriages = axes[:, 2:3] + self._arms(axes[:, :2])[2]
        return np.concatenate([carriages, axes[:, 3:4]], axis=1) if self.has_e else carriages

    def _effector(self, carriages: np.ndarray) -> np.ndarray:
        """(N, 3) -> (N, 3): the point a rod's length from all three carriage joints, below them.

        With w = z - c_0 and d_i = c_i - c_0, subtracting rod 0's sphere from the others' leaves the linear
        2 (T_i - T_0) . (x, y) = d_i (d_i - 2 w) (the towers share one radius): (x, y) = T_0 + a + b w. Rod
        0's sphere is then a quadratic in w, and the effector is its lower root (the other is its mirror
        image through the carriages' plane), computed without cancellation."""
        d = carriages[:, 1:] - carriages[:, :1]
        a = (d * d) @ self._plane.T - self.towers[0]
        b = -2.0 * d @ self._plane.T
        qa = 1.0 + np.einsum("ni,ni->n", b, b)
        qb = np.einsum("ni,ni->n", a, b)
        qc = np.einsum("ni,ni->n", a, a) - self.rod2
        with np.errstate(invalid="ignore", divide="ignore"):
            root = np.sqrt(qb * qb - qa * qc)
            w = np.where(qb > 0.0, -(qb + root) / qa, qc / (root - qb))
        return np.column_stack([self.towers[0] + a + b * w[:, None], carriages[:, 0] + w])

    def to_axes(self, motor_mm: np.ndarray, like: np.ndarray) -> np.ndarray:
        motor_mm = np.asarray(motor_mm, dtype=float)
        out = np.array(like, dtype=float, copy=True)
        out[:, :3] = self._effector(motor_mm[:, :3])
        if self.has_e:
            out[:, 3] = motor_mm[:, 3]
        return out

    def home(self) -> np.ndarray:
        """Every carriage at its top endstop: the nozzle `height` above the bed centre."""
        return np.array([0.0, 0.0, self.height, 0.0])

    # ---- derivatives ----

    @staticmethod
    def _jacobian(dx: np.ndarray, dy: np.ndarray, rise: np.ndarray) -> np.ndarray:
        """(N, 3, 3) d carriage_i / d (x, y, z) from `_arms`: it depends on x and y only."""
        return np.stack([-dx / rise, -dy / rise, np.ones_like(rise)], axis=2)

    def motor_factors(self, directions: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Carriage mm per mm of effector travel along `directions` at `points` (e: |d e|)."""
        directions, points = np.asarray(directions, dtype=float), np.asarray(points, dtype=float)
        dx, dy, rise = self._arms(points[:, :2])
        rates = np.abs(directions[:, 2:3] - (dx * directions[:, :1] + dy * directions[:, 1:2]) / rise)
        return np.concatenate([rates, np.abs(directions[:, 3:4])], axis=1) if self.has_e else rates

    def carriage_motion(self, position: np.ndarray, velocity: np.ndarray, accel: np.ndarray,
                        motor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, M) each motor's position (mm), velocity and acceleration where the effector is at `position` (N, 4)
        moving at `velocity` and accelerating by `accel`: c = z + rise, rise' = -(dx vx + dy vy) / rise. With
        `motor` (N,): only that motor's of each row, (N,) each."""
        if motor is None:
            dx, dy, rise = self._arms(position[:, :2])
        else:
            tower = self.towers[np.minimum(motor, 2)]
            dx, dy = position[:, :1] - tower[:, :1], position[:, 1:2] - tower[:, 1:2]
            with np.errstate(invalid="ignore"):
                rise = np.sqrt(self.rod2 - dx * dx - dy * dy)
        vx, vy, ax, ay = velocity[:, :1], velocity[:, 1:2], accel[:, :1], accel[:, 1:2]
        along = dx * vx + dy * vy
        speed = velocity[:, 2:3] - along / rise
        bend = accel[:, 2:3] - (vx * vx + vy * vy + dx * ax + dy * ay) / rise - along * along / rise ** 3
        parts, effector = (position[:, 2:3] + rise, speed, bend), (position, velocity, accel)
        if motor is not None:  # the extruder (motor 3) is linear
            return tuple(np.where(motor == 3, e[:, 3], part[:, 0]) for part, e in zip(parts, effector))
        if not self.has_e:
            return parts
        return tuple(np.concatenate([part, e[:, 3:4]], axis=1) for part, e in zip(parts, effector))

    def motor_bend(self, directions: np.ndarray, points: np.ndarray) -> np.ndarray:
        """|d^2 carriage / ds^2| along a straight line (per mm of path, squared): at speed v a carriage
        accelerates by v^2 times this even when the effector does not."""
        directions, points = np.asarray(directions, dtype=float), np.asarray(points, dtype=float)
        dx, dy, rise = self._arms(points[:, :2])
        along = dx * directions[:, :1] + dy * directions[:, 1:2]
        flat2 = directions[:, :1] ** 2 + directions[:, 1:2] ** 2
        with np.errstate(invalid="ignore", divide="ignore"):
            bend = np.abs((flat2 * rise ** 2 + along ** 2) / rise ** 3)
        bend = np.nan_to_num(bend, nan=np.inf)
        return np.concatenate([bend, np.zeros((len(points), 1))], axis=1) if self.has_e else bend

    def chord_kinks(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """The carriages move linearly along each piece, so a carriage's speed per mm of path is the chord's
        (c(end) - c(start)) / length there: along a straight line it changes at every cut by about the bend
        (`motor_bend`) times the pieces' length, at once. What the effector's turn explains (the Jacobian at the
        vertex times the change of direction) is the junction's own; this is the rest (0 beside a still piece)."""
        start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
        length = np.linalg.norm(end[:, :3] - start[:, :3], axis=1, keepdims=True)
        moving = length[:, 0] > 0.0
        carriages = self.to_motor(end)[:, :3] - self.to_motor(start)[:, :3]
        chord = np.divide(carriages, length, out=np.zeros_like(carriages), where=length > 0.0)
        u = np.divide(end[:, :3] - start[:, :3], length, out=np.zeros_like(carriages), where=length > 0.0)
        turn = np.einsum("nij,nj->ni", self._jacobian(*self._arms(start[1:, :2])), u[1:] - u[:-1])
        kinks = np.abs(chord[1:] - chord[:-1] - turn) * (moving[1:] & moving[:-1])[:, None]
        return np.concatenate([kinks, np.zeros((len(kinks), 1))], axis=1) if self.has_e else kinks

    def path_quantum(self) -> float:
        """Two carriages may each be half a step or more off their exact height, in opposite senses: the
        staircase allowance is the sum of the two largest single-step reaches."""
        reach = np.sort(self.step_reach()[:3])
        return float(reach[-1] + reach[-2])

    def _inverse_norms(self, xy: np.ndarray) -> np.ndarray:
        """(N, 3) |J^-1 e_i|: effector mm per mm of carriage i with the others held; -inf outside the region."""
        out = np.full((len(xy), 3), -np.inf)
        dx, dy, rise = self._arms(xy)
        inside = np.all(rise >= self.min_rise, axis=1)
        out[inside] = np.linalg.norm(np.linalg.inv(self._jacobian(dx[inside], dy[inside], rise[inside])), axis=1)
        return out

    @cached_property
    def _inverse_peak(self) -> np.ndarray:
        """(3,) the largest |J^-1 e_i| over the region where every rod is steep enough (any z)."""
        span = math.sqrt(self.rod2 - self.min_rise ** 2)  # the longest horizontal reach of a rod
        low, high = (self.towers - span).max(axis=0), (self.towers + span).min(axis=0)
        grid = np.stack(np.meshgrid(*(np.linspace(lo, hi, REACH_GRID) for lo, hi in zip(low, high))), axis=-1)
        points = grid.reshape(-1, 2)
        norms = self._inverse_norms(points)
        best = norms.max(axis=0)
        where = points[np.argmax(norms, axis=0)]  # (3, 2) the best point of each column
        cell = (high - low) / (REACH_GRID - 1)
        offsets = np.stack(np.meshgrid(*(np.linspace(-1.0, 1.0, 11),) * 2), axis=-1).reshape(-1, 2)
        for _ in range(REACH_ZOOMS):
            local = where[:, None, :] + offsets[None, :, :] * cell  # (3, 121, 2) around each best point
            values = self._inverse_norms(local.reshape(-1, 2)).reshape(3, -1, 3)[np.arange(3), :, np.arange(3)]
            k = np.argmax(values, axis=1)
            better = values[np.arange(3), k] > best
            best = np.where(better, values[np.arange(3), k], best)
            where = np.where(better[:, None], local[np.arange(3), k], where)
            cell = cell / 5.0
        return best

    def step_reach(self) -> np.ndarray:
        """(M,) the largest effector displacement (mm, xyz) one step of each motor can make.

        One step of carriage i, the others held, moves the effector along the circle where the other two
        rods' spheres meet, at |J^-1 e_i| mm per carriage mm (the i-th column of the inverse Jacobian). The
        Jacobian depends on x and y only (every carriage rides up with z), so over the whole reachable region
        (every rod at most MAX_ARM_RATIO flat, at any height) the displacement is at most one step times the
        largest column norm there: the integral of the column over the step is no longer than its peak. The
        peak (about 1.33 for Kossel-like rods, inside the region half-way to a tower) is found on a grid
        refined around the best point, and REACH_SAFETY covers the grid and steps that graze the region's
        edge. The extruder moves no xyz: 0."""
        reach = np.zeros(len(self.motors))
        reach[:3] = self._inverse_peak * REACH_SAFETY / self.limits.steps_per_mm[:3]
        return reach

    # ---- workspace ----

    def unreachable(self, points: np.ndarray) -> np.ndarray:
        """True where some rod would be flatter than MAX_ARM_RATIO (horizontal : vertical, Klipper's limit;
        this covers rods too short to reach and horizontal ones: rod^2 - horizontal^2 < rod^2 / (1 + 12^2)),
        or a carriage would be above its top (home: `height` + sqrt(rod^2 - radius^2)), or outside its motor's
        `range` when one is given (its minimum is the bed-level limit)."""
        points = np.asarray(points, dtype=float)
        rise = self._arms(points[:, :2])[2]
        carriages = points[:, 2:3] + rise
        with np.errstate(invalid="ignore"):
            good = ((rise >= self.min_rise) & (carriages <= self.high + SLACK) & (carriages >= self.low - SLACK))
        return ~np.all(good, axis=1)

    def reach(self, low_z: float, high_z: float) -> float:
        """The radius (mm) of the largest disc around the bed centre that is reachable (`unreachable`) at every
        height from `low_z` to `high_z`; negative where not even the centre is. Every tower stands `radius` from the
        centre, so over a disc of radius r a rod's horizontal span d is from radius - r to radius + r: a rod steep
        enough and a carriage above its minimum bound d from above, a carriage below its top from below."""
        rod = math.sqrt(self.rod2)
        lowest = np.maximum(self.low - low_z, self.min_rise)  # the least rise each rod may have at low_z
        far = np.sqrt(np.maximum(self.rod2 - lowest ** 2, 0.0)) - self.radius
        far[lowest > rod] = -np.inf
        rise = self.high - high_z  # the most each rod may rise at high_z
        near = np.where(rise >= rod, np.inf, self.radius - np.sqrt(np.maximum(self.rod2 - rise ** 2, 0.0)))
        near[rise < 0.0] = -np.inf
        return float(min(far.min(), near.min()))

    def highest(self, r: float) -> float:
        """The highest z (mm) at which every carriage stays below its top over the disc of radius `r` around the
        bed centre (`reach`'s other way round: its nearest point to a tower is radius - r from it)."""
        near = max(self.radius - r, 0.0)
        return float((self.high - math.sqrt(max(self.rod2 - near * near, 0.0))).min())

    # ---- straight moves ----

    def _curvature(self, start: np.ndarray, end: np.ndarray, samples: int) -> np.ndarray:
        """(n, samples + 1) how fast the effector leaves the line when the carriages move linearly:
        |(I - u u^T) J^-1 c''| per mm^2 of piece length (the deviation is about that times length^2 / 8)."""
        delta = end[:, :3] - start[:, :3]
        u = delta / np.linalg.norm(delta, axis=1, keepdims=True)
        t = np.linspace(0.0, 1.0, samples + 1)
        xy = (start[:, None, :2] + t[None, :, None] * delta[:, None, :2]).reshape(-1, 2)
        uu = np.repeat(u, len(t), axis=0)
        dx, dy, rise = self._arms(xy)
        along = dx * uu[:, :1] + dy * uu[:, 1:2]
        flat2 = uu[:, :1] ** 2 + uu[:, 1:2] ** 2
        bend = -(flat2 * rise ** 2 + along ** 2) / rise ** 3  # d^2 carriage / ds^2 (z enters linearly)
        moved = np.linalg.solve(self._jacobian(dx, dy, rise), bend[:, :, None])[:, :, 0]
        across = moved - np.einsum("nj,nj->n", moved, uu)[:, None] * uu
        return np.linalg.norm(across, axis=1).reshape(len(start), len(t))

    def _need(self, start: np.ndarray, end: np.ndarray, tolerance: float, samples: int) -> np.ndarray:
        """(n, samples + 1) the running integral along each segment of length * sqrt(curvature / (8 * AIM *
        tolerance)) over t: about how many pieces the segment needs up to each sample."""
        density = np.sqrt(self._curvature(start, end, samples) / (8.0 * AIM * tolerance))
        density *= np.linalg.norm(end[:, :3] - start[:, :3], axis=1)[:, None]  # per unit of t
        if not np.all(np.isfinite(density)):
            raise ValueError("delta moves: a move leaves the reachable region (check `unreachable` first)")
        steps = 0.5 * (density[:, 1:] + density[:, :-1]) / samples
        return np.concatenate([np.zeros((len(start), 1)), np.cumsum(steps, axis=1)], axis=1)

    def _first_cuts(self, start: np.ndarray, end: np.ndarray, tolerance: float):
        """Pieces (owner, f0, f1) that spread the second-order deviation evenly: cuts at equal steps of `_need`
        (piece count = its ceiling). Segments whose need, sampled at their ends and middle, is well under one
        piece stay whole (most moves of sliced G-code); the others are sampled finely."""
        rough = self._need(start, end, tolerance, 2)[:, -1]
        long = np.flatnonzero(rough > 0.5)
        total = np.zeros((len(start), CURVATURE_SAMPLES + 1))
        total[long] = self._need(start[long], end[long], tolerance, CURVATURE_SAMPLES)
        parts = np.maximum(1, np.ceil(total[:, -1])).astype(np.int64)
        owner = np.repeat(np.arange(len(start)), parts)
        rank = np.arange(len(owner)) - np.repeat(np.cumsum(parts) - parts, parts)
        target = total[owner, -1] * rank / parts[owner]  # the integral where each piece begins
        # Invert each row's increasing integral at once: rows shifted apart so one search serves them all.
        shift = (total[:, -1].max(initial=0.0) + 1.0) * np.arange(len(start))
        flat = (total + shift[:, None]).ravel()
        k = np.clip(np.searchsorted(flat, target + shift[owner], side="right") - 1,
                    owner * (CURVATURE_SAMPLES + 1), owner * (CURVATURE_SAMPLES + 1) + CURVATURE_SAMPLES - 1)
        lo, hi = flat[k], flat[k + 1]
        within = np.divide(target + shift[owner] - lo, hi - lo, out=np.zeros(len(k)), where=hi > lo)
        f0 = np.where(rank == 0, 0.0, (k % (CURVATURE_SAMPLES + 1) + within) / CURVATURE_SAMPLES)
        f1 = np.append(f0[1:], 1.0)
        f1[np.cumsum(parts) - 1] = 1.0
        return owner, f0, f1

    def _deviation(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """(n,) the largest distance from the straight piece of the effector under linearly moving carriages,
        measured at CHECK_POINTS - 1 interior points through the forward kinematics."""
        c0, c1 = self.to_motor(start)[:, :3], self.to_motor(end)[:, :3]
        t = np.arange(1, CHECK_POINTS) / CHECK_POINTS
        p = self._effector((c0[:, None, :] + t[None, :, None] * (c1 - c0)[:, None, :]).reshape(-1, 3))
        a, ab = start[:, None, :3], (end - start)[:, None, :3]
        p = p.reshape(len(start), len(t), 3) - a
        along = np.clip(np.einsum("nkj,nkj->nk", p, ab) / np.einsum("nkj,nkj->nk", ab, ab), 0.0, 1.0)
        return np.linalg.norm(p - along[:, :, None] * ab, axis=2).max(axis=1)

    def subdivide(self, segments: Segments, tolerance: float) -> Segments:
        """Cut every straight move so that moving the carriages linearly between the cuts keeps the effector
        within `tolerance` of the line. First cuts from the carriages' curvature (`_first_cuts`), then every
        piece is measured through the forward kinematics (`_deviation`) and the ones still too far out are cut
        evenly into ceil(sqrt(deviation / (AIM * tolerance))) parts, until every piece has measured within
        ACCEPT * tolerance (the margin covers a peak between measured points: the deviation of a short piece is
        a near-parabolic bump, whose peak exceeds the largest of 15 evenly spaced samples by 1/256 at most).
        Raises when pieces are still too coarse after ROUNDS rounds, or a move leaves the reachable region."""
        delta = segments.end[:, :3] - segments.start[:, :3]
        moving = np.flatnonzero(np.any(delta[:, :2] != 0.0, axis=1))  # vertical moves keep carriages linear
        owner, f0, f1 = self._first_cuts(segments.start[moving], segments.end[moving], tolerance)
        owner = moving[owner]
        todo = np.ones(len(owner), dtype=bool)
        for _ in range(ROUNDS):
            error = np.zeros(len(owner))
            error[todo] = self._deviation(self._points(segments, owner[todo], f0[todo]),
                                          self._points(segments, owner[todo], f1[todo]))
            bad = error > ACCEPT * tolerance
            if not np.any(bad):
                break
            parts = np.where(bad, np.ceil(np.sqrt(error / (AIM * tolerance))), 1).astype(np.int64)
            piece = np.repeat(np.arange(len(owner)), parts)
            rank = np.arange(len(piece)) - np.repeat(np.cumsum(parts) - parts, parts)
            width = (f1 - f0)[piece] / parts[piece]
            owner, todo = owner[piece], bad[piece]
            f0, f1 = f0[piece] + rank * width, np.where(rank == parts[piece] - 1, f1[piece],
                                                         f0[piece] + (rank + 1) * width)
        else:
            raise ArithmeticError(f"delta moves: {int(bad.sum())} pieces still stray more than {tolerance} mm "
                                  f"after {ROUNDS} rounds of cuts")
        keep = np.ones(len(segments), dtype=bool)
        keep[moving] = False
        whole = np.flatnonzero(keep)
        owner = np.concatenate([owner, whole])
        f0, f1 = np.concatenate([f0, np.zeros(len(whole))]), np.concatenate([f1, np.ones(len(whole))])
        order = np.lexsort((f0, owner))
        owner, f0, f1 = owner[order], f0[order], f1[order]
        jerk = np.where((f0 > 0.0)[:, None], np.nan, segments.jerk[owner])  # only where a move starts
        return segments.take(owner, start=self._points(segments, owner, f0),
                             end=self._points(segments, owner, f1), jerk=jerk)

    @staticmethod
    def _points(segments: Segments, owner: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Points at fractions `f` along segments `owner`; the segments' own ends exactly at 0 and 1."""
        start, end = segments.start[owner], segments.end[owner]
        point = start + f[:, None] * (end - start)
        point[f == 1.0] = end[f == 1.0]
        return point

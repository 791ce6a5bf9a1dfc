"""Checks on a pulse train (the twin's, or the simulator's): positions, path, motor rates and accelerations.

The same functions judge the twin against the plan (`build`) and the simulated pulses (`verify`).
- Positions: each motor's final position equals the job's end point rounded once.
- Path: after every step the tool lies within 1 step + tolerance of the job's path (lines exactly, arcs by
  their radius at the tool's angle (a spiral's grows with it), other curves by the true curve sampled 16 times
  along every chord).
- Rate: over any 8 consecutive steps no motor exceeds max_velocity * steps_per_mm.
- Acceleration: the velocity change between consecutive 20 ms windows stays within max_accel * 20 ms, plus the
  velocity jumps the junction model plans at corners inside those windows, plus one step of quantisation at
  each window edge (positions are interpolated between step times).
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass, field, replace

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.planner import Plan, segment_lengths
from codegen.native import contiguous, library, pointer
from codegen.tables.motor_checks import AccelCheck, RateCheck
from codegen.toolpath.segments import REF_ARC, Segments, concat

CHUNK = 1 << 20
ADVANCE_LIMIT_STEPS = 1.0  # how far an advanced extruder's pulse may be from the pressure advance formula


@dataclass
class MotorTrain:
    """One motor's pulses: times (s, on the plan's clock) and directions."""

    time: np.ndarray
    dir: np.ndarray


@dataclass
class Findings:
    final: dict[str, int]
    expected_final: dict[str, int]
    steps: dict[str, int]
    max_path_error_mm: float
    path_limit_mm: float
    rate_ratio: dict[str, float]  # highest 8-step rate / limit
    accel_ratio: dict[str, float]  # highest window velocity change / what is allowed
    problems: list[str] = field(default_factory=list)
    # Input shaping's (codegen/motion/shaped_motion.py `smoothing`): the largest distance of the shaped tool from
    # the planned one at the same moment, the planned point there and its G-code line (0: none); None: unshaped.
    smoothing_mm: float | None = None
    smoothing_at: tuple[float, ...] | None = None
    smoothing_line: int = 0
    # Pressure advance's (codegen/motion/advance.py): the largest distance (steps) of Klipper's formula from the
    # extruder's position at a pulse, when (s) and its G-code line; None: no pressure advance.
    advance_steps: float | None = None
    advance_time_s: float = 0.0
    advance_line: int = 0

    @property
    def ok(self) -> bool:
        return not self.problems


def step_length_mm(kin: Kinematics) -> float:
    """The tool's allowance for stepping: one step of the coarsest motor (two carriages' on a delta)."""
    return kin.path_quantum()


def chord_distance(p: np.ndarray, s: np.ndarray, segments: Segments,
                   clamp: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Distance (xyz) from points p (N, 3) to their straight segments s (N,) (to their lines when not
    `clamp`), and the nearest points."""
    a, b = segments.start[s, :3], segments.end[s, :3]
    ab = b - a
    denom = np.einsum("ij,ij->i", ab, ab)
    t = np.divide(np.einsum("ij,ij->i", p - a, ab), denom, out=np.zeros(len(s)), where=denom > 0)
    nearest = a + (np.clip(t, 0.0, 1.0) if clamp else t)[:, None] * ab
    return np.linalg.norm(p - nearest, axis=1), nearest


def fine_distance(p: np.ndarray, fine: np.ndarray) -> np.ndarray:
    """Distance from points (N, 3) to polylines (N, K + 1, 3) through the true curve."""
    a, b = fine[:, :-1], fine[:, 1:]
    ab = b - a
    denom = np.einsum("nkj,nkj->nk", ab, ab)
    t = np.clip(np.divide(np.einsum("nkj,nkj->nk", p[:, None, :] - a, ab), denom, out=np.zeros(denom.shape),
                          where=denom > 0), 0.0, 1.0)
    return np.linalg.norm(p[:, None, :] - (a + t[..., None] * ab), axis=2).min(axis=1)


def reference_distance(p: np.ndarray, s: np.ndarray, segments: Segments) -> np.ndarray:
    """Distance (mm, xyz) from points p (N, 3) to the job's path along segments s: lines exactly, arcs by
    their radius, other curves by their samples."""
    dist, on_chord = chord_distance(p, s, segments)
    curve = np.flatnonzero(segments.ref_fine[s] >= 0)
    if len(curve):
        dist[curve] = fine_distance(p[curve], segments.fine[segments.ref_fine[s[curve]]])
    arc = np.flatnonzero(segments.ref_kind[s] == REF_ARC)
    if len(arc):
        plane = segments.ref_plane[s[arc]]
        rows = np.arange(len(arc))
        pu = p[arc, plane[:, 0]] - segments.ref_center[s[arc], 0]
        pv = p[arc, plane[:, 1]] - segments.ref_center[s[arc], 1]
        turn = np.arctan2(pv, pu) - segments.ref_angle[s[arc]]
        turn -= 2.0 * np.pi * np.rint(turn / (2.0 * np.pi))  # within half a turn: the tool is near its chord
        radius = segments.ref_radius[s[arc]] + segments.ref_growth[s[arc]] * turn
        radial = np.abs(np.hypot(pu, pv) - radius)
        off_plane = p[arc] - on_chord[arc]
        off_plane[rows, plane[:, 0]] = 0.0
        off_plane[rows, plane[:, 1]] = 0.0
        dist[arc] = np.hypot(radial, np.linalg.norm(off_plane, axis=1))
    return dist


def path_errors(axes: np.ndarray, seg: np.ndarray, segments: Segments, near: float = 0.0) -> np.ndarray:
    """Distance (mm, xyz) from each position to the job's path: its own segment, or for positions further
    than `near` from it, either neighbour too (a step just past a corner is measured against the path it is
    on). In C (codegen/native/pathcheck.c) where the helper could be built."""
    lib = library("pathcheck")
    if lib is None or len(segments) == 0:
        return path_errors_numpy(axes, seg, segments, near)
    return _native_path_errors(lib, np.ascontiguousarray(axes, dtype=np.float64), None, seg, segments, near)


def step_path_errors(steps: np.ndarray, origin: np.ndarray, kin: Kinematics, seg: np.ndarray,
                     segments: Segments, near: float = 0.0) -> np.ndarray:
    """`path_errors` of motor positions in steps (less `origin`; axes no motor drives taken from each position's
    segment). Linear kinematics map the steps to axes in C as well."""
    lib = library("pathcheck")
    if lib is None or not kin.linear or len(segments) == 0:
        axes = kin.to_axes((steps + origin) / kin.limits.steps_per_mm, segments.start[seg])
        return path_errors(axes, seg, segments, near)
    to_axes = np.zeros((4, len(kin.motors)))
    to_axes[kin.driven_axes] = kin.inverse / kin.limits.steps_per_mm[None, :]
    return _native_path_errors(lib, None, (*contiguous(np.int64, steps, origin), to_axes), seg, segments, near)


def _native_path_errors(lib, axes, steps, seg, segments: Segments, near: float) -> np.ndarray:
    start, end, center, radius, angle, growth, fine = contiguous(
        np.float64, segments.start, segments.end, segments.ref_center, segments.ref_radius, segments.ref_angle,
        segments.ref_growth, segments.fine)
    seg, kind, plane, fine_row = contiguous(np.int64, seg, segments.ref_kind, segments.ref_plane, segments.ref_fine)
    out = np.empty(len(seg))
    steps, origin, to_axes = (None, None, None) if steps is None else steps
    motors = 0 if steps is None else steps.shape[1]
    to_axes = None if to_axes is None else contiguous(np.float64, to_axes)[0]
    lib.path_errors(ctypes.c_int64(len(seg)), pointer(axes), pointer(steps), ctypes.c_int64(motors),
                    pointer(origin), pointer(to_axes), pointer(seg), ctypes.c_double(near),
                    ctypes.c_int64(len(segments)),
                    *map(pointer, (start, end, kind, center, radius, angle, growth, plane, fine_row, fine)),
                    ctypes.c_int64(segments.fine.shape[1]), pointer(out))
    return out


def path_errors_numpy(axes: np.ndarray, seg: np.ndarray, segments: Segments, near: float = 0.0) -> np.ndarray:
    """`path_errors`, vectorised."""
    out = np.empty(len(axes))
    last = len(segments) - 1
    for lo in range(0, len(axes), CHUNK):
        p, s = axes[lo:lo + CHUNK, :3], seg[lo:lo + CHUNK]
        dist = reference_distance(p, s, segments)
        far = np.flatnonzero(dist > near)
        for k in (-1, 1):
            dist[far] = np.minimum(dist[far], reference_distance(p[far], np.clip(s[far] + k, 0, last), segments))
        out[lo:lo + CHUNK] = dist
    return out


def corner_jumps(plan: Plan, segments: Segments, kin: Kinematics) -> tuple[np.ndarray, np.ndarray]:
    """Times (s) of corners and each motor's planned velocity jump there (steps/s), (J,) and (J, M)."""
    j = np.flatnonzero(plan.corner[1:-1] & (plan.v_entry[1:] > 0)) + 1
    change = plan.direction[j] - plan.direction[j - 1]
    corner_points = segments.start[j]
    jump = plan.v_entry[j][:, None] * kin.motor_factors(change, corner_points) * kin.limits.steps_per_mm[None, :]
    return plan.t_start[j], jump


class Checker:
    """The checks over a pulse train that comes a window at a time (the motor checks carry what they need of
    the windows before); `findings` once the train has ended."""

    def __init__(self, kin: Kinematics, start_steps: np.ndarray, tolerance: float,
                 max_smoothing: float | None = None):
        """`max_smoothing` (mm): the input shaper's smoothing allowed (None: any)."""
        self.kin, self.start_steps = kin, np.asarray(start_steps, dtype=np.int64)
        self.max_smoothing = max_smoothing
        self.smoothing: tuple[float, tuple[float, ...], int] | None = None  # the worst so far: mm, where, line
        self.advance: tuple[float, float, int] | None = None  # the worst so far: steps, when, line
        spm = kin.limits.steps_per_mm
        self.rates = [RateCheck(float(r)) for r in kin.limits.max_rate]
        self.accels = [AccelCheck(float(a)) for a in kin.limits.max_accel * spm]
        self.steps = np.zeros(len(kin.motors), dtype=np.int64)
        self.net = np.zeros(len(kin.motors), dtype=np.int64)
        self.path_limit = step_length_mm(kin) + tolerance
        self.worst_path, self.worst_at, self.worst_line = 0.0, None, 0  # and its G-code line (0: none)
        self.blocks = 0  # blocks whose tool add_tool has compared
        self.tool_problem: str | None = None  # the first block whose tool differs from the program's

    def add(self, trains: list[MotorTrain], positions: np.ndarray, position_segment: np.ndarray,
            segments: Segments, corners_t: np.ndarray, jumps: np.ndarray, last: bool = False) -> list:
        """`positions` (P, M): motor steps (relative to the start) after each event (the pulses one interrupt
        makes together); `position_segment` (P,): the segment (of `segments`) each event belongs to;
        `corners_t`, `jumps`: the plan's corners in these pulses' time (`corner_jumps`). Returns, per motor,
        the rate hits (index of the pulse ending 8 fast steps, ratio) and the acceleration hits (start of
        the windows, ratio)."""
        spm = self.kin.limits.steps_per_mm
        for lo in range(0, len(positions), CHUNK):  # in chunks: the positions of a print are millions of rows
            seg, steps = position_segment[lo:lo + CHUNK], positions[lo:lo + CHUNK]
            errors = step_path_errors(steps, self.start_steps, self.kin, seg, segments, near=0.5 * self.path_limit)
            worst = int(np.argmax(errors))
            if errors[worst] > self.worst_path or self.worst_at is None:
                one = slice(worst, worst + 1)
                at = self.kin.to_axes((steps[one] + self.start_steps) / spm, segments.start[seg[one]])
                self.worst_path, self.worst_at = float(errors[worst]), at[0, :3]
                self.worst_line = int(segments.line[seg[worst]])
        hits = []
        for m, train in enumerate(trains):
            self.steps[m] += len(train.time)
            self.net[m] += int(train.dir.sum())
            rate = self.rates[m].add(train.time)
            accel = self.accels[m].add(train.time, train.dir, corners_t, jumps[:, m], last)
            hits.append((rate, accel))
        return hits

    def add_smoothing(self, mm: float, at: np.ndarray, line: int) -> None:
        """A shaped stretch's smoothing, its planned point and G-code line."""
        if self.smoothing is None or mm > self.smoothing[0]:
            self.smoothing = (float(mm), tuple(float(c) for c in at), int(line))

    def add_advance(self, steps: float, time: float, line: int) -> None:
        """An advanced extruder's largest distance from the formula in a stretch, when and its G-code line."""
        if self.advance is None or steps > self.advance[0]:
            self.advance = (float(steps), float(time), int(line))

    def add_tool(self, tables: np.ndarray, program: np.ndarray) -> None:
        """The tool of the next blocks as the tables have it against the program's (its segments' flags): the
        compressor carries a block's tool over from its segment, and nothing after it checks that it did."""
        wrong = np.flatnonzero(np.asarray(tables, dtype=bool) != np.asarray(program, dtype=bool))
        if len(wrong) and self.tool_problem is None:
            k = int(wrong[0])
            self.tool_problem = (f"the tables have the tool {'on' if tables[k] else 'off'} in block {self.blocks + k} "
                                 f"where the program has it {'on' if program[k] else 'off'} ({len(wrong)} blocks "
                                 f"of {len(tables)} in this window differ)")
        self.blocks += len(tables)

    def findings(self, expected_final: np.ndarray) -> Findings:
        names = self.kin.motors
        final = self.net + self.start_steps
        findings = Findings(
            final=dict(zip(names, final.tolist())),
            expected_final=dict(zip(names, np.asarray(expected_final).tolist())),
            steps=dict(zip(names, self.steps.tolist())),
            max_path_error_mm=self.worst_path,
            path_limit_mm=self.path_limit,
            rate_ratio={n: c.worst for n, c in zip(names, self.rates)},
            accel_ratio={n: c.worst for n, c in zip(names, self.accels)},
        )
        if self.smoothing is not None:
            findings.smoothing_mm, findings.smoothing_at, findings.smoothing_line = self.smoothing
        if self.advance is not None:
            findings.advance_steps, findings.advance_time_s, findings.advance_line = self.advance
            if self.advance[0] > ADVANCE_LIMIT_STEPS:
                findings.problems.append(
                    f"motor e (the extruder) is {self.advance[0]:.2f} steps from the pressure advance formula (limit "
                    f"{ADVANCE_LIMIT_STEPS:g} step) at {self.advance[1]:.4f} s"
                    + (f" on G-code line {self.advance[2]}" if self.advance[2] else ""))
        for name, got, want in zip(names, final, expected_final):
            if got != want:
                findings.problems.append(f"motor {name} ends at step {got}, the job ends at step {want}")
        if self.worst_at is not None and self.worst_path > self.path_limit + 1e-9:
            findings.problems.append(
                f"the tool strays {self.worst_path:.4f} mm from the path (limit {self.path_limit:.4f} mm: "
                f"1 step + tolerance) at ({', '.join(f'{c:.3f}' for c in self.worst_at)})"
                + (f" on G-code line {self.worst_line}" if self.worst_line else ""))
        if self.tool_problem is not None:
            findings.problems.append(self.tool_problem)
        if self.smoothing is not None and self.max_smoothing is not None and self.smoothing[0] > self.max_smoothing:
            mm, at, line = self.smoothing
            findings.problems.append(
                f"the input shaper smooths the path by {mm:.4f} mm, more than machine.input_shaper.max_smoothing "
                f"({self.max_smoothing:g} mm), at ({', '.join(f'{c:.3f}' for c in at)})"
                + (f" on G-code line {line}" if line else "") + ": a higher shaper frequency, a shaper with less "
                "smoothing (zv, mzv), or a lower acceleration there")
        for name in names:
            rate, accel = findings.rate_ratio[name], findings.accel_ratio[name]
            if rate > 1.0:
                findings.problems.append(f"motor {name} exceeds its rate over 8 steps by {100 * (rate - 1):.1f} %")
            if accel > 1.0:
                findings.problems.append(f"motor {name} exceeds its acceleration by {100 * (accel - 1):.1f} %")
        return findings


def check(trains: list[MotorTrain], positions: np.ndarray, position_segment: np.ndarray,
          segments: Segments, plan: Plan, kin: Kinematics, expected_final: np.ndarray,
          start_steps: np.ndarray, tolerance: float, warp=None) -> Findings:
    """The checks of a whole train at once (the simulator's); `warp` maps the plan's times onto the train's
    clock where a feed hold dilated it (its corners come later)."""
    checker = Checker(kin, start_steps, tolerance)
    corners_t, jumps = corner_jumps(plan, segments, kin)
    if warp is not None:
        corners_t = warp(corners_t)
    checker.add(trains, positions, position_segment, segments, corners_t, jumps, last=True)
    return checker.findings(expected_final)


def corners_after(plan, segments: Segments, last: Segments | None, kin: Kinematics) -> tuple[np.ndarray, np.ndarray]:
    """The corners (`corner_jumps`) of a stretch of the plan, the one where it meets the stretch before (whose last
    segment is `last`) included."""
    if last is None or len(plan.duration) == 0 or not (plan.corner[0] and plan.v_entry[0] > 0):
        return corner_jumps(plan, segments, kin)
    _, before = segment_lengths(last)
    joined = concat(last, segments)
    both = replace(plan, direction=np.concatenate([before, plan.direction]),
                   v_entry=np.concatenate([[0.0], plan.v_entry]),
                   t_start=np.concatenate([[plan.t_start[0]], plan.t_start]),
                   corner=np.concatenate([[True], plan.corner]))
    return corner_jumps(both, joined, kin)

"""The played tables against the job's G-code, read a second time (codegen/verify/gcode_reference.py) and put
through the machine's kinematics as JOB-FORMAT.md states them (not the planner's code): every line ends where the
program says, no line is done faster than its feed allows, every arc stays on the program's circle (a spiral
from the start's radius to the end's where the end is off the circle) and turns its way, every G4 dwells as long
as it says. The front end and the planner are the code under test here: a reading of G20, G92, an R arc or an F
word that both they and the twin share shows up nowhere else.

With input shaping the tool follows the program convolved with the shapers: it passes within the plan's reported
smoothing of every point (codegen/motion/shaped_motion.py), so ends, feeds and arcs get that much more room, and a
G4's rest is shorter by the shapers' spread (the motion before and after it overlaps it), none where it is shorter.

Each played event belongs to a segment and so to a G-code line (Segments.line). A line's last event is where its
move ends (to a step: the stepper rounds each motor once); from the line's last event before it, the move takes at
least its length over its speed, give or take a step at either end; an arc's length there is the shortest its
chords may add up to within the machine's `tolerance` (Grbl's $12: the firmware runs each chord at F).
"""

from __future__ import annotations

import math

import numpy as np

from codegen.verify.gcode_reference import Dwell, Move, Reading

STEP_SLACK = 1  # steps a line's end may differ from the reference's (a tie rounded the other way)
ARC_SLACK_STEPS = 1.5  # steps beyond the chord tolerance an arc's event may lie off its circle
SWEEP_SLACK_RAD = 0.02  # beyond a step's angle, how far an arc's turn may differ from the program's
DWELL_SLACK_S = 1e-6
TIME_SLACK = 1e-6  # relative: the plan's times are float sums


class MachineGeometry:
    """The motors' positions (steps) of tool positions (mm), from the job's machine as JOB-FORMAT.md defines its
    kinematics: cartesian x, y, z; corexy a = x + y, b = x - y; a delta's carriage i at
    z + sqrt(rod^2 - |(x, y) - T_i|^2), tower i at radius (cos angle_i, sin angle_i)."""

    def __init__(self, machine, motors: tuple[str, ...]):
        self.kind = machine.kinematics
        self.index = [k for k, name in enumerate(motors) if name != "e"]  # the motors x, y and z drive
        self.spm = np.array([float(machine.steppers[motors[k]].steps_per_mm) for k in self.index])
        if self.kind == "delta":
            angles = np.radians(np.asarray(machine.delta.tower_angles, dtype=float))
            self.towers = machine.delta.radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
            self.rod = float(machine.delta.diagonal_rod)
        self.names = [motors[k] for k in self.index]

    def steps(self, xyz: np.ndarray) -> np.ndarray:
        """(N, 3) mm -> (N, len(index)) whole steps."""
        if self.kind == "delta":
            reach = xyz[:, None, :2] - self.towers[None]
            coords = xyz[:, 2:3] + np.sqrt(self.rod ** 2 - np.sum(reach * reach, axis=2))
        elif self.kind == "corexy":
            coords = np.column_stack([xyz[:, 0] + xyz[:, 1], xyz[:, 0] - xyz[:, 1], xyz[:, 2]])
        else:
            coords = xyz
        return np.round(coords[:, :len(self.index)] * self.spm).astype(np.int64)

    def motor_per_mm(self, xyz: np.ndarray) -> np.ndarray:
        """(len(index),) the most mm each motor moves per mm of the tool near point `xyz` (3,): a corexy belt
        sqrt(2) (it sums x and y); a delta's carriage rod / height over the tool (its horizontal reach tilts the
        rod: more near the edge)."""
        if self.kind == "delta":
            reach = xyz[None, :2] - self.towers
            height = np.sqrt(np.maximum(self.rod ** 2 - np.sum(reach * reach, axis=1), 1e-12))
            return np.maximum(self.rod / height, 1.0)[:len(self.index)]
        return np.full(len(self.index), math.sqrt(2.0) if self.kind == "corexy" else 1.0)

    def tool(self, steps: np.ndarray) -> np.ndarray | None:
        """(N, len(index)) steps -> (N, 3) mm on a linear machine (None on a delta); a missing z stays 0."""
        if self.kind == "delta":
            return None
        coords = np.zeros((len(steps), 3))
        coords[:, :steps.shape[1]] = steps / self.spm
        if self.kind == "corexy":
            a, b = coords[:, 0].copy(), coords[:, 1].copy()
            coords[:, 0], coords[:, 1] = (a + b) / 2, (a - b) / 2
        return coords

    def step_mm(self) -> float:
        """A generous bound on the path one step of the leading motor stands for (a delta's near its edge: more)."""
        return (10.0 if self.kind == "delta" else 2.0) / float(self.spm.min())


def gcode_start(host) -> np.ndarray:
    """Where the G-code begins: the job's explicit `start` (a machine that homes at power-up travels there from its
    home first), else where the program starts (its home, or the origin)."""
    start = np.array(host.start[:3], dtype=float)
    if host.job.program.start_source is not None:
        given = [float(v) for v in host.job.program.start]
        start[:len(given)] = given
    return start


class ProgramCheck:
    """Fed a chapter at a time (codegen/verify/compare.py); `problems` once the last has come."""

    def __init__(self, host):
        job = host.job
        self.active = bool(job.program.gcode) and not job.program.shapes
        self.geometry = MachineGeometry(job.machine, host.kin.motors)
        self.reading = Reading(job, gcode_start(host)) if self.active else None
        self.start_steps = np.asarray(host.start_steps)[self.geometry.index]
        self.tolerance = host.settings.stages.tolerance_mm
        self.smoothing = float(host.findings.smoothing_mm or 0.0) if host.shaped else 0.0  # mm
        self.spread = max((s.spread for s in host.shapings if s is not None), default=0.0)  # s, the longest era's
        self.moves: dict[int, Move] = {}
        self.dwells: dict[int, Dwell] = {}
        self.open_run: tuple | None = None  # (line, position, time) of the last run so far: it may go on
        self.run_began = -math.inf  # the time of the run's last event before the open one
        self.arc_events: list = []  # the open run's arc positions (steps) when it is an arc
        self.problems: list[str] = []
        self.checked = {"ends": 0, "feeds": 0, "arcs": 0, "dwells": 0}

    def add(self, chapter) -> None:
        if not self.active:
            return
        segments, pulses = chapter.segments, chapter.pulses
        for record in self.reading.upto(int(segments.line.max(initial=0))):
            (self.moves if isinstance(record, Move) else self.dwells)[record.line] = record
        self._dwells(segments, chapter.plan.duration)
        if not len(pulses.event_tick):
            return
        line = segments.line[chapter.event_segments()]
        position = pulses.event_position[:, self.geometry.index] + self.start_steps
        time = chapter.events.time
        ends = np.flatnonzero(line[1:] != line[:-1])
        first_line = int(line[0])
        if self.open_run is not None and self.open_run[0] != first_line:
            self._close()
        for k, end in enumerate(ends):
            begin = 0 if k == 0 else ends[k - 1] + 1
            self._extend(int(line[end]), position[begin:end + 1], float(time[end]))
            self._close()
        begin = ends[-1] + 1 if len(ends) else 0
        self._extend(int(line[-1]), position[begin:], float(time[-1]))
        if chapter.last:
            self._close()

    def _extend(self, line: int, positions: np.ndarray, time: float) -> None:
        """The events of a line's run (which the open run may have begun)."""
        move = self.moves.get(line)
        if move is not None and move.arc is not None:
            self.arc_events.append(positions)
        self.open_run = (line, positions[-1].copy(), time)

    def _close(self) -> None:
        """The open run is whole: its line's end, its time, its arc."""
        line, position, time = self.open_run
        move = self.moves.pop(line, None)
        if move is not None and line > 0:
            self._end(move, position)
            self._feed(move, time)
            if move.arc is not None and self.arc_events:
                self._arc(move, np.concatenate(self.arc_events))
        for old in [k for k in self.moves if k < line]:  # lines that made no step
            del self.moves[old]
        self.arc_events, self.open_run, self.run_began = [], None, time

    def _end(self, move: Move, position: np.ndarray) -> None:
        if any(math.isnan(v) for v in move.end):
            return
        want = self.geometry.steps(np.array([move.end]))[0]
        self.checked["ends"] += 1
        # The shaped tool's distance from the planned one, in each motor's steps there.
        slack = STEP_SLACK + self.smoothing * self.geometry.motor_per_mm(np.array(move.end)) * self.geometry.spm
        if np.any(np.abs(position - want) > slack):
            self.problems.append(
                f"{_at(move)}: the tables end the move at steps {_steps(self.geometry, position)} where the "
                f"program's end, {_mm(move.end)} in machine mm, gives {_steps(self.geometry, want)}" + _offsets(move))

    def _feed(self, move: Move, time: float) -> None:
        length, chords = move.length(), move.length(self.tolerance)
        if move.speed is None or math.isnan(length) or not math.isfinite(self.run_began):
            return
        least = (chords - 2 * self.geometry.step_mm() - 2 * self.smoothing) / move.speed * (1 - TIME_SLACK)
        took = time - self.run_began
        self.checked["feeds"] += least > 0
        if least > 0 and took < least:
            drawn = f" along chords of {chords:.3f} mm" if chords < length else ""
            self.problems.append(
                f"{_at(move)}: the move of {length:.3f} mm takes {took:.4f} s in the plan, faster than its feed "
                f"of {move.speed * 60:.1f} mm/min allows{drawn} ({least:.4f} s or more)")

    def _arc(self, move: Move, steps: np.ndarray) -> None:
        tool = self.geometry.tool(steps)
        if tool is None or any(math.isnan(v) for v in (*move.start, *move.end)):
            return
        centre, radius, (u, v), _, sweep, end_radius = move.arc
        path = np.vstack([[move.start[u], move.start[v]], tool[:, [u, v]], [move.end[u], move.end[v]]])
        angle = np.unwrap(np.arctan2(path[:, 1] - centre[1], path[:, 0] - centre[0]))
        along = np.clip((angle[1:-1] - angle[0]) / sweep, 0.0, 1.0)  # of the sweep, where each event is
        off = np.hypot(tool[:, u] - centre[0], tool[:, v] - centre[1]) - (radius + (end_radius - radius) * along)
        limit = self.tolerance + ARC_SLACK_STEPS / float(self.geometry.spm.min()) + self.smoothing
        self.checked["arcs"] += 1
        worst = int(np.argmax(np.abs(off)))
        if abs(off[worst]) > limit:
            shape = f"radius {radius:.3f} mm" + (f" to {end_radius:.3f} mm" if end_radius != radius else "")
            self.problems.append(
                f"{_at(move)}: the arc strays {abs(off[worst]):.4f} mm from the program's circle (centre "
                f"{centre[0]:.3f}, {centre[1]:.3f}, {shape}; limit {limit:.4f} mm) at {_mm(tool[worst])}")
            return
        turn = float(angle[-1] - angle[0])
        if abs(turn - sweep) > SWEEP_SLACK_RAD + limit / max(radius, 1e-9):
            self.problems.append(f"{_at(move)}: the arc turns {math.degrees(turn):.1f} degrees where the program's "
                                 f"turns {math.degrees(sweep):.1f}")

    def _dwells(self, segments, duration: np.ndarray) -> None:
        """Each G4's dwell in the plan lasts what its line says; shaped, within the shapers' spread either way: the
        shaped motion of the moves beside it runs into it, and where they do not move (or the program ends there)
        the shaped tool's rest takes in their time."""
        for k in np.flatnonzero(segments.dwell > 0):
            dwell = self.dwells.pop(int(segments.line[k]), None)
            if dwell is None:
                continue
            self.checked["dwells"] += 1
            low, high = dwell.seconds - self.spread - DWELL_SLACK_S, dwell.seconds + self.spread + DWELL_SLACK_S
            if not low <= float(duration[k]) <= high:
                self.problems.append(f"{_at(dwell)}: the plan dwells {float(duration[k]):.4f} s where the "
                                     f"program's G4 says {dwell.seconds:.4f} s")

    def finish(self) -> list[str]:
        """The problems, with the G4s the plan never dwelt at (a program read to its end)."""
        if self.active:
            for record in self.reading.upto(math.inf):
                if isinstance(record, Dwell):
                    self.dwells[record.line] = record
            self.problems += [f"{_at(d)}: the program's G4 dwells {d.seconds:.4f} s, the plan not at all"
                              for d in self.dwells.values() if d.seconds > self.spread]
        return self.problems


def _at(record: Move | Dwell) -> str:
    return f"G-code line {record.line} ({record.text})"


def _offsets(move: Move) -> str:
    """Where coordinate 0 is, when a G92 or a coordinate system moved it."""
    if not any(move.offsets):
        return ""
    return f" (with G92 and coordinate system offsets {_mm(move.offsets)})"


def _steps(geometry: MachineGeometry, steps: np.ndarray) -> str:
    return ", ".join(f"{name} {int(s)}" for name, s in zip(geometry.names, steps))


def _mm(xyz) -> str:
    return " ".join(f"{axis}{float(v):.3f}" for axis, v in zip("XYZ", xyz) if not math.isnan(float(v)))

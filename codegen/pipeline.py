"""The host side of a build, stage by stage: job -> toolpath -> segments -> plan -> events -> schedule -> twin.

Each stage is a function with a typed result; this module only composes them (and knows no CLI).
"""

from __future__ import annotations

import math
import time
from contextlib import contextmanager

from dataclasses import dataclass, replace

import numpy as np

from codegen.checks import Findings, MotorTrain, accel_ratios, check, corner_jumps, step_length_mm
from codegen.compress import Compressed, TimingWindow, compress
from codegen.errors import BuildError, Diagnostic, JobError
from codegen.firmware import FirmwareConfig, HomingAxis, MotorPins
from codegen.kinematics import make_kinematics
from codegen.kinematics.base import Kinematics
from codegen.planner import ACCEL_WINDOW_S, RATE_WINDOW, Plan, PlannerLimits, plan, segment_lengths
from codegen.stepgen import (Events, generate, quantisation_split, segment_steps, split_at, split_long,
                             staircase_bound, staircase_error)
from codegen.gcode import toolpath_from_gcode
from codegen.homing import home_position, homes, homing_axes
from codegen.shapes import build_toolpath as toolpath_from_shapes
from codegen.curve_timing import smooth_curve_times
from codegen.targets import TargetInfo, target_info
from codegen.segments import Segments, flatten
from codegen.toolpath import Arc, Curve, Home, Line, Toolpath
from codegen.twin import Pulses, predict

STAIRCASE_LIMIT = 0.85  # steps: blocks whose Bresenham staircase strays further from their segment are cut
REFINE_ROUNDS = 4
REACH_SAMPLES = 16  # points along each piece where the kinematics is not linear
RATE_ROUNDS = 8  # plans at most: a stretch over a motor's rate or acceleration slows its segments, plans again
RETRY_SHARE = 0.95  # of the rate and acceleration those segments (and their neighbours) then aim at


@dataclass
class HostBuild:
    job: object
    target: TargetInfo
    kin: Kinematics
    toolpath: Toolpath
    segments: Segments
    plan: Plan
    events: Events
    compressed: Compressed
    pulses: Pulses
    findings: Findings
    start_steps: np.ndarray
    expected_final: np.ndarray
    warnings: list[Diagnostic]
    homing: tuple[HomingAxis, ...]  # the motors the firmware homes at power-up

    @property
    def schedule(self):
        return self.compressed.schedule

    def firmware_config(self) -> FirmwareConfig:
        steppers = self.job.machine.steppers
        return FirmwareConfig(
            job_name=self.job.name,
            job_file=self.job.path.name,
            target=self.target.target,
            board=self.target.board,
            motors=tuple(MotorPins(m, self.kin.socket(m), bool(steppers[m].invert_dir)) for m in self.kin.motors),
            step_pulse_us=self.job.machine.step_pulse_us,
            dir_setup_us=self.job.machine.dir_setup_us,
            homing=self.homing,
            start_steps=tuple(int(v) for v in self.start_steps),
        )

    def event_segments(self) -> np.ndarray:
        """The segment every event belongs to."""
        block = np.searchsorted(self.events.block_first, np.arange(len(self.events.time)), side="right") - 1
        return self.events.block_segment[block]


def build_toolpath(job, strict: bool = False) -> tuple[Toolpath, list[Diagnostic], bool]:
    """The program's toolpath, the warnings its front end gave, and whether it starts by homing (G28)."""
    if job.program.shapes:
        return toolpath_from_shapes(job), [], False
    toolpath, warnings = toolpath_from_gcode(job, strict)
    toolpath, homes_first = settle_homes(toolpath)
    return toolpath, warnings, homes_first


def homed_toolpath(job, kin: Kinematics, strict: bool = False) -> tuple[Toolpath, list[Diagnostic], bool]:
    """`build_toolpath` for a machine that homes at power-up whatever its program says (a delta, or
    `program.home`): the program starts where homing leaves the tool. An explicit `program.start` there is
    where the program begins after a tool-off travel move from the home position."""
    home = home_position(job, kin)
    source = job.program.start_source
    start = home.copy()
    if source is not None:
        start[:len(job.program.start)] = [float(v) for v in job.program.start]
    anchored = job.model_copy(update={"program": job.program.model_copy(update={"start": tuple(start[:3])})})
    toolpath, warnings, homes_first = build_toolpath(anchored, strict)
    if not homes_first and np.linalg.norm(start - home) > 1e-9:
        feed = math.inf if job.program.travel_feed is None else job.program.travel_feed / 60.0
        toolpath.items.insert(0, Line(home, start.copy(), feed, False, source, "travel"))
        toolpath.start = home
    if job.machine.kinematics == "delta" and toolpath.items:
        toolpath.items[:1] = descend_first(toolpath.items[0], home)
    return toolpath, warnings, homes_first


def descend_first(item, home: np.ndarray) -> list:
    """A delta's carriages stand at their tops once homed: the travel away from home goes straight down to its
    end's height first (every carriage moves down alike), then across."""
    if not (isinstance(item, Line) and not item.tool and np.allclose(item.start, home)):
        return [item]
    below = home.copy()
    below[2] = item.end[2]
    if item.end[2] >= home[2] or np.allclose(below[:2], item.end[:2]):
        return [item]
    return [replace(item, end=below), replace(item, start=below)]


def settle_homes(toolpath: Toolpath) -> tuple[Toolpath, bool]:
    """Homing before the first move is the firmware's (at power-up) and says where the program starts. A
    later one becomes a straight tool-off move to the home position: where the machine is afterwards (homing
    in the middle of a table is not supported yet). Also says whether the program homes first."""
    start, items, here, first = toolpath.start, [], None, False
    for item in toolpath.items:
        if isinstance(item, Home):
            if here is None:
                start, first = item.position, True
                continue
            item = Line(here, item.position, math.inf, False, item.source, "home")
        if isinstance(item, (Line, Arc, Curve)):
            here = item.end
        items.append(item)
    return Toolpath(np.asarray(start, dtype=float), items), first


def drop_empty(segments: Segments) -> Segments:
    """Remove moves of zero length (nothing to plan, nothing to step)."""
    length, _ = segment_lengths(segments)
    keep = (length > 0) | (segments.dwell > 0)
    if np.all(keep):
        return segments
    return segments.take(np.flatnonzero(keep))


def trains_from(pulse_time: np.ndarray, motor: np.ndarray, direction: np.ndarray, motors: int) -> list[MotorTrain]:
    return [MotorTrain(pulse_time[motor == m], direction[motor == m]) for m in range(motors)]


def refine(segments: Segments, kin: Kinematics) -> Segments:
    """Cut the blocks whose Bresenham staircase strays too far from their segment (the rounding of a block's
    two ends can tilt it): a few rounds, each looking only at the pieces the previous round cut."""
    limit = STAIRCASE_LIMIT * step_length_mm(kin)
    look = np.flatnonzero(staircase_bound(segments, kin) > limit)  # the others provably stay close
    for _ in range(REFINE_ROUNDS):
        bad = look[staircase_error(segments, kin, look) > limit]
        if len(bad) == 0:
            break
        segments = split_at(segments, bad, quantisation_split(segments, kin, bad))
        pieces = bad + np.arange(len(bad))  # where the cut segments' first halves now stand
        look = np.concatenate([pieces, pieces + 1])
    return segments


def check_reach(job, kin: Kinematics, toolpath: Toolpath, segments: Segments) -> None:
    """Every point of the path reachable and within each motor's `range`: an error at the shape or G-code
    line that leaves it (the first point of each; at most 20), before anything is built."""
    if not len(segments):
        return
    # Every piece's end; where motors are not linear in the axes (a delta's carriages rise and fall along a
    # straight line) also points along each piece.
    share = np.linspace(0.0, 1.0, 2 if kin.linear else REACH_SAMPLES + 1)[1:]
    points = np.concatenate([segments.start[:1], (segments.start[:, None, :] + share[None, :, None] * (
        segments.end - segments.start)[:, None, :]).reshape(-1, 4)])
    items = np.concatenate([segments.item[:1], np.repeat(segments.item, len(share))])
    motor = kin.to_motor(points)
    ends = np.concatenate([segments.end[:1], np.repeat(segments.end, len(share), axis=0)])
    at = lambda p: ", ".join(f"{c:.3f}" for c in p[:3])  # noqa: E731
    problems = [(np.flatnonzero(kin.unreachable(points)),
                 lambda k: f"the machine cannot reach ({at(points[k])})" + (
                     "" if np.allclose(points[k], ends[k]) else f" on the way to ({at(ends[k])})"))]
    for m, name in enumerate(kin.motors):
        span = job.machine.steppers[name].range
        if span:
            outside = np.flatnonzero((motor[:, m] < span[0] - 1e-9) | (motor[:, m] > span[1] + 1e-9))
            problems.append((outside, lambda k, m=m, name=name, span=span:
                             f"motor {name} would go to {motor[k, m]:.3f} mm, outside its range "
                             f"[{span[0]:g}, {span[1]:g}]"))
    diagnostics = []
    for where, message in problems:
        _, first = np.unique(items[where], return_index=True)
        diagnostics += [Diagnostic(toolpath.items[items[k]].source, message(k)) for k in where[np.sort(first)][:20]]
    if diagnostics:
        raise JobError(sorted(diagnostics, key=lambda d: (d.where.file, d.where.line, d.where.col))[:20])


class Stopwatch:
    """Wall time of each stage, for the benchmarks: `with watch("plan"): ...`."""

    def __init__(self):
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str):
        begin = time.perf_counter()
        yield
        self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - begin


def slow_down(result: HostBuild, trains: list[MotorTrain]) -> tuple[np.ndarray, np.ndarray] | None:
    """Where the tables' pulses take a motor over its rate (8 consecutive steps) or its acceleration (two 20 ms
    windows), which a plan per segment cannot see (a coarse motor's window across the Bresenham phases of
    several blocks, a delta carriage between cut points): the share of their peak speed and of their
    acceleration the segments under that stretch may keep. None when every window is within its limits."""
    kin, plan = result.kin, result.plan
    n = len(result.segments)
    speed, accel = np.ones(n), np.ones(n)
    pulse_segment = result.event_segments()[result.pulses.event]
    corners_t, jumps = corner_jumps(plan, result.segments, kin)
    for m, train in enumerate(trains):
        mine = pulse_segment[result.pulses.motor == m]
        if len(train.time) > RATE_WINDOW:
            ratio = RATE_WINDOW / np.maximum(train.time[RATE_WINDOW:] - train.time[:-RATE_WINDOW], 1e-12)
            ratio /= kin.limits.max_rate[m]
            for k in np.flatnonzero(ratio > 1.0):
                span = slice(max(mine[k] - 1, 0), mine[k + RATE_WINDOW] + 2)
                speed[span] = np.minimum(speed[span], RETRY_SHARE / ratio[k])
        begin, ratio = accel_ratios(train, kin.limits.max_accel[m] * kin.limits.steps_per_mm[m], corners_t,
                                    jumps[:, m])
        for k in np.flatnonzero(ratio > 1.0):
            first, last = np.searchsorted(plan.t_start, [begin[k], begin[k] + 2 * ACCEL_WINDOW_S], side="right") - 1
            span = slice(max(first - 1, 0), last + 2)
            speed[span] = np.minimum(speed[span], np.sqrt(RETRY_SHARE / ratio[k]))  # bends: v^2
            accel[span] = np.minimum(accel[span], RETRY_SHARE / ratio[k])
    return None if np.all(speed == 1.0) and np.all(accel == 1.0) else (speed, accel)


def timing_window(target: TargetInfo) -> TimingWindow:
    """How far an event may be from its ideal time. The 5 % share of the gap bounds the rate error; on the
    compact tables (8 KB of code memory) the absolute cap is wider, so that slow moves need fewer runs."""
    return TimingWindow(max_us=100.0) if target.compact_tables else TimingWindow()


def host_build(job, strict: bool = False, watch: Stopwatch | None = None) -> HostBuild:
    """Everything up to the twin and its checks against the plan: no compiler, no simulator."""
    watch = watch or Stopwatch()
    try:
        target = target_info(job.board)
    except FileNotFoundError:
        raise BuildError(f"the {job.target} target is not supported yet: targets/ has no board '{job.board}'") \
            from None
    kin = make_kinematics(job.machine)
    with watch("toolpath"):
        if homes(job, False):
            toolpath, warnings, homes_first = homed_toolpath(job, kin, strict)
        else:
            toolpath, warnings, homes_first = build_toolpath(job, strict)
    homing: tuple[HomingAxis, ...] = ()
    if homes(job, homes_first):
        homing = homing_axes(job, kin, target.tick_hz)
    with watch("segments"):
        segments = drop_empty(flatten(toolpath, job.machine.tolerance))
        check_reach(job, kin, toolpath, segments)
        segments = refine(split_long(kin.subdivide(segments, job.machine.tolerance), kin), kin)
        check_reach(job, kin, toolpath, segments)  # again on the pieces: a carriage may peak between samples
    start_steps = kin.to_steps(np.asarray(toolpath.start, float)[None, :])[0]
    expected_final = kin.to_steps(np.asarray(toolpath.end(), float)[None, :])[0]
    pulse_us, setup_us, motors = job.machine.step_pulse_us, job.machine.dir_setup_us, len(kin.motors)
    steps = segment_steps(segments, kin)
    limits = PlannerLimits(job.machine.junction_deviation, max_event_rate=target.max_event_rate(motors, pulse_us),
                           block_overhead=target.block_overhead_s(motors, pulse_us, setup_us))
    for _ in range(RATE_ROUNDS):
        with watch("plan"):
            motion = plan(segments, kin, steps, limits)
        with watch("step times"):
            events = generate(segments, motion, kin, steps, max_gap=target.max_gap_s)
            if target.compact_tables:
                events = smooth_curve_times(events, segments, motion, kin)
        with watch("rate runs"):
            compressed = compress(events, kin.motors, target.tick_hz, target.run_gap_ticks(motors, pulse_us),
                                  target.block_gap_ticks(pulse_us, setup_us), window=timing_window(target),
                                  cross_blocks=target.compact_tables, max_rate=kin.limits.max_rate)
        with watch("twin"):
            pulses = predict(compressed.schedule)
        result = HostBuild(job, target, kin, toolpath, segments, motion, events, compressed, pulses,
                           None, start_steps, expected_final, warnings, homing)  # type: ignore[arg-type]
        with watch("checks"):
            trains = trains_from(pulses.tick / target.tick_hz, pulses.motor, pulses.dir, len(kin.motors))
            result.findings = check(trains, pulses.event_position, result.event_segments(), segments, motion, kin,
                                    expected_final, start_steps, job.machine.tolerance)
        scale = slow_down(result, trains)
        if scale is None:
            break
        segments = replace(segments, feed=np.minimum(segments.feed, motion.v_peak * scale[0]),
                           accel=np.minimum(segments.accel, motion.accel * scale[1]))
    return result

"""Benchmark: host speed of plan + tables on a generated job, and table bytes per step and per mm.

    python benchmarks/host_speed.py [--segments 100000] [--kinematics cartesian|delta]

The job: a random polyline of short strokes and gentle curves, as G-code from a CAM tool would give, drawn by
a plotter (80 steps/mm, 200 mm/s, 3000 mm/s^2, 200 x 200 mm) or by a Kossel mini (the same carriages; rods
215 mm, radius 105.2 mm; the strokes fold into a disc of 60 mm radius, 2 to 40 mm above the bed). Prints the
wall time of every stage and the totals.
"""

from __future__ import annotations

import argparse
import time
from types import SimpleNamespace

import numpy as np

from codegen.kinematics import make_kinematics
from codegen.motion.planner import PlannerLimits, plan
from codegen.motion.staircase import refine, split_long
from codegen.motion.stepgen import generate, segment_steps
from codegen.tables.checks import MotorTrain, check
from codegen.tables.compress import compress
from codegen.tables.format import stream_bytes
from codegen.tables.twin import predict
from codegen.targets import target_info
from codegen.toolpath.items import FINE_STEPS
from codegen.toolpath.segments import REF_LINE, Segments


def random_segments(n: int, delta: bool, seed: int = 1) -> Segments:
    rng = np.random.default_rng(seed)
    heading = np.cumsum(rng.normal(0.0, 0.35, n))  # mostly smooth, now and then a sharp turn
    heading += np.where(rng.random(n) < 0.05, rng.uniform(-2.5, 2.5, n), 0.0)
    length = rng.uniform(0.2, 4.0, n)
    xy = np.cumsum(np.stack([np.cos(heading), np.sin(heading)], axis=1) * length[:, None], axis=0)
    xy = np.abs((xy % 400.0) - 200.0)  # fold into a 200 x 200 mm bed
    pts = np.zeros((n + 1, 4))
    if delta:  # fold the bed into a disc: the angle and radius of each point, the radius back and forth
        angle = np.arctan2(xy[:, 1] - 100.0, xy[:, 0] - 100.0)
        radius = np.abs((np.hypot(xy[:, 0] - 100.0, xy[:, 1] - 100.0) % 120.0) - 60.0)
        xy = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
        pts[1:, 2] = 2.0 + 38.0 * (np.arange(n) / n)  # rising slowly, as layers would
    pts[1:, :2] = xy
    pts[0] = pts[1]
    z = np.zeros(n)
    return Segments(start=pts[:-1], end=pts[1:], feed=np.full(n, 150.0), tool=np.ones(n, bool), power=np.ones(n),
                    dynamic=np.zeros(n, bool), dwell=z, item=np.arange(n), line=np.zeros(n, np.int64),
                    advance=z, shaping=np.zeros(n, np.int64), accel=np.full(n, np.inf), axis_velocity=np.full((n, 4), np.inf),
                    axis_accel=np.full((n, 4), np.inf), jerk=np.full((n, 4), np.nan),
                    junction_deviation=np.full(n, np.nan), ref_kind=np.full(n, REF_LINE),
                    ref_center=np.zeros((n, 2)), ref_radius=z, ref_angle=z, ref_growth=z,
                    ref_plane=np.tile([0, 1], (n, 1)),
                    ref_fine=np.full(n, -1), fine=np.zeros((0, FINE_STEPS + 1, 3)))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--segments", type=int, default=100_000)
    parser.add_argument("--kinematics", choices=("cartesian", "delta"), default="cartesian")
    args = parser.parse_args()
    delta = args.kinematics == "delta"
    stepper = SimpleNamespace(steps_per_mm=80.0, max_velocity=200.0, max_accel=3000.0, invert_dir=False, range=None)
    motors = ("a", "b", "c") if delta else ("x", "y")
    machine = SimpleNamespace(kinematics=args.kinematics, motor_names=motors, steppers={m: stepper for m in motors},
                              delta=SimpleNamespace(radius=105.2, diagonal_rod=215.0, height=250.0,
                                                    tower_angles=(210.0, 330.0, 90.0)))
    kin = make_kinematics(machine)
    target = target_info("ramps-1.4")
    segments = random_segments(args.segments, delta)
    stages = {}

    start_steps = kin.to_steps(segments.start[:1])[0]
    t = time.perf_counter()
    segments = refine(split_long(kin.subdivide(segments, 0.002), kin), kin)
    stages["subdivide + refine"] = time.perf_counter() - t
    t = time.perf_counter()
    steps = segment_steps(segments, kin)
    motion = plan(segments, kin, steps, PlannerLimits(0.01, max_event_rate=target.max_event_rate(len(motors))))
    stages["plan"] = time.perf_counter() - t
    t = time.perf_counter()
    events = generate(segments, motion, kin, steps, max_gap=target.max_gap_s)
    stages["step times"] = time.perf_counter() - t
    t = time.perf_counter()
    packed = compress(events, kin.motors, target.tick_hz, target.run_gap_ticks(len(motors)), target.block_gap_ticks())
    stages["rate runs"] = time.perf_counter() - t
    t = time.perf_counter()
    pulses = predict(packed.schedule)
    stages["twin"] = time.perf_counter() - t
    t = time.perf_counter()
    trains = [MotorTrain(pulses.tick[pulses.motor == m] / target.tick_hz, pulses.dir[pulses.motor == m])
              for m in range(len(kin.motors))]
    block = np.searchsorted(events.block_first, np.arange(len(events.time)), side="right") - 1
    findings = check(trains, pulses.event_position, events.block_segment[block], segments, motion, kin,
                     kin.to_steps(segments.end[-1:])[0], start_steps, 0.002)
    stages["checks"] = time.perf_counter() - t

    n_steps = len(pulses.tick)
    path_mm = float(motion.length.sum())
    total = sum(stages.values())
    table = stream_bytes(packed.schedule)
    print(f"{args.kinematics} job: {args.segments} segments ({len(segments)} blocks' worth after cutting), "
          f"{path_mm:.0f} mm of path, {n_steps} steps, "
          f"{motion.total:.1f} s of motion")
    for name, seconds in stages.items():
        print(f"  {name:<18} {seconds:7.3f} s")
    host = sum(stages[k] for k in ("subdivide + refine", "plan", "step times", "rate runs"))
    print(f"plan + tables: {host:.3f} s = {args.segments / host:,.0f} segments/s, {n_steps / host:,.0f} steps/s")
    print(f"with twin and checks: {total:.3f} s = {args.segments / total:,.0f} segments/s, "
          f"{n_steps / total:,.0f} steps/s")
    print(f"tables: {table} bytes = {table / n_steps:.3f} bytes/step, {table / path_mm:.2f} bytes/mm "
          f"({packed.schedule.n_blocks} blocks, {packed.schedule.n_runs} runs)")
    print(f"checks: {'pass' if findings.ok else 'FAIL: ' + '; '.join(findings.problems)}")


if __name__ == "__main__":
    main()

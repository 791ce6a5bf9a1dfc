"""The report's figures (codegen/report/html.py): series taken with numpy from the plan, the twin's pulses and the
simulated ones, each figure drawn on matplotlib's Agg canvas (no pyplot state) into PNG bytes.

A sliced print has millions of steps: every curve is sampled down to at most MAX_POINTS points, with no Python loop
over steps. Times are seconds from the player's tick 0 (the table's start), heaters' from power-up.
"""

from __future__ import annotations

import io
import math

import numpy as np
from matplotlib import colormaps
from matplotlib.collections import LineCollection
from matplotlib.colors import ListedColormap, Normalize
from matplotlib.figure import Figure

from codegen.motion.planner import ACCEL_WINDOW_S
from codegen.tables.schedule import HEATER_COMMANDS
from codegen.verify.report_samples import MAX_POINTS, PathSamples, PlannedPath, RunSamples

DPI = 90
WINDOW_S = 0.01  # the motors' velocity windows, at the least
SPEED_SPAN_STEPS = 64  # the simulated tool's speed is measured over about this many pulses
LIMIT = {"color": "tab:red", "linestyle": "--", "linewidth": 0.9}
TRAVEL = {"colors": "0.55", "linewidths": 0.6, "linestyles": (0, (3, 3))}
# Their pale ends cut off (they vanish on white): speed from dark blue to green, power as a burn, light to black.
SPEED_COLOURS = ListedColormap(colormaps["viridis"](np.linspace(0.0, 0.85, 256)))
POWER_COLOURS = ListedColormap(colormaps["inferno_r"](np.linspace(0.2, 0.95, 256)))


def png(fig: Figure) -> bytes:
    out = io.BytesIO()
    fig.savefig(out, format="png", dpi=DPI, metadata={"Software": None})
    return out.getvalue()


def planned_path(plan, segments, power: bool) -> PathSamples:
    """The job's path as planned (codegen/verify/report_samples.py PlannedPath, the whole plan at once)."""
    path = PlannedPath(plan.total, len(segments), power)
    path.add(plan, segments, last=True)
    return path.result()


def _level_at(edges: np.ndarray, cycles: np.ndarray) -> np.ndarray:
    """The value of a (K, 2) cycle, value log at `cycles` (0 before its first entry)."""
    if not len(edges):
        return np.zeros(len(cycles), dtype=np.int64)
    at = np.searchsorted(edges[:, 0], cycles, side="right") - 1
    return np.where(at >= 0, edges[np.maximum(at, 0), 1], 0)


def simulated_path(host, samples: RunSamples, trace, power: bool) -> PathSamples:
    """The tool's path from the simulated pulses (the table's, homing left out), as `samples` sampled them every few
    pulses; coloured by its speed over about SPEED_SPAN_STEPS pulses, or by the power the simulated PWM held
    (`trace`: the tool's edges and the laser's duty)."""
    cycle, steps = samples.simulated()
    count = samples.count
    kin = host.kin
    like = np.broadcast_to(np.asarray(host.start, dtype=float), (len(cycle), 4))
    axes = kin.to_axes((steps + host.start_steps) / kin.limits.steps_per_mm, like)
    extruding = np.diff(axes[:, 3]) > 0
    axes = axes[:, :3]
    span = max(1, math.ceil(SPEED_SPAN_STEPS * len(cycle) / count))
    piece = np.arange(len(cycle) - 1)
    lo, hi = np.maximum(piece - span + 1, 0), np.minimum(piece + span, len(cycle) - 1)
    seconds = (cycle[hi] - cycle[lo]) / samples.f_cpu
    distance = np.linalg.norm(axes[hi] - axes[lo], axis=1)
    speed = np.divide(distance, seconds, out=np.zeros_like(distance), where=seconds > 0)
    middle = (cycle[1:] + cycle[:-1]) // 2
    tool = _level_at(np.asarray(trace.tool_edges, dtype=np.int64).reshape(-1, 2), middle) > 0
    value = 100 * _level_at(trace.laser_duty, middle) / host.laser.top if power else speed
    return PathSamples(axes, value, tool | extruding)


def _polylines(points: np.ndarray, value: np.ndarray, mask: np.ndarray, pieces: int = 16):
    """The pieces (between neighbouring points) where `mask` holds, joined into polylines of up to `pieces` pieces,
    each coloured by their mean value: a few thousand lines, not tens of thousands of specks that antialias
    unevenly."""
    chosen = np.flatnonzero(mask)
    if not len(chosen):
        return [], np.zeros(0)
    k = np.arange(len(chosen))
    run_start = np.maximum.accumulate(np.where(np.diff(chosen, prepend=-2) != 1, k, 0))  # of consecutive pieces
    starts = np.flatnonzero((k - run_start) % pieces == 0)
    ends = np.append(starts[1:], len(chosen))
    lines = [points[chosen[a]:chosen[b - 1] + 2] for a, b in zip(starts, ends)]
    return lines, np.add.reduceat(value[chosen], starts) / (ends - starts)


def path_figure(planned: PathSamples, simulated: PathSamples | None, power: bool) -> bytes:
    """The planned path beside the simulated one (where there is one), in the plane of the two axes the job moves
    most along; working pieces coloured, travel thin grey dashed."""
    panels = [("planned", planned)] + ([("simulated", simulated)] if simulated is not None else [])
    extent = np.ptp(planned.axes, axis=0) if len(planned.axes) else np.ones(3)
    pair = np.sort(np.argsort(-extent, kind="stable")[:2])
    lit = np.concatenate([p.value[p.working] for _, p in panels])
    norm = Normalize(0.0, float(lit.max()) if len(lit) and lit.max() > 0 else 1.0)
    wide = max(extent[pair[0]], 1e-6) / max(extent[pair[1]], 1e-6)  # each panel about the data's shape
    width = 5.0 if wide >= 1 else float(np.clip(5.0 * wide, 2.2, 5.0))
    height = 5.9 if wide < 1 else float(np.clip(5.0 / wide, 2.2, 5.0)) + 0.9
    fig = Figure(figsize=(width * len(panels) + 1.4, height), layout="constrained")
    axs = fig.subplots(1, len(panels), sharex=True, sharey=True, squeeze=False)[0]
    for ax, (title, path) in zip(axs, panels):
        points = path.axes[:, pair]
        ax.add_collection(LineCollection(_polylines(points, path.value, ~path.working, len(points))[0], **TRAVEL))
        lines, values = _polylines(points, path.value, path.working)
        drawn = LineCollection(lines, cmap=POWER_COLOURS if power else SPEED_COLOURS, norm=norm, linewidths=1.3)
        drawn.set_array(values)
        ax.add_collection(drawn)
        ax.set_title(f"{title} tool path (grey dashed: travel)", fontsize="medium")
        ax.set_xlabel(f"{'xyz'[pair[0]]} (mm)")
        ax.set_aspect("equal", adjustable="box")
        ax.autoscale_view()
    axs[0].set_ylabel(f"{'xyz'[pair[1]]} (mm)")
    fig.colorbar(drawn, ax=list(axs), label="laser power (% of full scale)" if power else "speed (mm/s)", shrink=0.85)
    return png(fig)


def motor_motion(trains: list[tuple[np.ndarray, np.ndarray]], steps_per_mm: np.ndarray,
                 duration: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each motor's velocity (mm/s) over windows of WINDOW_S or more (at most MAX_POINTS of them) from 0 to
    `duration`, and its acceleration (mm/s^2) as the acceleration check measures it: the velocity change between
    neighbouring ACCEL_WINDOW_S windows, positions interpolated between pulses. `trains`: per motor, pulse times
    (s) and directions. Returns the velocity's times, velocities (M, N), the acceleration's times and
    accelerations (M, K)."""
    edges = motion_edges(duration)
    position = np.zeros((len(trains), len(edges)))
    for m, (t, direction) in enumerate(trains):
        if len(t):
            position[m] = np.interp(edges, t, np.cumsum(direction, dtype=np.int64), left=0.0) / steps_per_mm[m]
    return motion_of(edges, position)


def motion_from_grid(times: np.ndarray, steps: np.ndarray, duration: float,
                     steps_per_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """motor_motion's series from every motor's net steps (M, K) at `times` (s), a grid finer than the plot's."""
    edges = motion_edges(duration)
    position = np.stack([np.interp(edges, times, steps[m]) / steps_per_mm[m] for m in range(len(steps))])
    return motion_of(edges, position)


def motion_edges(duration: float) -> np.ndarray:
    """The motion plots' grid from 0 to `duration` (s): WINDOW_S or more, at most MAX_POINTS windows."""
    grid = max(WINDOW_S, duration / MAX_POINTS)
    return np.arange(0.0, duration + grid, grid)


def motion_of(edges: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """motor_motion's series from every motor's position (mm, (M, N)) at the grid's `edges`."""
    grid = float(edges[1] - edges[0]) if len(edges) > 1 else WINDOW_S
    n = max(1, round(ACCEL_WINDOW_S / grid))  # grid steps per acceleration window
    velocity = np.diff(position, axis=1) / grid
    accel = (position[:, 2 * n:] - 2 * position[:, n:-n] + position[:, :-2 * n]) / (n * grid) ** 2
    return 0.5 * (edges[1:] + edges[:-1]), velocity, edges[n:-n], accel


def motion_figure(names, series, max_velocity: np.ndarray, max_accel: np.ndarray, source: str) -> bytes:
    """Per motor (a row each), velocity and acceleration over time against its limits."""
    t_v, velocity, t_a, accel = series
    fig = Figure(figsize=(11.0, 1.7 * len(names) + 0.9), layout="constrained")
    axs = fig.subplots(len(names), 2, sharex=True, squeeze=False)
    for m, name in enumerate(names):
        for ax, t, y, limit, unit in ((axs[m, 0], t_v, velocity[m], max_velocity[m], "mm/s"),
                                      (axs[m, 1], t_a, accel[m], max_accel[m], "mm/s²")):
            ax.plot(t, y, linewidth=0.8, color="tab:blue")
            ax.axhline(limit, **LIMIT)
            ax.axhline(-limit, **LIMIT)
            ax.set_ylabel(f"{name} ({unit})")
            ax.grid(alpha=0.3)
    axs[0, 0].set_title(f"velocity ({source}); red: max_velocity", fontsize="medium")
    axs[0, 1].set_title(f"acceleration ({1000 * ACCEL_WINDOW_S:g} ms windows); red: max_accel", fontsize="medium")
    for ax in axs[-1]:
        ax.set_xlabel("time (s)")
    return png(fig)


def timing_figure(errors: dict[str, tuple[np.ndarray, np.ndarray]], limit_us: float) -> bytes:
    """A histogram per motor of the simulator's timing against the twin's (log counts). `errors`: per motor, each
    error (us) and how many pulses had it."""
    lo = min(0.0, *(float(e.min()) for e, _ in errors.values()))  # 0 in view: how far off, not just how spread
    hi = max(0.0, *(float(e.max()) for e, _ in errors.values()))
    pad = max(0.1, 0.03 * (hi - lo))
    bins = np.linspace(lo - pad, hi + pad, 61)
    fig = Figure(figsize=(8.0, 3.2), layout="constrained")
    ax = fig.subplots()
    for name, (e, count) in errors.items():
        ax.stairs(np.histogram(e, bins, weights=count)[0], bins, fill=True, alpha=0.45,
                  label=f"{name} ({int(count.sum())} pulses)")
    ax.set_yscale("log")
    ax.set_ylim(bottom=0.5)
    ax.set_xlabel("simulated time - twin's time (µs)")
    ax.set_ylabel("pulses")
    ax.set_title(f"timing against the twin (limit ±{limit_us:.2f} µs)")
    ax.legend(fontsize="small")
    return png(fig)


def _lowest_per_bucket(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """At most MAX_POINTS points: each bucket's lowest value, at the bucket's first time."""
    size = math.ceil(len(y) / MAX_POINTS)
    if size <= 1:
        return t, y
    starts = np.arange(0, len(y), size)
    return t[starts], np.minimum.reduceat(y, starts)


def ring_fill_figure(t: np.ndarray, fill: np.ndarray, ring_bytes: int, planned_min: int | None, end_s: float,
                     when: str) -> bytes:
    """A stream's ring fill over time (`when`: at which moments it is known) against the ring's size and the plan's
    lowest fill, to the run's end at `end_s`."""
    t, fill = _lowest_per_bucket(t, fill)
    fig = Figure(figsize=(8.0, 3.0), layout="constrained")
    ax = fig.subplots()
    ax.step(t, fill, where="post", marker=".", markersize=3, linewidth=0.9, label="ring fill")
    ax.axhline(ring_bytes, **LIMIT, label=f"ring ({ring_bytes} bytes)")
    if planned_min is not None:
        ax.axhline(planned_min, color="tab:orange", linestyle=":", label=f"planned lowest fill ({planned_min})")
    ax.set_ylim(0, ring_bytes * 1.08)
    ax.set_xlim(min(0.0, float(t[0])), max(end_s, float(t[-1])))
    ax.set_xlabel("time from the table's start (s)")
    ax.set_ylabel("bytes held")
    ax.set_title(f"the streaming firmware's ring fill {when}", fontsize="medium")
    ax.legend(fontsize="small", loc="lower right")
    ax.grid(alpha=0.3)
    return png(fig)


def heater_targets(timeline, tick_hz: int, trace, heater: str) -> tuple[np.ndarray, np.ndarray]:
    """Where the tables set `heater`'s target (`timeline`: their runtime records on the twin's clock): simulated s
    from power-up (the player's holds counted in, as codegen/verify/heaters.py places a record) and degC."""
    mine = np.flatnonzero(timeline.command == HEATER_COMMANDS[heater])
    if trace.timer_start_cycle is None or not len(mine):
        return np.zeros(0), np.zeros(0)
    tick = timeline.tick[mine]
    waits = timeline.tick[timeline.waits()][:len(trace.resumes)]
    part = np.searchsorted(waits, tick, side="left")  # the player's run (between resumes) that reads the record
    base_cycle = np.array([trace.timer_start_cycle, *trace.resumes], dtype=np.int64)[part]
    base_tick = np.concatenate([[0], waits]).astype(np.int64)[part]
    cycles = base_cycle + (tick - base_tick) * (trace.f_cpu // tick_hz)
    return cycles / trace.f_cpu, timeline.value[mine] / 10


def heater_figure(curves: dict[str, tuple], holds: list[dict], table_start_s: float | None) -> bytes:
    """Per heater, the simulated plant's temperature against the targets the tables set; the player's holds
    shaded. `curves`: name -> (times, degC, target times, target degC), at least one target each."""
    fig = Figure(figsize=(11.0, 2.4 * len(curves) + 0.6), layout="constrained")
    axs = fig.subplots(len(curves), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (name, (t, temp, target_t, target_c)) in zip(axs, curves.items()):
        every = max(1, math.ceil(len(t) / MAX_POINTS))
        ax.plot(t[::every], temp[::every], linewidth=0.9, color="tab:orange", label="temperature")
        end = max(float(t[-1]) if len(t) else 0.0, float(target_t[-1]))
        ax.step(np.append(target_t, end), np.append(target_c, target_c[-1]), where="post", **LIMIT, label="target")
        for h in holds:
            ax.axvspan(h["at_s"], h["at_s"] + h["waited_s"], color="0.85", zorder=0)
        if table_start_s is not None:
            ax.axvline(table_start_s, color="0.4", linewidth=0.8, linestyle=":")
        ax.set_ylabel(f"{name} (°C)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small", loc="lower right")
    axs[0].set_title("heaters: simulated plant against the tables' targets (grey: the player held for them; "
                     "dotted: the table's start)")
    axs[-1].set_xlabel("simulated time from power-up (s)")
    return png(fig)


def vibration_figure(vibration: dict) -> bytes:
    """Per axis, the toolhead's residual vibration after its worst acceleration change (codegen/verify/vibration.py:
    the place where the shaped run rings most), shaped against unshaped: each the free ringing the model measured
    there, Re(z exp(p t)), from where the change has settled in that run (unshaped at once, shaped after its
    shaper's span), in um against ms after the change."""
    axes = {name: v for name, v in vibration.items() if v["worst"] is not None}
    fig = Figure(figsize=(8.0, 2.6 * len(axes)), layout="constrained")
    for ax, (name, v) in zip(np.atleast_1d(fig.subplots(len(axes), 1, squeeze=False)[:, 0]), axes.items()):
        worst = v["worst"]
        omega = 2 * math.pi * v["freq_hz"]
        pole = complex(-v["damping"] * omega, omega * math.sqrt(1 - v["damping"] ** 2))
        span = max(worst["length_s"], worst["residual_delay_s"])
        runs = [("unshaped", worst["unshaped_um"], worst["unshaped_phase_rad"], 0.0, "tab:red")]
        if worst["shaper"] is not None:  # the shaper of the worst place's era
            runs.append((f"shaped ({worst['shaper']})", worst["residual_um"], worst["residual_phase_rad"],
                         worst["residual_delay_s"], "tab:blue"))
        for label, amplitude, phase, delay, colour in runs:
            t = np.linspace(delay, span, 400)
            ax.plot(t * 1e3, (amplitude * np.exp(1j * phase + pole * (t - delay))).real, color=colour,
                    label=f"{label}: {amplitude:.2f} µm")
        ax.axhline(0.0, color="0.6", linewidth=0.6)
        ax.set_xlabel("time after the change (ms)")
        ax.set_ylabel(f"{name} vibration (µm)")
        line = f" (line {worst['line']})" if worst["line"] else ""
        ax.set_title(f"{name} at {v['freq_hz']:g} Hz, damping {v['damping']:g}: the worst place, "
                     f"{worst['time_s']:.4f} s{line}", fontsize="medium")
        ax.legend(fontsize="small")
    return png(fig)

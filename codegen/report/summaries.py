"""Reports: report.json of a build, the JSON of `plan` and `verify`, the trace CSV, and human summaries."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from codegen import __version__
from codegen.pipeline.host import HostBuild
from codegen.pipeline.normalized import job_fingerprint
from codegen.tables.format import stream_bytes
from codegen.tables.schedule import HEATER_COMMANDS, RT_WAIT
from codegen.verify.results import positions, rounded
from codegen.verify.steps_csv import StepsCsv


def plan_summary(host: HostBuild) -> dict:
    f, totals = host.findings, host.totals
    return {
        "job": host.job.name,
        "duration_s": rounded(totals.duration_s),
        "table_bytes": totals.table_bytes,
        "segments": totals.segments,
        "windows": totals.windows,
        "blocks": totals.blocks,
        "runs": totals.runs,
        "events": totals.events,
        "motors": {
            name: {"steps": f.steps[name], **positions(host, f, name),
                   "max_rate_ratio": rounded(f.rate_ratio[name], 4), "max_accel_ratio": rounded(f.accel_ratio[name], 4)}
            for name in host.kin.motors
        },
        "max_path_error_mm": rounded(f.max_path_error_mm),
        "path_limit_mm": rounded(f.path_limit_mm),
        "max_timing_error_us": rounded(totals.max_timing_error_ticks / host.target.tick_hz * 1e6, 3),
        **({"input_shaper": shaper_plan(host)} if f.smoothing_mm is not None else {}),
        **({"pressure_advance": advance_plan(host)} if f.advance_steps is not None else {}),
        "pass": f.ok,
        "problems": list(f.problems),
        **(host.link_plan.summary() if host.link_plan is not None else
           {"mcu": host.target.mcu, "flash_bytes": host.target.flash_bytes}),
        **({"heaters": heaters_plan(host)} if host.heaters else {}),
        **({"laser": laser_plan(host)} if host.laser else {}),
        **({"feed_hold": feed_hold_plan(host)} if host.hold_plan is not None else {}),
    }


def shaper_plan(host: HostBuild) -> dict:
    """The input shapers and their smoothing: the largest distance of the shaped tool from the planned one at the
    same moment, where (the planned point, its G-code line) and the limit (codegen/motion/shaped_motion.py); the
    machine's shapers, and how many M593s changed them."""
    f, machine = host.findings, host.job.machine.input_shaper
    axes = {name: {"type": s.type, "freq_hz": s.freq, "damping": s.damping}
            for name, s in ({} if machine is None else machine.axes).items()}
    return {"axes": axes, "m593_changes": max(len(host.shapings) - 1, 0),
            "smoothing_mm": rounded(f.smoothing_mm), "smoothing_at": [rounded(c) for c in f.smoothing_at],
            "smoothing_line": f.smoothing_line, "max_smoothing_mm": None if machine is None else machine.max_smoothing}


def advance_plan(host: HostBuild) -> dict:
    """Pressure advance: the job's K and smoothing time, and the extruder's pulses against the formula: the largest
    distance (steps) of a pulse's half step from it, when and the G-code line (codegen/motion/advance.py)."""
    f, machine = host.findings, host.job.machine.pressure_advance
    return {"k": machine.k, "smooth_time_s": machine.smooth_time, "max_deviation_steps": rounded(f.advance_steps, 4),
            "at_s": rounded(f.advance_time_s, 6), "line": f.advance_line}


def feed_hold_plan(host: HostBuild) -> dict:
    """Feed hold's ramp and keys, and the override's ceiling records (codegen/tables/headroom.py) with their bytes."""
    plan = host.hold_plan
    return {"ramp_s": rounded(plan.ramp_seconds(host.target.tick_hz), 4), "max_override_pct": plan.max_step * 10,
            "ceiling_records": host.totals.ceiling_records,
            "ceiling_bytes": host.totals.ceiling_bytes, "keys": dict(plan.keys)}


def laser_plan(host: HostBuild) -> dict:
    """A laser's PWM and the tables' power records (codegen/tables/laser.py)."""
    laser = host.laser
    return {"pin": laser.pin, "pwm_hz": rounded(laser.actual_hz, 3), "top": laser.top,
            "power_records": host.totals.power_records,
            "max_power_error_pct": rounded(100 * host.totals.max_power_error, 4)}


def heaters_plan(host: HostBuild) -> dict:
    """The heaters of the image (or of the streaming firmware): how many target records the tables carry for each
    and how many waits, its last target (degC), its pins, and its ADC table's flash bytes (int16 per reading)."""
    out = {}
    for h in host.heaters:
        records = host.runtime_settings(h.name)
        targets = records.value[records.command == HEATER_COMMANDS[h.name]]
        out[h.name] = {"settings": len(targets), "waits": int(np.count_nonzero(records.command == RT_WAIT)),
                       "last_target_c": float(targets[-1]) / 10 if len(targets) else 0.0, "pwm_pin": h.pwm_pin,
                       "sensor_pin": h.sensor_pin, "table_bytes": 2 * len(h.table)}
    return out


def build_report(host: HostBuild, image, fingerprint: str, sources: dict[str, str]) -> dict:
    table = stream_bytes(host.schedule)
    sections = dict(image.sections)
    return {
        "printer_codegen": __version__,
        "job": host.job.name,
        "job_file": str(host.job.path),
        "target": host.target.target,
        "board": host.target.board,
        "mcu": host.target.mcu,
        "fingerprint": fingerprint,
        "job_fingerprint": job_fingerprint(host.job),  # what `flash` compares with the job (codegen/pipeline/normalized.py)
        "image": {
            "hex": image.hex_path.name,
            "elf": image.elf_path.name if image.elf_path else None,
            "flash_bytes": image.flash_bytes,
            "flash_capacity": image.flash_capacity,
            "ram_bytes": image.ram_bytes,
            "ram_capacity": image.ram_capacity,
            "table_bytes": table,
            "flash_parts": dict(image.flash_parts),
            "ram_parts": dict(image.ram_parts),
            "sections": sections,
        },
        "sources": sorted(sources),
        "plan": plan_summary(host),
    }


def write_json(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data, indent=2, sort_keys=False) + "\n", encoding="utf-8")


def write_trace(path: Path, host: HostBuild, trace) -> None:
    """One row per simulated step pulse: time_s,motor,dir,phase (CLI.md), written in chunks."""
    order = np.argsort(trace.step_cycle, kind="stable")
    rows = StepsCsv(path, host.kin.motors, trace.f_cpu)
    rows.write(trace.step_cycle[order], trace.step_motor[order], trace.step_dir[order],
               np.asarray(trace.step_phase, dtype=object)[order])
    rows.close()


def motion(m: dict) -> str:
    """A motor's end in words: net steps against the job's, and the absolute position."""
    return f"net {m['final']:+d} (job: {m['expected_final']:+d}), ends at step {m['end_position']}"


def human_plan(summary: dict) -> str:
    lines = [f"{summary['job']}: {summary['duration_s']:.3f} s planned, {summary['segments']} segments, "
             f"{summary['blocks']} blocks, {summary['runs']} runs, {summary['table_bytes']} table bytes"]
    for name, m in summary["motors"].items():
        lines.append(f"  {name}: {m['steps']} steps, {motion(m)}, "
                     f"rate {100 * m['max_rate_ratio']:.1f} %, accel {100 * m['max_accel_ratio']:.1f} % of limit")
    lines.append(f"  path error {summary['max_path_error_mm']:.4f} mm (limit {summary['path_limit_mm']:.4f} mm), "
                 f"timing within {summary['max_timing_error_us']:.2f} us of the plan")
    if "input_shaper" in summary:
        shaper = summary["input_shaper"]
        axes = ", ".join(f"{name} {s['type']} {s['freq_hz']:g} Hz" for name, s in shaper["axes"].items())
        if shaper["m593_changes"]:
            axes = f"{axes or 'none'}, then {shaper['m593_changes']} M593 changes"
        limit = "" if shaper["max_smoothing_mm"] is None else f" (limit {shaper['max_smoothing_mm']:g} mm)"
        line = f" on G-code line {shaper['smoothing_line']}" if shaper["smoothing_line"] else ""
        lines.append(f"  input shaper {axes}: smoothing {shaper['smoothing_mm']:.4f} mm{limit}, the most at "
                     f"({', '.join(f'{c:.3f}' for c in shaper['smoothing_at'])}){line}")
    if "pressure_advance" in summary:
        advance = summary["pressure_advance"]
        line = f" on G-code line {advance['line']}" if advance["line"] else ""
        lines.append(f"  pressure advance K {advance['k']:g} s, smoothing {advance['smooth_time_s']:g} s: the extruder "
                     f"within {advance['max_deviation_steps']:.3f} steps of the formula, the most at "
                     f"{advance['at_s']:.4f} s{line}")
    if summary.get("flash_bytes") is not None and summary["table_bytes"] > summary["flash_bytes"]:
        lines.append(f"  too big for a flash image: the tables alone are {summary['table_bytes']} bytes, the "
                     f"{summary['mcu']} has {summary['flash_bytes']}; stream the job (--stream)")
    if "prefill_bytes" in summary:
        low = summary["min_ring_fill_bytes"]
        lines.append(f"  link {summary['baud']} baud: {summary['stream_bytes']} bytes to stream, prefill "
                     f"{summary['prefill_bytes']} of the {summary['ring_bytes']}-byte ring, lowest fill "
                     f"{'n/a (the stream fits the ring)' if low is None else f'{low} bytes'}, "
                     f"{summary['link_slowdown_s']:.3f} s slower for the link")
    for name, h in summary.get("heaters", {}).items():
        lines.append(f"  heater {name} ({h['pwm_pin']}, thermistor {h['sensor_pin']}): {h['settings']} settings and "
                     f"{h['waits']} waits in the tables, the last {h['last_target_c']:g} degC; ADC table "
                     f"{h['table_bytes']} bytes")
    if "laser" in summary:
        laser = summary["laser"]
        lines.append(f"  laser on {laser['pin']} at {laser['pwm_hz']:g} Hz ({laser['top']} counts): "
                     f"{laser['power_records']} power changes, within {laser['max_power_error_pct']:.2f} % of "
                     f"full scale of the plan")
    if "feed_hold" in summary:
        hold = summary["feed_hold"]
        keys = ", ".join(f"{k} {v}" for k, v in hold["keys"].items())
        lines.append(f"  feed hold ({keys}): {hold['ramp_s']:.4f} s from 100 % to rest; override up to "
                     f"{hold['max_override_pct']} %, {hold['ceiling_records']} ceiling records "
                     f"({hold['ceiling_bytes']} bytes of the tables, with the runs they split)")
    lines.extend(f"  problem: {p}" for p in summary["problems"])
    return "\n".join(lines)

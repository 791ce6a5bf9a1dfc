"""verify's result as CLI.md's `verify --json` gives it: pass, durations, path error, each motor's steps, end and
timing, the image's sizes and every problem found; the figures of heaters, the link and hold join it."""

from __future__ import annotations

from codegen.pipeline.host import HostBuild
from codegen.verify.vibration_eras import least_ringing


def rounded(value: float, digits: int = 6) -> float:
    return float(round(value, digits))


def positions(host: HostBuild, f, name: str) -> dict:
    """A motor's end (CLI.md): `final` and `expected_final` count from its position when the program began
    (after any homing); `end_position` and `expected_end_position` are absolute steps."""
    start = int(host.start_steps[host.kin.motors.index(name)])
    return {"final": f.final[name] - start, "expected_final": f.expected_final[name] - start,
            "end_position": f.final[name], "expected_end_position": f.expected_final[name]}


def verify_json(host: HostBuild, verdict, image) -> dict:
    f = verdict.findings
    return {
        "pass": verdict.ok,
        "target": host.target.target,
        "board": host.target.board,
        "duration_s": rounded(verdict.duration_s),
        "planned_duration_s": rounded(verdict.planned_duration_s),
        "max_path_error_mm": rounded(f.max_path_error_mm) if verdict.path_measured else None,
        "path_limit_mm": rounded(f.path_limit_mm),
        "not_compared": verdict.not_compared,
        "motors": {
            name: {
                "steps": f.steps[name],
                **positions(host, f, name),
                "max_timing_error_us": (None if name not in verdict.timing_error_us
                                        else rounded(verdict.timing_error_us[name], 3)),
                "max_rate_ratio": rounded(f.rate_ratio[name], 4),
                "max_accel_ratio": rounded(f.accel_ratio[name], 4),
                "min_pulse_us": rounded(verdict.pulse_width_us.get(name, 0.0), 3),
                "min_dir_setup_us": (None if verdict.dir_setup_us.get(name) is None
                                     else rounded(verdict.dir_setup_us[name], 3)),
            }
            for name in host.kin.motors
        },
        "start_offset_us": rounded(verdict.latency_us, 3),
        "homing": verdict.homing,
        "display": verdict.display,
        **({"laser": verdict.laser.as_json()} if verdict.laser else {}),
        **({"gcode_checked": verdict.gcode_checked} if verdict.gcode_checked is not None else {}),
        **({"pressure_advance_steps": rounded(verdict.advance_steps, 4)} if verdict.advance_steps is not None else {}),
        "image": {"flash_bytes": image.flash_bytes, "ram_bytes": image.ram_bytes,
                  "table_bytes": host.totals.table_bytes},
        "problems": verdict.problems + f.problems,
        **({"vibration": vibration_json(verdict.vibration)} if verdict.vibration else {}),
        **({"smoothing_mm": rounded(host.findings.smoothing_mm)} if host.findings.smoothing_mm is not None else {}),
    }


def vibration_json(vibration: dict) -> dict:
    """`vibration.<axis>` (codegen/verify/vibration.py figures), rounded."""
    def tidy(value):
        if isinstance(value, dict):
            return {k: tidy(v) for k, v in value.items()}
        if isinstance(value, list):
            return [tidy(v) for v in value]
        return rounded(value, 4) if isinstance(value, float) else value
    return {axis: tidy(figures) for axis, figures in vibration.items()}


def vibration_lines(vibration: dict) -> list[str]:
    """verify's text lines of the toolhead's residual vibration, an axis a line; with M593s, a line an era after
    it and the era that rings least."""
    lines = []
    for axis, v in vibration.items():
        worst = v["worst"] or {}
        place = f", the most at {worst['time_s']:.4f} s" if worst else ""
        place += f" (line {worst['line']})" if worst.get("line") else ""
        if v["shaper"] is None:
            lines.append(f"  vibration {axis} ({v['freq_hz']:g} Hz, damping {v['damping']:g}, unshaped): residual "
                         f"{v['residual_peak_um']:.2f} um peak, {v['residual_rms_um']:.2f} um RMS after "
                         f"{v['places']} acceleration changes{place}")
            continue
        eras = v.get("eras", [])
        shapers = f"{len(eras)} eras of M593: {v['shaper']}" if eras else v["shaper"]
        ratio = "" if v["ratio"] is None else f": {100 * v['ratio']:.1f} % of unshaped"
        theory = "" if v["theory_ratio"] is None else f" (the shaper's theory: {100 * v['theory_ratio']:.1f} %)"
        lines.append(f"  vibration {axis} ({v['freq_hz']:g} Hz, damping {v['damping']:g}, {shapers}): residual "
                     f"{v['residual_peak_um']:.2f} um peak, {v['residual_rms_um']:.2f} um RMS after {v['places']} "
                     f"acceleration changes{place}; unshaped {v['unshaped_peak_um']:.2f} um peak, "
                     f"{v['unshaped_rms_um']:.2f} um RMS{ratio}{theory}")
        lines += [f"    era {e['era']}{_from_line(e)} ({era_shaper(e)}): residual {e['residual_peak_um']:.2f} um peak, "
                  f"{e['residual_rms_um']:.2f} um RMS after {e['places']} changes; unshaped "
                  f"{e['unshaped_peak_um']:.2f} um peak, {e['unshaped_rms_um']:.2f} um RMS: "
                  f"{100 * e['ratio']:.1f} % of unshaped (theory {100 * e['theory_ratio']:.1f} %)"
                  for e in eras if e["ratio"] is not None]
        least = least_ringing(eras)
        if least is not None:
            lines.append(f"  vibration {axis} rings least in era {least['era']}{_from_line(least)} "
                         f"({era_shaper(least)}): {100 * least['ratio']:.1f} % of unshaped")
    return lines


def _from_line(era: dict) -> str:
    return f" from line {era['line']}" if era["line"] else ""


def era_shaper(era: dict) -> str:
    """An era's shaper as the text names it: type, frequency and damping, or unshaped."""
    if era["shaper"] is None:
        return "unshaped"
    if era["shaper_freq_hz"] is None:
        return era["shaper"]
    return f"{era['shaper']} {era['shaper_freq_hz']:g} Hz, damping {era['shaper_damping']:g}"

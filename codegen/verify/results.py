"""verify's result as CLI.md's `verify --json` gives it: pass, durations, path error, each motor's steps, end and
timing, the image's sizes and every problem found; the figures of heaters, the link and hold join it."""

from __future__ import annotations

from codegen.pipeline.host import HostBuild


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
    }

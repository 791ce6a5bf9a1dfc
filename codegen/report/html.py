"""`plan --report FILE.html` and `verify --report FILE.html`: one self-contained page, every figure embedded as a
PNG data URI (codegen/report/plots.py draws them): a header with the run's figures, then the tool path (planned; and
simulated), each motor's velocity and acceleration against its limits, the simulator's timing against the twin,
a stream's ring fill over time, and the heaters' temperatures against their targets, each where the run has its
data; where it has not, one line says why. The page goes to a temporary file beside FILE and replaces it once
whole, after the stage has run (a failed verification gets its page too: that is when it helps most).
"""

from __future__ import annotations

import base64
import html
import os
from dataclasses import dataclass
from pathlib import Path

from codegen import __version__
from codegen.report import plots
from codegen.report.plan_samples import PlanSamples
from codegen.verify.compare import MAX_TIMING_ERROR_US
from codegen.verify.report_samples import PathSamples, RunSamples
from codegen.verify.results import era_shaper
from codegen.verify.vibration_eras import least_ringing

STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.4em; } h2 { font-size: 1.1em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
td, th { border: 1px solid #ccc; padding: 2px 8px; text-align: left; }
.pass { color: #070; font-weight: bold; } .fail { color: #b00; font-weight: bold; }
img { max-width: 100%; } .missing { color: #666; font-style: italic; }
"""
UNITS = {"s": "s", "us": "µs", "mm": "mm", "pct": "%", "c": "°C", "hz": "Hz"}
RING_FILL_WHEN = {"avr": "at each ACK (none once the whole stream is in)",  # codegen/sim/avr_link.py
                  "mcs51": "where the player reads each record"}  # codegen/sim/mcs51_link.py


@dataclass
class Section:
    """One plot of the page (`png`), or the line saying why it is not there (`missing`)."""

    key: str  # the img's data-plot
    title: str
    png: bytes | None = None
    missing: str = ""
    colour: str = ""  # what colours a path: speed or power
    caption: str = ""


def _value(v) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def _pct(ratio) -> str:
    return "–" if ratio is None else f"{100 * ratio:.1f} %"


def _label(key: str, group: str = "") -> str:
    """A JSON key as a header's label: its unit in brackets, its group's name before it once."""
    words = ([group] if group else []) + key.removeprefix(f"{group}_").split("_")
    unit = UNITS.get(words[-1]) if len(words) > 1 else None
    return " ".join(words[:-1] if unit else words) + (f" ({unit})" if unit else "")


def _groups(data: dict, groups: tuple[str, ...]) -> list[tuple[str, object]]:
    """The header's pairs of a JSON's groups (`image`, `link`, `laser`: one per key) and its heaters (one each)."""
    pairs = [(_label(key, group), v) for group in groups for key, v in data.get(group, {}).items()]
    for name, h in data.get("heaters", {}).items():
        pairs.append((f"heater {name}", ", ".join(f"{_label(k)} {_value(v)}" for k, v in h.items())))
    return pairs


def _table(pairs: list[tuple[str, object]]) -> str:
    """Label and value pairs, two to a row."""
    cells = [f"<th>{html.escape(k)}</th><td>{html.escape(_value(v))}</td>" for k, v in pairs]
    return "<table>" + "".join(f"<tr>{''.join(cells[i:i + 2])}</tr>" for i in range(0, len(cells), 2)) + "</table>"


def _motor_table(motors: dict, columns: tuple[tuple[str, str], ...]) -> str:
    head = "".join(f"<th>{html.escape(title)}</th>" for _, title in columns)
    body = ""
    for name, m in motors.items():
        cells = "".join(f"<td>{html.escape(_pct(m.get(key)) if key.endswith('_ratio') else _value(m.get(key)))}</td>"
                        for key, _ in columns)
        body += f"<tr><th>{html.escape(name)}</th>{cells}</tr>"
    return f"<table><tr><th>motor</th>{head}</tr>{body}</table>"


def _page(title: str, verdict: bool, header: str, sections: list[Section], problems: list[str]) -> str:
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{STYLE}</style></head><body>",
             f"<h1>{html.escape(title)}: <span class='{'pass' if verdict else 'fail'}' id='verdict'>"
             f"{'PASS' if verdict else 'FAIL'}</span></h1>", header]
    if problems:
        parts.append("<ul>" + "".join(f"<li>{html.escape(p)}</li>" for p in problems) + "</ul>")
    for s in sections:
        if s.png is None:
            parts.append(f"<p class='missing' data-missing='{s.key}'>{html.escape(s.title)}: "
                         f"{html.escape(s.missing)}</p>")
            continue
        data = base64.b64encode(s.png).decode("ascii")
        parts.append(f"<h2>{html.escape(s.title)}</h2><img data-plot='{s.key}' data-colour='{s.colour}' "
                     f"alt='{html.escape(s.title)}' src='data:image/png;base64,{data}'>")
        if s.caption:
            parts.append(f"<p>{html.escape(s.caption)}</p>")
    parts.append(f"<p class='missing'>printer-codegen {__version__}</p></body></html>\n")
    return "\n".join(parts)


def _write(path: Path, page: str) -> None:
    """Atomically: a temporary file beside `path`, then moved over it."""
    partial = path.with_name(f".{path.name}.partial")
    try:
        partial.write_text(page, encoding="utf-8")
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def _path_section(host, planned: PathSamples | None, simulated: PathSamples | None) -> Section:
    """The tool path, planned and simulated."""
    power = host.laser is not None
    colour = "power" if power else "speed"
    title = f"tool path, coloured by {'laser power' if power else 'speed'}"
    if planned is None or not len(planned.axes):
        return Section("path", title, missing="the job does not move")
    return Section("path", title, plots.path_figure(planned, simulated, power), colour=colour)


def _motion_section(host, series, duration: float, source: str) -> Section:
    """`series`: plots.motor_motion's, or a function of the limits that makes them."""
    title = "motors: velocity and acceleration against their limits"
    if duration <= 0:
        return Section("motion", title, missing="no motor steps")
    limits = host.kin.limits
    return Section("motion", title, plots.motion_figure(host.kin.motors, series, limits.max_velocity,
                                                        limits.max_accel, source),
                   caption="Velocity over 10 ms windows (or more, on a long job); acceleration as the checks measure "
                           "it, the velocity change between 20 ms windows: at a corner the plan's velocity jump "
                           "(the junction deviation's) shows as a spike the checks allow.")


def write_plan_report(path: Path, host, summary: dict, samples: PlanSamples) -> None:
    """plan --report: the planned path and the twin's motor motion (no simulation: no simulated path, timing, ring
    fill over time or temperatures), from what `samples` gathered a window at a time."""
    duration = samples.duration_s
    motion = samples.motion(host.kin.limits.steps_per_mm) if duration > 0 else None
    segments = samples.segments()
    planned = plots.planned_path(samples.plan(), segments, host.laser is not None) if segments is not None else None
    sections = [_path_section(host, planned, None),
                Section("simulated-path", "simulated tool path", missing="plan runs no simulator (verify does)"),
                _motion_section(host, motion, duration, "the twin's pulses: what the tables play"),
                Section("timing", "timing against the twin", missing="plan runs no simulator (verify does)")]
    if host.link_plan is not None:
        sections.append(Section("ring-fill", "ring fill over time",
                                missing="plan only plans the link (verify --stream simulates it)"))
    if host.heaters:
        sections.append(Section("heaters", "heater temperatures", missing="plan simulates no thermal plant "
                                                                          "(verify does)"))
    pairs = _identity(host, "plan (no simulation)") + [("planned duration (s)", summary["duration_s"])] + [
        (_label(key), summary[key]) for key in ("table_bytes", "segments", "max_path_error_mm",
                                                "path_limit_mm", "baud", "stream_bytes", "ring_bytes", "prefill_bytes",
                                                "min_ring_fill_bytes", "link_slowdown_s") if key in summary]
    pairs += [("twin's timing against the plan (µs)", summary["max_timing_error_us"])] + _groups(summary, ("laser",))
    header = _table(pairs) + _motor_table(summary["motors"], (
        ("steps", "steps"), ("final", "net steps"), ("expected_final", "job's net steps"),
        ("max_rate_ratio", "rate of limit"), ("max_accel_ratio", "accel of limit")))
    _write(path, _page(f"plan {host.job.name}", summary["pass"], header, sections, summary["problems"]))


def _identity(host, stage: str) -> list[tuple[str, object]]:
    target = host.target
    return [("job", host.job.name), ("target", f"{target.target} ({target.board}, {target.mcu})"), ("stage", stage)]


def _verify_header(host, result: dict) -> str:
    pairs = _identity(host, "verify, streamed" if "link" in result else "verify") + [
        ("simulated duration (s)", result["duration_s"])] + [
        (_label(key), result[key]) for key in ("planned_duration_s", "max_path_error_mm",
                                               "path_limit_mm", "start_offset_us", "table_start_s") if key in result]
    pairs += _groups(result, ("image", "link", "laser"))
    if "trip" in result:
        trip = result["trip"]
        pairs.append(("thermal protection trip", f"{trip['reason']} on {trip['heater']} at {trip['time_s']} s"))
    pairs += [(f"vibration {axis} (µm)", f"{v['residual_peak_um']:.2f} peak, {v['residual_rms_um']:.2f} RMS; "
               f"unshaped {v['unshaped_peak_um']:.2f}, {v['unshaped_rms_um']:.2f}")
              for axis, v in result.get("vibration", {}).items()]
    least = {axis: least_ringing(v.get("eras", [])) for axis, v in result.get("vibration", {}).items()}
    pairs += [(f"vibration {axis}: least ringing M593 era", f"era {e['era']} ({era_shaper(e)}): "
               f"{100 * e['ratio']:.1f} % of unshaped (theory {100 * e['theory_ratio']:.1f} %)")
              for axis, e in least.items() if e is not None]
    pairs += [("not compared", reason) for reason in result.get("not_compared", [])]
    return _table(pairs) + _motor_table(result["motors"], (
        ("steps", "steps"), ("final", "net steps"), ("expected_final", "job's net steps"),
        ("max_timing_error_us", "timing (µs)"), ("max_rate_ratio", "rate of limit"),
        ("max_accel_ratio", "accel of limit"), ("min_pulse_us", "min pulse (µs)"),
        ("min_dir_setup_us", "min DIR setup (µs)")))


def _timing_section(host, result: dict, samples: RunSamples) -> Section:
    title = "timing: the simulator against the twin"
    if "hold" in result:
        return Section("timing", title, missing="a held or overridden run is compared with the dilated twin (its "
                                                "figures are in the table above)")
    errors = samples.timing_us()  # on the twin's clock: the heaters' holds taken out
    if not errors:
        return Section("timing", title, missing="no motor's simulated pulses pair with the twin's")
    return Section("timing", title, plots.timing_figure(errors, MAX_TIMING_ERROR_US + host.target.isr_latency_us))


def _ring_section(host, result: dict, trace, end_s: float) -> Section:
    """`end_s`: the run's last pulse, from the player's tick 0."""
    title = "ring fill over time"
    fill = trace.ring_fill
    if not len(fill):
        return Section("ring-fill", title, missing="the simulated session recorded no fill of the ring")
    start = trace.timer_start_cycle or 0
    ring = host.link_plan.summary().get("ring_bytes") or int(fill[:, 1].max())
    return Section("ring-fill", title, plots.ring_fill_figure((fill[:, 0] - start) / trace.f_cpu, fill[:, 1], ring,
                                                              result["link"].get("planned_min_ring_fill_bytes"), end_s,
                                                              RING_FILL_WHEN[host.target.target]))


def _heater_section(host, result: dict, trace, timeline) -> Section:
    title = "heaters: temperature against target"
    plants = getattr(trace, "plants", None)
    if not plants:
        return Section("heaters", title, missing="this run kept no plant trace (a held or overridden run)")
    curves = {}
    for name, plant in plants.items():
        target_t, target_c = plots.heater_targets(timeline, host.target.tick_hz, trace, name)
        if len(target_t):  # a heater the program never sets stays at ambient: not drawn
            curves[name] = (plant.time_s, plant.temp_c, target_t, target_c)
    if not curves:
        return Section("heaters", title, missing="the program sets no heater's target (the fan's only)")
    return Section("heaters", title, plots.heater_figure(curves, result.get("holds", []),
                                                         result.get("table_start_s")))


def _vibration_section(vibration: dict) -> Section:
    title = "toolhead vibration at the worst acceleration change, shaped against unshaped"
    if not any(v["worst"] is not None for v in vibration.values()):
        return Section("vibration", title, missing="no acceleration change was measured")
    return Section("vibration", title, plots.vibration_figure(vibration),
                   caption="The toolhead modelled as a damped spring driven by the pulses (verify --resonance); the "
                           "residual each run leaves, as measured once the commanded acceleration is constant again.")


def write_verify_report(path: Path, host, result: dict, trace, samples: RunSamples) -> None:
    """verify --report: the planned and simulated paths, the simulated motors' motion, the timing against the twin,
    and for a stream its ring fill, for heaters their temperatures, drawn from `samples` (gathered as the run was
    compared) and `trace` (the run's slow pins, a stream's ring fill; with heaters, codegen/verify/heaters.py's
    HeatedTrace), on the simulated clock."""
    power = host.laser is not None
    simulated = plots.simulated_path(host, samples, trace, power) if samples.count > 1 else None
    duration = samples.duration_s
    motion = plots.motion_from_grid(*samples.positions(), duration, host.kin.limits.steps_per_mm) \
        if duration > 0 else None
    sections = [_path_section(host, samples.planned.result(), simulated),
                _motion_section(host, motion, duration, "simulated pulses"),
                _timing_section(host, result, samples)]
    if "link" in result:
        sections.append(_ring_section(host, result, trace, duration))
    if "heaters" in result:
        sections.append(_heater_section(host, result, trace, samples.timeline))
    if "vibration" in result:
        sections.append(_vibration_section(result["vibration"]))
    _write(path, _page(f"verify {host.job.name}", result["pass"], _verify_header(host, result), sections,
                       result.get("problems", [])))

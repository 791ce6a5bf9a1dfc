"""Pressure advance through the host pipeline (codegen/pipeline/shaping.py, codegen/motion/advance.py): the
tables carry Klipper's advanced extruder, its pulses stay within a step of the formula, it ends where the program
does, its limits hold on its pulses, and a formula with K off by 10 % fails the check at its place."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codegen.motion.pieces as pieces
from codegen.errors import JobError
from codegen.job import load_job
from codegen.motion.shapers import make_shaper
from codegen.pipeline.host import host_build
from codegen.report.summaries import human_plan, plan_summary
from codegen.toolpath.segments import Segments
from codegen.verify.advance import advance_check

E_STEPS = 415.0
MOTORS = {"cartesian": ("x", "y"), "corexy": ("a", "b")}


def job_text(gcode: str, advance: str | None = "{k: 0.05}", kinematics: str = "cartesian", extra: str = "") -> str:
    steppers = "".join(f"    {m}: {{steps_per_mm: 100, max_velocity: 200, max_accel: 3000}}\n"
                       for m in MOTORS[kinematics])
    return (f"machine:\n  kinematics: {kinematics}\n  steppers:\n{steppers}"
            f"    z: {{steps_per_mm: 400, max_velocity: 12, max_accel: 400}}\n"
            f"    e: {{steps_per_mm: {E_STEPS:g}, max_velocity: 80, max_accel: 5000}}\n"
            + ("" if advance is None else f"  pressure_advance: {advance}\n") + extra
            + "program:\n  start: [10, 10]\n  gcode: |\n" + textwrap.indent(gcode, "    "))


def built(tmp_path: Path, text: str, name: str = "job"):
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    return host_build(load_job(path))


LINE = "G90\nM83\nG1 X110 Y10 E10 F3000\n"  # 100 mm at 50 mm/s: the extruder at 5 mm/s, K 0.05 leads 0.25 mm


def twin_e(host, t: np.ndarray) -> np.ndarray:
    """The twin's extruder step (absolute) after the last event at or before each time."""
    e = host.kin.motors.index("e")
    event = np.searchsorted(host.events.time, t, side="right") - 1
    return host.start_steps[e] + host.pulses.event_position[event, e]


def test_the_extruder_leads_by_k_times_its_velocity_while_cruising(tmp_path):
    """Mid-cruise the advanced extruder is K v_e = 0.25 mm (103.75 steps) ahead of the nominal one, a step at most
    off; it ends where the program ends."""
    host = built(tmp_path, job_text(LINE))
    plain = built(tmp_path, job_text(LINE, advance=None), "plain")
    assert host.findings.ok and plain.findings.ok, host.findings.problems
    _, plan = host.planned
    shift = host.settings.stages.shaping.shift
    assert shift == 0.02  # half the smoothing time: x and y unshaped, but on the delayed clock
    cruise = plan.t_start[0] + plan.t_acc[0] + np.array([0.1, 0.5, 1.0])
    s = plan.s_acc[0] + plan.v_peak[0] * (cruise - plan.t_start[0] - plan.t_acc[0])
    nominal = s / plan.length[0] * 10.0 * E_STEPS
    lead = twin_e(host, cruise + shift) - nominal
    assert np.all(np.abs(lead - 0.05 * 5.0 * E_STEPS) <= 1.0), lead
    assert host.findings.final["e"] == plain.findings.final["e"] == 4150
    assert plain.findings.steps["e"] == 4150  # the advanced extruder turns back as it slows down (K a > v): more
    assert host.findings.steps["e"] > 4150
    assert 0.0 < host.findings.advance_steps <= 1.0 and plain.findings.advance_steps is None


def test_decelerating_the_extruder_turns_back_and_the_summary_says_how_close(tmp_path):
    """A short extruding move at high acceleration: K a exceeds the extruder's velocity as it slows down, so it
    retracts (steps both ways, the same end); `plan` reports the formula check."""
    gcode = "G90\nM83\nG1 X20 Y10 E0.5 F6000\nG1 X20 Y20 E0.5\n"
    host = built(tmp_path, job_text(gcode, "{k: 0.2, smooth_time: 0.02}"))
    assert host.findings.ok, host.findings.problems
    assert host.findings.final["e"] == round(1.0 * E_STEPS)
    assert host.findings.steps["e"] > host.findings.final["e"] + 20  # it went back and forth
    summary = plan_summary(host)
    advance = summary["pressure_advance"]
    assert (advance["k"], advance["smooth_time_s"]) == (0.2, 0.02) and advance["max_deviation_steps"] <= 1.0
    assert f"pressure advance K 0.2 s, smoothing 0.02 s: the extruder within {advance['max_deviation_steps']:.3f} " \
           "steps of the formula" in human_plan(summary)


def extruder_pulses(host) -> tuple:
    """The twin's extruder pulses as AdvanceCheck.add takes them (verify's simulated ones in its place): played
    times (s), motors, directions, and each one's planned time, where the formula is read."""
    mine = host.pulses.motor == host.kin.motors.index("e")
    return (host.pulses.tick[mine] / host.target.tick_hz, host.pulses.motor[mine], host.pulses.dir[mine],
            None, host.events.time[host.pulses.event[mine]])


def scaled(segments: Segments, factor: float) -> Segments:
    return segments.take(np.arange(len(segments)), advance=segments.advance * factor)


@pytest.mark.parametrize("kinematics", ["cartesian", "corexy"])
def test_a_formula_with_k_off_by_ten_percent_fails_at_its_line(tmp_path, kinematics):
    """The twin's pulses against the formula (codegen/verify/advance.py, as verify holds the simulator's): with the
    job's K within a step; with 1.1 K, a problem naming the extruder, when, and the G-code line."""
    gcode = "G90\nM83\nG1 X60 Y10 E2 F3000\nG1 X60 Y50 E2\nG1 E-1 F2100\nG1 X20 Y20 F9000\nG1 E1 F2100\n" \
            "M900 K0.08\nG2 X40 Y40 I10 J10 E1.5 F2400\n"
    host = built(tmp_path, job_text(gcode, kinematics=kinematics))
    assert host.findings.ok, host.findings.problems
    right, wrong = advance_check(host), advance_check(host, scaled(host.planned[0], 1.1))
    for check in (right, wrong):
        check.add(*extruder_pulses(host))
    assert right.problems() == [] and right.worst[0] == pytest.approx(host.findings.advance_steps)
    (problem,) = wrong.problems()
    steps, when, line = wrong.worst
    assert steps > 3.0 and 14 <= line <= 22  # a line of the G-code (the job file's line 14 on)
    assert problem == f"motor e (the extruder) is {steps:.2f} steps from the pressure advance formula at " \
                      f"{when:.4f} s on G-code line {line} (limit 1 step)"


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(moves=st.lists(st.tuples(st.integers(0, 80), st.integers(0, 80), st.floats(-1.0, 2.0),
                                st.sampled_from([1200, 3000, 6000])), min_size=2, max_size=6),
       k=st.floats(0.0, 0.15), smooth=st.sampled_from([0.01, 0.04, 0.1]))
def test_random_moves_and_k_end_where_the_program_does_within_a_step_of_the_formula(tmp_path, moves, k, smooth):
    gcode = "G90\nM83\n" + "".join(f"G1 X{x + 10} Y{y + 10} E{de:.3f} F{f}\n" for x, y, de, f in moves)
    host = built(tmp_path, job_text(gcode, f"{{k: {k:.4f}, smooth_time: {smooth}}}"))
    f = host.findings
    assert f.ok, f.problems
    assert f.final == f.expected_final
    assert (f.advance_steps or 0.0) <= 1.0  # None where nothing moves
    assert f.rate_ratio["e"] <= 1.0 and f.accel_ratio["e"] <= 1.0


def test_k_0_plays_the_nominal_extruder_as_a_job_without_pressure_advance(tmp_path):
    """Klipper turns the smoothing off with K 0: the same extruder steps at the same times as without pressure
    advance (both shaped MZV 50 Hz, whose delay is longer than half the smoothing time: one clock), and the
    formula the pulses are held against is the nominal extruder."""
    gcode = "G90\nM83\nG1 X60 Y10 E2 F3000\nG1 X60 Y50 E2\nG1 E-1 F2100\nG1 X20 Y20 F9000\nG1 E1 F2100\n" \
            "G2 X40 Y40 I10 J10 E1.5 F2400\n"
    mzv = "  input_shaper: {x: {type: mzv, freq: 50}, y: {type: mzv, freq: 50}}\n"
    host = built(tmp_path, job_text(gcode, "{k: 0, smooth_time: 0.01}", extra=mzv))
    plain = built(tmp_path, job_text(gcode, None, extra=mzv), "plain")
    assert host.findings.ok and plain.findings.ok, host.findings.problems
    assert host.settings.stages.shaping.shift == plain.settings.stages.shaping.shift > 0.005
    e = host.kin.motors.index("e")
    (tick, direction), (plain_tick, plain_direction) = host.pulses.of_motor(e), plain.pulses.of_motor(e)
    assert np.array_equal(tick, plain_tick) and np.array_equal(direction, plain_direction)
    assert host.findings.steps["e"] == round(7.5 * E_STEPS)  # no turning back: 5.5 mm, and 1 mm back and forth
    assert host.findings.advance_steps <= 0.5 and not [w for w in host.warnings if "pressure advance" in w.message]


def test_after_m900_k0_the_smoothing_goes_on_in_every_window(tmp_path, monkeypatch):
    """K 0.05, then M900 K0 before a zigzag with retractions, cut into many windows: the windows after it keep
    smoothing (the tail says so), as the formula of the whole plan does (one per era: codegen/verify/advance.py),
    so the pulses stay within a step of it."""
    zigzag = "".join(f"G1 X{10 + 3 * k} Y{10 + 40 * (k % 2)} E1 F6000\nG1 E-0.8 F2100\nG1 E0.8\n" for k in range(12))
    monkeypatch.setattr(pieces, "CHUNK_EVENTS", 1500)
    host = built(tmp_path, job_text(f"G90\nM83\nG1 X60 Y10 E2 F3000\nM900 K0\n{zigzag}"))
    assert host.findings.ok, host.findings.problems
    assert host.totals.windows >= 6
    check = advance_check(host)
    check.add(*extruder_pulses(host))
    assert check.problems() == [] and check.worst[0] == pytest.approx(host.findings.advance_steps)


def test_k_0_first_then_m900_later_is_held_to_the_formula_the_host_played(tmp_path, monkeypatch):
    """K 0 for the first windows, M900 K0.05 windows later: the host plays the nominal extruder until the first
    window with a K other than 0 and smooths from there on (Totals.smoothed_from), and the kept build's formula
    (codegen/verify/advance.py) is nominal up to there too, so the pulses are within a step of it throughout."""
    zigzag = "".join(f"G1 X{10 + 3 * k} Y{10 + 40 * (k % 2)} E1 F6000\nG1 E-0.8 F2100\nG1 E0.8\n" for k in range(12))
    monkeypatch.setattr(pieces, "CHUNK_EVENTS", 1500)
    host = built(tmp_path, job_text(f"G90\nM83\n{zigzag}M900 K0.05\n{zigzag}", "{k: 0}"))
    assert host.findings.ok, host.findings.problems
    assert host.totals.windows >= 6 and 0 < host.totals.smoothed_from[0] < np.inf
    check = advance_check(host)
    assert [r.half for r in check.references] == [0.0, 0.02]
    check.add(*extruder_pulses(host))
    assert check.problems() == [] and check.worst[0] == pytest.approx(host.findings.advance_steps)
    assert check.worst[0] <= 1.0


def test_k_0_with_a_first_window_shorter_than_the_delay_builds(tmp_path):
    """K 0 plays the nominal extruder on a clock half a smoothing time late; a first window (a 0.37 mm travel,
    0.02 s) that ends before that clock begins was an empty stretch, and shaped_blocks failed (IndexError). The
    nominal extruder rests a half width either side, as the smoothed one does."""
    gcode = "G0 X0.250 Y36.722\nG2 X0.2496 Y36.7215 I0.4534 J0.2751\n"
    text = job_text(gcode, "{k: 0}").replace("start: [10, 10]", "start: [0, 37]")
    host = built(tmp_path, text)
    assert host.findings.ok, host.findings.problems
    assert host.totals.windows >= 2 and host.findings.steps["e"] == 0


@pytest.mark.parametrize("text, message", [
    ("{k: -0.1}", "machine.pressure_advance.k: must be >= 0"),
    ("{k: 0.05, smooth_time: 0.3}", "machine.pressure_advance.smooth_time: must be > 0 and <= 0.2 (s, Klipper's "
                                    "range)"),
    ("{k: 0.05, smooth_time: 0}", "machine.pressure_advance.smooth_time: must be > 0 and <= 0.2 (s, Klipper's "
                                  "range)"),
    ("{k: 0.05, smoth_time: 0.02}", "machine.pressure_advance: unknown key 'smoth_time' (did you mean "
                                    "'smooth_time'?)"),
])
def test_pressure_advance_errors_point_at_their_key(tmp_path, text, message):
    path = tmp_path / "job.yaml"
    path.write_text(job_text(LINE, text))
    with pytest.raises(JobError) as caught:
        load_job(path)
    (diagnostic,) = caught.value.diagnostics
    assert (diagnostic.where.line, diagnostic.message) == (8, message)


DELTA_SQUARE = """G28
G1 Z0.3 F3000
G1 X20 Y0 F3000
M83
G1 X40 Y0 E1.0 F2400
G1 X40 Y20 E1.0
G1 X20 Y20 E1.0
G1 X20 Y0 E1.0
G1 E-1 F2400
G1 X0 Y0 F6000
"""


def test_a_delta_advances_its_extruder_beside_its_carriages(tmp_path):
    """A delta's carriages are cut from the shaped motion (codegen/motion/shaped_delta.py), and the advanced
    extruder with them: every check passes, the extruder ends where the program does, and it makes more steps
    than without the advance (it turns back as the moves slow down)."""
    text = ("machine:\n  kinematics: delta\n  steppers:\n"
            + "".join(f"    {m}: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}\n" for m in "abc")
            + f"    e: {{steps_per_mm: {E_STEPS:g}, max_velocity: 60, max_accel: 5000}}\n"
            "  delta: {radius: 105.2, diagonal_rod: 215, height: 250}\n  pressure_advance: {k: 0.05}\n"
            "program:\n  gcode: |\n" + textwrap.indent(DELTA_SQUARE, "    "))
    host = built(tmp_path, text)
    plain = built(tmp_path, text.replace("  pressure_advance: {k: 0.05}\n", ""), "plain")
    f = host.findings
    assert f.ok, f.problems
    assert f.final == f.expected_final == plain.findings.final and f.final["e"] == round(3 * E_STEPS)
    assert f.advance_steps <= 1.0
    assert f.steps["e"] > plain.findings.steps["e"] + 20


def test_the_plan_slows_where_the_advance_breaks_the_extruders_limits_and_says_where(tmp_path):
    """K 0.1 on an extruder allowed 20 mm/s and 300 mm/s^2: the advanced pulses break them at first, so the plan
    slows the moves under them until they hold (checked on the pulses), with a note at the first such line."""
    gcode = "G90\nM83\nG1 X60 Y10 E2 F3000\nG1 X60 Y50 E2\nG1 X20 Y20 F9000\nG1 X40 Y40 E1.5 F2400\n"
    text = job_text(gcode, "{k: 0.1}").replace("max_velocity: 80, max_accel: 5000", "max_velocity: 20, max_accel: 300")
    host = built(tmp_path, text)
    plain = built(tmp_path, text.replace("  pressure_advance: {k: 0.1}\n", ""), "plain")
    f = host.findings
    assert f.ok and f.rate_ratio["e"] <= 1.0 and f.accel_ratio["e"] <= 1.0 and f.advance_steps <= 1.0
    assert host.totals.duration_s > plain.totals.duration_s + 0.3  # slower than the plan without the advance
    (note,) = [w for w in host.warnings if "pressure advance" in w.message]
    assert note.severity == "note" and 14 <= note.where.line <= 17  # a move's line (the release spills over)
    assert note.message.startswith(f"pressure advance: the plan was slowed {host.totals.advance_slowed} times to "
                                   "keep motor e within its max_velocity and max_accel")
    assert not [w for w in plain.warnings if "pressure advance" in w.message]


def test_a_machine_without_an_extruder_is_refused_at_the_key(tmp_path):
    path = tmp_path / "plotter.yaml"
    path.write_text("machine:\n  kinematics: cartesian\n  steppers:\n"
                    "    x: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}\n"
                    "    y: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}\n"
                    "  pressure_advance: {k: 0.05}\nprogram:\n  gcode: |\n    G1 X1\n")
    with pytest.raises(JobError) as caught:
        load_job(path)
    (diagnostic,) = caught.value.diagnostics
    assert (diagnostic.where.line, diagnostic.message) == (
        6, "machine.pressure_advance: pressure advance needs an extruder (motor 'e')")


def test_m593_mid_program_shapes_what_follows_and_the_extruder_keeps_the_formula(tmp_path):
    """Pressure advance with M593s (codegen/pipeline/settings.py ShapingEras): each stretch keeps the job's advance
    and the K an M900 set before it; the stretch after `M593 F40` plays what a machine shaped ZV 40 Hz with that K
    plays, and the one after `M593 F0` what an unshaped machine with pressure advance plays (its extruder still
    advanced); the machine rests at each M593 while the advanced and shaped motion settles, and the twin's
    extruder stays within a step of the formula throughout, each stretch on its own clock."""
    square = "G1 X60 Y10 E2 F6000\nG1 X60 Y60 E2\nG1 X10 Y60 E2\nG1 X10 Y10 E2\n"
    zv40 = "{type: zv, freq: 40, damping: 0.1}"
    head = "G90\nM83\nG1 X60 Y10 E2 F6000\nM900 K0.08\nG1 X60 Y60 E2\nG1 X10 Y60 E2\nG1 X10 Y10 E2\n"
    host = built(tmp_path, job_text(f"{head}M593 F40 D0.1\n{square}M593 F0\n{square}"))
    shaped = built(tmp_path, job_text(f"G90\nM83\n{square}", "{k: 0.08}", extra=f"  input_shaper: {{x: {zv40}, "
                                      f"y: {zv40}}}\n"), "shaped")
    plain = built(tmp_path, job_text(f"G90\nM83\n{square}", "{k: 0.08}"), "plain")
    assert host.findings.ok, host.findings.problems
    assert all(s is not None and s.advance.smooth_time == 0.04 for s in host.shapings) and len(host.shapings) == 3
    assert [s.shaped for s in host.shapings] == [False, True, False]  # after F0: xyz unshaped, the extruder advanced
    x, y, z = host.shapings[1].shapers
    assert z is None and x.name == y.name == "zv" and np.allclose(x.times, make_shaper("zv", 40, 0.1).times)
    segments, plan = host.planned
    assert set(np.round(segments.advance[segments.shaping > 0], 6)) == {0.08}  # M900's K goes on across the M593s
    rests = segments.dwell > 0
    assert segments.dwell[rests] == pytest.approx([s.spread for s in host.shapings[:2]])  # 0.04 s: the smoothing
    # Each stretch after an M593 plays the events of the same moves on its own machine, from where its era begins,
    # until the plan's motion ends, and ends at the same steps. The advanced extruder is fitted on another clock
    # (and has the rest's breaks besides), so as a slave of x and y it may take a step one event sooner or later.
    era_start = plan.t_start[np.flatnonzero(np.diff(segments.shaping)) + 1]
    for part, begin in zip((shaped, plain), era_start):
        mine = (host.events.time > begin + 1e-9) & (host.events.time <= begin + part.totals.duration_s + 1e-9)
        time, position = host.events.time[mine] - begin, host.pulses.event_position[mine]
        offset = position[0] - part.pulses.event_position[0]
        moving = part.events.time < part.totals.duration_s - part.shapings[0].spread
        assert np.abs(time[:np.sum(moving)] - part.events.time[moving]).max() <= 1e-9
        apart = position[:np.sum(moving)] - part.pulses.event_position[moving] - offset
        assert not np.any(apart[:, :3]) and np.abs(apart[:, 3]).max() <= 1
        assert np.array_equal(position[-1], part.pulses.event_position[-1] + offset)
    # The twin's extruder against the formula as verify holds it (a reference per era), within a step.
    check = advance_check(host)
    check.add(*extruder_pulses(host))
    assert len(check.references) == 3 and check.problems() == []
    assert check.worst[0] == pytest.approx(host.findings.advance_steps) and host.findings.advance_steps <= 1.0

"""M593 through the host pipeline: each stretch of the program between M593s is shaped by its own shapers, in its
own windows; the machine rests at each M593 while the motion shaped before settles. A job with M593s plays, stretch
by stretch, exactly what separate jobs with those shapers in the machine play, one after the other."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codegen.motion.pieces as pieces
import codegen.pipeline.host as host_module
from codegen.job import load_job
from codegen.motion.shapers import make_shaper
from codegen.report.summaries import plan_summary
from codegen.toolpath.segments import WAIT_REST_S

SQUARE_A = "G1 X60 Y10 F9000\nG1 X60 Y60\nG1 X10 Y60\nG1 X10 Y30\n"  # from (10, 10)
SQUARE_B = "G1 X40 Y30 F9000\nG1 X40 Y50\nG1 X10 Y50\nG1 X10 Y10\n"  # from (10, 30)
ZV40 = "{type: zv, freq: 40, damping: 0.1}"


def built(tmp_path, gcode: str, name: str, shaper: str | None = None, start=(10, 10)):
    shaping = "" if shaper is None else f"  input_shaper: {{x: {shaper}, y: {shaper}}}\n"
    text = (f"name: {name}\nmachine:\n  kinematics: cartesian\n  steppers:\n"
            "    x: {steps_per_mm: 80, max_velocity: 250, max_accel: 3000}\n"
            "    y: {steps_per_mm: 80, max_velocity: 250, max_accel: 3000}\n"
            f"{shaping}program:\n  start: {list(start)}\n  gcode: |\n{textwrap.indent(gcode, '    ')}")
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    return host_module.host_build(load_job(path))


def events_within(host, begin: float, end: float) -> tuple[np.ndarray, np.ndarray]:
    """The events from `begin` to `end` (s): their times from `begin`, and the motors' positions (steps from the
    start)."""
    mine = (host.events.time > begin + 1e-9) & (host.events.time <= end + 1e-9)  # (not the rest's last, at begin)
    return host.events.time[mine] - begin, host.pulses.event_position[mine]


def assert_plays(joined, part, begin: float, offset: np.ndarray) -> None:
    """`joined`'s events from `begin` for as long as `part` lasts are `part`'s, `begin` later and `offset` steps on."""
    time, position = events_within(joined, begin, begin + part.totals.duration_s)
    assert len(time) == len(part.events.time)
    assert np.abs(time - part.events.time).max() <= 1e-9
    assert np.array_equal(position, part.pulses.event_position + offset)


def test_m593_shapes_what_follows_as_the_machines_shaper_would(tmp_path):
    """Unshaped, then M593 F40 D0.1 (Marlin's ZV on x and y): the stretch after it plays the events of the same
    moves on a machine shaped ZV 40 Hz, starting after the unshaped stretch and the M593's rest."""
    joined = built(tmp_path, f"{SQUARE_A}M593 F40 D0.1\n{SQUARE_B}", "joined")
    before = built(tmp_path, SQUARE_A, "before")
    after = built(tmp_path, SQUARE_B, "after", ZV40, start=(10, 30))
    assert joined.findings.ok, joined.findings.problems
    assert joined.shapings[0] is None and joined.shapings[1].shapers[0].name == "zv"
    begin = before.totals.duration_s + WAIT_REST_S
    assert_plays(joined, before, 0.0, 0)
    assert_plays(joined, after, begin, before.pulses.event_position[-1])
    assert joined.totals.duration_s == pytest.approx(begin + after.totals.duration_s, abs=1e-9)
    assert joined.findings.steps == {m: before.findings.steps[m] + after.findings.steps[m] for m in ("x", "y")}
    assert "M593" in joined.warnings[0].message and joined.warnings[0].severity == "note"
    assert plan_summary(joined)["input_shaper"]["m593_changes"] == 1


def test_the_motion_shaped_before_m593_settles_in_its_rest(tmp_path):
    """Shaped by the machine, then M593 F0: the machine rests the shaper's spread (the shaped motion comes to rest
    at the programmed point, every event of the first stretch as the shaped job alone plays it) and what follows
    is unshaped."""
    joined = built(tmp_path, f"{SQUARE_A}M593 F0\n{SQUARE_B}", "joined", ZV40)
    before = built(tmp_path, SQUARE_A, "before", ZV40)
    after = built(tmp_path, SQUARE_B, "after", start=(10, 30))
    spread = make_shaper("zv", 40.0, 0.1).duration  # ZV's two impulses: half a damped period apart
    assert spread == pytest.approx(1 / (2 * 40 * np.sqrt(1 - 0.01)))
    rest = joined.planned[0].dwell[joined.planned[0].dwell > 0]
    assert rest == pytest.approx([spread])
    assert joined.shapings[1] is None and joined.findings.ok, joined.findings.problems
    assert_plays(joined, before, 0.0, 0)
    assert_plays(joined, after, before.totals.duration_s, before.pulses.event_position[-1])
    assert joined.findings.final == after.findings.final == {"x": 800, "y": 800}  # at (10, 10), 80 steps a mm
    assert joined.findings.steps == {m: before.findings.steps[m] + after.findings.steps[m] for m in ("x", "y")}


def test_each_stretch_has_its_own_windows_and_shapers(tmp_path, monkeypatch):
    """Three stretches (MZV 40 Hz, then x at 55 Hz, then unshaped): no window spans an M593, with one window to a
    stretch or many, and the events are the same either way."""
    gcode = f"{SQUARE_A}M593 X F55\n{SQUARE_B}M593 F0\n{SQUARE_A.replace(' F9000', '')}"
    shaper = "{type: mzv, freq: 40, damping: 0.1}"
    few = built(tmp_path, gcode, "few", shaper)
    eras = []

    class Watched(host_module.Stages):
        def play(self, window, after, last):
            eras.append(tuple(np.unique(window.segments.shaping)))
            return super().play(window, after, last)

    monkeypatch.setattr(host_module, "Stages", Watched)
    monkeypatch.setattr(pieces, "CHUNK_EVENTS", 1500)
    many = built(tmp_path, gcode, "many", shaper)
    assert len(eras) > 6 and {len(e) for e in eras} == {1} and sorted(set(eras)) == [(0,), (1,), (2,)]
    durations = [None if s is None else [None if a is None else a.duration for a in s.shapers] for s in few.shapings]
    assert durations == [[make_shaper("mzv", 40).duration] * 2 + [None],
                         [make_shaper("mzv", 55).duration, make_shaper("mzv", 40).duration, None], None]
    assert few.findings.ok and many.findings.ok, many.findings.problems
    assert few.findings.steps == many.findings.steps and few.findings.final == many.findings.final
    assert_plays(many, few, 0.0, 0)


def test_a_stretch_slowed_to_keep_a_limit_delays_the_next(tmp_path):
    """A corexy corner that x shaped at 5 Hz would take over belt a's speed is slowed (codegen/pipeline/windows.py);
    the stretch after the M593 (planned once that one is played: codegen/motion/lookahead.py) starts when the
    slowed one has come to rest, not when its first plan would have."""
    zigzag = "".join(f"G1 X{60 - 6 * k} Y{60 if k % 2 else 54}\n" for k in range(1, 10))  # settled corners
    gcode = f"G1 X60 Y0 F9000\nG1 X60 Y60\nM593 F0\n{zigzag}"
    text = ("machine:\n  kinematics: corexy\n  steppers:\n"
            "    a: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}\n"
            "    b: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}\n"
            "  junction_deviation: 5\n  input_shaper: {x: {type: zv, freq: 5}}\n"
            f"program:\n  gcode: |\n{textwrap.indent(gcode, '    ')}")
    path = tmp_path / "slowed.yaml"
    path.write_text(text)
    host = host_module.host_build(load_job(path))
    (tmp_path / "plain.yaml").write_text(text.replace("  input_shaper: {x: {type: zv, freq: 5}}\n", ""))
    plain = host_module.host_build(load_job(tmp_path / "plain.yaml"))
    assert host.findings.ok, host.findings.problems
    assert max(host.findings.rate_ratio.values()) <= 1.0
    segments, plan = host.planned
    rest = int(np.flatnonzero(segments.dwell > 0)[0])
    assert plan.t_start[rest] > plain.plan.t_start[rest] + 0.05  # slowed (the plain job rests at the same place)
    assert plan.t_start[rest + 1] == pytest.approx(plan.t_start[rest] + plan.duration[rest], abs=1e-12)
    rest_end = plan.t_start[rest] + plan.duration[rest]
    moving = host.events.time[np.any(np.diff(host.pulses.event_position, axis=0, prepend=0) != 0, axis=1)]
    assert np.all(np.diff(host.events.time) > 0)
    assert moving[moving <= rest_end + 1e-9][-1] < rest_end  # the shaped motion settles in the rest
    assert moving[moving > rest_end + 1e-9][0] > rest_end  # and the next stretch starts after it


@st.composite
def programs(draw):
    """A polyline of corners with M593s between some of its moves (frequencies, off, one axis or both)."""
    count = draw(st.integers(2, 6))
    points = draw(st.lists(st.tuples(st.integers(5, 45), st.integers(5, 45)), min_size=count, max_size=count))
    lines = [f"G1 X{points[0][0]} Y{points[0][1]} F{draw(st.sampled_from((3000, 9000)))}"]
    for x, y in points[1:]:
        if draw(st.booleans()):
            axis = draw(st.sampled_from(("", " X", " Y")))
            lines.append(f"M593{axis} F{draw(st.sampled_from((0, 25, 40.5, 90)))}")
        lines.append(f"G1 X{x} Y{y}")
    return "\n".join(lines) + "\n", draw(st.sampled_from((None, ZV40, "{type: ei, freq: 60, damping: 0.2}")))


@settings(max_examples=10, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(programs())
def test_random_m593_programs_keep_every_check_and_rest_for_the_spread_before(tmp_path, program):
    gcode, shaper = program
    host = built(tmp_path, gcode, "random", shaper, start=(0, 0))
    assert host.findings.ok, host.findings.problems
    assert host.findings.final == host.findings.expected_final
    assert np.all(np.diff(host.events.time) >= 0)
    segments = host.segments if host.planned is None else host.planned[0]  # None: nothing shaped
    rests = np.flatnonzero(segments.dwell > 0)
    assert len(host.shapings) == gcode.count("M593") + 1 and len(rests) == gcode.count("M593")
    for rest in rests:  # each M593's rest: the shaped motion before it settles
        before = host.shapings[segments.shaping[rest]]
        assert segments.dwell[rest] == pytest.approx(max(WAIT_REST_S, 0.0 if before is None else before.spread))
        assert rest + 1 == len(segments) or segments.shaping[rest + 1] == segments.shaping[rest] + 1


def test_a_delta_plans_m593_era_by_era(tmp_path):
    """A delta is shaped in cartesian space (codegen/motion/shaped_delta.py); M593 changes its shapers there as on
    any machine: each era's, its rest, every check (its carriages within their limits and the path)."""
    path = tmp_path / "delta.yaml"
    path.write_text(
        "name: delta\nmachine:\n  kinematics: delta\n  steppers:\n"
        + "".join(f"    {m}: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}\n" for m in "abc")
        + "  delta: {radius: 105.2, diagonal_rod: 215, height: 250}\n"
        f"  input_shaper: {{x: {ZV40}, y: {ZV40}}}\nprogram:\n  start: [0, 0, 250]\n  gcode: |\n"
        + textwrap.indent("G1 X0 Y0 Z5 F6000\nG1 X30 Y0 F4000\nG1 X30 Y30\nM593 F55\nG1 X-30 Y30\nG1 X-30 Y-30\n"
                          "M593 F0\nG1 X0 Y0\n", "    "))
    host = host_module.host_build(load_job(path))
    assert host.findings.ok, host.findings.problems
    assert [None if s is None else s.shapers[0].duration for s in host.shapings] == pytest.approx(
        [make_shaper("zv", f, 0.1).duration for f in (40, 55)] + [None])
    segments, _ = host.planned
    assert segments.dwell[segments.dwell > 0] == pytest.approx([make_shaper("zv", f, 0.1).duration for f in (40, 55)])

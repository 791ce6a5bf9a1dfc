"""The plan and the twin against the rules codegen/verify/plan_checks.py states: the planned corner speeds against
Grbl's junction deviation (or the program's classic jerk), the twin's events against the rate runs' window. The
right builds pass; a doctored plan or twin, or the compressor with a wider window, or windows whose twin starts its
clock at 0 again (the mutants of scripts/mutants.py, in process), is named."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from codegen.job import load_job
from codegen.pipeline import windows
from codegen.pipeline.host import host_build
from codegen.tables import compress
from codegen.tables.twin import predict
from codegen.verify.chapters import Chapters, whole_chapter
from codegen.verify.plan_checks import PlanChecks
from tests.helpers import DATA

PLOTTER = """name: corner
target: avr
board: ramps-1.4
machine:
  kinematics: cartesian
  junction_deviation: 0.02
  steppers:
    x: {{steps_per_mm: 80, max_velocity: 60, max_accel: 1500, range: [0, 60]}}
    y: {{steps_per_mm: 80, max_velocity: 60, max_accel: 1500, range: [0, 60]}}
program:
  gcode: |
    G21 G90 F2400
{moves}
"""
TURN_45 = "G1 X10\nG1 X20 Y10"  # junction 1 turns 45 degrees
# Grbl's rule there: the normal (-sin 22.5, cos 22.5) gets 1500 / cos 22.5 mm/s^2 from the motors, sin(theta/2) =
# cos 22.5, so v^2 = 1500 * jd / (1 - cos 22.5).
HALF = math.cos(math.radians(22.5))


def planned(tmp_path: Path, moves: str):
    path = tmp_path / "corner.yaml"
    path.write_text(PLOTTER.format(moves="\n".join("    " + line for line in moves.splitlines())))
    return host_build(load_job(path))


def with_speed(chapter, junction: int, speed: float):
    v_entry = chapter.plan.v_entry.copy()
    v_entry[junction] = speed
    return replace(chapter, plan=replace(chapter.plan, v_entry=v_entry))


@pytest.mark.parametrize("moves, planned_speed, doctored, rule", [
    (TURN_45, math.sqrt(0.98 * 1500 * 0.02 / (1 - HALF)), 25.0, "the junction deviation 0.02 mm allows 19.9"),
    ("M205 J0.08\n" + TURN_45, math.sqrt(0.98 * 1500 * 0.08 / (1 - HALF)), 45.0,
     "the junction deviation 0.08 mm allows 39.7"),
    ("M205 X5 Y5\n" + TURN_45, 5 / math.sin(math.radians(45)), 9.0, "the jerk set there allows 7.1"),  # y's jerk
    ("G1 X10\nG1 X2", 0.0, 3.0, "the junction deviation 0.02 mm allows 0.0"),  # a full reversal stops
], ids=["machine's deviation", "M205 J", "M205 X Y jerk", "reversal"])
def test_a_corner_faster_than_its_rule_allows_is_named(tmp_path, moves, planned_speed, doctored, rule):
    host = planned(tmp_path, moves)
    assert host.plan.v_entry[1] == pytest.approx(planned_speed, rel=1e-6)  # the rule binds there
    chapter = whole_chapter(host)
    assert PlanChecks(host).add(chapter) == []
    [problem] = PlanChecks(host).add(with_speed(chapter, 1, doctored))
    line = int(host.segments.line[1])  # the G-code line the corner begins (inline: the job file's)
    assert line > 0 and problem == (f"corner at {host.plan.t_start[1]:.3f} s (segment 1, where G-code line {line} "
                                    f"begins): planned {doctored:.1f} mm/s where {rule} mm/s")


def test_the_corner_with_the_chapter_before_is_checked_and_counted_on(tmp_path):
    host = planned(tmp_path, "G1 X5\n" + TURN_45)  # junction 2 turns 45 degrees
    plan, segments = host.plan, host.segments
    first = whole_chapter(host)
    later = replace(first, segments=segments.take(np.arange(1, 3)), before=segments.take(np.arange(1)),
                    plan=replace(plan, **{name: getattr(plan, name)[1:] for name in ("length", "direction", "v_entry",
                                                                                    "t_start")}))
    checks = PlanChecks(host, timing=False)
    assert checks.add(later) == [] and checks.segments == 2
    checks.segments = 1  # a chapter of the first segment came before
    [problem] = checks.add(with_speed(later, 1, 30.0))
    assert problem == (f"corner at {plan.t_start[2]:.3f} s (segment 2, where G-code line {segments.line[2]} "
                       "begins): planned 30.0 mm/s where the junction deviation 0.02 mm allows 19.9 mm/s")


def timing_problem(event: int, away: float, window: float, outside: int = 1) -> str:
    return (f"timing: the twin plays event {event} {away:.0f} ticks from its planned time (the rate runs' window lets "
            f"an event move 5 % of its gap, at least 2 ticks, plus 1 of rounding: here {window:.0f} ticks; {outside} "
            "events outside)")


def with_ticks(chapter, event_tick: np.ndarray):
    return replace(chapter, pulses=replace(chapter.pulses, event_tick=event_tick))


def test_an_event_outside_the_rate_runs_window_is_named_and_a_late_block_start_is_not(tmp_path):
    host = planned(tmp_path, TURN_45)
    chapter = whole_chapter(host)
    assert PlanChecks(host).add(chapter) == []
    planned_tick = host.events.time * host.target.tick_hz
    ticks = host.pulses.event_tick
    k = len(ticks) // 3  # cruising along the first line, 625 ticks apart
    gap = planned_tick[k] - min(planned_tick[k - 1], ticks[k - 1])
    assert 600 < gap < 650 and k not in host.events.block_first
    moved = ticks.copy()
    moved[k] = round(planned_tick[k] - 0.1 * gap)
    [problem] = PlanChecks(host).add(with_ticks(chapter, moved))
    assert problem == timing_problem(k, planned_tick[k] - moved[k], 0.05 * gap + 1)
    start = host.events.block_first[1]  # the diagonal's first event: the player may need longer to load it
    later = ticks.copy()
    later[start] += 400
    assert PlanChecks(host).add(with_ticks(chapter, later)) == []
    later[start] -= 800
    [problem] = PlanChecks(host).add(with_ticks(chapter, later))
    assert problem.startswith(f"timing: the twin plays event {start} ")


FAST_DIAGONAL = """name: diagonal
target: avr
board: ramps-1.4
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 400, max_velocity: 200, max_accel: 10000, range: [0, 200]}
    y: {steps_per_mm: 400, max_velocity: 200, max_accel: 10000, range: [0, 200]}
program:
  gcode: |
    G21 G90
    G1 X95 Y95 F20000
"""


def test_a_block_loaded_at_its_motors_rate_catches_up_after_its_first_event(tmp_path):
    """38000 steps a motor: two blocks (MAX_MODULUS), the second loaded at 96.7 % of x's and y's rate, 26 ticks
    after the event before where the player needs 38: the compressor puts its first event back 17 ticks, and the
    events after catch up at the motors' rate, about 100 of them: the load's, not the rate runs' (verify named event
    19001, 18 ticks late, where the rule took only the first event as the player's)."""
    path = tmp_path / "diagonal.yaml"
    path.write_text(FAST_DIAGONAL)
    host = host_build(load_job(path))
    chapter = whole_chapter(host)
    start = host.events.block_first[1]
    planned_tick, ticks = host.events.time * host.target.tick_hz, host.pulses.event_tick
    assert start == 19000 and planned_tick[start] - planned_tick[start - 1] < 27
    late = ticks - planned_tick
    assert min(late[start], late[start + 1]) > 15 and np.count_nonzero(late[start:] > 3) > 50
    checks = PlanChecks(host)
    assert checks.add(chapter) == [] and checks.worst_timing <= 1.0
    later = ticks.copy()  # an event after the load later than the load
    later[start + 1] = round(planned_tick[start + 1] + late[start] + 8)  # the windows: 3 ticks each
    [problem] = PlanChecks(host).add(with_ticks(chapter, later))
    assert problem.startswith(f"timing: the twin plays event {start + 1} ")
    end = start + 500  # the block ending in the cruise, not caught up by its end: only its last event is named
    events = replace(chapter.events, block_first=np.insert(host.events.block_first, 2, end))
    later = ticks.copy()
    later[start + 100:end] = np.round(planned_tick[start + 100:end] + 10)
    assert PlanChecks(host).add(replace(chapter, events=events)) == []
    [problem] = PlanChecks(host).add(replace(with_ticks(chapter, later), events=events))
    assert problem.startswith(f"timing: the twin plays event {end - 1} 10 ticks ")
    assert problem.endswith("; 1 events outside)")


def chapters_of(job: Path, size: int = 1):
    """The job's chapters as verify makes them, a window each (size 1)."""
    out = []
    chapters = Chapters(out.append, size)
    host = host_build(load_job(job), keep=False, observe=chapters)
    chapters.close()
    return host, out


def test_a_rate_run_window_of_half_the_gap_is_named(monkeypatch):
    ellipse = DATA.parent.parent / "examples" / "ellipse.yaml"
    host, chapters = chapters_of(ellipse)
    checks = PlanChecks(host)
    assert [p for ch in chapters for p in checks.add(ch)] == [] and 0.95 < checks.worst_timing <= 1.0
    wide = (compress.TimingWindow(share=0.5),) + compress.compress.__defaults__[1:]
    monkeypatch.setattr(compress.compress, "__defaults__", wide)
    host, chapters = chapters_of(ellipse)
    checks = PlanChecks(host)
    [problem] = [p for ch in chapters for p in checks.add(ch)]
    assert problem.startswith("timing: the twin plays event ") and checks.worst_timing > 3.0


def test_windows_whose_twin_starts_at_clock_0_are_named(monkeypatch):
    job = DATA / "mutants" / "windows.yaml"
    host, chapters = chapters_of(job)
    assert [len(ch.segments) for ch in chapters] == [3, 3, 2]  # the x moves; the dwells and a y move; the y moves
    moves = [np.abs(ch.pulses.event_position[-1] - ch.pulses.event_position[0]) for ch in chapters]
    assert moves[0][1] == 0 and moves[1][0] == moves[2][0] == 0
    checks = PlanChecks(host)
    assert [p for ch in chapters for p in checks.add(ch)] == []
    monkeypatch.setattr(windows, "predict", lambda schedule, origin_fx, position: predict(schedule, 0, position))
    host, wrong = chapters_of(job)
    # The stages' checks find the third window's pulses running back in time and play the y moves as one window,
    # whose twin runs the whole x part early: no check of the stages' sees it.
    assert [len(ch.segments) for ch in wrong] == [3, 5]
    assert np.array_equal(wrong[0].pulses.event_tick, chapters[0].pulses.event_tick)
    planned_tick, played = wrong[1].events.time * host.target.tick_hz, wrong[1].pulses.event_tick
    shift = planned_tick - played
    assert np.all(np.abs(shift - chapters[0].pulses.event_tick[-1]) < 1000)
    checks = PlanChecks(host)
    problems = [p for ch in wrong for p in checks.add(ch)]
    before = np.minimum(np.append(chapters[0].events.time[-1] * host.target.tick_hz, planned_tick[:-1]),
                        np.append(chapters[0].pulses.event_tick[-1], played[:-1]))  # a window's runs count from there
    window = np.maximum(0.05 * (planned_tick - before), 2) + 1
    k = int(np.argmax(shift / window))
    event = len(chapters[0].events.time) + k
    assert problems == [timing_problem(event, shift[k], window[k], len(planned_tick))]

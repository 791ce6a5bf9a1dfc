"""codegen/verify/pins.py: the checks on hand-made pin waves, then images made wrong on purpose (the sources of a
tiny job rendered as `build` renders them, one line of the generated text changed, compiled with the project's own
build functions and run in the real simulator) that verify must fail with a message naming the fault."""

from __future__ import annotations

import importlib
import re
import shutil
from dataclasses import replace

import numpy as np
import pytest

from codegen.firmware.avr.image import build_image, render_sources
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.sim.avr import PinWave
from codegen.tables.format import stream_bytes
from codegen.verify.bounded import verify_flash
from codegen.verify.compare import compare, simulated_switches
from codegen.verify.pins import (DirCarry, HomingCarry, HomingPhase, dir_hold_chunk, first_off_level, homing_pace_chunk,
                                 level_at, level_problems, tool_off_problems)
from codegen.verify.results import verify_json
from tests.helpers import DATA

F_CPU = 16_000_000


def wave(initial, *changes):
    cycles, levels = zip(*changes) if changes else ((), ())
    return PinWave(initial, np.array(cycles, dtype=np.int64), np.array(levels, dtype=np.uint8))


# --- the checks on hand-made waves ---

def test_level_at_counts_a_change_from_its_own_cycle():
    w = wave(1, (10, 0), (20, 1))
    assert level_at(w, np.array([0, 9, 10, 19, 20, 99])).tolist() == [1, 1, 0, 0, 1, 1]
    assert first_off_level(w, 1, 0, 9) is None and first_off_level(w, 1, 0, 10) == 10
    assert first_off_level(w, 1, 15, 30) == 15 and first_off_level(w, 1, 20, 30) is None


def test_an_enable_that_drops_while_the_motors_step_is_named():
    enable = wave(0, (100, 0), (5_000, 1), (6_000, 0))  # active low: off from 5,000 to 6,000
    wanted = [("x.enable", 0, "ENABLE PD7 (driver of x, active low)")]
    assert level_problems({"x.enable": enable}, wanted, 200, 4_000, "while stepping", F_CPU) == []
    [problem] = level_problems({"x.enable": enable}, wanted, 200, 9_000, "while stepping", F_CPU)
    assert problem.startswith("ENABLE PD7 (driver of x, active low) is high at 0.312 ms")
    [missing] = level_problems({}, wanted, 200, 9_000, "while stepping", F_CPU)
    assert "not recorded" in missing


def test_a_held_pin_low_before_the_first_step_is_named():
    held = wave(1, (50, 0), (90_000, 1))  # main drives HALF/FULL low, and high only later
    wanted = [("held.P1_6", 1, "held pin P1.6 (L297 HALF/FULL, high = half-step mode)")]
    [problem] = level_problems({"held.P1_6": held}, wanted, 80_000, 100_000, "from the first STEP", F_CPU)
    assert "held pin P1.6 (L297 HALF/FULL" in problem and "is low when the first STEP rises (5.000 ms)" in problem


def test_the_tool_and_the_laser_stay_off_until_tick_0():
    no_duty = np.zeros((0, 2), dtype=np.int64)
    assert tool_off_problems(wave(0, (9_000, 1), (9_500, 0)), 1, no_duty, 8_000, 20_000, F_CPU) == []
    [on] = tool_off_problems(wave(0, (100, 1), (9_500, 0)), 1, no_duty, 8_000, 20_000, F_CPU)
    assert on.startswith("the tool is on at 0.006 ms, before the table starts")
    assert tool_off_problems(wave(0), 0, no_duty, None, 20_000, F_CPU)[0].startswith("the tool is on at 0.000 ms")
    duty = np.array([[10, 0], [400, 77], [9_000, 500]])
    [lit] = tool_off_problems(wave(0), 1, duty, 8_000, 20_000, F_CPU)
    assert lit.startswith("the laser's PWM holds 77 counts at 0.025 ms")


def test_dir_may_change_only_after_the_fall_and_the_hold_time():
    rise, fall = np.array([100, 1_000, 2_000]), np.array([132, 1_032, 2_032])
    fine = np.array([50, 140, 1_500])  # before any pulse, after a fall, between pulses
    assert dir_hold_chunk(rise, fall, fine, 40)[0].tolist() == []
    assert dir_hold_chunk(rise, fall, np.array([110, 1_000, 1_035, 2_050]), 40)[0].tolist() == [110, 1_000, 1_035]
    still_high = dir_hold_chunk(np.array([100]), np.array([]), np.array([5_000]), 4)[0]
    assert still_high.tolist() == [5_000]  # STEP never fell


def test_dir_hold_fed_a_chunk_at_a_time_finds_what_it_finds_at_once():
    rng = np.random.default_rng(5)
    rise = np.cumsum(rng.integers(60, 200, 400))
    fall = rise + 32
    moved = np.sort(rng.choice(np.arange(int(rise[-1]) + 100), 300, replace=False))
    whole, _ = dir_hold_chunk(rise, fall, moved, 40)
    carry, found = DirCarry(), []
    for lo, hi in zip(range(0, int(rise[-1]) + 200, 997), range(997, int(rise[-1]) + 1_200, 997)):
        part = (lambda a: a[(a >= lo) & (a < hi)])
        late, carry = dir_hold_chunk(part(rise), part(fall), part(moved), 40, carry)
        found += late.tolist()
    assert len(whole) > 10 and found == whole.tolist()


SLOW_AT_FAST = np.concatenate([np.arange(5) * 800, 20_000 + np.arange(3) * 800, 50_000 + np.arange(3) * 800])


def test_homing_pace_names_the_phase_at_the_wrong_interval():
    phases = [HomingPhase("motor x (switch x_min)", "fast approach", 5, 800),
              HomingPhase("motor x (switch x_min)", "back off", 3, 800),
              HomingPhase("motor x (switch x_min)", "slow approach", 3, 8_000)]
    good = np.concatenate([np.arange(5) * 800, 20_000 + np.arange(3) * 800, 50_000 + np.arange(3) * 8_000])
    assert homing_pace_chunk(good, phases, 16_000, 50, F_CPU)[0] == []
    [problem] = homing_pace_chunk(SLOW_AT_FAST, phases, 16_000, 50, F_CPU)[0]
    assert problem.startswith("homing motor x (switch x_min), slow approach: its step 1 comes 50.0 us after")
    assert "give 500.0 us" in problem
    no_pause = good.copy()
    no_pause[5:] -= 15_000
    [problem] = homing_pace_chunk(no_pause, phases, 16_000, 50, F_CPU)[0]
    assert "back off: its step 0 comes" in problem and "at least" in problem
    carry, found = HomingCarry(), []
    for part in np.array_split(SLOW_AT_FAST, 4):
        problems, carry = homing_pace_chunk(part, phases, 16_000, 50, F_CPU, carry)
        found += problems
    assert found == homing_pace_chunk(SLOW_AT_FAST, phases, 16_000, 50, F_CPU)[0] and carry.seen == 11


# --- images made wrong on purpose ---

TOOLS = {"avr": ("avr-gcc", "simavr"), "mcs51": ("sdcc", "s51")}


def verify_patched(tmp_path, job: str, patch=None, misread=None) -> dict:
    """verify's result for tests/data/mutants/<job>.yaml's image with `patch` (file name -> source text, changed in
    place; it must change something) applied to its sources; `misread` replaces the host (a bug in the host code:
    the image and verify's twin both follow it)."""
    host = host_build(load_job(DATA / "mutants" / f"{job}.yaml"))
    host = misread(host) if misread else host
    target = host.target.target
    if any(shutil.which(tool) is None for tool in TOOLS[target]):
        pytest.skip(f"needs {' and '.join(TOOLS[target])} (scripts/setup.sh installs them)")
    firmware = importlib.import_module(f"codegen.firmware.{target}.image")
    sources = firmware.render_sources(host.schedule, host.firmware_config())
    patched = dict(sources)
    if patch:
        patch(patched)
        assert patched != sources, "the patch changed nothing"
    image = firmware.build_image(patched, tmp_path / "out", stream_bytes(host.schedule))
    simulator = importlib.import_module(f"codegen.sim.{target}")
    switches = simulated_switches(host)
    budget = int((host.plan.total * 1.2 + 1.0) * host.target.f_cpu)
    trace = simulator.simulate(image.hex_path, host.firmware_config(), budget, switches=switches)
    return verify_json(host, compare(host, trace, switches), image)


def replace_once(sources: dict, name: str, pattern: str, new: str) -> None:
    text, count = re.subn(pattern, new, sources[name], count=1, flags=re.MULTILINE)
    assert count == 1, f"{pattern!r} not in {name}"
    sources[name] = text


def failed_with(result: dict, *words: str) -> str:
    """The problem that names the fault (every one of `words`), once verify has failed."""
    assert result["pass"] is False
    named = [p for p in result["problems"] if all(w in p for w in words)]
    assert named, result["problems"]
    return named[0]


def test_avr_drivers_never_enabled(tmp_path):
    # main's `PORTx &= ~(X_ENABLE_BIT)` becomes `|=`: the drivers are held disabled from the start
    result = verify_patched(tmp_path, "avr-home", lambda s: replace_once(
        s, "player.c", r"^(\s*PORT\w) &= ~(\(X_ENABLE_BIT\));", r"\1 |= \2;"))
    assert failed_with(result, "ENABLE PD7 (driver of x, active low) is high when the first STEP rises")


def test_mcs51_drivers_never_enabled(tmp_path):
    # at89c52's enables are active low and its pins come out of reset high: without main's line, never enabled
    result = verify_patched(tmp_path, "at89-home", lambda s: replace_once(
        s, "player.c", r"^.*/\* drivers on \*/\n", ""))
    assert failed_with(result, "ENABLE P2.0 (driver of x, active low) is high")


def test_mcs51_half_full_driven_low(tmp_path):
    result = verify_patched(tmp_path, "seed51-home", lambda s: replace_once(
        s, "player.c", r"^(\s*)P1 \|= 0x40; (/\* P1.6 high)", r"\1P1 &= 0xbf; \2"))
    assert failed_with(result, "held pin P1.6 (L297 HALF/FULL, high = half-step mode) is low")


def test_avr_tool_on_from_reset_through_homing(tmp_path):
    # main turns the tool on instead of off; the player's first block load turns it off again
    result = verify_patched(tmp_path, "avr-home", lambda s: replace_once(
        s, "player.c", r"^(\s*PORTB) &= ~TOOL_BIT;", r"\1 |= TOOL_BIT;"))
    assert failed_with(result, "the tool is on at", "before the table starts")


def test_avr_homing_slow_approach_at_the_fast_interval(tmp_path):
    result = verify_patched(tmp_path, "avr-home", lambda s: replace_once(
        s, "homing.c", r"PHASE_SLOW \? X_HOME_SLOW_TICKS", "PHASE_SLOW ? X_HOME_FAST_TICKS"))
    assert failed_with(result, "homing motor x (switch x_min), slow approach", "where the homing settings give")


def test_avr_dir_written_while_step_is_high(tmp_path):
    # a new block's DIR pins written before its STEP pins fall (the fall moved after them)
    def patch(sources):
        fall = ("    in T0, _SFR_IO_ADDR(PORTF)\n    andi T0, lo8(~STEP_F_PINS)\n"
                "    out _SFR_IO_ADDR(PORTF), T0 ; STEP x, y fall\n")
        head, dirs = sources["player_isr.S"].split(fall + "    ; the new block's DIR pins, then the tool\n", 1)
        dirs, tail = dirs.split("    set\n", 1)
        sources["player_isr.S"] = head + dirs + fall + "    set\n" + tail

    result = verify_patched(tmp_path, "avr-home", patch)
    assert failed_with(result, "DIR changes", "the A4988 needs DIR held 0.250 us after the rise and while STEP is high")


def test_homing_paced_by_the_job_not_by_its_reading_in_the_host(tmp_path):
    # program/homing.py reading the fast approach's speed from slow_speed: the image homes slowly, and the host's own
    # homing axes agree with it; verify reads the job's settings again
    def misread(host):
        return replace(host, homing=tuple(replace(h, fast_interval=h.slow_interval) for h in host.homing))

    result = verify_patched(tmp_path, "avr-home", misread=misread)
    assert failed_with(result, "homing motor x (switch x_min), fast approach", "the homing settings give 1250.0 us")


def test_avr_laser_pwm_period_not_the_plans(tmp_path):
    # ICR5 a sixteenth over the plan's TOP: every power 16/17 of what the tables say, with the same compare writes
    result = verify_patched(tmp_path, "laser-end", lambda s: replace_once(
        s, "laser.h", r"ICR5 = LASER_TOP;", "ICR5 = LASER_TOP + LASER_TOP / 16;"))
    assert failed_with(result, "laser: the PWM's TOP is", "counts, where the plan's period takes")


def test_a_run_out_of_time_names_what_went_wrong_first(tmp_path):
    """Timer1 at an eighth of its clock: homing (which Timer1 paces too) cannot end within the run's budget, and
    verify (comparing beside the simulator) says first where the pulses left the settings, then that the firmware
    did not finish."""
    if any(shutil.which(tool) is None for tool in TOOLS["avr"]):
        pytest.skip("needs avr-gcc and simavr (scripts/setup.sh installs them)")
    host = host_build(load_job(DATA / "mutants" / "avr-home.yaml"), keep="tables")
    sources = render_sources(host.schedule, host.firmware_config())
    replace_once(sources, "config.h", r"^#define TIMER1_CLOCK_BITS \((_BV\(\w+\))\)",
                 r"#define TIMER1_CLOCK_BITS (\1 | _BV(CS10))")
    image = build_image(sources, tmp_path / "out", stream_bytes(host.schedule))
    result, _ = verify_flash(host, image, (), False)
    assert result["pass"] is False
    assert "after the one before, where the homing settings give" in result["problems"][0], result["problems"]
    assert any(p.startswith("the firmware did not finish within") for p in result["problems"])

"""The 4-wire coil drive of the 8051 player (board coil-51), with the real SDCC and s51: every step against
tests/reference_player.py, and the exact half-step patterns seen on the coil port."""

from __future__ import annotations

import numpy as np
import pytest

from codegen.errors import BuildError
from codegen.firmware.mcs51.image import HALF_STEPS, render_sources
from codegen.sim.mcs51 import coil_steps
from tests.firmware.mcs51.helpers import build_and_run, check_plays, config, make_schedule
from tests.reference_player import play

COIL_SCHEDULE = [
    # X the master (a step at every event) +, Y a Bresenham slave -
    ((1, -1), (40, 17), 40, (20, 5), True, [(900 * 256, 0, 40)]),
    # both back, Y the master, X a slave; an accelerating run
    ((-1, 1), (13, 30), 30, (0, 29), False, [(1200 * 256 + 55, -2000, 30)]),
    # a dwell across a long wait (past 0xFFFF ticks), then both slaves in a long block record
    ((1, 1), (0, 0), 1, (0, 0), False, [(70_000 * 256 + 9, 0, 1)]),
    ((1, 1), (299, 150), 300, (150, 0), True, [(800 * 256, 0, 300)]),
]


def pattern(phase_x, phase_y):
    """P2 with X's coils on P2.0-P2.3 and Y's on P2.4-P2.7 at these phases."""
    bits = lambda ph, base: sum(b << (base + i) for i, b in enumerate(HALF_STEPS[ph]))  # noqa: E731
    return bits(phase_x, 0) | bits(phase_y, 4)


def test_coil_drive_plays_steps_and_half_step_patterns(tmp_path):
    sched = make_schedule(("x", "y"), COIL_SCHEDULE)
    cfg = config(("x", "y"), ("X", "Y"), board="coil-51", inverted=("y",))
    image, trace = build_and_run(sched, cfg, tmp_path)
    check_plays(sched, cfg, trace)
    assert trace.pulse_high_min_cycles == [None, None] and trace.dir_setup_min_cycles == [None, None]
    player = render_sources(sched, cfg)["player.c"]
    assert "mov P2,a" in player and "orl P2" not in player
    # The port itself: reset (0xFF), main's two writes (coils off, phase 0), then at each event the byte of both
    # phases, X's phase going + with its steps and Y's - (invert_dir), each change one half-step of one motor or
    # of both at once.
    writes = trace.coil_writes["P2"]
    values = writes[:, 1]
    assert values[0] == 0x00 and values[1] == pattern(0, 0)
    phase, expected, last_tick = [0, 0], [], None
    for tick, m, d in play(sched):
        phase[m] = (phase[m] + (d if m == 0 else -d)) % 8
        if tick == last_tick:  # both motors at one event: one write
            expected[-1] = pattern(*phase)
        else:
            expected.append(pattern(*phase))
        last_tick = tick
    changes = [int(v) for i, v in enumerate(values[2:], 2) if v != values[i - 1]]
    assert changes == expected
    assert len(values) > len(changes) + 2  # rewrites of the same byte (events without a step, long waits)
    assert image.flash_bytes < 2048


def test_coil_decode_refuses_a_skipped_phase():
    class Pin:
        port, bit, name = 2, 0, "P2.0"
    coils = []
    for b in range(4):
        p = Pin()
        p.bit, p.name = b, f"P2.{b}"
        coils.append(p)
    rec = np.array([[10, 2, pattern(0, 0)], [20, 2, pattern(1, 0)], [30, 2, pattern(0, 0)]])
    clock, way = coil_steps(rec, coils)
    assert clock.tolist() == [20, 30] and way.tolist() == [1, -1]
    with pytest.raises(BuildError, match="not one half-step"):
        coil_steps(np.array([[10, 2, pattern(0, 0)], [20, 2, pattern(2, 0)]]), coils)


def test_bad_coil_boards_are_refused(tmp_path, monkeypatch):
    """Coil ports carry nothing that changes during the run; a socket has 4 coil pins on one port."""
    import shutil

    import codegen.firmware.config as firmware_config
    from codegen.paths import targets_dir

    folder = tmp_path / "targets"
    folder.mkdir()
    shutil.copy(targets_dir() / "at89c52.yaml", folder)
    text = (targets_dir() / "coil-51.yaml").read_text()
    bad = {
        "share their port": text.replace("pin: P3.4", "pin: P2.7").replace("P2.7]", "P1.7]"),
        "4 coil pins": text.replace("P2.2, P2.3]", "P2.2]"),
        "one port": text.replace("P2.3]", "P1.3]"),
        "pins used twice": text.replace("P2.4,", "P2.0,"),
    }
    for k, (_, body) in enumerate(bad.items()):
        (folder / f"bad-{k}.yaml").write_text(body.replace("name: coil-51", f"name: bad-{k}"))
    monkeypatch.setattr(firmware_config, "targets_dir", lambda: folder)
    firmware_config.load_target.cache_clear()
    try:
        sched = make_schedule(("x", "y"), COIL_SCHEDULE[:1])
        for k, message in enumerate(bad):
            with pytest.raises(BuildError, match=message):
                render_sources(sched, config(("x", "y"), ("X", "Y"), board=f"bad-{k}"))
    finally:
        firmware_config.load_target.cache_clear()


COIL_JOB = """\
name: coil-plot
target: mcs51
board: coil-51
machine:
  kinematics: cartesian
  tolerance: 0.05
  steppers:
    x: {steps_per_mm: 20, max_velocity: 20, max_accel: 200, range: [0, 100], invert_dir: true}
    y: {steps_per_mm: 20, max_velocity: 20, max_accel: 200, range: [0, 100]}
program:
  feed: 600
  travel_feed: 1200
  shapes:
    - line: {from: [10, 10], to: [30, 15]}
    - arc: {center: [30, 30], radius: 8, start: 0, sweep: 180}
"""


def test_a_cartesian_job_verifies_on_the_coil_board(tmp_path, capsys):
    import json

    from tests.helpers import run_cli as run

    job = tmp_path / "coil.yaml"
    job.write_text(COIL_JOB, encoding="utf-8")
    code, out, _ = run(capsys, "verify", job, "--out", tmp_path / "out", "--json")
    result = json.loads(out)
    assert code == 0, result["problems"]
    for motor in result["motors"].values():
        assert motor["final"] == motor["expected_final"]
        assert motor["max_timing_error_us"] <= 5.0 and motor["max_rate_ratio"] <= 1.0
    assert result["max_path_error_mm"] <= result["path_limit_mm"]

"""The ATmega2560 player, end to end with the real avr-gcc and the real simavr: hand-made schedules are rendered,
built, run, and every simulated pulse is compared with a plain-Python reading of codegen/schedule.py's semantics.
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from codegen.errors import BuildError
from codegen.firmware import FirmwareConfig, MotorPins
from codegen.firmware.avr import build_image, render_sources
from codegen.schedule import Schedule
from codegen.sim.avr import simulate

F_CPU = 16_000_000
LATENCY_TOLERANCE = 4  # cycles around the constant compare-match-to-edge latency


def make_schedule(motors, blocks, final_tool=False):
    """blocks: (dirs, steps, modulus, init, tool, [(interval in 1/256 tick, add, count), ...])."""
    m = len(motors)
    runs = [r for b in blocks for r in b[5]]
    as_array = (lambda k, dtype: np.array([b[k] for b in blocks], dtype=dtype).reshape(len(blocks), m))
    return Schedule(
        motors=tuple(motors), tick_hz=F_CPU, block_dirs=as_array(0, np.int8), block_steps=as_array(1, np.int64),
        block_modulus=np.array([b[2] for b in blocks], dtype=np.int64), block_init=as_array(3, np.int64),
        block_tool=np.array([b[4] for b in blocks], dtype=bool),
        block_runs=np.concatenate([[0], np.cumsum([len(b[5]) for b in blocks])]).astype(np.int64),
        block_segment=np.zeros(len(blocks), dtype=np.int64),
        run_interval=np.array([r[0] for r in runs], dtype=np.int64),
        run_add=np.array([r[1] for r in runs], dtype=np.int64),
        run_count=np.array([r[2] for r in runs], dtype=np.int64), final_tool=final_tool)


def reference(schedule):
    """Pulses (tick, motor, dir) and, per block, the ticks of its first and last event (plain Python)."""
    pulses, spans, pos = [], [], 0
    for b in range(schedule.n_blocks):
        acc = [int(a) for a in schedule.block_init[b]]
        first = None
        for r in range(int(schedule.block_runs[b]), int(schedule.block_runs[b + 1])):
            interval = int(schedule.run_interval[r])
            for _ in range(int(schedule.run_count[r])):
                pos += interval
                first = pos >> 8 if first is None else first
                for m in range(len(schedule.motors)):
                    acc[m] -= int(schedule.block_steps[b, m])
                    if acc[m] < 0:
                        acc[m] += int(schedule.block_modulus[b])
                        pulses.append((pos >> 8, m, int(schedule.block_dirs[b, m])))
                interval += int(schedule.run_add[r])
        spans.append((first, pos >> 8))
    return pulses, spans


def config(motors, sockets, board="ramps-1.4", inverted=(), pulse_us=2.0):
    pins = tuple(MotorPins(n, s, invert_dir=n in inverted) for n, s in zip(motors, sockets))
    return FirmwareConfig("test", "tests/test_avr_firmware.py", "avr", board, pins, step_pulse_us=pulse_us)


def build_and_run(schedule, cfg, out_dir, budget=50_000_000):
    image = build_image(render_sources(schedule, cfg), out_dir, schedule.table_bytes())
    return image, simulate(image.hex_path, cfg, budget)


def check_plays(schedule, cfg, trace):
    """Same pulses (motor, dir, order) as the reference, each at its tick + one constant latency."""
    pulses, spans = reference(schedule)
    assert trace.state == "done"
    for m in range(len(schedule.motors)):
        ref = [(t, d) for t, mm, d in pulses if mm == m]
        mine = trace.step_motor == m
        assert mine.sum() == len(ref), f"motor {schedule.motors[m]}: pulse count"
        assert np.array_equal(trace.step_dir[mine], [d for _, d in ref]), f"motor {schedule.motors[m]}: dirs"
    ticks = np.array([t for t, _, _ in pulses], dtype=np.int64)
    motors = np.array([mm for _, mm, _ in pulses], dtype=np.int64)
    # Per motor, the k-th simulated pulse against the k-th reference pulse; with events far more than the
    # tolerance apart, one constant latency for all of them also fixes the order across motors.
    late = np.zeros(len(ticks), dtype=np.int64)
    for m in range(len(schedule.motors)):
        late[motors == m] = trace.step_cycle[trace.step_motor == m] - trace.timer_start_cycle - ticks[motors == m]
    latency = int(np.median(late))
    assert np.abs(late - latency).max() <= LATENCY_TOLERANCE, "a pulse off its scheduled tick"
    assert 0 < latency < 40
    pulse = int(np.ceil(cfg.step_pulse_us * F_CPU / 1e6))
    assert all(h is None or h >= pulse for h in trace.pulse_high_min_cycles)
    setup = int(np.ceil(cfg.dir_setup_us * F_CPU / 1e6))
    assert all(s is None or s >= setup for s in trace.dir_setup_min_cycles)
    return latency, spans


def test_blocks_runs_dwell_long_waits_and_tool(tmp_path):
    """Directions, slave motors, accelerating runs, a dwell with waits past 0xFFFF ticks and an add beyond 16 bits,
    the tool on and off."""
    sched = make_schedule(("x", "y", "z"), [
        ((1, 1, -1), (200, 150, 50), 200, (100, 100, 100), True,
         [(2000 * 256, -1000, 120), (1530 * 256 + 77, 0, 80)]),
        ((1, 1, 1), (0, 0, 0), 1, (0, 0, 0), False, [(70_000 * 256 + 123, 0, 1), (300_000 * 256, -2_000_000, 3)]),
        ((-1, 1, 1), (37, 100, 0), 100, (5, 99, 0), True, [(1500 * 256 + 77, 300, 100)]),
        ((1, -1, 1), (3, 7, 11), 11, (0, 6, 10), False, [(900 * 256, 0, 11)]),
    ], final_tool=True)
    cfg = config(("x", "y", "z"), ("X", "Y", "Z"))
    _, trace = build_and_run(sched, cfg, tmp_path)
    latency, spans = check_plays(sched, cfg, trace)
    # Tool: on before the timer starts, then set right after the last pulse of the block before each change.
    states = [on for _, on in trace.tool_edges]
    assert states == [1, 0, 1, 0, 1]
    assert trace.tool_edges[0][0] < trace.timer_start_cycle
    for (cycle, _), b in zip(trace.tool_edges[1:], (1, 2, 3)):
        previous_last, first = spans[b - 1][1], spans[b][0]
        assert previous_last + latency < cycle - trace.timer_start_cycle < first + latency
    assert trace.tool_edges[-1][0] > trace.step_cycle[-1]


def test_inverted_dir_other_sockets_and_long_pulses(tmp_path):
    """Motors on E0 and E1 of an MKS GEN L, one DIR inverted (step_dir undoes it), 5 us STEP pulses, a first
    event more than 0xFFFF ticks after the timer start."""
    sched = make_schedule(("x", "e", "b"), [
        ((1, 1, -1), (10, 20, 5), 20, (10, 10, 10), False, [(70_000 * 256 + 9, 0, 1), (400 * 256, 0, 19)]),
        ((-1, -1, 1), (20, 3, 20), 20, (0, 19, 7), False, [(300 * 256 + 200, 5, 20)]),
    ])
    cfg = config(("x", "e", "b"), ("X", "E0", "E1"), board="mks-gen-l", inverted=("e",), pulse_us=5.0)
    _, trace = build_and_run(sched, cfg, tmp_path)
    check_plays(sched, cfg, trace)
    assert min(trace.pulse_high_min_cycles) >= 80
    assert trace.tool_edges == []


def test_sources_and_image_are_deterministic(tmp_path):
    sched = make_schedule(("x", "y"), [((1, -1), (30, 20), 30, (15, 15), True, [(500 * 256, 0, 30)])])
    cfg = config(("x", "y"), ("X", "Y"))
    first, second = render_sources(sched, cfg), render_sources(sched, cfg)
    assert first == second
    assert first["player.c"].startswith(
        "/* AUTO-GENERATED by printer-codegen 0.1.0 from tests/test_avr_firmware.py (target avr). Do not edit. */")
    one = build_image(first, tmp_path / "one", sched.table_bytes())
    two = build_image(second, tmp_path / "two", sched.table_bytes())
    assert one.hex_path.read_bytes() == two.hex_path.read_bytes()
    assert one.flash_bytes < 4096 and one.ram_bytes < 256 and one.table_bytes == sched.table_bytes()


def test_no_float_division_or_sqrt_in_the_image(tmp_path):
    sched = make_schedule(("x",), [((1,), (5,), 5, (2,), False, [(500 * 256, 0, 5)])])
    image = build_image(render_sources(sched, config(("x",), ("X",))), tmp_path, sched.table_bytes())
    symbols = subprocess.run(["avr-nm", str(image.elf_path)], capture_output=True, text=True, check=True).stdout
    for helper in ("divmod", "__mul", "sf3", "sqrt", "__fix", "__float"):
        assert helper not in symbols


def test_table_above_64k_plays_through_far_reads(tmp_path):
    """A table of ~72 KB: the reads cross the 64 KB boundary, the code lands above it."""
    rng = np.random.default_rng(7)
    intervals = rng.integers(180 * 256, 400 * 256, 9000)
    runs = [(int(v), int(a), 1) for v, a in zip(intervals, rng.integers(-200, 200, 9000))]
    sched = make_schedule(("x", "y"), [((1, -1), (9000, 4321), 9000, (4500, 17), False, runs)])
    assert sched.table_bytes() > 65536
    cfg = config(("x", "y"), ("X", "Y"))
    image, trace = build_and_run(sched, cfg, tmp_path)
    assert image.flash_bytes > 65536
    check_plays(sched, cfg, trace)


def test_too_big_table_is_refused_with_the_sizes(tmp_path):
    sched = make_schedule(("x",), [((1,), (100,), 100, (0,), False, [(300 * 256, 0, 1)] * 33_000)])
    cfg = config(("x",), ("X",))
    small = make_schedule(("x",), [((1,), (1,), 1, (0,), False, [(300 * 256, 0, 1)])])
    build_image(render_sources(small, cfg), tmp_path, small.table_bytes())  # an earlier image must not survive
    with pytest.raises(BuildError) as error:
        build_image(render_sources(sched, cfg), tmp_path, sched.table_bytes())
    needed = int(str(error.value).split("needs ")[1].split()[0])
    assert needed > sched.table_bytes() > 262144 and "262144 available" in str(error.value)
    assert not (tmp_path / "firmware.hex").exists() and not (tmp_path / "firmware.elf").exists()


def test_compile_error_and_budget_raise_build_error(tmp_path):
    sched = make_schedule(("x",), [((1,), (1,), 1, (0,), False, [(10_000_000 * 256, 0, 2)])])
    cfg = config(("x",), ("X",))
    sources = render_sources(sched, cfg)
    with pytest.raises(BuildError, match="player.c"):
        build_image({**sources, "player.c": sources["player.c"] + "\nint broken(void) { return }\n"},
                    tmp_path / "bad", sched.table_bytes())
    assert not (tmp_path / "bad" / "firmware.hex").exists()
    image = build_image(sources, tmp_path / "good", sched.table_bytes())
    with pytest.raises(BuildError, match="did not finish"):
        simulate(image.hex_path, cfg, 1_000_000)


def test_every_socket_combination_builds_with_a_stackless_isr(tmp_path):
    """build_image refuses a naked ISR that spills to the stack: no RAMPS socket combination may trigger it."""
    sockets = ("X", "Y", "Z", "E0", "E1")
    for mask in range(1, 1 << len(sockets)):
        chosen = [s for i, s in enumerate(sockets) if mask >> i & 1]
        names = [f"m{i}" for i in range(len(chosen))]
        n = len(chosen)
        sched = make_schedule(names, [((1,) * n, (3,) * n, 3, (1,) * n, False, [(500 * 256, 0, 3)])])
        build_image(render_sources(sched, config(names, chosen, inverted=names[:1])), tmp_path / str(mask),
                    sched.table_bytes())

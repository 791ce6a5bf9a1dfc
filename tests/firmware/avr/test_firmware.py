"""The ATmega2560 player, end to end with the real avr-gcc and the real simavr: hand-made schedules in the compact
stream (codegen/tables/format.py) are rendered, built, run, and every simulated pulse is compared with
tests/reference_player.py's plain readings of the semantics (from the schedule and from the stream's bytes).
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

import codegen.tables.format as tables
from codegen.errors import BuildError
from codegen.firmware.avr.image import build_image, render_sources
from codegen.firmware.config import FirmwareConfig, MotorPins
from codegen.sim.avr import simulate
from codegen.tables.format import stream_bytes
from tests.firmware.avr.helpers import BLOCKS, CYCLES, F_CPU, RUNS, cut, make_schedule
from tests.helpers import block_spans
from tests.reference_player import play, play_stream

LATENCY_TOLERANCE = 4  # cycles around the constant compare-match-to-edge latency


def config(motors, sockets, board="ramps-1.4", inverted=(), pulse_us=2.0):
    pins = tuple(MotorPins(n, s, invert_dir=n in inverted) for n, s in zip(motors, sockets))
    return FirmwareConfig("test", "tests/firmware/avr/test_firmware.py", "avr", board, pins, step_pulse_us=pulse_us)


def build_and_run(schedule, cfg, out_dir, budget=100_000_000):
    image = build_image(render_sources(schedule, cfg), out_dir, stream_bytes(schedule))
    return image, simulate(image.hex_path, cfg, budget)


def check_plays(schedule, cfg, trace):
    """Same pulses (motor, dir, order) as the reference readings of the schedule and of its stream, each at
    CYCLES x its tick + one constant latency per motor; STEP pulses and DIR setup as long as the config says."""
    pulses = play(schedule)
    stream_pulses, _, final_tool = play_stream(tables.encode(schedule).data, len(schedule.motors))
    assert stream_pulses == pulses and final_tool == schedule.final_tool
    assert trace.state == "done"
    ticks = np.array([t for t, _, _ in pulses], dtype=np.int64)
    motors = np.array([mm for _, mm, _ in pulses], dtype=np.int64)
    latencies = []
    for m in range(len(schedule.motors)):
        mine = trace.step_motor == m
        assert mine.sum() == (motors == m).sum(), f"motor {schedule.motors[m]}: pulse count"
        assert np.array_equal(trace.step_dir[mine], [d for _, mm, d in pulses if mm == m]), \
            f"motor {schedule.motors[m]}: dirs"
        late = trace.step_cycle[mine] - trace.timer_start_cycle - CYCLES * ticks[motors == m]
        if len(late):
            assert np.abs(late - np.median(late)).max() <= LATENCY_TOLERANCE, "a pulse off its scheduled tick"
            latencies.append(int(np.median(late)))
    assert all(0 < late < 40 for late in latencies)
    pulse = int(np.ceil(cfg.step_pulse_us * F_CPU / 1e6))
    assert all(h is None or h >= pulse for h in trace.pulse_high_min_cycles)
    setup = int(np.ceil(cfg.dir_setup_us * F_CPU / 1e6))
    assert all(s is None or s >= setup for s in trace.dir_setup_min_cycles)
    return min(latencies, default=0)


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
    image, trace = build_and_run(sched, cfg, tmp_path)
    latency = check_plays(sched, cfg, trace)
    spans = block_spans(sched)
    # Tool: on at tick 0's block load (before the first event), then set right after the last pulse of the block
    # before each change, and the final state after the last pulse.
    assert [on for _, on in trace.tool_edges] == [1, 0, 1, 0, 1]
    assert trace.timer_start_cycle < trace.tool_edges[0][0] < trace.timer_start_cycle + CYCLES * spans[0][0]
    for (cycle, _), b in zip(trace.tool_edges[1:4], (1, 2, 3)):
        assert CYCLES * spans[b - 1][1] + latency < cycle - trace.timer_start_cycle < CYCLES * spans[b][0] + latency
    assert trace.tool_edges[-1][0] > trace.step_cycle[-1]
    assert image.flash_parts["table"] == stream_bytes(sched) and sum(image.flash_parts.values()) == image.flash_bytes


@pytest.mark.parametrize("motors, sockets, board", [
    (("x",), ("X",), "ramps-1.4"),
    (("x", "y"), ("X", "Y"), "ramps-1.4"),  # one STEP port, every motor in registers
    (("x", "y", "z"), ("X", "Y", "Z"), "ramps-1.4"),  # z's Bresenham in SRAM
    (("x", "y", "z", "e"), ("X", "Y", "Z", "E0"), "ramps-1.4"),
    (("x", "z", "e", "b"), ("X", "Z", "E0", "E1"), "mks-gen-l"),  # four STEP ports
])
def test_runs_go_on_across_blocks_in_short_and_long_records(motors, sockets, board, tmp_path):
    """The compact stream: short blocks (master left out, at any index) and long ones, a dwell, runs that start
    inside a block and go on across several, short and long run records, the end marker's tool; with 1 to 4
    motors (the format's limit), their Bresenham state in registers or in SRAM."""
    n = len(motors)
    sched = make_schedule(motors, cut(BLOCKS, n), final_tool=True, runs=RUNS)
    table = tables.encode(sched)
    assert table.counts()["long_blocks"] >= 2 and table.counts()["long_runs"] == 2
    cfg = config(motors, sockets, board=board, inverted=motors[1:2])
    image, trace = build_and_run(sched, cfg, tmp_path)
    check_plays(sched, cfg, trace)
    assert [on for _, on in trace.tool_edges] == [1, 0, 1, 0, 1]
    assert image.flash_parts["table"] == len(table.data)


def test_waits_around_one_timer_period(tmp_path):
    """Tick deltas just under, at and just over one timer period (0x10000 ticks), some with a carry from the
    fractional tick: the long path with and without compare B's periods."""
    runs = [(0xFF00 * 256, 0, 2), (0xFFFF * 256 + 200, 0, 3), (0x10000 * 256, 0, 2), (0x10000 * 256 - 1, 0, 2),
            (0x17FFF * 256 + 255, 0, 2), (600 * 256, 0, 5), (0x3FFFF * 256 + 128, -0x7FFFFF, 3)]
    blocks = [((1, -1), (19, 7), 19, (9, 3), False, 19)]
    sched = make_schedule(("x", "y"), blocks, runs=runs)
    cfg = config(("x", "y"), ("X", "Y"))
    _, trace = build_and_run(sched, cfg, tmp_path, budget=200_000_000)
    check_plays(sched, cfg, trace)


def test_inverted_dir_other_sockets_and_long_pulses(tmp_path):
    """Motors on E0 and E1 of an MKS GEN L, one DIR inverted (step_dir undoes it), 5 us STEP pulses, a first
    event more than 0xFFFF ticks after tick 0."""
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
    for name in ("player.c", "player_isr.S", "table.c", "config.h"):
        assert first[name].startswith(
            "/* AUTO-GENERATED by printer-codegen 0.1.0 from tests/firmware/avr/test_firmware.py (target avr). Do not edit. */")
    one = build_image(first, tmp_path / "one", stream_bytes(sched))
    two = build_image(second, tmp_path / "two", stream_bytes(sched))
    assert one.hex_path.read_bytes() == two.hex_path.read_bytes()
    assert one.flash_bytes < 4096 and one.ram_bytes < 256 and one.table_bytes == stream_bytes(sched)


def test_no_float_division_or_sqrt_in_the_image(tmp_path):
    sched = make_schedule(("x",), [((1,), (5,), 5, (2,), False, [(500 * 256, 0, 5)])])
    image = build_image(render_sources(sched, config(("x",), ("X",))), tmp_path, stream_bytes(sched))
    symbols = subprocess.run(["avr-nm", str(image.elf_path)], capture_output=True, text=True, check=True).stdout
    for helper in ("divmod", "__mul", "sf3", "sqrt", "__fix", "__float"):
        assert helper not in symbols


def test_table_above_64k_plays_through_far_reads(tmp_path):
    """A table of ~72 KB (12,000 short run records in one long block): the reads cross the 64 KB boundary (ELPM
    through RAMPZ) and the table's chunks, and the code lands above it."""
    rng = np.random.default_rng(7)
    n = 12_000
    intervals = rng.integers(180 * 256, 400 * 256, n)
    runs = [(int(v), int(a), 1) for v, a in zip(intervals, rng.integers(-200, 200, n))]
    sched = make_schedule(("x", "y"), [((1, -1), (n, 4321), n, (n // 2, 17), False, runs)])
    assert stream_bytes(sched) > 65536 and tables.encode(sched).counts()["short_runs"] == n
    cfg = config(("x", "y"), ("X", "Y"))
    image, trace = build_and_run(sched, cfg, tmp_path)
    assert image.flash_bytes > 65536 and len(render_sources(sched, cfg)["table.c"].split("PROGMEM")) == 4
    check_plays(sched, cfg, trace)


def test_too_big_table_is_refused_with_the_sizes(tmp_path):
    sched = make_schedule(("x",), [((1,), (22_500,), 22_500, (0,), False, [(300 * 256, 0, 1)] * 22_500)] * 2)
    cfg = config(("x",), ("X",))
    small = make_schedule(("x",), [((1,), (1,), 1, (0,), False, [(300 * 256, 0, 1)])])
    build_image(render_sources(small, cfg), tmp_path, stream_bytes(small))  # an earlier image must not survive
    with pytest.raises(BuildError) as error:
        build_image(render_sources(sched, cfg), tmp_path, stream_bytes(sched))
    needed = int(str(error.value).split("needs ")[1].split()[0])
    assert needed > stream_bytes(sched) > 262144 and "262144 available" in str(error.value)
    assert not (tmp_path / "firmware.hex").exists() and not (tmp_path / "firmware.elf").exists()


def test_compile_error_and_budget_raise_build_error(tmp_path):
    sched = make_schedule(("x",), [((1,), (1,), 1, (0,), False, [(10_000_000 * 256, 0, 1)])])
    cfg = config(("x",), ("X",))
    sources = render_sources(sched, cfg)
    with pytest.raises(BuildError, match="player.c"):
        build_image({**sources, "player.c": sources["player.c"] + "\nint broken(void) { return }\n"},
                    tmp_path / "bad", stream_bytes(sched))
    assert not (tmp_path / "bad" / "firmware.hex").exists()
    image = build_image(sources, tmp_path / "good", stream_bytes(sched))
    with pytest.raises(BuildError, match="did not finish"):
        simulate(image.hex_path, cfg, 1_000_000)


def test_every_socket_combination_builds_with_a_stackless_isr(tmp_path):
    """build_image refuses a step interrupt that touches the stack: no combination of up to four RAMPS sockets may
    trigger it; five motors are more than the compact stream holds."""
    sockets = ("X", "Y", "Z", "E0", "E1")
    for mask in range(1, 1 << len(sockets)):
        chosen = [s for i, s in enumerate(sockets) if mask >> i & 1]
        names = [f"m{i}" for i in range(len(chosen))]
        n = len(chosen)
        sched = make_schedule(names, [((1,) * n, (3,) * n, 3, (1,) * n, False, [(500 * 256, 0, 3)])])
        cfg = config(names, chosen, inverted=names[:1])
        if n > 4:
            with pytest.raises(BuildError, match="at most 4 motors"):
                render_sources(sched, cfg)
            continue
        build_image(render_sources(sched, cfg), tmp_path / str(mask), stream_bytes(sched))

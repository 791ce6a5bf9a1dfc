"""The 8051 player, end to end with the real SDCC and the real s51: hand-made schedules are rendered, built, run,
and every simulated pulse is compared with tests/reference_player.py's plain reading of codegen/tables/schedule.py.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import codegen.tables.format as tables
from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig
from codegen.firmware.mcs51.image import build_image, render_sources
from codegen.firmware.mcs51.sdcc import MAP_FILE, SYMBOLS_FILE
from codegen.program.homing import HomingAxis
from codegen.sim.mcs51 import simulate
from codegen.tables.format import stream_bytes
from tests.firmware.mcs51.helpers import CLOCKS, TOLERANCE, build_and_run, check_plays, config, make_schedule
from tests.helpers import block_spans
from tests.reference_player import play


def test_blocks_runs_dwell_long_waits_and_tool(tmp_path):
    """Directions, Bresenham slaves, accelerating runs, a dwell with waits past 0xFFFF ticks and an add beyond
    16 bits, the tool on and off, on the default board."""
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
    assert trace.timer_start_cycle < trace.tool_edges[0][0] < trace.timer_start_cycle + CLOCKS * spans[0][0]
    for (cycle, _), b in zip(trace.tool_edges[1:4], (1, 2, 3)):
        assert CLOCKS * spans[b - 1][1] + latency < cycle - trace.timer_start_cycle < CLOCKS * spans[b][0] + latency
    assert trace.tool_edges[-1][0] > trace.step_cycle[-1]
    assert image.flash_bytes < 2048 and image.ram_bytes < 64 and image.flash_parts["table"] == stream_bytes(sched)
    assert sum(image.flash_parts.values()) == image.flash_bytes and image.flash_parts["player"] < 1100


def test_seed_board_inverted_dir_long_pulses_and_a_first_long_wait(tmp_path):
    """The seed board (external RAM, model large, L297 pins with HALF/FULL held), one DIR inverted (step_dir undoes
    it), 20 us STEP pulses (the interrupt pads every path), a first event 200,000 ticks after tick 0, a run of 256
    events."""
    sched = make_schedule(("a", "b", "c"), [
        ((1, -1, -1), (10, 20, 5), 20, (10, 10, 10), False, [(200_000 * 256 + 9, 0, 1), (400 * 256, 0, 19)]),
        ((-1, -1, 1), (20, 3, 20), 20, (0, 19, 7), False, [(300 * 256 + 200, 5, 20)]),
        ((1, 1, 1), (260, 130, 7), 260, (2, 2, 259), False,
         [(500 * 256, 0, 1), (450 * 256, 0, 3), (300 * 256, 0, 256)]),
    ])
    cfg = config(("a", "b", "c"), ("X", "Y", "Z"), board="seed-51", inverted=("b",), pulse_us=20.0)
    image, trace = build_and_run(sched, cfg, tmp_path)
    check_plays(sched, cfg, trace)
    assert min(trace.pulse_high_min_cycles) >= 20 * CLOCKS
    assert trace.tool_edges == []
    assert image.sections["xram_used"] == 0  # the player keeps everything in internal RAM
    assert "P1 |= 0x40; /* P1.6 high: L297 HALF/FULL" in (tmp_path / "player.c").read_text()


def test_many_runs_across_code_pages(tmp_path):
    """About 7 KB of table on the STC89C52RC: a run load at most events, random intervals and adds, reads across
    every 256-byte page of the table, 1100 short runs in one long block."""
    rng = np.random.default_rng(51)
    n = 1100
    intervals = rng.integers(200 * 256, 600 * 256, n)
    runs = [(int(v), int(a), int(c)) for v, a, c in zip(intervals, rng.integers(-300, 300, n), rng.integers(1, 3, n))]
    total = sum(c for _, _, c in runs)
    sched = make_schedule(("x", "y", "z", "e"), [
        ((1, -1, 1, -1), (total, 1234 % total, total // 2, 7), total, (total // 2, 17, 0, total - 1), True, runs)])
    assert 6000 < stream_bytes(sched) < 7500
    cfg = config(("x", "y", "z", "e"), ("X", "Y", "Z", "E0"), board="stc89c52rc")
    image, trace = build_and_run(sched, cfg, tmp_path)
    check_plays(sched, cfg, trace)
    assert image.flash_bytes > 6000 and image.flash_capacity == 8192


def test_short_blocks_of_four_motors_read_the_inits_of_their_bresenham_slaves_only(tmp_path):
    """Four motors, every one the master of a short block once: slaves at no event, at every event and Bresenham
    ones mixed in every order, so that a short record is 5 to 8 bytes and the inits it stores sit at other places
    than their slaves' steps; a slave at no event keeps the Bresenham state of the block before."""
    blocks = [
        ((1, 1, 1, 1), (20, 7, 13, 19), 20, (10, 3, 12, 1), False, [(900 * 256, 0, 20)]),  # every init: 8 bytes
        ((1, -1, 1, -1), (0, 9, 0, 4), 9, (0, 0, 0, 8), True, [(700 * 256, 5, 9)]),  # master y; x, z idle: 6 bytes
        ((-1, 1, 1, 1), (11, 11, 3, 11), 11, (0, 0, 2, 0), True, [(800 * 256, 0, 11)]),  # master x; z's init only
        ((1, 1, -1, 1), (6, 0, 25, 25), 25, (5, 0, 24, 0), False, [(600 * 256, -3, 25)]),  # master z; x only: 6 bytes
        ((-1, -1, -1, 1), (1, 2, 0, 30), 30, (29, 0, 0, 0), True, [(1000 * 256, 0, 30)]),  # master e; x, y
        ((1, 1, 1, 1), (0, 0, 0, 0), 1, (0, 0, 0, 0), False, [(500 * 256, 0, 2)]),  # a dwell (long)
        ((1, 1, 1, -1), (17, 17, 17, 17), 17, (0, 0, 0, 0), False, [(900 * 256, 0, 17)]),  # no init: 5 bytes
    ]
    sched = make_schedule(("x", "y", "z", "e"), blocks, final_tool=True)
    table = tables.encode(sched)
    assert table.counts()["short_blocks"] == 6
    # 8 + 6 + 6 + 6 + 7 + 5 bytes of short blocks, a long dwell, 7 short runs, the end marker
    assert len(table.data) == 38 + tables.long_block_bytes(4) + 7 * tables.SHORT_RUN_BYTES + 2
    cfg = config(("x", "y", "z", "e"), ("X", "Y", "Z", "E0"), board="stc89c52rc")
    image, trace = build_and_run(sched, cfg, tmp_path)
    check_plays(sched, cfg, trace)
    assert image.flash_parts["table"] == len(table.data)


def test_sources_and_image_are_deterministic(tmp_path):
    sched = make_schedule(("x", "y"), [((1, -1), (30, 20), 30, (15, 15), True, [(500 * 256, 0, 30)])])
    cfg = config(("x", "y"), ("X", "Y"))
    first, second = render_sources(sched, cfg), render_sources(sched, cfg)
    assert first == second
    assert first["player.c"].startswith(
        "/* AUTO-GENERATED by printer-codegen 0.1.0 from tests/firmware/mcs51/test_firmware.py (target mcs51). Do not edit. */")
    one = build_image(first, tmp_path / "one", stream_bytes(sched))
    two = build_image(second, tmp_path / "two", stream_bytes(sched))
    assert one.hex_path.read_bytes() == two.hex_path.read_bytes()
    assert (tmp_path / "one" / SYMBOLS_FILE).read_bytes() == (tmp_path / "two" / SYMBOLS_FILE).read_bytes()
    assert one.table_bytes == stream_bytes(sched) and one.ram_capacity == 256 and one.flash_capacity == 8192


def test_integer_only_no_library_calls(tmp_path):
    """No float, multiply, divide or modulo helpers anywhere in the image (they are not reentrant on SDCC)."""
    sched = make_schedule(("x",), [((1,), (5,), 5, (2,), False, [(500 * 256, 0, 5)])])
    build_image(render_sources(sched, config(("x",), ("X",))), tmp_path, stream_bytes(sched))
    symbols = (tmp_path / MAP_FILE).read_text()
    for helper in ("__mul", "__div", "__mod", "___fs", "sqrt", "__sdcc_call"):
        assert helper not in symbols
    sym = json.loads((tmp_path / SYMBOLS_FILE).read_text())
    assert sym["isr"] == 0x000B and sym["halt"] > sym["isr"]


def test_an_empty_program_only_sets_the_tool(tmp_path):
    sched = make_schedule(("x", "y"), [], final_tool=True)
    cfg = config(("x", "y"), ("X", "Y"))
    _, trace = build_and_run(sched, cfg, tmp_path)
    assert len(trace.step_cycle) == 0 and trace.state == "done"
    assert [on for _, on in trace.tool_edges] == [1]


def test_too_big_table_is_refused_with_the_sizes(tmp_path):
    cfg = config(("x",), ("X",))
    small = make_schedule(("x",), [((1,), (1,), 1, (0,), False, [(300 * 256, 0, 1)])])
    build_image(render_sources(small, cfg), tmp_path, stream_bytes(small))  # an earlier image must not survive
    sched = make_schedule(("x",), [((1,), (850,), 850, (0,), False, [(70_000 * 256, 0, 1)] * 850)])
    assert 8192 < stream_bytes(sched) < 9000
    with pytest.raises(BuildError) as error:
        build_image(render_sources(sched, cfg), tmp_path, stream_bytes(sched))
    text = str(error.value)
    needed = int(text.split("needs ")[1].split()[0])
    assert needed > stream_bytes(sched) and "code memory" in text and "8192 available on the at89c52" in text
    assert not (tmp_path / "firmware.hex").exists() and not (tmp_path / SYMBOLS_FILE).exists()


def test_ram_overflows_name_the_memory(tmp_path):
    sched = make_schedule(("x",), [((1,), (1,), 1, (0,), False, [(300 * 256, 0, 1)])])
    sources = render_sources(sched, config(("x",), ("X",)))
    with pytest.raises(BuildError, match="does not fit in internal RAM"):
        build_image({**sources, "extra.c": "__data unsigned char big[240];\nvoid use(void) { big[1] = 2; }\n"},
                    tmp_path / "iram", stream_bytes(sched))
    seed = render_sources(sched, config(("x",), ("X",), board="seed-51"))
    with pytest.raises(BuildError, match=r"external RAM: it needs \d+ bytes, 512 available"):
        build_image({**seed, "extra.c": "__xdata unsigned char big[600];\nvoid use(void) { big[1] = 2; }\n"},
                    tmp_path / "xram", stream_bytes(sched))
    assert not (tmp_path / "iram" / "firmware.hex").exists() and not (tmp_path / "xram" / "firmware.hex").exists()


def test_compile_error_budget_sockets_and_homing(tmp_path):
    sched = make_schedule(("x",), [((1,), (2,), 2, (0,), False, [(10_000_000 * 256, 0, 2)])])
    cfg = config(("x",), ("X",))
    sources = render_sources(sched, cfg)
    with pytest.raises(BuildError, match="player.c"):
        build_image({**sources, "player.c": sources["player.c"] + "\nint broken(void) { return }\n"},
                    tmp_path / "bad", stream_bytes(sched))
    assert not (tmp_path / "bad" / "firmware.hex").exists()
    image = build_image(sources, tmp_path / "good", stream_bytes(sched))
    with pytest.raises(BuildError, match="did not finish"):
        simulate(image.hex_path, cfg, 12_000_000)
    with pytest.raises(BuildError, match="no stepper socket E0"):
        render_sources(make_schedule(("e",), []), config(("e",), ("E0",), board="seed-51"))
    homing = FirmwareConfig("test", "t", "mcs51", "at89c52", cfg.motors,
                            homing=(HomingAxis((0,), (-1,), "x_min", -1, 100, 500, 1000, 10),))
    with pytest.raises(BuildError, match="does not home"):
        simulate(image.hex_path, homing, 1_000_000)


def test_step_pins_on_two_ports(tmp_path, monkeypatch):
    """A board with STEP pins on P1 and P2: the second port's pins wait in R0 between interrupts and rise 2 cycles
    after the first port's; each motor keeps one constant latency."""
    import shutil

    import codegen.firmware.config as firmware_config
    from codegen.paths import targets_dir

    folder = tmp_path / "targets"
    folder.mkdir()
    shutil.copy(targets_dir() / "at89c52.yaml", folder)
    (folder / "two-ports.yaml").write_text(
        "target: mcs51\nmcu: at89c52\nenable_active_low: true\nsteppers:\n"
        "  X: {step: P1.0, dir: P1.1, enable: P3.6}\n  Y: {step: P2.5, dir: P2.6, enable: P3.7}\n"
        "tool: {pin: P3.4, active_high: true}\n")
    monkeypatch.setattr(firmware_config, "targets_dir", lambda: folder)
    firmware_config.load_target.cache_clear()
    try:
        sched = make_schedule(("x", "y"), [
            ((1, -1), (40, 25), 40, (20, 3), True, [(900 * 256, -300, 20), (700 * 256, 0, 20)]),
            ((-1, 1), (10, 10), 10, (0, 9), False, [(80_000 * 256, 0, 1), (600 * 256, 0, 9)])])
        cfg = config(("x", "y"), ("X", "Y"), board="two-ports")
        _, trace = build_and_run(sched, cfg, tmp_path / "out")
    finally:
        firmware_config.load_target.cache_clear()
    pulses = play(sched)
    latency = []
    for m in range(2):
        ticks = np.array([t for t, mm, _ in pulses if mm == m])
        mine = trace.step_motor == m
        assert np.array_equal(trace.step_dir[mine], [d for _, mm, d in pulses if mm == m])
        late = trace.step_cycle[mine] - trace.timer_start_cycle - CLOCKS * ticks
        assert late.max() - late.min() <= TOLERANCE
        latency.append(int(late[0]))
    assert latency[1] - latency[0] == 2 * CLOCKS
    assert [on for _, on in trace.tool_edges] == [0, 1, 0]  # active high: on from reset until main turns it off


def test_runs_go_on_across_blocks_in_short_and_long_records(tmp_path):
    """The compact stream: short blocks (master left out, at any index) and long ones, a dwell, runs that start
    inside a block and go on across several, short and long run records, the end marker's tool."""
    runs = [(3000 * 256, -5000, 30), (1200 * 256 + 100, 3, 300), (70_000 * 256, 0, 2), (800 * 256, 0, 40)]
    blocks = [
        ((1, -1, 1), (10, 4, 0), 10, (5, 2, 5), True, 10),
        ((-1, 1, 1), (3, 12, 12), 12, (1, 0, 0), True, 12),  # two masters: y is the one left out
        ((1, 1, -1), (0, 5, 8), 8, (0, 4, 7), False, 8),
        ((1, 1, 1), (300, 299, 1), 300, (150, 0, 299), False, 300),  # long: modulus > 255
        ((1, 1, 1), (0, 0, 0), 1, (0, 0, 0), True, 2),  # a dwell of two events
        ((-1, -1, -1), (40, 40, 39), 40, (0, 39, 20), False, 40),
    ]
    sched = make_schedule(("x", "y", "z"), blocks, final_tool=True, runs=runs)
    table = tables.encode(sched)
    assert table.counts() == {"short_blocks": 4, "long_blocks": 2, "short_runs": 2, "long_runs": 2}
    # short block: flags (the master in bits 4-5), modulus, the slaves' steps, then the inits of the Bresenham
    # slaves only (not of one at no event or at every one): here 5 bytes each, z's init (0 steps) left out
    assert table.data[0] == 0x40 | 0b101 and table.data[1] == 10 and list(table.data[2:5]) == [4, 0, 2]
    assert len(table.data) == 4 * 5 + 2 * (3 + 12) + 2 * 6 + 2 * 10 + 2
    assert table.data[-2:] == bytes([0x40, 0])
    cfg = config(("x", "y", "z"), ("X", "Y", "Z"))
    image, trace = build_and_run(sched, cfg, tmp_path)
    check_plays(sched, cfg, trace)
    assert [on for _, on in trace.tool_edges] == [1, 0, 1, 0, 1]
    assert image.flash_parts["table"] == len(table.data)

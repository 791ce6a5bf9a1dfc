"""The 8051 streaming firmware on a board without XRAM (the at89c52): its ring in the top of internal RAM, read
and written with MOV @Ri at index | RING_BASE, end to end with the real SDCC and s51 (the closed loop of
codegen/sim/mcs51_link.py, the host's own protocol code at 9600 baud); the build's internal RAM figures, and the
refusal of a ring too small.
"""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest
import yaml

import codegen.firmware.mcs51.stream as mcs51_stream
from codegen.cli.main import main
from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig, MotorPins
from codegen.firmware.mcs51.stream import (STACK_RESERVE, build_stream_image, iram_need, render_stream_sources,
                                           ring_layout)
from codegen.link import protocol
from codegen.link.faults import Faulty, LineFaults
from codegen.link.host import HostLink
from codegen.link.ring import link_budget
from codegen.program.homing import HomingAxis
from codegen.sim.mcs51_link import simulate_stream
from codegen.tables.twin import predict
from tests.firmware.mcs51.stream_helpers import (BAUD, BUDGET, F_CPU, MOTORS, TICK_HZ, build, check_pulses, config,
                                                 make_schedule, net_steps, short_schedule, stream_of)
from tests.helpers import ROOT

pytestmark = pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None,
                                reason="needs sdcc and s51 (scripts/setup.sh installs them)")

RING_WHERE = "internal RAM 0xC0-0xFF (MOV @Ri), the variables and the stack below it"
PREFILL = 48  # six DATA frames of 8 bytes before START, of the 63 the ring takes


@pytest.fixture(scope="module")
def at89(tmp_path_factory):
    return build(config("at89c52"), tmp_path_factory.mktemp("at89c52"))


def slow_schedule(events=100, seed=7):
    """One block of `events` events, each with a run record of its own (6 bytes every 20-25 ms: 620 bytes, the
    63-byte ring ten times over, records across its end); a the master, b and c Bresenham slaves."""
    rng = np.random.default_rng(seed)
    runs = [(int(v), int(a), 1) for v, a in zip(rng.integers(20000 * 256, 25000 * 256, events),
                                                 rng.integers(-200, 200, events))]
    return make_schedule(MOTORS, [((1, -1, -1), (events, events * 5 // 8, events // 2), events, (events // 2,) * 3,
                                   False, runs)])


def host_for(schedule, cfg):
    """The host's session in the DATA frames the link plan takes for the ring (codegen/link/ring.py: 8 bytes),
    six of them before START."""
    data = stream_of(schedule)
    budget = link_budget(BAUD, ring_layout(cfg).ring_bytes, len(cfg.motors))
    return HostLink([data], len(cfg.motors), protocol.firmware_identity(cfg, F_CPU, TICK_HZ), 10 / BAUD,
                    min(PREFILL, len(data)), payload=budget.payload)


def test_ten_rings_of_records_through_internal_ram_play_like_the_twin(at89):
    image, cfg = at89
    sched = slow_schedule()
    assert len(stream_of(sched)) > 9 * 64
    link = host_for(sched, cfg)
    trace, figures = simulate_stream(image.hex_path, cfg, link, BUDGET)
    assert link.outcome == "finished", link.message
    check_pulses(sched, trace)
    assert link.position == tuple(int(p) for p in predict(sched).final_positions()) == net_steps(trace)
    assert figures.lost_bytes == 0 and figures.underruns == 0 and figures.retransmits == 0
    assert protocol.max_record_bytes(3) <= figures.min_ring_fill_bytes <= 63


def test_records_of_every_kind_from_internal_ram(at89):
    """Short and long blocks and runs, runs across blocks, a dwell with long waits, the tool at each block and at
    the end: every way the player reads a record (byte k, the next byte, byte A)."""
    image, cfg = at89
    sched = short_schedule()
    link = host_for(sched, cfg)
    trace, figures = simulate_stream(image.hex_path, cfg, link, BUDGET)
    assert link.outcome == "finished", link.message
    check_pulses(sched, trace)
    assert link.position == tuple(int(p) for p in predict(sched).final_positions())
    assert [on for _, on in trace.tool_edges] == [1, 0, 1, 0, 1]
    assert figures.lost_bytes == 0 and figures.underruns == 0


def test_a_host_pause_longer_than_the_ring_lasts_ends_in_underrun(at89):
    """The host stalls for 1 s while playing (the ring lasts about 0.25 s): the player stops at the first record it
    cannot have whole and reports UNDERRUN with the positions of the pulses it made."""
    image, cfg = at89
    sched = slow_schedule()
    link = host_for(sched, cfg)
    trace, figures = simulate_stream(image.hex_path, cfg, Faulty(link, LineFaults(pause=(0.6, 1.6))), BUDGET)
    assert link.outcome == "underrun"
    made = check_pulses(sched, trace, whole=False)
    assert 0 < sum(made) < len(predict(sched).tick)
    assert link.position == net_steps(trace)
    assert figures.underruns == 1 and figures.min_ring_fill_bytes < protocol.max_record_bytes(3)
    assert figures.lost_bytes == 0


def test_window_updates_spare_the_host_its_pings(at89, tmp_path):
    """The player takes 6 bytes every 20-25 ms, half what the link carries: the ring fills and the host, blocked on
    credit, waits. main's window update (an ACK unasked once the player has made room for a DATA frame) brings the
    next frame before the host's ping would: no ping, 26 ACKs beyond one per frame (a count that shifts with the
    player's cycles: 25 when the short block load was 5 cycles shorter). The same firmware without
    them leaves the host pinging every 50 ms for its credit."""
    image, cfg = at89
    sources = render_stream_sources(cfg)
    assert sources["link.c"].count("    window_update();\n") == 1
    sources["link.c"] = sources["link.c"].replace("    window_update();\n", "")
    without = build_stream_image(sources, tmp_path)
    sched = slow_schedule()
    counts = []
    for hex_path in (image.hex_path, without.hex_path):
        link = host_for(sched, cfg)
        parser, acks, receive = protocol.Parser(protocol.MAX_ANSWER), [0], link.receive

        def counted(data, now, parser=parser, acks=acks, receive=receive):
            acks[0] += sum(f.kind == protocol.ACK for f in parser.feed(data))
            receive(data, now)

        link.receive = counted
        trace, figures = simulate_stream(hex_path, cfg, link, BUDGET)
        assert link.outcome == "finished", link.message
        check_pulses(sched, trace)
        assert figures.lost_bytes == 0 and figures.underruns == 0
        counts.append((link.stats.pings, acks[0] - link.stats.frames))
    assert counts == [(0, 26), (12, 0)]


def test_the_plotter_set_streams_into_internal_ram(tmp_path, capsys):
    """`verify --stream` of the plotter set's first three drawings on the at89c52 at 9600 baud: the plan counts on
    what the host keeps in the 63-byte ring with window updates (56 bytes, 22 once its refill lags two ACKs and two
    frames behind: codegen/link/ring.py), sends 46 bytes before START (the first record's 11 and `need` for the
    second, both read at tick 0, a frame on the line and two of margin), slows the stretches whose records come
    faster than the ring can take them (starts from rest), and the simulated ring never falls below the plan's
    lowest fill."""
    job = yaml.safe_load((ROOT / "examples" / "plotter-set-51.yaml").read_text())
    job["program"]["shapes"] = job["program"]["shapes"][:3]  # a line, an arc, an ellipse
    path = tmp_path / "plotter-three.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    code = main(["verify", "--stream", str(path), "--json", "--out", str(tmp_path / "out")])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and result["pass"] is True and result["problems"] == [], result["problems"]
    link = result["link"]
    assert link["baud"] == 9600 and link["prefill_bytes"] == 46
    assert link["retransmits"] == 0 and link["underruns"] == 0 and link["lost_bytes"] == 0
    assert link["min_ring_fill_bytes"] >= link["planned_min_ring_fill_bytes"] >= protocol.max_record_bytes(2)
    assert link["link_slowdown_s"] > 0
    for name, motor in result["motors"].items():
        assert motor["final"] == motor["expected_final"], name
    assert abs(result["duration_s"] - result["planned_duration_s"]) < 1e-3


def test_the_build_report_says_where_the_ring_is(tmp_path):
    """`build --stream` of the plotter set (board at89c52): the ring's 64 bytes at the top of internal RAM, the
    variables where iram_need counts them, at least STACK_RESERVE bytes of stack between them and the ring."""
    out = tmp_path / "stream"
    assert main(["build", "--stream", str(ROOT / "examples" / "plotter-set-51.yaml"), "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["link"]["ring_bytes"] == 63 and report["link"]["ring_where"] == RING_WHERE
    assert report["link"]["payload_bytes"] == 8
    sections = report["image"]["sections"]
    cfg = config("at89c52", motors=("x", "y"))
    assert sections["ring_bytes"] == 64 and sections["xram_used"] == 0
    assert 0xC0 - sections["stack_free"] == iram_need(cfg) == 132  # where SDCC starts the stack
    assert sections["stack_free"] == 60 >= STACK_RESERVE
    assert report["image"]["ram_bytes"] == sections["iram_used"] + 64
    link_h = render_stream_sources(cfg)["link.h"]
    assert "#define RING_SIZE 64 " in link_h and "#define RING_BASE 0xC0 " in link_h


def test_iram_need_counts_where_the_stack_starts(tmp_path):
    """The homing machine's state and four motors' variables: where ring_layout counts them is where SDCC put
    them."""
    axes = tuple(HomingAxis((m,), (1,), key, 1, 2000, 1000, 3000, 50) for m, key in enumerate(("x_max", "y_max")))
    four = FirmwareConfig("stream", "tests/firmware/mcs51/test_stream_iram.py", "mcs51", "at89c52",
                          tuple(MotorPins(n, s) for n, s in zip("abcd", ("X", "Y", "Z", "E0"))))
    for k, cfg in enumerate((config("at89c52", motors=("a", "b"), homing=axes), four)):
        image = build_stream_image(render_stream_sources(cfg), tmp_path / str(k))
        assert 0xC0 - image.sections["stack_free"] == iram_need(cfg) == (159, 169)[k]


def test_too_little_internal_ram_for_the_ring_or_the_stack_is_refused(tmp_path, monkeypatch):
    axes = tuple(HomingAxis((m,), (1,), key, 1, 2000, 1000, 3000, 50) for m, key in enumerate(("x_max", "y_max",
                                                                                                "z_max")))
    message = ("board at89c52 has no XRAM, and its internal RAM leaves too little for the streaming player's ring "
               "buffer: the ring must hold 43 bytes (two DATA frames of 8 bytes + 6 of overhead each, and the "
               "longest record of 3 motors: 15); the largest ring of 128, 64, 32 bytes that fits holds 31 (50 of "
               "the 256 bytes are free after the variables' 186 and a stack of 20); use fewer motors or homed axes, "
               "or a board with XRAM")
    with pytest.raises(BuildError, match=re.escape(message)):
        ring_layout(config("at89c52", homing=axes))
    with pytest.raises(BuildError, match="the streaming player drives STEP/DIR sockets, not coils"):
        render_stream_sources(config("coil-51", motors=("x", "y")))
    sources = render_stream_sources(config("at89c52"))
    monkeypatch.setattr(mcs51_stream, "STACK_RESERVE", 43)
    with pytest.raises(BuildError, match=re.escape("the image's variables end at 0x96 in internal RAM, which leaves "
                                                   "42 bytes of stack below 0xC0 (the end of the internal RAM it "
                                                   "may use), fewer than the 43 it needs")):
        build_stream_image(sources, tmp_path)
    assert not (tmp_path / "firmware.hex").exists()

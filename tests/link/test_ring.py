"""Bandwidth in the plan (codegen/link/ring.py, codegen/pipeline/windows.py): the ring's fill window by window, the
prefill, and stretches slowed where the link cannot carry their bytes; checked against a direct simulation of
the bytes arriving and the records read, record by record."""

from __future__ import annotations

import math

import numpy as np
import pytest

from codegen.errors import BuildError
from codegen.job import load_job
from codegen.link import protocol
from codegen.link.ring import LinkBudget, Ring, link_budget
from codegen.pipeline.host import host_build
from codegen.tables.format import record_events, stream_bytes
from tests.helpers import ROOT

EXAMPLES = ROOT / "examples"
UNLIMITED = link_budget(2_000_000, 60000, 2)  # the streaming player's costs, a link that never holds it back


def direct_fill(times: np.ndarray, sizes: np.ndarray, budget: LinkBudget, prefill: int) -> np.ndarray:
    """The fill before every record, record by record: the prefill's whole frames less the one on the line, refilled
    at the link's rate; or what the host keeps less the bytes taken in the last lag_s; or `usable` after a record
    read by lag_s before, refilled since; never more than the stream has."""
    total = int(sizes.sum()) + budget.need
    taken = np.concatenate([[0], np.cumsum(sizes[:-1])]).tolist()
    sent = min(-(-prefill // budget.payload) * budget.payload, total)
    fills, refilled, back, since = [], math.inf, 0, 0  # back: records read by lag_s before; since: the first after
    for t, c in zip(times.tolist(), taken):
        while times[back] <= t - budget.lag_s:
            refilled = min(refilled, taken[back] + budget.usable - budget.rate * times[back])
            back += 1
        while times[since] < t - budget.lag_s:
            since += 1
        arrived = min(sent - budget.payload + budget.rate * t, budget.kept + taken[since], refilled + budget.rate * t,
                      total)
        fills.append(arrived - c)
    return np.array(fills)


def test_a_steady_stream_under_the_rate_needs_a_small_prefill_and_never_runs_dry():
    budget = link_budget(250000, 4096, 3)
    ring = Ring(budget)
    times = np.arange(20000) * 1e-3  # 6 bytes a millisecond: 6 kB/s on a 24 kB/s link
    sizes = np.full(20000, 6)
    for lo in range(0, 20000, 5000):
        assert ring.add(times[lo:lo + 5000], sizes[lo:lo + 5000]) == []
    prefill, low = ring.result(int(sizes.sum()) + budget.need)
    assert budget.need <= prefill <= budget.need + 6 + 3 * budget.payload  # a frame on the line, two of margin
    fills = direct_fill(times, sizes, budget, prefill)
    assert fills.min() >= budget.need
    assert low == pytest.approx(fills[: len(fills) - budget.ring_bytes // 6].min(), abs=1)


def test_a_burst_the_ring_can_absorb_is_met_by_the_prefill():
    budget = link_budget(9600, 512, 2)
    ring = Ring(budget)
    times = np.concatenate([np.zeros(30), 0.5 + np.arange(100) * 0.05])  # 180 bytes at once, then slowly
    sizes = np.full(130, 6)
    assert ring.add(times, sizes) == []
    prefill, _ = ring.result(int(sizes.sum()) + budget.need)
    assert prefill >= 180
    margin = 2 * budget.payload
    assert direct_fill(times, sizes, budget, prefill)[:40].min() >= budget.need + margin  # the burst and after
    assert direct_fill(times, sizes, budget, prefill - margin - budget.payload).min() < budget.need  # a frame less: dry


def test_a_stretch_denser_than_the_link_is_a_shortfall_with_the_time_it_lacks():
    budget = link_budget(9600, 512, 2)
    ring = Ring(budget)
    times = np.arange(2000) * 1e-3  # 6 kB/s on a link of under 1 kB/s
    short = ring.add(times, np.full(2000, 6))[0]
    assert 0 <= short.begin_s < short.end_s < 2.0
    bytes_in_stretch = 6 * (round(short.end_s * 1000) - round(short.begin_s * 1000))
    # More than the link carries in it from the level the refill counts from; slowed by extra_s, no more than the
    # link carries plus what the host keeps in the ring.
    assert budget.rate * (short.end_s - short.begin_s) + budget.usable < bytes_in_stretch
    assert bytes_in_stretch <= budget.rate * (short.end_s - short.begin_s + short.extra_s) + budget.kept


@pytest.mark.parametrize("baud", [1200, 2400])
def test_a_slow_link_slows_the_plan_and_the_ring_never_runs_dry(baud):
    job = load_job(EXAMPLES / "plotter-set-51.yaml")
    budget = link_budget(baud, 512, 2)
    free = host_build(job, link=UNLIMITED)
    host = host_build(job, link=budget)
    plan = host.link_plan
    assert host.findings.ok, host.findings.problems
    assert plan.link_slowdown_s > 0
    assert host.totals.duration_s == pytest.approx(free.totals.duration_s + plan.link_slowdown_s, rel=1e-6)
    event, sizes = record_events(host.schedule)
    ticks = np.concatenate([[0], host.pulses.event_tick])
    fills = direct_fill(ticks[event] / host.target.tick_hz, sizes, budget, plan.prefill_bytes)
    assert fills.min() >= budget.need
    assert plan.stream_bytes == stream_bytes(host.schedule) + len(protocol.tail_padding(2))


def test_a_fast_link_changes_nothing():
    job = load_job(EXAMPLES / "plotter-set-51.yaml")
    free = host_build(job, link=UNLIMITED)
    host = host_build(job, link=link_budget(250000, 4096, 2))
    assert host.link_plan.link_slowdown_s == 0
    assert host.totals.duration_s == free.totals.duration_s
    assert host.link_plan.prefill_bytes >= host.link_plan.budget.need


def test_a_machine_without_program_is_enough_for_the_streaming_firmware_only(tmp_path):
    from codegen.errors import JobError

    path = tmp_path / "machine.yaml"
    path.write_text("machine:\n  kinematics: cartesian\n  link: {baud: 115200}\n  steppers:\n"
                    "    x: {steps_per_mm: 80, max_velocity: 150, max_accel: 2000}\n"
                    "    y: {steps_per_mm: 80, max_velocity: 150, max_accel: 2000}\n", encoding="utf-8")
    job = load_job(path, program_required=False)
    assert job.program is None and job.machine.link.baud == 115200
    with pytest.raises(JobError) as caught:
        load_job(path)
    assert "1:1: error: missing key 'program' (only `build --stream` goes without one)" in caught.value.render()
    path.write_text(path.read_text().replace("baud: 115200", "baud: -1"), encoding="utf-8")
    with pytest.raises(JobError) as caught:
        load_job(path, program_required=False)
    assert "3:16: error: machine.link.baud: must be > 0" in caught.value.render()


def test_the_host_keeps_the_ring_less_a_frame_and_counts_the_refill_two_acks_and_two_frames_late():
    """kept = ring - (payload - 1); usable = kept - payload / frame x refill_byte_times (host.py): the at89c52's 63
    bytes at 9600 baud in 8-byte frames with window updates (two ACKs and their answers, 12 byte times each, two
    14-byte frames, a fallback ping's 6 bytes); the seed-51's 255 in 31-byte frames; the RAMPS board's 7805 at
    250000 baud in 128-byte frames, refilled after a ping (10 ms, the ping's 6 bytes, two ACKs, the frame's
    134)."""
    at89 = link_budget(9600, 63, 2, window_updates=True)
    assert (at89.payload, at89.refill_byte_times, at89.kept, at89.usable) == (8, 58, 56, 22)
    assert at89.usable == int(56 - 8 / 14 * 58) and at89.lag_s == pytest.approx((56 - 22) / at89.rate)
    seed = link_budget(9600, 255, 2, window_updates=True)
    assert (seed.payload, seed.refill_byte_times, seed.kept, seed.usable) == (31, 104, 225, 137)
    ramps = link_budget(250000, 7805, 4)
    assert (ramps.payload, ramps.refill_byte_times, ramps.usable) == (128, pytest.approx(414), 7282)
    assert link_budget(9600, 63, 2).usable == 3  # pings alone: 50 ms late, the refill counts from 3 bytes


def test_the_lowest_fill_counts_each_record_before_the_last_ring_of_the_stream():
    budget = link_budget(9600, 512, 2)
    ring = Ring(budget)
    times = np.arange(300) * 0.02  # 300 B/s, one window
    sizes = np.full(300, 6)
    assert ring.add(times, sizes) == []
    stream = int(sizes.sum()) + budget.need
    prefill, low = ring.result(stream)
    counted = np.concatenate([[0], np.cumsum(sizes[:-1])]) <= stream - budget.ring_bytes
    assert low == int(np.floor(direct_fill(times, sizes, budget, prefill)[counted].min()))


def test_a_ring_the_slowed_plan_cannot_keep_fed_is_refused_with_its_size_and_what_would_help():
    job = load_job(EXAMPLES / "plotter-set-51.yaml")
    with pytest.raises(BuildError, match=r"the link at 600 baud cannot keep the streaming player's ring of 63 "
                                         r"bytes \(the host keeps 56 of them filled, 22 after the refill's lag\) fed "
                                         r"between [0-9.]+ and [0-9.]+ "
                                         r"s into the job, even slowed 15 times: a board with a larger ring \(XRAM\), "
                                         r"a faster link \(machine.link.baud\), or a larger machine.tolerance"):
        host_build(job, link=link_budget(600, 63, 2, window_updates=True))

"""The dilated clock played a piece at a time (codegen/tables/hold.py Dilator): windows asked for in order, the
ticks of a few events, the first event from a tick and the parks give what the whole dilation gives, wherever the
pieces end (a factor written across a piece's start, a park, a ramp, an override above 100 % under the ceilings)."""

from __future__ import annotations

import numpy as np
import pytest

import codegen.tables.hold
from codegen.tables.hold import RESUME_TICKS, Dilator, dilate, override_target


def _cases(host) -> list[tuple[list, list]]:
    """(changes, resumes): a hold resumed, an override up and down, a hold never resumed, random ones."""
    events = int(host.schedule.run_count.sum())
    at = events // 2
    parked = dilate(host.schedule, host.hold_plan, [(at, 0)]).parks[0][1]
    rng = np.random.default_rng(7)
    cases = [([(at, 0)], [parked + 40_000 + RESUME_TICKS]), ([(1, override_target(20)), (at, override_target(5))], []),
             ([(at, 0)], [])]
    for _ in range(4):
        first, second = sorted(int(e) for e in rng.integers(1, events, 2))
        cases.append(([(first, int(rng.integers(1, 256))), (second, 0)], [int(rng.integers(0, 1 << 24))]))
    return cases


@pytest.mark.parametrize("stretch", [7, 1000, 1 << 16])
def test_windows_in_order_are_the_whole_dilation(star_host, monkeypatch, stretch):
    schedule, plan = star_host.schedule, star_host.hold_plan
    events = int(schedule.run_count.sum())
    rng = np.random.default_rng(stretch)
    for changes, resumes in _cases(star_host):
        whole = dilate(schedule, plan, changes, resumes)  # pieces of 65536
        monkeypatch.setattr(codegen.tables.hold, "STRETCH", stretch)
        dilator = Dilator(schedule, plan, changes, resumes)
        cuts = np.unique(np.concatenate([[0], rng.integers(0, events, 20), [events]]))
        for first, end in zip(cuts[:-1], cuts[1:]):
            window = dilator.window(int(first), int(end) + 1)  # overlapping by one, as the comparison asks
            assert np.array_equal(window.tick, whole.tick[first:end + 1])
            assert np.array_equal(window.factor, whole.factor[first:end + 1])
        assert dilator.parks == whole.parks
        monkeypatch.setattr(codegen.tables.hold, "STRETCH", 1 << 16)


def test_a_few_ticks_the_first_from_a_tick_and_the_parks_are_the_whole_s(star_host, monkeypatch):
    schedule, plan = star_host.schedule, star_host.hold_plan
    monkeypatch.setattr(codegen.tables.hold, "STRETCH", 1000)
    events = int(schedule.run_count.sum())
    for changes, resumes in _cases(star_host):
        whole = dilate(schedule, plan, changes, resumes)
        some = np.unique(np.random.default_rng(3).integers(0, events, 300))
        assert np.array_equal(Dilator(schedule, plan, changes, resumes).ticks_at(some), whole.tick[some])
        played = whole.tick[whole.tick >= 0]
        for tick in (0, int(played[len(played) // 3]) + 1, int(played[-1]) + 1):
            expected = int(np.flatnonzero((whole.tick >= tick) | (whole.tick < 0))[0]) \
                if ((whole.tick >= tick) | (whole.tick < 0)).any() else events
            assert Dilator(schedule, plan, changes, resumes).first_from(tick) == expected
        dilator = Dilator(schedule, plan, changes, resumes)
        assert [dilator.park(k) for k in range(len(whole.parks) + 1)] == whole.parks + [None]


def test_the_dilator_holds_pieces_not_the_run(star_host, monkeypatch):
    """Played through to the end a window at a time, it never holds more than a window and a piece."""
    schedule, plan = star_host.schedule, star_host.hold_plan
    monkeypatch.setattr(codegen.tables.hold, "STRETCH", 1000)
    dilator = Dilator(schedule, plan, [(1, 64)])
    events, held = int(schedule.run_count.sum()), 0
    for first in range(0, events, 5000):
        dilator.window(first, min(first + 5000, events) + 1)
        held = max(held, sum(len(tick) for _, tick, _ in dilator.pieces))
    assert held <= 5000 + 2 * 1000

"""verify --hold/--override (and a job's M0/M1 pauses) of an ATmega2560's flash image in bounded memory
(codegen/verify/hold.py, with a host build that keeps only its tables).

The run with the requests is read twice while the harness's edges file is there, each time paired a chapter at a
time with the twin planned again (codegen/verify/chapters.py, codegen/verify/run_reader.py): first for the cycles
of the events near the requests, all that placing them reads of the run (codegen/verify/hold_search.py); then
compared with the dilated twin (codegen/verify/bounded.py BoundedComparison, its chapters on the clock the placing
found, played a chapter at a time: codegen/tables/hold.py Dilator, the plan's times taken onto it a chapter at a
time). What it holds is a chapter of each and what the requests' neighbourhoods need, nothing per event of the
print; the laser's power writes, one per event while the clock is dilated, are forgotten once no pulse to come
reads them (RunReader.forget_duty).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np

from codegen.pipeline.host import HostBuild, host_build
from codegen.tables.hold import Dilator
from codegen.verify import chapters
from codegen.verify.bounded import BoundedComparison, Compared, RunOutputs, give_back_freed_memory
from codegen.verify.chapters import Chapter, Chapters
from codegen.verify.compare import Comparison
from codegen.verify.heaters import host_timeline
from codegen.verify.hold_limits import CeilingShares, RampWatch, ramp_watch
from codegen.verify.hold_search import FirstCycles, NearRequests, Requests, dilated_clock
from codegen.verify.run_reader import RunReader

_NO_EVENT = (np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))


class FirstPulses:
    """The first reading: the first simulated pulse of the twin's events near the requests (`near`), their cycles
    on the twin's clock in `cycles` (none where the pulses do not pair up, per motor, with the twin's), every
    chapter's first event's planned time and twin tick in `firsts` (by its index: the dilated clock of the
    chapter before ends there), and the ceilings' shares in `shares` (hold_limits.py)."""

    def __init__(self, host: HostBuild, chapter_pulses: int, near: NearRequests, link=None):
        self.host, self.chapter_pulses, self.near, self.link = host, chapter_pulses, near, link
        self.events: list[np.ndarray] = []
        self.cycles: list[np.ndarray] = []
        self.firsts: dict[int, tuple[float, int]] = {}
        self.shares = CeilingShares(host)
        self.paired = True

    def run(self, edges: Path, ended: Callable[[], bool]) -> None:
        host, motors = self.host, len(self.host.kin.motors)
        reader = RunReader(edges, host.firmware_config(), ended, keep=True)  # the comparison reads it again
        timeline = host_timeline(host)
        waits = timeline.tick[timeline.waits()]

        def chapter(ch: Chapter) -> None:
            pulses, first = ch.pulses, ch.first_event
            if len(pulses.event_tick):
                self.firsts[first] = (float(ch.events.time[0]), int(pulses.event_tick[0]))
            self.shares.add(pulses, first)
            counts = np.bincount(pulses.motor, minlength=motors)
            sim = reader.take(counts, self.chapter_pulses)
            reader.forget_duty()  # the laser's power is the comparison's: it reads the run again
            self.paired = self.paired and np.array_equal(np.bincount(sim.motor, minlength=motors), counts)
            if self.paired:
                clock = reader.clock(sim.cycle, waits)
                sim_of_pulse = np.empty(len(pulses.motor), dtype=np.int64)
                for m in range(motors):  # the k-th pulse of each motor is the twin's k-th
                    sim_of_pulse[pulses.motor == m] = clock[sim.motor == m]
                stepping, at = np.unique(pulses.event, return_index=True)
                near = self.near.keep(sim_of_pulse[at])
                self.events.append(first + stepping[near])
                self.cycles.append(sim_of_pulse[at][near])
            give_back_freed_memory()

        sink = Chapters(chapter, self.chapter_pulses)
        host_build(host.job, keep=False, link=self.link, observe=sink)
        sink.close()
        self.paired = self.paired and not len(reader.rest().cycle)

    def first_cycles(self) -> FirstCycles:
        """What was read, for placing the requests (none where the pulses did not pair up)."""
        if not self.paired:
            return FirstCycles(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
        return FirstCycles(np.concatenate(self.events or [np.zeros(0, np.int64)]),
                           np.concatenate(self.cycles or [np.zeros(0, np.int64)]))


class DilatedComparison(BoundedComparison):
    """The second reading: the run compared with the twin's chapters on the dilated clock of `dilation` (a Dilator,
    set once the requests are placed, with `firsts`: FirstPulses'), played a chapter at a time, its ramp watched
    (`ramp`). The plan's times go onto it a chapter at a time (`warp`): through the chapter's events, the last one
    before it and the first one after it, all that interpolating between events reads of the times there."""

    def __init__(self, host: HostBuild, switches: dict, chapter_pulses: int, steps_csv: Path | None, link=None):
        super().__init__(host, False, link, switches, link is not None, chapter_pulses,
                         RunOutputs(steps_csv=steps_csv))
        self.dilation: Dilator | None = None
        self.firsts: dict[int, tuple[float, int]] = {}
        self.before = _NO_EVENT  # the chapter before's last event: planned time, twin tick, dilated tick
        self.chapter_warp: Callable | None = None
        self.ramp = ramp_watch(host)

    def _comparison(self, reader: RunReader) -> Comparison:
        return Comparison(self.host, reader, self.streamed, self.warp, self.dilation)

    def warp(self, t):
        """The plan's times (s) onto the dilated clock, in the chapter being compared."""
        return self.chapter_warp(t)

    def _twin(self, chapter: Chapter) -> Chapter:
        pulses, first = chapter.pulses, chapter.first_event
        end = first + len(pulses.event_tick)
        window = self.dilation.window(first, end + 1)  # and the event after (Comparison reads the same)
        self.ramp.add(window, first)
        tick = window.tick[:end - first]
        after = _NO_EVENT
        if end in self.firsts:
            (time, twin), dilated_tick = self.firsts[end], window.tick[end - first]
            after = (np.array([time]), np.array([twin]), np.array([dilated_tick]))
        ours = (chapter.events.time, pulses.event_tick, tick)
        self.chapter_warp = dilated_clock(*(np.concatenate(parts) for parts in zip(self.before, ours, after)),
                                          self.host.target.tick_hz)
        if len(tick):
            self.before = tuple(part[-1:] for part in ours)
        dilated = dataclasses.replace(pulses, tick=tick[pulses.event], event_tick=tick, motor_tick=None,
                                      motor_dir=None, motor_first=None)
        return dataclasses.replace(chapter, pulses=dilated)


def held_bounded(host: HostBuild, runner, requests: Requests, presses: list[tuple[str, int]], slower: float,
                 steps_csv: Path | None = None) -> tuple[Compared, RampWatch, list, list[int], dict]:
    """hold_verify's run of a flash image or an ATmega2560's stream (`runner`: hold_runs.py's FlashRun, HeatedRun or
    StreamRun, with its stream's `link_budget`) read beside the simulation: what the comparison found (its
    trace without the table's pulses), the ramp's watch, the parks, the resumes' arrivals and the ceilings'
    shares."""
    chapter_pulses, link = chapters.CHAPTER_PULSES, runner.link_budget
    comparison = DilatedComparison(host, runner.switches, chapter_pulses, steps_csv, link)
    resume_arrived: list[int] = []
    shares: dict = {}  # the first reading's

    def beside(edges: Path, ended: Callable[[], bool]) -> None:
        first = FirstPulses(host, chapter_pulses, requests.near(presses), link)
        first.run(edges, ended)
        shares.update(first.shares.shares())
        arrived = runner.arrivals(presses)  # a frame reaches the firmware when its last byte has arrived
        for a, when in zip(requests.actions, arrived):
            a.press = when
        resume_arrived.extend(arrived[len(requests.actions):])
        comparison.dilation = requests.place(first.first_cycles(), resume_arrived)
        comparison.firsts = first.firsts
        del first  # placed: the pass's arrays go before the comparison's chapters come
        give_back_freed_memory()
        comparison.run(edges, lambda: True)  # the run has ended: its file is whole

    give_back_freed_memory()  # the requests' placing before the run
    end, _ = runner.run(presses, slower, beside)
    compared = comparison.finish(end)
    return compared, comparison.ramp, comparison.dilation.parks, resume_arrived, shares

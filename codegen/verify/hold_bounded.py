"""verify --hold/--override (and a job's M0/M1 pauses) of an ATmega2560's flash image in bounded memory
(codegen/verify/hold.py, with a host build that keeps only its tables).

The run with the requests is read twice while the harness's edges file is there, each time paired a chapter at a
time with the twin planned again (codegen/verify/chapters.py, codegen/verify/run_reader.py): first for the cycle of
every event's first pulse, all that placing the requests reads of the run (codegen/verify/hold_search.py), and the
events' planned times; then compared with the dilated twin (codegen/verify/bounded.py BoundedComparison, its
chapters on the clock the placing found). What it holds is a chapter of each and a few numbers per event of the
tables (which flash bounds), whatever the print's length.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np

from codegen.pipeline.host import HostBuild, host_build
from codegen.sim.avr import SimTrace
from codegen.tables.hold import Dilation
from codegen.tables.twin import event_ticks
from codegen.verify import chapters
from codegen.verify.bounded import BoundedComparison, RunOutputs, give_back_freed_memory
from codegen.verify.chapters import Chapter, Chapters
from codegen.verify.compare import Comparison, Verdict
from codegen.verify.heaters import host_timeline
from codegen.verify.hold_limits import CeilingShares
from codegen.verify.hold_search import Requests, dilated_clock
from codegen.verify.run_reader import RunReader


class FirstPulses:
    """The first reading: every twin event's first simulated pulse, its cycle on the twin's clock in `cycle` (-1
    for an event without one, or for all where the pulses do not pair up, per motor, with the twin's), every
    event's planned time in `time`, and the ceilings' shares in `shares` (hold_limits.py)."""

    def __init__(self, host: HostBuild, chapter_pulses: int):
        self.host, self.chapter_pulses = host, chapter_pulses
        events = int(host.schedule.run_count.sum())
        self.cycle = np.full(events, -1, dtype=np.int64)
        self.time = np.zeros(events)
        self.shares = CeilingShares(host)
        self.paired = True

    def run(self, edges: Path, ended: Callable[[], bool]) -> None:
        host, motors = self.host, len(self.host.kin.motors)
        reader = RunReader(edges, host.firmware_config(), ended, keep=True)  # the comparison reads it again
        timeline = host_timeline(host)
        waits = timeline.tick[timeline.waits()]

        def chapter(ch: Chapter) -> None:
            pulses, first = ch.pulses, ch.first_event
            self.time[first:first + len(pulses.event_tick)] = ch.events.time
            self.shares.add(pulses, first)
            counts = np.bincount(pulses.motor, minlength=motors)
            sim = reader.take(counts, self.chapter_pulses)
            self.paired = self.paired and np.array_equal(np.bincount(sim.motor, minlength=motors), counts)
            if self.paired:
                clock = reader.clock(sim.cycle, waits)
                sim_of_pulse = np.empty(len(pulses.motor), dtype=np.int64)
                for m in range(motors):  # the k-th pulse of each motor is the twin's k-th
                    sim_of_pulse[pulses.motor == m] = clock[sim.motor == m]
                stepping, at = np.unique(pulses.event, return_index=True)
                self.cycle[first + stepping] = sim_of_pulse[at]
            give_back_freed_memory()

        sink = Chapters(chapter, self.chapter_pulses)
        host_build(host.job, keep=False, observe=sink)
        sink.close()
        self.paired = self.paired and not len(reader.rest().cycle)
        if not self.paired:
            self.cycle[:] = -1


class DilatedComparison(BoundedComparison):
    """The second reading: the run compared with the twin's chapters on the dilated clock of `dilation`, `warp`
    taking the plan's times onto it (both set once the requests are placed)."""

    def __init__(self, host: HostBuild, switches: dict, chapter_pulses: int, steps_csv: Path | None):
        super().__init__(host, False, None, switches, False, chapter_pulses, RunOutputs(steps_csv=steps_csv))
        self.dilation: Dilation | None = None
        self.warp = None

    def _comparison(self, reader: RunReader) -> Comparison:
        return Comparison(self.host, reader, self.streamed, self.warp, self.dilation)

    def _twin(self, chapter: Chapter) -> Chapter:
        pulses, first = chapter.pulses, chapter.first_event
        tick = self.dilation.tick[first:first + len(pulses.event_tick)]
        dilated = dataclasses.replace(pulses, tick=tick[pulses.event], event_tick=tick, motor_tick=None,
                                      motor_dir=None, motor_first=None)
        return dataclasses.replace(chapter, pulses=dilated)


def held_bounded(host: HostBuild, runner, requests: Requests, presses: list[tuple[str, int]], slower: float,
                 steps_csv: Path | None = None) -> tuple[Verdict, SimTrace, Dilation, list[int], dict]:
    """hold_verify's run of a flash image (`runner`: hold_runs.py's FlashRun or HeatedRun, whose keys reach the
    firmware as they are pressed) read beside the simulation: the verdict, the trace (without the table's pulses),
    the dilation, the resumes' presses and the ceilings' shares."""
    chapter_pulses = chapters.CHAPTER_PULSES
    comparison = DilatedComparison(host, runner.switches, chapter_pulses, steps_csv)
    resume_arrived = [cycle for function, cycle in presses if function == "resume"]
    shares: dict = {}  # the first reading's

    def beside(edges: Path, ended: Callable[[], bool]) -> None:
        first = FirstPulses(host, chapter_pulses)
        first.run(edges, ended)
        shares.update(first.shares.shares())
        comparison.dilation = requests.place(first.cycle, resume_arrived)
        comparison.warp = dilated_clock(first.time, event_ticks(host.schedule), comparison.dilation,
                                        host.target.tick_hz)
        del first  # placed: the pass's arrays go before the comparison's chapters come
        give_back_freed_memory()
        comparison.run(edges, lambda: True)  # the run has ended: its file is whole

    give_back_freed_memory()  # the requests' placing before the run
    end, _ = runner.run(presses, slower, beside)
    compared = comparison.finish(end)
    return compared.verdict, compared.trace, comparison.dilation, resume_arrived, shares

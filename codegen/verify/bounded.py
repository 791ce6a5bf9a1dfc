"""verify in bounded memory, on both cores: the simulator's records compared with the twin a chapter at a time
while the simulation runs.

The host's first pass (the caller's, `keep=False`) gave the tables, the link's plan and the totals. While the
simulator runs, the program is planned again window by window (the same windows: planning is deterministic) and
each chapter of the twin (codegen/verify/chapters.py) paired with the pulses the simulator has written by then
(codegen/verify/run_reader.py), compared (codegen/verify/compare.py Comparison) and dropped. A streamed run's
comparison runs in a second process (the first drives the link in lockstep with simavr); a flash image's in this
process, beside the simulator's. Memory holds a chapter of each, whatever the print's length.
"""

from __future__ import annotations

import multiprocessing
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from codegen import progress
from codegen.pipeline.host import HostBuild, host_build
from codegen.sim.avr import SimTrace
from codegen.verify.chapters import CHAPTER_PULSES, Chapter, Chapters, RuntimeTimeline
from codegen.verify.compare import Comparison, Verdict
from codegen.verify.run_reader import RunReader


@dataclass
class Compared:
    """What the comparison of a run found, and what the figures after it need of the run and of the twin."""

    verdict: Verdict
    trace: SimTrace  # the run without its table's pulses: homing's, the clock, the slow pins
    timeline: RuntimeTimeline  # the tables' runtime records on the twin's clock
    twin_final: np.ndarray  # the twin's positions at the end (steps from the program's start)
    made_position: np.ndarray  # where the simulated run's pulses took the motors (from the program's start)
    trip: tuple[dict, list[str]]  # Comparison.trip_figures
    span_cycles: int  # from the run's first pulse to its last (as simulated)
    planned_s: float
    first_run_cycle: int | None
    seconds: dict = field(default_factory=dict)  # wall time: planning again, waiting for the simulator, in all


def compare_run(host: HostBuild, strict: bool, link, edges: Path, ended: Callable[[], bool],
                end_trace: Callable[[], SimTrace], switches: dict, streamed: bool,
                chapter_pulses: int = CHAPTER_PULSES) -> Compared:
    """Plan `host`'s job again and compare it, chapter by chapter, with the run the harness writes to `edges`
    (`ended()`: it has written its last record; `end_trace()`: the run's state and cycles then)."""
    began = time.perf_counter()
    config = host.firmware_config()
    reader = RunReader(edges, config, ended)
    comparison = Comparison(host, reader, streamed)

    def chapter(ch: Chapter) -> None:
        sim = reader.take(np.bincount(ch.pulses.motor, minlength=len(host.kin.motors)), chapter_pulses)
        timeline = chapters.timeline()
        comparison.add(ch, sim, reader.clock(sim.cycle, timeline.tick[timeline.waits()]))

    chapters = Chapters(chapter, chapter_pulses)
    host_build(host.job, strict, keep=False, link=link, observe=chapters)
    chapters.close()
    comparison.extra(reader.rest())
    trace = reader.trace(end_trace())
    verdict = comparison.finish(trace, switches)
    span = comparison.span_cycles[1] - comparison.span_cycles[0] if comparison.span_cycles else 0
    return Compared(verdict, trace, chapters.timeline(), comparison.twin_final, comparison.position,
                    comparison.trip_figures(), span, comparison.planned_s(), reader.first_run_cycle,
                    {"wait_s": reader.wait_s, "compare_s": time.perf_counter() - began})


class ComparingProcess:
    """compare_run in a second process while this one simulates; `result(end_trace)` hands it the run's end and
    waits for what it found. The process is a fresh interpreter (spawned, the host build pickled: a few KB): a fork
    would start with this process's memory mapped, and the simulator's pipes open."""

    def __init__(self, host: HostBuild, strict: bool, link, edges: Path, switches: dict, streamed: bool):
        context = multiprocessing.get_context("spawn")
        self._here, there = context.Pipe()
        self._process = context.Process(target=_compare_there,
                                        args=(there, host, strict, link, edges, switches, streamed))
        self._process.start()

    def result(self, end_trace: SimTrace) -> Compared:
        try:
            self._here.send(end_trace)
        except BrokenPipeError:  # it ended before the run did: its answer says why
            pass
        try:
            kind, value = self._here.recv()
        except EOFError:
            kind, value = "error", f"the comparing process ended with exit code {self._process.exitcode}"

        self._process.join()
        if kind == "error":
            raise RuntimeError(f"the comparison failed:\n{value}")
        return value

    def stop(self) -> None:
        if self._process.is_alive():
            self._process.kill()
            self._process.join()


def _compare_there(conn, host, strict, link, edges, switches, streamed) -> None:
    progress.enable(False)  # the simulation's bar is this process's parent's
    try:
        compared = compare_run(host, strict, link, edges, conn.poll, conn.recv, switches, streamed)
        conn.send(("result", compared))
    except BaseException:  # noqa: BLE001 -- whatever it was, the parent reports it
        conn.send(("error", traceback.format_exc()))

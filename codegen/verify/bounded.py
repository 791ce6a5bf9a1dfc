"""verify in bounded memory, on both cores: the simulator's records compared with the twin a chapter at a time
while the simulation runs (a streamed run: verify_stream in codegen/verify/stream.py; a flash image: verify_flash).

The host's first pass (the caller's, `keep=False`) gave the tables, the link's plan and the totals. While the
simulator runs, the program is planned again window by window (the same windows: planning is deterministic) and
each chapter of the twin (codegen/verify/chapters.py) paired with the pulses the simulator has written by then
(codegen/verify/run_reader.py), compared (codegen/verify/compare.py Comparison) and dropped. A streamed run's
comparison runs in a second process (the first drives the link in lockstep with simavr); a flash image's in this
process, beside the simulator's. Memory holds a chapter of each, whatever the print's length; so do the outputs
written as the run is compared (RunOutputs: --trace's rows, --vcd's waveform, what --report draws).
"""

from __future__ import annotations

import ctypes
import multiprocessing
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from codegen import progress
from codegen.errors import BuildError
from codegen.firmware.homing import homing_ticks_bound
from codegen.pipeline.host import HostBuild, host_build
from codegen.sim.avr import PHASE_HOME, PHASE_RUN, SimTrace, simulate, switch_thresholds
from codegen.sim.avr_edges import Steps
from codegen.sim.avr_plant import HeaterRun, simulate_heaters
from codegen.verify.chapters import CHAPTER_PULSES, Chapter, Chapters, RuntimeTimeline
from codegen.verify.compare import Comparison, Verdict, simulated_switches
from codegen.verify.heaters import (HEAT_LIMIT_S, HELD_AFTER_FACTOR, HELD_AFTER_S, HeatedTrace, heater_figures,
                                    job_plants, table_start_s, trip_result, with_holds)
from codegen.verify.report_samples import RunSamples
from codegen.verify.resonance import AxisResonance
from codegen.verify.results import verify_json
from codegen.verify.run_reader import RunReader
from codegen.verify.steps_csv import StepsCsv
from codegen.verify.stream_tables import StreamTableCheck
from codegen.verify.waveform import EdgeWaveform


@dataclass(frozen=True)
class RunOutputs:
    """What verify writes of the run as it is compared: --trace's CSV, --vcd's waveform, and whether to gather what
    --report draws (codegen/verify/report_samples.py)."""

    steps_csv: Path | None = None
    vcd: Path | None = None
    report: bool = False
    sent_table: Path | None = None  # a stream's table bytes as the link sends them: decoded, held against the plan
    resonance: tuple[AxisResonance, ...] = ()  # verify --resonance (codegen/verify/resonance.py)


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
    samples: RunSamples | None = None  # what --report draws


class BoundedComparison:
    """Plan `host`'s job again and compare it, chapter by chapter, with the run the harness writes (`run`), then
    the verdict (`finish`)."""

    def __init__(self, host: HostBuild, strict: bool, link, switches: dict, streamed: bool,
                 chapter_pulses: int = CHAPTER_PULSES, outputs: RunOutputs = RunOutputs()):
        self.host, self.strict, self.link, self.switches = host, strict, link, switches
        self.sent = None if outputs.sent_table is None else StreamTableCheck(outputs.sent_table, len(host.kin.motors))
        self.streamed, self.chapter_pulses, self.resonance = streamed, chapter_pulses, outputs.resonance
        self.began = time.perf_counter()
        self.reader = self.comparison = self.chapters = None
        self.steps_csv = outputs.steps_csv  # verify --trace: the pulses written as they are compared
        self.rows: StepsCsv | None = None
        self.waveform = None if outputs.vcd is None else EdgeWaveform(outputs.vcd, host.job.name,
                                                                      host.firmware_config())
        self.samples = RunSamples(host, host.target.f_cpu) if outputs.report else None

    def run(self, edges: Path, ended: Callable[[], bool]) -> None:
        """`ended()`: the harness has written its last record."""
        try:
            self._run(edges, ended)
        except BaseException:
            self.discard()
            raise

    def _run(self, edges: Path, ended: Callable[[], bool]) -> None:
        host = self.host
        self.reader = reader = RunReader(edges, host.firmware_config(), ended,
                                         records=self.waveform.feed if self.waveform else None)
        self.comparison = comparison = self._comparison(reader)

        def chapter(ch: Chapter) -> None:
            ch = self._twin(ch)
            sim = reader.take(np.bincount(ch.pulses.motor, minlength=len(host.kin.motors)), self.chapter_pulses)
            self._rows(sim)
            timeline = chapters.timeline()
            clock = reader.clock(sim.cycle, timeline.tick[timeline.waits()])
            comparison.add(ch, sim, clock)
            if self.samples is not None:
                self.samples.add(ch, sim, clock, reader.timer_start_cycle)
            else:  # --report draws the laser's power from every write
                reader.forget_duty()
            give_back_freed_memory()

        self.chapters = chapters = Chapters(chapter, self.chapter_pulses)

        def observe(played) -> None:
            if self.sent is not None:
                self.sent.window(played.table_schedule, played.events_count)
            chapters(played)

        host_build(host.job, self.strict, keep=False, link=self.link, observe=observe)
        chapters.close()
        rest = reader.rest()
        self._rows(rest)
        comparison.extra(rest)
        if self.samples is not None:
            self.samples.extra(rest)

    def _comparison(self, reader: RunReader) -> Comparison:
        """The run's comparison (a held run's, with its dilated clock: codegen/verify/hold_bounded.py)."""
        return Comparison(self.host, reader, self.streamed, resonance=self.resonance)

    def _twin(self, chapter: Chapter) -> Chapter:
        """The twin's chapter the run is compared with (a held run's on its dilated clock)."""
        return chapter

    def _rows(self, sim) -> None:
        """--trace's rows of the table's pulses `sim`; homing's first (they all came before the player's tick 0)."""
        if self.steps_csv is None:
            return
        if self.rows is None:
            self.rows = StepsCsv(self.steps_csv, self.host.kin.motors, self.reader.f_cpu)
            home = self.reader.homing_steps()
            self.rows.write(home.cycle, home.motor, home.dir, PHASE_HOME)
        self.rows.write(sim.cycle, sim.motor, sim.dir, PHASE_RUN)

    def finish(self, end: SimTrace) -> Compared:
        """`end`: the run's state, cycles and homing fault as its simulation ended."""
        comparison, reader = self.comparison, self.reader
        trace = reader.trace(end)
        if self.steps_csv is not None:
            self._rows(Steps.empty())  # homing's rows, where no chapter came
            self.rows.close()
        if self.waveform is not None:
            self.waveform.close()
        verdict = comparison.finish(trace, self.switches)
        if self.sent is not None:  # the bytes first: a wrong byte explains any pulse it puts out of place
            verdict.problems[:0] = self.sent.close()
        span = comparison.span_cycles[1] - comparison.span_cycles[0] if comparison.span_cycles else 0
        timeline = self.chapters.timeline()
        if self.samples is not None:
            self.samples.timeline = timeline
        return Compared(verdict, trace, timeline, comparison.twin_final, comparison.position,
                        comparison.trip_figures(), span, comparison.planned_s(), reader.first_run_cycle,
                        {"wait_s": reader.wait_s, "compare_s": time.perf_counter() - self.began}, self.samples)

    def discard(self) -> None:
        """No waveform file where the run was not compared to its end."""
        if self.waveform is not None:
            self.waveform.discard()


_LIBC = None


def give_back_freed_memory() -> None:
    """glibc keeps the pages of freed arrays in its heap, and a long run's chapters fragment it upward: hand the
    free pages back to the system (malloc_trim; elsewhere nothing)."""
    global _LIBC
    try:
        _LIBC = _LIBC or ctypes.CDLL("libc.so.6")
        _LIBC.malloc_trim(0)
    except (OSError, AttributeError):
        pass


def compare_run(host: HostBuild, strict: bool, link, edges: Path, ended: Callable[[], bool],
                end_trace: Callable[[], SimTrace], switches: dict, streamed: bool,
                chapter_pulses: int = CHAPTER_PULSES, outputs: RunOutputs = RunOutputs()) -> Compared:
    """BoundedComparison's run and finish (`end_trace()`: the run's end, once it has ended)."""
    comparison = BoundedComparison(host, strict, link, switches, streamed, chapter_pulses, outputs)
    comparison.run(edges, ended)
    try:
        return comparison.finish(end_trace())
    except BaseException:
        comparison.discard()
        raise


class ComparingProcess:
    """compare_run in a second process while this one simulates; `result(end_trace)` hands it the run's end and
    waits for what it found. The process is a fresh interpreter (spawned, the host build pickled: a few KB): a fork
    would start with this process's memory mapped, and the simulator's pipes open."""

    def __init__(self, host: HostBuild, strict: bool, link, edges: Path, switches: dict, streamed: bool,
                 outputs: RunOutputs = RunOutputs()):
        context = multiprocessing.get_context("spawn")
        self._here, there = context.Pipe()
        self._process = context.Process(target=_compare_there,
                                        args=(there, host, strict, link, edges, switches, streamed, outputs))
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
            raise BuildError("verify's comparing process failed (a bug of printer-codegen: please report it):\n"
                             + value)
        return value

    def stop(self) -> None:
        if self._process.is_alive():
            self._process.kill()
            self._process.join()


def _compare_there(conn, host, strict, link, edges, switches, streamed, outputs) -> None:
    progress.enable(False)  # the simulation's bar is this process's parent's
    try:
        compared = compare_run(host, strict, link, edges, conn.poll, conn.recv, switches, streamed, outputs=outputs)
        conn.send(("result", compared))
    except BaseException:  # noqa: BLE001 -- whatever it was, the parent reports it
        conn.send(("error", traceback.format_exc()))


def heater_verdict(host: HostBuild, run: HeaterRun, compared: Compared, image, faults) -> dict:
    """verify's result of a run with heaters compared chunk by chunk (run.steps: its end, without its pulses): a
    trip's (codegen/verify/heaters.py trip_result), or the comparison's with the holds' problems; the heaters'
    figures. compared.trace becomes a HeatedTrace, with the plants' (what --report draws)."""
    run.steps = compared.trace
    compared.trace = HeatedTrace(**vars(compared.trace), plants=run.heaters)
    if run.trip is not None:
        result = trip_result(host, run, image, *compared.trip, compared.span_cycles, compared.planned_s)
    else:
        waits = compared.timeline.tick[compared.timeline.waits()]
        result = with_holds(verify_json(host, compared.verdict, image), run, waits)
    start = table_start_s(run.steps, compared.first_run_cycle)
    result.update(heater_figures(host, run, compared.timeline, start))
    result["faults"] = [{"name": f.kind, "heater": f.heater, "at_s": f.at_s} for f in faults]
    return result


def verify_flash(host: HostBuild, image, faults, strict: bool,
                 outputs: RunOutputs = RunOutputs()) -> tuple[dict, Compared]:
    """verify of a flash image in bounded memory: `host` keeps its tables only (host_build keep="tables"); the
    simulator runs as its own process, the comparison in this one beside it. What the comparison found has the
    trace with the homing pulses, the clock and the slow pins (and --report's samples)."""
    comparison = BoundedComparison(host, strict, None, simulated_switches(host), streamed=False, outputs=outputs)
    try:
        return _verify_flash(host, image, faults, comparison)
    finally:
        comparison.discard()  # a waveform finished stands: this removes only a partial one


def _verify_flash(host: HostBuild, image, faults, comparison: BoundedComparison) -> tuple[dict, Compared]:
    config, switches = host.firmware_config(), comparison.switches
    if host.heaters:
        homing_s = homing_ticks_bound(config, switch_thresholds(config, switches), host.target.tick_hz) \
            / host.target.tick_hz
        held_after_s = host.totals.duration_s * HELD_AFTER_FACTOR + HELD_AFTER_S  # as verify_heaters'
        run = simulate_heaters(image.hex_path, config, HEAT_LIMIT_S + homing_s + held_after_s,
                               job_plants(host.job, config), faults, switches, held_after_s, beside=comparison.run)
        compared = comparison.finish(run.steps)
        return heater_verdict(host, run, compared, image, faults), compared
    budget = int((host.totals.duration_s * 1.2 + 1.0) * host.target.f_cpu)
    trace = simulate(image.hex_path, config, budget, switches=switches, beside=comparison.run)
    compared = comparison.finish(trace)
    return verify_json(host, compared.verdict, image), compared

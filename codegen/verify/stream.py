"""`verify --stream`: the job streamed to its streaming firmware in the simulator, through the host's own link
code (codegen/link/host.py), and verify's result with the link's checks and figures."""

from __future__ import annotations

import dataclasses
import importlib
import tempfile
from pathlib import Path

import numpy as np

import codegen.tables.format as tables
from codegen import progress
from codegen.link.host import HostLink
from codegen.pipeline.host import HostBuild
from codegen.pipeline.streaming import SIM_MODULES, StreamSetup, file_chunks, stream_chunks
from codegen.sim.avr_link import StreamSim, heater_run
from codegen.verify.bounded import Compared, ComparingProcess, RunOutputs, heater_verdict
from codegen.verify.compare import compare, simulated_switches
from codegen.verify.heaters import HEAT_LIMIT_S, heater_result, job_plants
from codegen.verify.results import verify_json


def simulate_stream(host: HostBuild, setup: StreamSetup, image, faults) -> tuple[dict, object]:
    """The job streamed to its firmware in the simulator: verify's result (with `link`) and the trace (on the
    simulated clock)."""
    config = setup.config
    link = new_link(host, setup)
    simulator = importlib.import_module(SIM_MODULES[setup.target.target])
    budget = session_budget_s(host, setup)
    switches = simulated_switches(host)
    cycles = int(budget * setup.target.f_cpu)
    with progress.stage("stream (simulated)", host.link_plan.stream_bytes, "bytes") as bar:
        shown = ShownSession(link, bar)
        if config.heaters:
            run, figures = simulator.simulate_stream_heaters(image.hex_path, config, shown, cycles,
                                                             job_plants(host.job, config), faults, switches)
        else:
            trace, figures = simulator.simulate_stream(image.hex_path, config, shown, cycles, switches=switches)
    if config.heaters:
        result, trace = heater_result(host, run, image, faults, switches, streamed=True)
    else:
        result = verify_json(host, compare(host, trace, switches, streamed=True), image)
    run_trace = run.steps if config.heaters else trace
    return stream_result(host, link, figures, result, host.pulses.final_positions(),
                         made_positions(run_trace, len(host.kin.motors))), trace


class ShownSession:
    """A simulated session's host (HostLink's interface, or a wrapper of it such as codegen/verify/hold_runs.py's
    Scripted) whose stream bytes, as the firmware acknowledges them, move a progress bar; the session finds the
    wrapped host as `link`."""

    def __init__(self, link: HostLink, bar):
        self.link, self.bar = link, bar

    def __getattr__(self, name: str):
        return getattr(self.link, name)  # only for what this class does not define itself

    def receive(self, data: bytes, now: float) -> None:
        self.link.receive(data, now)
        progress.move_to(self.bar, self.link.stats.data_bytes)


def new_link(host: HostBuild, setup: StreamSetup) -> HostLink:
    """The host's side of a simulated session: the job's table stream, as `stream` sends it."""
    data = tables.encode(host.schedule).data
    return HostLink(stream_chunks(data, len(host.kin.motors)), len(host.kin.motors), setup.identity,
                    10 / setup.layout.baud, host.link_plan.prefill_bytes, payload=setup.budget.payload,
                    ping_s=setup.budget.ping_s,
                    stream_bytes=host.link_plan.stream_bytes, heaters=tuple(h.name for h in setup.config.heaters))


def session_budget_s(host: HostBuild, setup: StreamSetup) -> float:
    """Simulated seconds a session may take: the plan, the ring's fill and drain, a heat-up."""
    return (host.totals.duration_s * 1.5 + 2.0 + 2 * setup.budget.ring_bytes / setup.budget.rate
            + (HEAT_LIMIT_S if setup.config.heaters else 0.0))


def stream_result(host: HostBuild, link: HostLink, figures, result: dict, expected: np.ndarray,
                  made: np.ndarray) -> dict:
    """verify's result of a session with the link's checks and figures (`link`); `expected`: the twin's positions
    at the end, `made`: where the simulated pulses took the motors (both from the job's start)."""
    problems = result["problems"]
    if link.outcome not in ("finished", "fault"):
        problems.append(f"the stream ended {link.outcome}: {link.message}".rstrip(": "))
    expected = tuple(int(v) for v in expected)
    if link.outcome == "finished" and link.position != expected:
        problems.append(f"the firmware reports positions {list(link.position)} at the end, the twin "
                        f"{list(expected)}")
    if link.outcome == "fault" and link.position != tuple(int(v) for v in made):  # where its pulses took them
        problems.append(f"the firmware reports positions {list(link.position)} at the trip, its pulses made "
                        f"{[int(v) for v in made]}")
    if figures.lost_bytes:
        problems.append(f"{figures.lost_bytes} received bytes were read too late: a real UART would have "
                        f"lost them")
    result["pass"] = result["pass"] and not problems
    result["image"]["table_bytes"] = 0
    result["link"] = {"baud": figures.baud, "bytes": figures.bytes, "frames": figures.frames,
                      "retransmits": figures.retransmits, "min_ring_fill_bytes": figures.min_ring_fill_bytes,
                      "underruns": figures.underruns, "lost_bytes": figures.lost_bytes,
                      "planned_min_ring_fill_bytes": host.link_plan.min_ring_fill_bytes,
                      "prefill_bytes": host.link_plan.prefill_bytes,
                      "link_slowdown_s": round(host.link_plan.link_slowdown_s, 6)}
    return result


def made_positions(trace, motors: int) -> np.ndarray:
    """Where a trace's table pulses took the motors."""
    run = trace.run_only()
    return np.array([int(run.step_dir[run.step_motor == m].sum()) for m in range(motors)], dtype=np.int64)


def simulate_stream_bounded(host: HostBuild, setup: StreamSetup, image, faults, table, strict: bool,
                            comparing=ComparingProcess, outputs: RunOutputs = RunOutputs()) -> tuple[dict, Compared]:
    """simulate_stream in bounded memory (codegen/verify/bounded.py): `host` is the first pass's (not kept), its
    table stream in `table` (a named file: the comparison decodes the bytes the link sends and holds them against
    the plan); the comparison runs beside the simulation (`comparing`: in a second process, while this one drives
    the link, writing `outputs`). What the comparison found has the trace with the homing pulses, the
    clock, the slow pins and the ring's fill, not the table's pulses (and --report's samples)."""
    table.flush()
    outputs = dataclasses.replace(outputs, sent_table=Path(table.name))
    config = setup.config
    motors = len(host.kin.motors)
    link = HostLink(file_chunks(table, motors), motors, setup.identity, 10 / setup.layout.baud,
                    host.link_plan.prefill_bytes, payload=setup.budget.payload, ping_s=setup.budget.ping_s,
                    stream_bytes=host.link_plan.stream_bytes, heaters=tuple(h.name for h in config.heaters))
    switches = simulated_switches(host)
    cycles = int(session_budget_s(host, setup) * setup.target.f_cpu)
    if setup.target.target == "mcs51":
        compared, figures = _s51_session(host, setup, image, strict, link, switches, cycles, comparing, outputs)
        run = None
    else:
        plants = job_plants(host.job, config) if config.heaters else None
        with StreamSim(image.hex_path, config, switches, plants, faults) as sim:
            comparing = comparing(host, strict, setup.budget, sim.edges, switches, True, outputs)
            try:
                with progress.stage("stream (simulated)", host.link_plan.stream_bytes, "bytes") as bar:
                    summary, figures = sim.session(ShownSession(link, bar), cycles, decode=False)
                run = heater_run(sim, link, summary) if config.heaters else None
                compared = comparing.result(summary)
            finally:
                comparing.stop()
    if run is None:
        result = verify_json(host, compared.verdict, image)
    else:
        result = heater_verdict(host, run, compared, image, faults)
    result = stream_result(host, link, figures, result, compared.twin_final, compared.made_position)
    return result, compared


def _s51_session(host: HostBuild, setup: StreamSetup, image, strict: bool, link: HostLink, switches: dict,
                 cycles: int, comparing, outputs: RunOutputs) -> tuple[Compared, object]:
    """An 8051's session in s51, its pins written to an edges file as they come (codegen/sim/mcs51_edges.py) and
    compared beside it: what the comparison found, and the link's figures."""
    simulator = importlib.import_module(SIM_MODULES["mcs51"])
    with tempfile.TemporaryDirectory(prefix="printer-codegen-s51edges-") as tmp:
        edges = Path(tmp) / "edges.bin"
        comparing = comparing(host, strict, setup.budget, edges, switches, True, outputs)
        try:
            with progress.stage("stream (simulated)", host.link_plan.stream_bytes, "bytes") as bar:
                summary, figures = simulator.simulate_stream(image.hex_path, setup.config, ShownSession(link, bar),
                                                             cycles, switches=switches, edges=edges)
            return comparing.result(summary), figures
        finally:
            comparing.stop()

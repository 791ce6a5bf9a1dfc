"""The simulated runs of codegen/verify/hold.py: a flash image whose hold keys are pressed (simavr's key pins; s51's
key matrix on the 8051), or a streaming firmware whose host sends HOLD, RESUME, FEED_DOWN and FEED_UP frames (the
closed-loop link of codegen/sim/avr_link.py). Each run takes the presses as (function, cycle) and says when each
reached the firmware: a key at once (on the 8051: at main's first poll after it), a frame once its last byte has
arrived (it is sent when the line is idle, at or after its cycle). A stream runs in its target's closed-loop
simulator: simavr's (codegen/sim/avr_link.py) or s51's (codegen/sim/mcs51_link.py)."""

from __future__ import annotations

import importlib
import time

from codegen import progress
from codegen.errors import BuildError
from codegen.link import protocol
from codegen.pipeline.host import HostBuild
from codegen.pipeline.streaming import SIM_MODULES
from codegen.sim.avr import simulate
from codegen.sim.avr_link import StreamSim, heater_run
from codegen.sim.avr_plant import simulate_heaters
from codegen.sim.mcs51 import simulate as simulate_51
from codegen.sim.mcs51_keys import seen_at
from codegen.verify.compare import simulated_switches
from codegen.verify.heaters import (HEAT_LIMIT_S, HELD_AFTER_FACTOR, HELD_AFTER_S, heater_figures, hold_problems,
                                    host_timeline, job_plants, on_twin_clock)
from codegen.verify.results import verify_json
from codegen.verify.run_reader import POLL_S
from codegen.verify.stream import ShownSession, made_positions, new_link, session_budget_s, stream_result

PRESS_S = 0.05  # a key held down this long (main polls at least every 32 ms: the longest undilated wait)
RESUME_EVERY_S = 0.01  # the first run's RESUME frames: every M0/M1 goes on at once
MAIN_TURN_CANDIDATES = 12  # events that may be a frame's first dilated one on the 8051's stream, where main's turn
# (link_poll, and a display's refresh of up to 2 ms) comes between the frame and hold_poll (verify_hold's CANDIDATES)
MAX_CLOCK = (1 << 32) - 1  # s51's sim_ticks never passes it: a key held down to the end
KINDS = {"hold": protocol.HOLD, "resume": protocol.RESUME, "feed-": protocol.FEED_DOWN, "feed+": protocol.FEED_UP}
FRAME_BYTES = protocol.OVERHEAD_BYTES  # a request has no payload


class FlashRun:
    """A flash image in simavr, its keys pressed."""

    def __init__(self, host: HostBuild, image):
        self.host, self.image = host, image
        self.config, self.switches = host.firmware_config(), simulated_switches(host)
        self.f_cpu = host.target.f_cpu
        self.budget = int((host.totals.duration_s * 1.2 + 1.0) * self.f_cpu)
        self.streamed = False
        self.link_budget = None  # a stream's (its chapters are planned again with it)
        self.candidates = None  # verify_hold's CANDIDATES

    def tick0(self, pauses: bool) -> int:
        """The job's tick 0 (cycles from reset); with `pauses` the resume key is held down all along."""
        held = [(self.host.hold_plan.keys["resume"], 1, 1 << 62)] if pauses else []
        return simulate(self.image.hex_path, self.config, self.budget, switches=self.switches, presses=held,
                        beside=unread).timer_start_cycle

    def run(self, presses: list[tuple[str, int]], slower: float, beside=None) -> tuple[object, list[int]]:
        """The run with `presses` and when each reached the firmware; `beside(edges, ended)` reads its records
        while the harness writes them (codegen/sim/avr.py simulate's: the trace then has none)."""
        pins, hold = self.host.hold_plan.keys, int(PRESS_S * self.f_cpu)
        keys = [(pins[function], cycle, cycle + hold) for function, cycle in presses]
        budget = int(self.budget * slower) + max((c for _, c in presses), default=0) + int(2 * self.f_cpu)
        trace = simulate(self.image.hex_path, self.config, budget, switches=self.switches, presses=keys,
                         beside=beside)
        return trace, self.arrivals(presses)

    def arrivals(self, presses: list[tuple[str, int]]) -> list[int]:
        """When each press reached the firmware (a key: as it is pressed); a run read beside (`run`'s `beside`)
        knows them by the time it has ended."""
        return [cycle for _, cycle in presses]

    def result(self, verdict, trace, compared=None) -> dict:
        """verify's result (`compared`: what a run read beside found, codegen/verify/bounded.py Compared)."""
        return verify_json(self.host, verdict, self.image)


class S51FlashRun(FlashRun):
    """An 8051 flash image in s51, its matrix keys pressed (codegen/sim/mcs51_keys.py): main polls them every 2 ms
    (hold.c's hold_due), so each press reaches the firmware at the first poll that sees it."""

    def tick0(self, pauses: bool) -> int:
        held = [("resume", 1, MAX_CLOCK)] if pauses else []  # down all along: every M0/M1 goes on at once
        return simulate_51(self.image.hex_path, self.config, self.budget, switches=self.switches,
                           hold_keys=held).timer_start_cycle

    def run(self, presses: list[tuple[str, int]], slower: float) -> tuple[object, list[int]]:
        hold = int(PRESS_S * self.f_cpu)
        keys = [(function, cycle, cycle + hold) for function, cycle in presses]
        budget = int(self.budget * slower) + max((c for _, c in presses), default=0) + int(2 * self.f_cpu)
        trace = simulate_51(self.image.hex_path, self.config, budget, switches=self.switches, hold_keys=keys)
        return trace, [seen_at(trace.hold_polls, trace.hold_changes, cycle) for _, cycle in presses]


class HeatedRun(FlashRun):
    """A flash image with heaters in simavr against their thermal plants (codegen/verify/heaters.py), its keys
    pressed after the heaters' last wait: the waits' holds are taken out of the trace (on_twin_clock), so the run
    is on the twin's clock as a run without heaters is; the presses come in on that clock and go to the simulator
    moved by the holds' time."""

    def __init__(self, host: HostBuild, image):
        super().__init__(host, image)
        self.plants = job_plants(host.job, self.config)
        self.timeline = host_timeline(host)
        self.waits = self.timeline.tick[self.timeline.waits()]
        self.cycles_per_tick = self.f_cpu // host.target.tick_hz
        self.held_after_s = host.totals.duration_s * HELD_AFTER_FACTOR + HELD_AFTER_S  # verify_heaters' own run
        self.seconds = HEAT_LIMIT_S + self.held_after_s
        self.start = 0  # the job's tick 0 (cycles from reset)
        self.shift = 0  # simulated cycles after the last wait's hold, less the twin's
        self.after = 0  # the twin's cycle of the last wait: the presses come after it
        self.heated = None

    def _run(self, keys: list, slower: float, beside=None):
        return simulate_heaters(self.image.hex_path, self.config, self.seconds * slower, self.plants, (),
                                self.switches, self.held_after_s * slower, presses=keys, beside=beside)

    def tick0(self, pauses: bool) -> int:
        held = [(self.host.hold_plan.keys["resume"], 1, 1 << 62)] if pauses else []
        trace = self._run(held, 1.0, unread).steps
        if trace.timer_start_cycle is None:
            raise BuildError("verify --hold/--override: the image's heaters did not settle; verify it without them")
        self.start = trace.timer_start_cycle
        if len(self.waits):
            self.after, self.shift = waits_shift(trace, self.waits, self.cycles_per_tick)
        return self.start

    def run(self, presses: list[tuple[str, int]], slower: float, beside=None) -> tuple[object, list[int]]:
        refuse_before(presses, self.start, self.after, self.f_cpu)
        pins, hold = self.host.hold_plan.keys, int(PRESS_S * self.f_cpu)
        keys = [(pins[function], cycle + self.shift, cycle + self.shift + hold) for function, cycle in presses]
        self.heated = self._run(keys, slower + max((c for _, c in presses), default=0) / self.f_cpu, beside)
        self.heated.steps = on_twin_clock(self.heated.steps, self.waits, self.cycles_per_tick)
        return self.heated.steps, self.arrivals(presses)

    def result(self, verdict, trace, compared=None) -> dict:
        return with_heaters(verify_json(self.host, verdict, self.image), self.host, self.heated, self.timeline)


class Scripted:
    """A HostLink that sends the script's requests ((cycle, kind), in order) once the line is idle at or after
    their cycle, noting when each arrives; with `resume_every` a RESUME that often besides, once the job has started
    (before, they would only delay START on a slow link: the 8051's at 9600 baud)."""

    def __init__(self, link, script: list[tuple[int, int]], f_cpu: int, resume_every: float | None = None):
        self.link, self.script, self.f_cpu = link, list(script), f_cpu
        self.resume_every = resume_every
        self.next_resume = resume_every
        self.arrived: list[int] = []

    def __getattr__(self, name: str):
        return getattr(self.link, name)

    def _due(self) -> float | None:
        if not self.script or self.link.ident is None:
            return None
        return max(self.script[0][0] / self.f_cpu, self.link.line_free_at)

    def wake_at(self) -> float | None:
        times = [t for t in (self.link.wake_at(), self._due()) if t is not None]
        if self.resume_every is not None and self.link.started_at is not None:
            times.append(self.next_resume)
        return min(times) if times else None

    def transmit(self, now: float) -> bytes:
        due = self._due()
        if due is not None and now >= due - 1e-12:  # the line is idle: the request goes first, at once
            self.link.feed(self.script.pop(0)[1])
            self.arrived.append(int(round((now + FRAME_BYTES * self.link.byte_s) * self.f_cpu)))
        if self.resume_every is not None and self.link.started_at is not None and now >= self.next_resume:
            self.link.feed(protocol.RESUME)
            self.next_resume = now + self.resume_every
        return self.link.transmit(now)

    def receive(self, data: bytes, now: float) -> None:
        self.link.receive(data, now)

    @property
    def done(self) -> bool:
        return self.link.done


class StreamRun:
    """A streaming firmware in its simulator, the job streamed to it, its requests sent over the link; with heaters,
    against their plants, its requests after the heaters' last wait and the run on the twin's clock (as
    HeatedRun's)."""

    def __init__(self, host: HostBuild, image, setup):
        self.host, self.image, self.setup = host, image, setup
        self.link_budget = setup.budget
        self.switches = simulated_switches(host)
        self.f_cpu = host.target.f_cpu
        self.streamed = True
        self.candidates = MAIN_TURN_CANDIDATES if setup.target.target == "mcs51" else None
        self.link = self.figures = self.heated = self.scripted = None
        self.waits = self.timeline = None
        if host.heaters:
            self.timeline = host_timeline(host)
            self.waits = self.timeline.tick[self.timeline.waits()]
        self.cycles_per_tick = self.f_cpu // host.target.tick_hz
        self.start = self.shift = self.after = 0  # as HeatedRun's

    def _session(self, scripted: Scripted, slower: float, beside=None):
        """The session's trace and the link's figures; with `beside(edges, ended)` (an ATmega2560's), the records
        are left to it, read once the session has ended, and the trace has no pulses."""
        simulator = importlib.import_module(SIM_MODULES[self.setup.target.target])
        budget = int(session_budget_s(self.host, self.setup) * slower * self.f_cpu)
        config = self.setup.config
        plants = None if self.waits is None else job_plants(self.host.job, config)
        with progress.stage("stream (simulated)", self.host.link_plan.stream_bytes, "bytes") as bar:
            shown = ShownSession(scripted, bar)
            if beside is not None:
                with StreamSim(self.image.hex_path, config, self.switches, plants) as sim:
                    trace, figures = sim.session(shown, budget, decode=False)
                    if plants is not None:
                        self.heated = heater_run(sim, scripted.link, trace)
                    beside(sim.edges, lambda: True)
                return trace, figures
            if plants is None:
                return simulator.simulate_stream(self.image.hex_path, config, shown, budget, switches=self.switches)
            self.heated, figures = simulator.simulate_stream_heaters(self.image.hex_path, config, shown, budget,
                                                                     plants, (), self.switches)
        return self.heated.steps, figures

    def _scripted(self, script: list[tuple[int, int]], resume_every: float | None = None) -> Scripted:
        self.scripted = Scripted(new_link(self.host, self.setup), script, self.f_cpu, resume_every)
        return self.scripted

    def tick0(self, pauses: bool) -> int:
        scripted = self._scripted([], RESUME_EVERY_S if pauses else None)
        trace, _ = self._session(scripted, 1.0)
        if trace.timer_start_cycle is None:
            raise BuildError("verify --hold/--override: the player never started (did its heaters settle?)")
        self.start = trace.timer_start_cycle
        if self.waits is not None and len(self.waits):
            self.after, self.shift = waits_shift(trace, self.waits, self.cycles_per_tick)
        return self.start

    def run(self, presses: list[tuple[str, int]], slower: float, beside=None) -> tuple[object, list[int]]:
        """As FlashRun's; `beside` reads the records once the session has ended (an ATmega2560's stream)."""
        refuse_before(presses, self.start, self.after, self.f_cpu)
        order = sorted(range(len(presses)), key=lambda i: presses[i][1])  # the line sends them one after another
        scripted = self._scripted([(presses[i][1] + self.shift, KINDS[presses[i][0]]) for i in order])
        trace, self.figures = self._session(scripted, slower + sum(c for _, c in presses) / self.f_cpu, beside)
        self.link = scripted.link
        if self.heated is not None:
            trace = self.heated.steps = on_twin_clock(trace, self.waits, self.cycles_per_tick)
        return trace, self.arrivals(presses)

    def arrivals(self, presses: list[tuple[str, int]]) -> list[int]:
        """When each request's frame had arrived (its last byte), in the order of `presses` (once sent)."""
        order = sorted(range(len(presses)), key=lambda i: presses[i][1])
        arrived = [-1] * len(presses)
        for i, cycle in zip(order, self.scripted.arrived):
            arrived[i] = cycle - self.shift
        return arrived

    def result(self, verdict, trace, compared=None) -> dict:
        motors = len(self.host.kin.motors)
        expected, made = ((self.host.pulses.final_positions(), made_positions(trace, motors)) if compared is None
                          else (compared.twin_final, compared.made_position))
        result = stream_result(self.host, self.link, self.figures, verify_json(self.host, verdict, self.image),
                               expected, made)
        return result if self.heated is None else with_heaters(result, self.host, self.heated, self.timeline)


def unread(edges, ended) -> None:
    """A run's `beside` that reads none of its records (a run for its clock only: tick0): it waits for its end."""
    while not ended():
        time.sleep(POLL_S)


def waits_shift(trace, waits, cycles_per_tick: int) -> tuple[int, int]:
    """The twin's cycle of the heaters' last wait, and how much later the run goes on after its hold."""
    after = trace.timer_start_cycle + int(waits[-1]) * cycles_per_tick
    return after, trace.resumes[len(waits) - 1] - after


def refuse_before(presses: list[tuple[str, int]], start: int, after: int, f_cpu: int) -> None:
    """BuildError for a key pressed before the heaters' last wait (`after`; `start`: the job's tick 0)."""
    early = [c for _, c in presses if c < after]
    if early:
        raise BuildError(f"verify --hold/--override: a key pressed {(early[0] - start) / f_cpu:.3f} s into the job, "
                         f"before the heaters' last wait ({(after - start) / f_cpu:.3f} s): with heaters, verify "
                         "holds and overrides after the waits")


def with_heaters(result: dict, host: HostBuild, run, timeline) -> dict:
    """verify's result with the heaters' figures and the waits' holds (codegen/verify/heaters.py)."""
    result["problems"] += hold_problems(run.steps, timeline.tick[timeline.waits()])
    result["pass"] = result["pass"] and not result["problems"]
    result.update(heater_figures(host, run, timeline, None), faults=[])
    return result

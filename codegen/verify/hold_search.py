"""Where the requests of a held or overridden run (codegen/verify/hold.py) are pressed, and which event each is first
seen by: the twin on the dilated clock (codegen/tables/hold.py) placed against the simulated run's first pulse of
every event.

The override requests (feed- or feed+, one per 10 %) come from 10 ms into the job, one every 100 ms; the hold at
SECONDS into the job; resume once the twin says the machine is at rest (REST_S after its park). A request is seen
by main's poll after a step interrupt, and that event's next interrupt dilates the event after it: which event that
is depends on cycles the twin does not count, so each request's first dilated event is chosen among a few
(CANDIDATES) as the one the simulated pulses agree with. All it reads of the run is the first cycle of the
events near the requests (NearRequests), and the twin's dilated clock is played, not kept (Dilator)."""

from __future__ import annotations

import dataclasses

import numpy as np

from codegen.errors import BuildError
from codegen.pipeline.host import HostBuild
from codegen.tables.hold import F_ONE, RESUME_TICKS, Dilator, override_target

OVERRIDE_FIRST_S, OVERRIDE_EVERY_S = 0.01, 0.1  # the override key presses from the job's start
REST_S = 0.02  # from the park the twin predicts to the resume key
POLL_CYCLES = 400  # a step interrupt and main's poll: a key pressed this long before an event may be seen after it
CANDIDATES = 5  # events, after the first one within POLL_CYCLES of the press, that may be the key's first
# (a runner may need more: its `candidates`)
RESUME_FIT = 32  # events after a resume whose earliest pulse places it (some may come late behind a link interrupt)
NEAR_BEFORE_S, NEAR_AFTER_S = 0.01, 0.1  # what placing reads of the run around a press: from before it to after it
NEAR_EVENTS = 4 * RESUME_FIT  # events from a press on that placing reads, however long they take


@dataclasses.dataclass
class KeyAction:
    function: str  # hold, feed-, feed+
    target: int  # the factor the key sets (F)
    press: int  # cycles from reset
    event: int | None = None  # its first dilated event, once known


def key_actions(host: HostBuild, tick0: int, hold_s: float | None, override: int | None) -> list[KeyAction]:
    f_cpu, start = host.target.f_cpu, host.job.machine.feed_hold.override // 10
    actions = []
    if override is not None:
        goal = override // 10
        for i, step in enumerate(range(start, goal, 1 if goal > start else -1)):
            press = tick0 + int((OVERRIDE_FIRST_S + i * OVERRIDE_EVERY_S) * f_cpu)
            nxt = step + (1 if goal > start else -1)
            actions.append(KeyAction("feed+" if goal > start else "feed-", override_target(nxt), press))
    if hold_s is not None:
        last = (actions[-1].press - tick0) / f_cpu + OVERRIDE_EVERY_S if actions else 0.0
        if hold_s < last:
            raise BuildError(f"verify --hold {hold_s:g}: the override's requests go on until {last:g} s into the "
                             "job; hold after them")
        actions.append(KeyAction("hold", 0, tick0 + int(hold_s * f_cpu)))
    return actions


@dataclasses.dataclass
class FirstCycles:
    """The simulated run as placing the requests reads it: the first pulse's cycle (on the twin's clock) of the
    events in `event` (sorted): every event with a pulse, or those near a request (NearRequests)."""

    event: np.ndarray  # (K,) int64
    cycle: np.ndarray  # (K,) int64

    @classmethod
    def whole(cls, cycles: np.ndarray) -> FirstCycles:
        """From every twin event's first cycle (-1: none)."""
        stepping = np.flatnonzero(cycles >= 0)
        return cls(stepping, cycles[stepping])


class NearRequests:
    """Which events' first pulses placing the requests reads (FirstCycles): those from NEAR_BEFORE_S before any
    press to `after_s` after it, and the first NEAR_EVENTS from each press on (a slow stretch has few). Fed with
    the events in order (`keep`), a chapter at a time."""

    def __init__(self, presses: list[int], f_cpu: int, after_s: float):
        self.press = np.array(sorted(presses), dtype=np.int64)
        self.low = self.press - POLL_CYCLES - int(NEAR_BEFORE_S * f_cpu)
        self.high = self.press + int(after_s * f_cpu)
        self.counted = np.zeros(len(self.press), dtype=np.int64)  # events kept from each press on, so far

    def keep(self, cycle: np.ndarray) -> np.ndarray:
        """(N,) bool: which of these events (their first cycles, in order, -1: none) to keep."""
        keep = np.zeros(len(cycle), dtype=bool)
        for k, press in enumerate(self.press):
            keep |= (cycle >= self.low[k]) & (cycle < self.high[k])
            after = np.flatnonzero(cycle >= press)[:max(NEAR_EVENTS - int(self.counted[k]), 0)]
            keep[after] = True
            self.counted[k] += len(after)
        return keep


@dataclasses.dataclass
class Requests:
    """A run's requests on the twin's clock: `tick0` (the job's tick 0, cycles from reset), the keys' `actions`, the
    factor a resume goes on to, and how many events may be a request's first (`candidates`)."""

    host: HostBuild
    tick0: int
    actions: list[KeyAction]
    resume_target: int
    candidates: int = CANDIDATES

    def __post_init__(self):
        target = self.host.target
        self.prescale = target.f_cpu // target.tick_hz
        self.latency = int(target.mcu_data.get("isr_latency_cycles", 0))
        self.least_latency = int(target.mcu_data.get("isr_latency_min_cycles", self.latency))

    def predict(self, actions: list[KeyAction], events: list[int], resumes: list[int]) -> Dilator:
        """The twin on the dilated clock, to be played; an image that starts below 100 % dilates from its first
        event on."""
        host = self.host
        start = override_target(host.job.machine.feed_hold.override // 10)
        changes = ([(0, start)] if start != F_ONE else []) + [(e, a.target) for a, e in zip(actions, events)]
        return Dilator(host.schedule, host.hold_plan, changes, resumes, self.resume_target)

    def cycles_of(self, tick: np.ndarray) -> np.ndarray:
        """Predicted cycles of events from their ticks; one never played (after a park without its resume): the
        end of time."""
        cycles = tick * self.prescale
        cycles += self.tick0 + self.latency
        cycles[tick < 0] = np.iinfo(np.int64).max
        return cycles

    def first_seen(self, d: Dilator, press: int) -> int:
        """The first event predicted within POLL_CYCLES before `press` or after it."""
        return d.first_from(-(-(press - POLL_CYCLES - self.tick0 - self.latency) // self.prescale))

    def near(self, presses: list[tuple[str, int]]) -> NearRequests:
        """The events a placing of these presses reads: near each, for twice the ramp from 100 % to rest and a
        tenth of a second more (a request's first event and the ramp it starts tell the candidates apart)."""
        target = self.host.target
        after_s = 2 * self.host.hold_plan.ramp_seconds(target.tick_hz) + NEAR_AFTER_S
        return NearRequests([cycle for _, cycle in presses], target.f_cpu, after_s)

    def presses(self) -> list[tuple[str, int]]:
        """Every press, (function, cycle): the keys', then the resume's after each park. Where each request is
        first seen (the middle candidate, to place those that follow and the resumes), on the clock of the
        requests before it and of the M0/M1 pauses before it, each resumed as resume_presses says."""
        guess: list[int] = []
        for a in self.actions:
            done = self.actions[:len(guess)]
            resumes = [(r - self.tick0) // self.prescale + RESUME_TICKS for r in self.resume_presses(done, guess)]
            first = self.first_seen(self.predict(done, guess, resumes), a.press)
            guess.append(first + self.candidates // 2 + 1)
        return ([(a.function, a.press) for a in self.actions]
                + [("resume", r) for r in self.resume_presses(self.actions, guess)])

    def resume_presses(self, actions: list[KeyAction], guess: list[int]) -> list[int]:
        """The resume key's presses: REST_S after each park the twin predicts (a hold's: the latest of its
        candidates), in order; each predicted resume is RESUME_TICKS after its press."""
        f_cpu, presses, resumes, k_mid = self.host.target.f_cpu, [], [], self.candidates // 2
        hold = next((i for i, a in enumerate(actions) if a.function == "hold"), None)
        while True:
            park = self.predict(actions, guess, resumes).park(len(resumes))
            if park is None:
                return presses
            event, tick, paused = park
            if not paused and hold is not None:  # the hold's park: the latest of its candidates
                for k in range(self.candidates):
                    other = guess[:hold] + [guess[hold] - k_mid + k] + guess[hold + 1:]
                    other_park = self.predict(actions, other, resumes).park(len(resumes))
                    if other_park is not None:
                        tick = max(tick, other_park[1])
            press = self.tick0 + tick * self.prescale + int(REST_S * f_cpu)
            presses.append(press)
            resumes.append((press - self.tick0) // self.prescale + RESUME_TICKS)

    def place(self, sim: FirstCycles, resume_arrived: list[int]) -> Dilator:
        """The run as the player played it, to be played: each request's first dilated event (its action's
        `event`), the candidate that the pulses agree with, and each park's resume placed by the pulses after it."""
        actions = self.actions

        def resumed(events: list[int]) -> list[int]:
            """Each park's resumed tick: the one that puts the first pulses after its resume in place (everything
            after a resume moves with it), at the player's least latency: the earliest of RESUME_FIT pulses (a
            link interrupt may have delayed the first)."""
            ticks: list[int] = []
            for r in resume_arrived:
                provisional = (r - self.tick0) // self.prescale + RESUME_TICKS
                d = self.predict(actions[:len(events)], events, ticks + [provisional])
                park = d.park(len(ticks))
                if r < 0 or park is None:
                    break
                after = np.flatnonzero((sim.event >= park[0]) & (sim.cycle > r))[:RESUME_FIT]
                if not len(after):
                    break
                predicted = d.ticks_at(sim.event[after])
                if len(d.parks) > len(ticks) + 1:  # the next park comes first
                    before_next = sim.event[after] < d.parks[len(ticks) + 1][0]
                    after, predicted = after[before_next], predicted[before_next]
                    if not len(after):
                        break
                late = (sim.cycle[after] - self.tick0 - self.least_latency) / self.prescale - predicted
                ticks.append(provisional + int(round(float(late.min()))))
            return ticks

        chosen: list[int] = []
        for i, a in enumerate(actions):
            first = self.first_seen(self.predict(actions[:i], chosen, resumed(chosen)), a.press)
            # the pulses before the next request can tell (it has not come yet)
            before = sim.cycle < (actions[i + 1].press if i + 1 < len(actions) else np.inf)
            events, cycles = sim.event[before], sim.cycle[before]
            best, best_err = first + 1, None
            for n in range(first + 1, first + 1 + self.candidates):
                gap = self.cycles_of(self.predict(actions[:i + 1], chosen + [n], resumed(chosen + [n]))
                                     .ticks_at(events))
                gap -= cycles
                err = int(np.abs(gap, out=gap).max(initial=0))
                if best_err is None or err < best_err:
                    best, best_err = n, err
            chosen.append(best)
            a.event = best
        return self.predict(actions, chosen, resumed(chosen))


def dilated_clock(plan_time: np.ndarray, twin_tick: np.ndarray, dilated_tick: np.ndarray, tick_hz: int):
    """The plan's times (s) onto a held run's clock: every event (its planned time, its tick on the twin's clock and
    on the dilated one) moved by as much as the dilation moved its tick. Where the delay stays the same (before the
    first request, after a resume's ramp) only the stretch's ends are kept: interpolating between them gives it as
    it is."""
    delay = (dilated_tick - twin_tick) / tick_hz
    inside = np.zeros(len(delay), dtype=bool)  # within a stretch of the same delay
    inside[1:-1] = (delay[1:-1] == delay[:-2]) & (delay[1:-1] == delay[2:])
    plan_time, delay = plan_time[~inside], delay[~inside]

    def warp(t):
        return t + np.interp(t, plan_time, delay)

    return warp

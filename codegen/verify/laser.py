"""`verify` of a laser's power (codegen/tables/laser.py): the PWM counts the simulated firmware wrote (the harness logs
every write of the compare register) at every simulated event against the twin's (the tables' power records)
and against the plan's ideal power; the energy per mm along each cut; the laser off at the end.

An event's power is the last write no later than APPLY_CYCLES after its first STEP edge (and before the next
event's): the interrupt writes a new power right after that edge (templates/avr/player_isr.S.j2). Later writes
belong to events without steps (a dwell's) or to the end marker, which turns the power to 0 after the last.

A held or overridden run (codegen/verify/hold.py) gives every twin event's feed factor: M4's power then follows it
(codegen/tables/laser.py follow), written again at the end of the dilated path, so an event's power is the last write
before the next event the twin plays (the last event's stays the undilated window's: the end marker comes in its
interrupt); the ideal power is the plan's times the factor, and the energy per mm is the twin's on the dilated
clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from codegen.tables.hold import F_ONE
from codegen.tables.laser import DYNAMIC_FLAG, event_power, follow, played_counts

# From an event's first STEP edge to the interrupt's write of a new power: at most 17 cycles (counted: the other
# ports' rises, the latch's check and its two stores); the end marker's power 0, in the last event's interrupt,
# comes 30 cycles or more after its edge.
APPLY_CYCLES = 24
MAX_POWER_ERROR = 0.01  # of full scale: the bound, at every step


@dataclass
class OpenCut:
    """A cut still on at the end of a stretch of the run: its energies so far (simulated, planned) and its last
    event's power and times, so that the next stretch judges the cut whole."""
    sim: float
    plan: float
    played: float
    ideal: float
    seconds: float
    planned_s: float


@dataclass
class LaserVerdict:
    pwm_hz: float
    max_power_error: float  # of full scale: the played power against the plan's, over every simulated event
    cuts: int  # stretches of tool-on events
    max_energy_error: float  # relative: each cut's energy per mm, simulated against planned
    problems: list[str] = field(default_factory=list)
    open_cut: OpenCut | None = None  # the cut going on into the next stretch

    def as_json(self) -> dict:
        return {"pwm_hz": round(self.pwm_hz, 3), "max_power_error_pct": round(100 * self.max_power_error, 4),
                "cuts": self.cuts, "max_energy_per_mm_error_pct": round(100 * self.max_energy_error, 4)}


def laser_verdict(host, trace, event_cycle: np.ndarray, twin_event: np.ndarray | None,
                  dilation=None, counts_before: int = 0, cut_before: OpenCut | None = None,
                  ends_run: bool = True) -> LaserVerdict | None:
    """The laser's figures from a stretch of a run (a chapter's: codegen/verify/chapters.py) whose simulated events
    (their first STEP edge, `event_cycle`) are paired with the twin's events (`twin_event`; None: they could not be
    paired); `dilation`: a held or overridden run's (codegen/tables/hold.py Dilation); `counts_before`: the PWM
    counts the tables had set before the stretch; `cut_before`: the cut the stretch before left on (its first cut
    goes on: counted there, judged whole where it ends); `ends_run`: the stretch is the run's last (a held run's dilation
    has the event after any other's last). `merge_laser` joins the stretches' figures."""
    laser = host.laser
    if laser is None:
        return None
    verdict = LaserVerdict(laser.actual_hz, 0.0, 0, 0.0)
    duty = trace.laser_duty
    if twin_event is None:
        verdict.problems.append("laser: the simulated events do not pair with the twin's; power not compared")
        return verdict
    apply = np.full(len(event_cycle), APPLY_CYCLES)
    if dilation is not None:  # up to the next event the twin plays, with steps or without
        prescale = host.target.f_cpu // host.target.tick_hz
        following = np.minimum(twin_event + 1, len(dilation.tick) - 1)
        through = len(apply) - 1 if ends_run else len(apply)  # the run's last event: APPLY_CYCLES
        apply[:through] = ((dilation.tick[following] - dilation.tick[twin_event]) * prescale)[:through]
    window = np.minimum(event_cycle + apply + 1, np.append(event_cycle[1:], np.iinfo(np.int64).max))
    at = np.searchsorted(duty[:, 0], window, side="left") - 1
    played = np.where(at >= 0, duty[np.maximum(at, 0), 1], 0)
    records = played_counts(host.schedule, counts_before)[twin_event]
    factor = F_ONE if dilation is None else dilation.factor[twin_event]
    tables = follow(records, factor)
    differ = np.flatnonzero(played != tables)
    if len(differ):
        k = differ[0]
        verdict.problems.append(f"laser: at simulated event {k} the PWM holds {played[k]} counts, the tables "
                                f"{tables[k]} ({len(differ)} events differ)")
    ideal = event_power(host.events, host.plan, host.segments)[twin_event]
    if dilation is not None:  # M4's follows the actual speed, the plan's times the factor; dark at rest
        ideal = np.where(records & DYNAMIC_FLAG, ideal * np.clip(factor, 0, F_ONE) / F_ONE, ideal)
        ideal = np.where(factor < 0, 0.0, ideal)
    error = np.abs(played / laser.top - ideal)
    verdict.max_power_error = float(error.max(initial=0.0))
    if verdict.max_power_error > MAX_POWER_ERROR:
        k = int(np.argmax(error))
        verdict.problems.append(f"laser: at simulated event {k} the power is {100 * played[k] / laser.top:.2f} % of "
                                f"full scale, the plan's {100 * ideal[k]:.2f} % (more than "
                                f"{100 * MAX_POWER_ERROR:.0f} % apart)")
    verdict.problems += steady_power_problems(host, twin_event, played, records, factor)
    seconds = (event_cycle - (trace.timer_start_cycle or 0)) / trace.f_cpu
    twin_s = host.events.time if dilation is None else dilation.tick / host.target.tick_hz
    verdict.cuts, verdict.max_energy_error, verdict.open_cut = _energy(
        host, twin_event, seconds, played / laser.top, ideal, twin_s[twin_event], cut_before, ends_run)
    return verdict


def steady_power_problems(host, twin_event: np.ndarray, played: np.ndarray, records: np.ndarray,
                          factor: np.ndarray | int) -> list[str]:
    """M3's power against the program's own S (its segments' power, 0..1): at every tool-on event of a constant
    power cut the PWM holds round(power x TOP) counts, within one. (The ideal above is the tables' maker's
    reckoning: were it wrong, the tables and the simulator would agree on the wrong power.)"""
    events, laser = host.events, host.laser
    per_block = np.diff(events.block_first)
    segment = np.repeat(events.block_segment, per_block)[twin_event]
    on = np.repeat(events.block_tool, per_block)[twin_event].astype(bool) & (host.segments.dwell[segment] <= 0)
    steady = on & ~host.segments.dynamic[segment] & (np.asarray(factor) >= 0) & ((records & DYNAMIC_FLAG) == 0)
    want = np.round(np.clip(host.segments.power[segment], 0.0, 1.0) * laser.top).astype(np.int64)
    wrong = np.flatnonzero(steady & (np.abs(played - want) > 1))
    if not len(wrong):
        return []
    k = int(wrong[0])
    return [f"laser: at simulated event {k} the power is {played[k]} PWM counts where the program's S gives "
            f"{want[k]} of {laser.top} ({len(wrong)} events of M3 cuts differ)"]


def merge_laser(parts: list[LaserVerdict], duty: np.ndarray, top: np.ndarray, planned_top: int) -> LaserVerdict | None:
    """The run's laser figures from its stretches' (their first problems), the PWM's period as planned (`top`:
    every write of its TOP register; the power checks count in the plan's TOP, so a wrong period scales every
    power), and the laser off at the end (`duty`: every write of the compare register, cycle and counts)."""
    if not parts:
        return None
    problems = list(dict.fromkeys(p for part in parts for p in part.problems[:1]))
    wrong = top[top[:, 1] != planned_top]
    if len(top) == 0 or len(wrong):
        counts = int(wrong[0, 1]) if len(wrong) else None
        problems.insert(0, f"laser: the PWM's TOP is {counts if counts is not None else 'never set'}"
                           f"{' counts' if counts is not None else ''}, where the plan's period takes {planned_top}: "
                           f"every power would be off by that ratio")
    if len(duty) and duty[-1, 1] != 0:
        problems.append(f"laser: the PWM still holds {duty[-1, 1]} counts when the program ends")
    return LaserVerdict(parts[0].pwm_hz, max(p.max_power_error for p in parts), sum(p.cuts for p in parts),
                        max(p.max_energy_error for p in parts), problems)


def _energy(host, twin_event: np.ndarray, seconds: np.ndarray, played: np.ndarray, ideal: np.ndarray,
            planned_s: np.ndarray, before: OpenCut | None, ends_run: bool) -> tuple[int, float, OpenCut | None]:
    """Cuts (stretches of tool-on events; one going on from before not counted again), the largest relative
    difference of a cut's energy per mm, simulated (the played power over the simulated times) against planned
    (the ideal power over the plan's times), and the cut left on at the stretch's end (judged where it ends, or
    here at the run's end): the path is the same, so the energies' ratio is that of their energy per mm."""
    on = host.schedule.block_tool[host.pulses.event_block[twin_event]].astype(bool)
    if not len(on):
        return 0, 0.0, before
    going_on = before is not None and bool(on[0])
    if going_on:  # the interval from the cut's last event before to this stretch's first is the cut's too
        on = np.concatenate([[True], on])
        seconds, played = np.concatenate([[before.seconds], seconds]), np.concatenate([[before.played], played])
        ideal, planned_s = np.concatenate([[before.ideal], ideal]), np.concatenate([[before.planned_s], planned_s])
    if not on.any():
        return 0, 0.0, None
    cut = np.cumsum(np.diff(np.concatenate([[0], on.astype(np.int8)])) == 1) - 1
    inside = on[:-1] & on[1:] & (cut[:-1] == cut[1:])  # the time from one event to the next within a cut
    n = int(cut[-1]) + 1
    sim = np.bincount(cut[:-1][inside], weights=(played[:-1] * np.diff(seconds))[inside], minlength=n)
    plan = np.bincount(cut[:-1][inside], weights=(ideal[:-1] * np.diff(planned_s))[inside], minlength=n)
    if going_on:
        sim[0], plan[0] = sim[0] + before.sim, plan[0] + before.plan
    left_on = None
    if on[-1] and not ends_run:
        left_on = OpenCut(float(sim[-1]), float(plan[-1]), float(played[-1]), float(ideal[-1]), float(seconds[-1]),
                          float(planned_s[-1]))
        sim, plan = sim[:-1], plan[:-1]
    lit = plan > 0
    return n - int(going_on), float(np.max(np.abs(sim[lit] - plan[lit]) / plan[lit], initial=0.0)), left_on

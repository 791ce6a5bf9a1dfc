"""The feed hold's and the override's own limits, checked against the job's settings (`verify --hold/--override`,
codegen/verify/hold.py). The dilated twin that the simulated pulses are compared with is made from the same ramp and
ceilings as the tables, so a ramp or a ceiling that breaks its rule agrees with it; the rules are stated here, apart
from the code that builds the ramp and the ceilings (codegen/tables/hold.py, codegen/tables/headroom.py):

- The ramp (hold, resume, override): the feed factor f (1 = 100 %) changes by at most RAMP_ACCEL_SHARE x
  max_accel / max_velocity per second of the job's stepper with the least of that, so that no motor's extra
  acceleration v x df/dt, at its top speed, takes more than that share of its acceleration. Measured on the run's
  dilation: the factor every event's interrupt leaves against the time of the event after it, over every pair of
  events between two rests (a resume starts again from rest), within RAMP_ROUNDING.
- The ceilings (override above 100 %): a steady factor at its ceiling takes no motor past CEILING_RATE_SHARE of its
  rate (max_velocity x steps_per_mm): over every 8 consecutive steps of the (undilated) twin, their rate x the
  highest ceiling in force at their events. Stretches whose ceiling is 100 % are the plan's (the checks' rate).
"""

from __future__ import annotations

import numpy as np

from codegen.motion.planner import RATE_WINDOW
from codegen.pipeline.host import HostBuild
from codegen.tables.hold import F_ONE, PARKED, Dilation, run_ceilings
from codegen.tables.twin import Pulses

RAMP_ACCEL_SHARE = 0.2  # of each motor's acceleration, at its top speed, that the factor's ramp may take
CEILING_RATE_SHARE = 1.0  # of each motor's rate that a steady factor at its ceiling may take
RAMP_ROUNDING = 1.0  # F: the dilation reports the factor's whole part (the player keeps F.frac16)


def ramp_limit(host: HostBuild) -> tuple[float, str]:
    """The fastest the factor may change (1 = 100 %, per second) and the stepper whose limits set it."""
    steppers = host.job.machine.steppers
    name = min(steppers, key=lambda n: steppers[n].max_accel / steppers[n].max_velocity)
    return RAMP_ACCEL_SHARE * steppers[name].max_accel / steppers[name].max_velocity, name


class RampWatch:
    """The most the factor moved beyond `per_tick` (F per tick) between two events of one stretch between rests, over
    a held run's dilation fed a window at a time (`add`): (|F_j - F_i| - per_tick x (t_j - t_i), i, j) in `excess`,
    F_i the factor event i's interrupt left and t_i the tick of the event after it ((0, 0, 0) where nothing moved),
    and (F_i, F_j, t_i, t_j) there in `at`."""

    def __init__(self, per_tick: float):
        self.per_tick = per_tick
        self.excess, self.at = (0.0, 0, 0), (0, 0, 0, 0)
        self.lowest: list[tuple[float, int, int, int]] | None = None  # rise's and fall's, in the stretch going on
        self.highest_factor = 0  # the highest factor played

    def add(self, window: Dilation, first: int) -> None:
        """Events first.. of the dilation, with the one after the last unless the run ends there (the windows
        overlap by that one)."""
        factor, tick = window.factor[:-1], window.tick[1:]
        played = (factor != PARKED) & (tick >= 0)
        self.highest_factor = max(self.highest_factor, int(window.factor[window.factor >= 0].max(initial=0)))
        cuts = np.flatnonzero(~played)
        for a, b in zip(np.concatenate([[0], cuts + 1]), np.concatenate([cuts, [len(factor)]])):
            if a > 0:
                self.lowest = None  # a rest: the stretch ends
            if b > a:
                self._stretch(factor[a:b].astype(np.float64), tick[a:b].astype(np.float64), first + a)

    def _stretch(self, f: np.ndarray, t: np.ndarray, first: int) -> None:
        carried = self.lowest or [None, None]
        lowest = []
        for side, gain in enumerate((f - self.per_tick * t, -(f + self.per_tick * t))):  # a rise, then a fall
            event = first + np.arange(len(gain))
            fs, ts = f, t
            if carried[side] is not None:  # the lowest before, in the stretch going on
                g0, e0, f0, t0 = carried[side]
                gain, event = np.concatenate([[g0], gain]), np.concatenate([[e0], event])
                fs, ts = np.concatenate([[f0], f]), np.concatenate([[t0], t])
            low = np.minimum.accumulate(gain)  # how far each event got from the lowest before it
            j = int(np.argmax(gain - low))
            excess = float(gain[j] - low[j])
            if excess > self.excess[0]:
                i = int(np.argmin(gain[:j + 1]))
                self.excess = (excess, int(event[i]), int(event[j]))
                self.at = (int(fs[i]), int(fs[j]), int(ts[i]), int(ts[j]))
            m = int(np.argmin(gain))
            lowest.append((float(gain[m]), int(event[m]), float(fs[m]), float(ts[m])))
        self.lowest = lowest


def ramp_excess(dilation: Dilation, per_tick: float) -> tuple[float, int, int]:
    """RampWatch's excess over a whole dilation."""
    watch = RampWatch(per_tick)
    watch.add(dilation, 0)
    return watch.excess


def ramp_watch(host: HostBuild) -> RampWatch:
    """A RampWatch at the ramp's limit (ramp_limit)."""
    return RampWatch(ramp_limit(host)[0] * F_ONE / host.target.tick_hz)


def ramp_problems(host: HostBuild, ramp: Dilation | RampWatch) -> list[str]:
    """The run's factor changed faster than the ramp's rule lets it (`ramp`: the run's dilation, or a RampWatch
    that has seen it a window at a time)."""
    if isinstance(ramp, Dilation):
        dilation, ramp = ramp, ramp_watch(host)
        ramp.add(dilation, 0)
    limit, name = ramp_limit(host)
    (excess, i, j), (f_i, f_j, t_i, t_j) = ramp.excess, ramp.at
    if excess <= RAMP_ROUNDING:
        return []
    seconds = (t_j - t_i) / host.target.tick_hz
    return [f"the feed factor ramps from {100 * f_i / F_ONE:.1f} % to {100 * f_j / F_ONE:.1f} % in "
            f"{1e3 * seconds:.1f} ms (after events {i} to {j}): faster than the hold's ramp may, "
            f"{100 * limit:.1f} % per second ({100 * RAMP_ACCEL_SHARE:.0f} % of stepper {name}'s acceleration at its "
            f"top speed)"]


def ceiling_shares(host: HostBuild) -> dict[str, tuple[float, int, int, int]]:
    """Per motor, where a steady factor at the ceilings would run it fastest against its rate, over stretches whose
    ceiling is above 100 %: (share of its rate, ceiling F, first and last event of its 8 steps). Empty where the
    tables have no ceiling above 100 %. (A kept host build's twin as one chapter of CeilingShares.)"""
    shares = CeilingShares(host)
    if shares.active:
        shares.add(host.pulses)
    return shares.shares()


class CeilingShares:
    """ceiling_shares over the twin a chapter at a time (codegen/verify/chapters.py): `add` each chapter's pulses,
    then `shares`. Each motor's last RATE_WINDOW steps go on to the next chapter: the windows that begin there."""

    def __init__(self, host: HostBuild):
        count = host.schedule.run_count
        stepping = count > 0  # a ceiling is in force at an event through its run: the runs that have events
        self.ceiling = run_ceilings(host.schedule)[stepping]
        self.run_end = np.cumsum(count[stepping])  # one past each such run's last event
        self.active = bool(len(self.ceiling)) and int(self.ceiling.max()) > F_ONE
        steppers, self.names, self.tick_hz = host.job.machine.steppers, host.kin.motors, host.target.tick_hz
        self.rate = [steppers[name].max_velocity * steppers[name].steps_per_mm for name in self.names]
        empty = np.zeros(0, dtype=np.int64)
        self.carried = [(empty, empty)] * len(self.names)  # each motor's last steps: ticks, events
        self.best: dict[str, tuple[float, int, int, int]] = {}

    def add(self, pulses: Pulses, first_event: int = 0) -> None:
        """A chapter's twin pulses (their events counted from `first_event`, the program's index of its first)."""
        if not self.active:
            return
        ceiling = self.ceiling
        for m, name in enumerate(self.names):
            mine = pulses.motor == m
            tick = np.concatenate([self.carried[m][0], pulses.tick[mine]])
            event = np.concatenate([self.carried[m][1], pulses.event[mine] + first_event])
            self.carried[m] = (tick[-RATE_WINDOW:], event[-RATE_WINDOW:])
            if len(tick) <= RATE_WINDOW:
                continue
            run = np.searchsorted(self.run_end, event, side="right")  # each step's event's run: no array per event
            between = np.maximum(np.maximum.reduceat(ceiling, run)[:-1], ceiling[run[1:]])  # steps k to k + 1
            highest = between[:len(between) - RATE_WINDOW + 1].copy()  # over the 8 steps from k
            for k in range(1, RATE_WINDOW):
                np.maximum(highest, between[k:k + len(highest)], out=highest)
            rate = RATE_WINDOW * self.tick_hz / np.maximum(tick[RATE_WINDOW:] - tick[:-RATE_WINDOW], 1)
            share = np.where(highest > F_ONE, rate * highest / F_ONE, 0.0) / self.rate[m]
            k = int(np.argmax(share))
            if name not in self.best or share[k] > self.best[name][0]:  # the first of the highest, as over the whole
                self.best[name] = (float(share[k]), int(highest[k]), int(event[k]), int(event[k + RATE_WINDOW]))

    def shares(self) -> dict[str, tuple[float, int, int, int]]:
        """ceiling_shares's answer over the chapters added, motors in their order."""
        return {name: self.best[name] for name in self.names if name in self.best}


def ceiling_problems(shares: dict[str, tuple[float, int, int, int]]) -> list[str]:
    """The ceilings that would take a motor past its rate (ceiling_shares)."""
    return [f"motor {name}: the override's ceiling of {100 * ceiling / F_ONE:.1f} % in force at events {first} to "
            f"{last} would take it to {100 * share:.1f} % of its rate over 8 steps (max_velocity x steps_per_mm)"
            for name, (share, ceiling, first, last) in shares.items() if share > CEILING_RATE_SHARE]

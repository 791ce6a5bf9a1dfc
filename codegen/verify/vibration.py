"""The toolhead's residual vibration after every acceleration change and corner, shaped and unshaped, measured
chapter by chapter (codegen/verify/chapters.py) on the model of codegen/verify/resonance.py.

Per resonating axis, two runs of the same job drive a toolhead each: the simulated pulses (shaped where the job
shapes), and the plan before shaping played as steps at their ideal times (codegen/motion/stepgen.py: the unshaped
run, made on the host). Every change of the axis's planned acceleration or velocity (an acceleration's start or
end, a corner) begins a place; the vibration is measured where the command has settled again: from the change
until the next one unshaped, and from the shaper's last impulse of the change to the next change's first
shaped (places too short for the shaper are measured in neither run: the runs compare at the same places). There
the commanded acceleration is constant, so the ringing is free and decays as exp(-zeta w t): its amplitude at the
place's start (the residual the change left, turned back from the samples of its first damped period) and its RMS
over the first RMS_PERIODS periods. By linearity a shaped place's residual is the unshaped one's times the
shaper's remaining vibration at the resonance (codegen/motion/shapers.py remaining_vibration), up to the steps'
own ringing. Where the program changes its shapers (M593), each place is measured with its change's era's, and
the figures come per era too (codegen/verify/vibration_eras.py).

Samples are taken SAMPLES_PER_PERIOD a period; those later than the pulses a chapter has wait for the next one,
so memory holds a chapter and a few periods. The place a chapter ends in stays open until the next chapter's
first change (its samples after that are dropped then), so a place is the same however the chapters cut the run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.blocks import bresenham
from codegen.motion.planner import Plan
from codegen.motion.shaped_motion import Motion, ShapingSettings, planned_motion
from codegen.motion.stepgen import generate, segment_steps
from codegen.toolpath.segments import Segments
from codegen.verify.resonance import AxisResonance, Oscillator, job_resonances
from codegen.verify.vibration_eras import UM, Carry, EraShaping, Tally, era_figures, shaper_names

SAMPLES_PER_PERIOD = 8
RMS_PERIODS = 8  # a place's RMS: over this many damped periods from its start (or the place, if shorter)
SAME = 1e-9  # relative: a piece continues its neighbour's acceleration and velocity this closely
LATE_PULSE_S = 1e-3  # a simulated pulse comes at most this long after the twin's time (the next chapter's too)


@dataclass
class Samples:
    """Moments to measure a run's ringing at: the command there, the place each belongs to, and whether it is
    in the place's first damped period (its amplitude)."""

    t: np.ndarray
    u: np.ndarray
    du: np.ndarray
    ddu: np.ndarray
    place: np.ndarray  # int64
    since: np.ndarray  # s from the place's start
    first: np.ndarray  # bool

    @staticmethod
    def empty() -> Samples:
        return Samples(*(np.zeros(0) for _ in range(4)), np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool))

    def take(self, mask: np.ndarray) -> Samples:
        return Samples(*(getattr(self, k)[mask] for k in Samples.__dataclass_fields__))

    @staticmethod
    def join(parts: list[Samples]) -> Samples:
        return Samples(*(np.concatenate([getattr(p, k) for p in parts]) for k in Samples.__dataclass_fields__))


class _Run:
    """One run's toolhead on one axis and its samples still to measure; per place (from `base` on), the sums of
    what was measured: z turned back to the place's start over its first period (`amplitude`, `amplitude_n`
    samples), Re(z)^2 (`squares`, `squares_n`), and with e = exp(p since) the sums Re(z) e, e^2 and |e|^2 that
    take a ringing carried in out of the squares (codegen/verify/vibration_eras.py Carry)."""

    SUMS = {"amplitude": complex, "amplitude_n": float, "squares": float, "squares_n": float, "cross": complex,
            "double": complex, "decay": float}

    def __init__(self, resonance: AxisResonance, level: float):
        self.oscillator = Oscillator(resonance, level)
        self.waiting = Samples.empty()
        self.sums = {name: np.zeros(0, kind) for name, kind in _Run.SUMS.items()}
        self.carry = Carry(self.oscillator.pole)

    def measure(self, times: np.ndarray, steps: np.ndarray, samples: Samples, known: float, base: int,
                places: int) -> None:
        """Play the chapter's changes of the command, then measure the samples up to `known` (s)."""
        self.oscillator.play(times, steps)
        every = Samples.join([self.waiting, samples])
        # a moment before the chapter's last change has every change before it
        now = every.t <= max(known, float(times[-1]) if len(times) else -math.inf)
        self.waiting, s = every.take(~now), every.take(now)
        z = self.oscillator.ringing(s.t, s.u, s.du, s.ddu)
        turn = np.exp(self.oscillator.pole * s.since)
        index = (s.place - base).astype(np.int64)
        values = {"amplitude": z / turn * s.first, "amplitude_n": s.first.astype(float), "squares": z.real**2,
                  "squares_n": np.ones(len(z)), "cross": z.real * turn, "double": turn**2, "decay": np.abs(turn)**2}
        for name, total in self.sums.items():
            grown = np.concatenate([total, np.zeros(places - len(total), total.dtype)])
            value = values[name]
            grown += np.bincount(index, value.real, places)
            if total.dtype == complex:
                grown += 1j * np.bincount(index, value.imag, places)
            self.sums[name] = grown

    def trim(self, place: int, last: float, step: float) -> None:
        """Drop the place's samples still to measure after its sample `last` (`step` s apart): it ended there."""
        self.waiting = self.waiting.take((self.waiting.place != place) | (np.round(self.waiting.since / step) <= last))

    def take(self, count: int) -> dict[str, np.ndarray]:
        """The first `count` places' sums, dropped from here."""
        done = {name: total[:count] for name, total in self.sums.items()}
        self.sums = {name: total[count:] for name, total in self.sums.items()}
        return done


class AxisVibration:
    """One axis's residual vibration, shaped (as played) and unshaped, place by place; per era of the program's
    shapers (codegen/verify/vibration_eras.py) and over the whole run."""

    def __init__(self, resonance: AxisResonance, eras: tuple[EraShaping, ...], unshaped: bool, level: float):
        """`eras`: the axis's shaping in each era; `unshaped`: whether some era is shaped (then the host's
        unshaped run is measured beside the played one)."""
        self.resonance, self.eras = resonance, eras
        self.shift, self.first_delay, self.last_delay, self.smoothing = (
            np.array([getattr(e, k) for e in eras]) for k in ("shift", "first_delay", "last_delay", "smoothing"))
        self.played = _Run(resonance, level)
        self.unshaped = _Run(resonance, level) if unshaped else None
        self.base = self.places = 0  # places measured and dropped; places made
        self.meta: dict[str, list] = {key: [] for key in ("time", "line", "length", "era", "begin", "straddle",
                                                          "kept")}
        self.open: int | None = None  # the place the last chapter ended in, until the next change
        self.tail: tuple[float, float] | None = None  # the axis's planned acceleration and velocity there
        self.whole = Tally()
        self.tallies = [Tally() for _ in eras]
        self.worst: dict | None = None

    @property
    def period(self) -> float:
        return self.played.oscillator.period

    def add(self, pieces: Motion, line: np.ndarray, era: np.ndarray, played: tuple[np.ndarray, np.ndarray],
            unshaped: tuple[np.ndarray, np.ndarray] | None, last: bool) -> None:
        """A chapter: its planned motion in `pieces` (each piece's G-code line in `line`, its shapers' era in
        `era`), the changes of this axis's commanded position as played and (a shaped job's) unshaped: times and
        steps (mm). Its last place stays open (it ends with the next chapter's first change), unless `last`."""
        axis = self.resonance.axis
        first = self._changes(pieces)
        begin, eras = pieces.breaks[first], era[first]
        end = np.append(begin[1:], pieces.breaks[-1] if last else math.inf)[:len(begin)]
        ends = np.append(eras[1:], era[-1])[:len(begin)]
        stop = np.full(len(begin), math.inf)  # the plan's time from which the command rests at its end
        if last:  # the program's end: the tool rests, and rings on
            begin, end, stop = (np.append(a, b) for a, b in ((begin, pieces.breaks[-1]), (end, math.inf),
                                                              (stop, pieces.breaks[-1])))
            first, eras, ends = np.append(first, len(pieces) - 1), np.append(eras, era[-1]), np.append(ends, era[-1])
        if len(begin):
            self._close(float(begin[0]), int(eras[0]))
        # A place's shaped stretch begins after its own change's last impulse, ends at the next change's first.
        shaped_begin = begin + self.shift[eras] + self.last_delay[eras]
        shaped_end = end + self.shift[ends] + self.first_delay[ends]
        keep = shaped_end >= shaped_begin
        begin, end, stop, first, eras, ends, shaped_begin, shaped_end = (
            a[keep] for a in (begin, end, stop, first, eras, ends, shaped_begin, shaped_end))
        ids = self.places + np.arange(len(begin))
        self.places += len(begin)
        if not last and len(begin) and end[-1] == math.inf:
            self.open = int(ids[-1])
        self.meta["time"] += shaped_begin.tolist()
        self.meta["line"] += line[first].tolist()
        self.meta["length"] += np.minimum(end - begin, RMS_PERIODS * self.period).tolist()
        self.meta["era"] += eras.tolist()
        self.meta["begin"] += begin.tolist()
        self.meta["straddle"] += (eras != ends).tolist()  # its era's last: the rest at an M593
        self.meta["kept"] += [True] * len(begin)
        a, length = pieces.accel[-1, axis], pieces.breaks[-1] - pieces.breaks[-2]
        self.tail = (float(a), float(pieces.velocity[-1, axis] + a * length))
        known = pieces.breaks[-1] - LATE_PULSE_S if not last else math.inf
        places = (ids, begin, end, first, stop)
        self.played.measure(*played, self._samples(pieces, axis, places, shaped_begin, shaped_end, self.shift[eras],
                                                   self.smoothing[eras]), known, self.base, self.places - self.base)
        if self.unshaped is not None:
            zero = np.zeros(len(begin))
            self.unshaped.measure(*unshaped, self._samples(pieces, axis, places, begin, end, zero, zero), known,
                                  self.base, self.places - self.base)
        self._settle()

    def _changes(self, pieces: Motion) -> np.ndarray:
        """The pieces where the axis's planned acceleration or velocity changes (the first against the chapter
        before's end; the program's first piece always)."""
        axis = self.resonance.axis
        a, v, length = pieces.accel[:, axis], pieces.velocity[:, axis], np.diff(pieces.breaks)
        before_a = np.concatenate([[self.tail[0] if self.tail else 0.0], a[:-1]])
        before_v = np.concatenate([[self.tail[1] if self.tail else 0.0], v[:-1] + a[:-1] * length[:-1]])
        scale = SAME * (1.0 + np.abs(a) + np.abs(v))
        changes = (np.abs(a - before_a) > scale) | (np.abs(before_v - v) > scale)
        changes[0] |= self.tail is None
        return np.flatnonzero(changes)

    def _close(self, end: float, era: int) -> None:
        """The open place ends at `end` (the plan's s), where a change of `era` begins: its samples after are
        dropped, and the place itself where it is too short for the shapers."""
        if self.open is None:
            return
        k = self.open - self.base
        shaped_end = end + self.shift[era] + self.first_delay[era]
        self.meta["kept"][k] = shaped_end >= self.meta["time"][k]
        self.meta["straddle"][k] = self.meta["era"][k] != era
        self.meta["length"][k] = min(end - self.meta["begin"][k], RMS_PERIODS * self.period)
        step = self.period / SAMPLES_PER_PERIOD  # as _samples counts them
        self.played.trim(self.open, np.floor((shaped_end - self.meta["time"][k]) / step), step)
        if self.unshaped is not None:
            self.unshaped.trim(self.open, np.floor((end - self.meta["begin"][k]) / step), step)
        self.open = None

    def _samples(self, pieces: Motion, axis: int, places: tuple, begin: np.ndarray, end: np.ndarray,
                 shift: np.ndarray, offset: np.ndarray) -> Samples:
        """Each place's samples from `begin` to `end` (the run's clock, `shift` after the plan's): the command
        there (the shaped one `offset` per mm/s^2 off the plan's). `places`: their ids, their plan's stretches,
        first pieces (whose quadratic holds over the place, an open one's beyond the chapter too) and where the
        command comes to rest at the plan's end."""
        ids, plan_begin, plan_end, first, stop = places
        step = self.period / SAMPLES_PER_PERIOD
        count = np.minimum(np.floor((end - begin) / step), RMS_PERIODS * SAMPLES_PER_PERIOD).astype(np.int64) + 1
        k = np.repeat(np.arange(len(ids)), count)
        since = (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)) * step
        t = begin[k] + since
        # a place across an M593 (the next era's clock runs less behind) rests until the next era's motion
        plan_t = np.clip(t - shift[k], plan_begin[k], plan_end[k])
        piece = first[k]
        moving = plan_t < stop[k]
        dt = plan_t - pieces.breaks[piece]
        a = np.where(moving, pieces.accel[piece, axis], 0.0)
        du = np.where(moving, pieces.velocity[piece, axis] + a * dt, 0.0)
        u = np.where(moving, pieces.position[piece, axis] + pieces.velocity[piece, axis] * dt + 0.5 * a * dt * dt,
                     pieces.end[axis]) + offset[k] * a
        return Samples(t, u, du, a, ids[k], since, since < self.period)

    def _settle(self) -> None:
        """Fold the places no sample waits for any more into the figures, and drop them: the whole run's as the
        toolhead rings, each era's less what the era before left ringing (Carry)."""
        waiting = [r.waiting.place for r in (self.played, self.unshaped) if r is not None and len(r.waiting.t)]
        done = int(min([w.min() for w in waiting] + [self.places if self.open is None else self.open])) - self.base
        if done <= 0:
            return
        runs = [self.played] if self.unshaped is None else [self.played, self.unshaped]
        kept = np.array(self.meta["kept"][:done])
        sums = [{name: total[kept] for name, total in r.take(done).items()} for r in runs]
        amplitude = [s["amplitude"] / np.maximum(s["amplitude_n"], 1) for s in sums]
        meta = {key: np.array(values[:done])[kept] for key, values in self.meta.items()}
        starts = [meta["time"], meta["begin"]]
        own = [r.carry.own(a, starts[k], meta["straddle"], s) for k, (r, a, s) in enumerate(zip(runs, amplitude, sums))]
        squares = np.array([sums[0]["squares"], sums[-1]["squares"]])
        squares_n = np.array([sums[0]["squares_n"], sums[-1]["squares_n"]])
        shaped, unshaped = np.abs(amplitude[0]), np.abs(amplitude[-1])
        era, lines = meta["era"], meta["line"]
        self.whole.add(shaped, unshaped, squares, squares_n, lines)
        own_squares = np.array([own[0][1], own[-1][1]])
        for e in np.unique(era):
            mine = era == e
            self.tallies[e].add(np.abs(own[0][0][mine]), np.abs(own[-1][0][mine]), own_squares[:, mine],
                                squares_n[:, mine], lines[mine])
        worst = int(np.argmax(shaped)) if len(shaped) else -1
        if worst >= 0 and (self.worst is None or shaped[worst] >= self.whole.peak):
            e = self.eras[era[worst]]
            self.worst = {"time_s": float(meta["time"][worst]), "line": int(lines[worst]),
                          "residual_um": float(shaped[worst]) * UM, "unshaped_um": float(unshaped[worst]) * UM,
                          "residual_phase_rad": float(np.angle(amplitude[0][worst])),
                          "unshaped_phase_rad": float(np.angle(amplitude[-1][worst])),
                          "residual_delay_s": e.last_delay - e.first_delay,
                          "length_s": float(meta["length"][worst]), "era": int(era[worst]),
                          "shaper": None if e.shaper is None else e.shaper.name}
        for values in self.meta.values():
            del values[:done]
        self.base += done

    def figures(self) -> dict:
        """verify --json's `vibration.<axis>`: the whole run's figures, and with M593s each era's (`eras`)."""
        r = self.resonance
        eras = [era_figures(k, e, t, r) for k, (e, t) in enumerate(zip(self.eras, self.tallies))]
        theory = eras[0]["theory_ratio"] if len(eras) == 1 and self.eras[0].shaper is not None else None
        return {"freq_hz": r.freq, "damping": r.damping, "shaper": shaper_names(self.eras),
                **self.whole.figures(), "theory_ratio": theory, "worst": self.worst,
                **({"eras": eras} if len(eras) > 1 else {})}


class VibrationCheck:
    """Every resonating axis's residual vibration over a run, a chapter at a time: `add` each chapter with its
    simulated pulses (or the twin's), then `figures`."""

    def __init__(self, kin: Kinematics, resonances: tuple[AxisResonance, ...],
                 shapings: tuple[ShapingSettings | None, ...], specs: tuple, start_steps: np.ndarray, max_gap: float):
        """`shapings`: each era's shapers (codegen/pipeline/host.py HostBuild.shapings), `specs` what set them."""
        self.kin, self.max_gap = kin, max_gap
        self.played_steps = np.asarray(start_steps, dtype=np.int64).copy()  # the motors after the last pulse
        level = self._axes(self.played_steps[None, :])[0]
        self.played_axes, self.unshaped_axes = level.copy(), level.copy()
        self.unshaped = any(s is not None for s in shapings)
        self.axes = [AxisVibration(r, tuple(EraShaping.of(s, p, r.axis) for s, p in zip(shapings, specs)),
                                   self.unshaped, level[r.axis]) for r in resonances]

    @staticmethod
    def of(host, resonances: tuple[AxisResonance, ...]) -> VibrationCheck:
        """The check of a host build's run (codegen/pipeline/host.py HostBuild)."""
        return VibrationCheck(host.kin, resonances, host.shapings, host.shaper_specs, host.start_steps,
                              host.target.max_gap_s)

    def _axes(self, steps: np.ndarray) -> np.ndarray:
        return self.kin.to_axes(steps / self.kin.limits.steps_per_mm, np.zeros((len(steps), 4)))

    def add(self, chapter, times: np.ndarray, motor: np.ndarray, direction: np.ndarray) -> None:
        """`chapter` (codegen/verify/chapters.py) and its pulses: times (s, the twin's clock), motors, directions."""
        segments, plan = chapter.planned or (chapter.segments, chapter.plan)
        if not len(plan.duration):
            return
        pieces = planned_motion(segments, plan)
        line, era = segments.line[pieces.origin], segments.shaping[pieces.origin]
        moved = np.zeros((len(times), len(self.kin.motors)), dtype=np.int64)
        moved[np.arange(len(times)), motor] = direction
        played = self._changes(times, np.cumsum(moved, axis=0) + self.played_steps, "played_axes")
        if len(times):
            self.played_steps = self.played_steps + moved.sum(axis=0)
        unshaped = self._unshaped(segments, plan) if self.unshaped else None
        for vibration in self.axes:
            a = vibration.resonance.axis
            vibration.add(pieces, line, era, (played[0][a], played[1][a]),
                          None if unshaped is None else (unshaped[0][a], unshaped[1][a]), chapter.last)

    def _unshaped(self, segments: Segments, plan: Plan):
        """The plan before shaping as steps at their ideal times (Bresenham's, as the blocks make them)."""
        events = generate(segments, plan, self.kin, segment_steps(segments, self.kin), self.max_gap)
        _, _, position = bresenham(events.block_steps, events.block_modulus, events.block_init,
                                   np.diff(events.block_first))
        return self._changes(events.time, position + self.kin.to_steps(segments.start[:1]), "unshaped_axes")

    def _changes(self, times: np.ndarray, steps: np.ndarray, carried: str):
        """Per axis, where its position (from the motors' steps, (N, M) absolute, at `times`) changes, and by how
        much (mm); `carried` names the axes' positions before, which this moves on."""
        axes = self._axes(steps)
        before = getattr(self, carried)
        delta = np.diff(np.concatenate([before[None, :], axes]), axis=0)
        if len(axes):
            setattr(self, carried, axes[-1].copy())
        found = [np.flatnonzero(np.abs(delta[:, a]) > 1e-12) for a in range(4)]
        return [times[k] for k in found], [delta[k, a] for a, k in enumerate(found)]

    def figures(self) -> dict:
        return {v.resonance.name: v.figures() for v in self.axes}


def vibration_check(host, resonance: tuple[AxisResonance, ...], held: bool) -> tuple[VibrationCheck | None, list[str]]:
    """The check of a host build's run (codegen/pipeline/host.py HostBuild) for the job's shaped axes and
    `resonance` (verify --resonance: beside or instead of them), or None where none resonates; and why not, for a
    `held` run (its clock dilated by holds and overrides) or a shaped one without a resonance to model."""
    resonances = job_resonances(host.job, resonance)
    if not resonances:
        shaped = any(s is not None and s.shaped for s in host.shapings)
        return None, ["toolhead vibration: no resonance known (the machine has no input_shaper, and no --resonance "
                      "AXIS=HZ[,ZETA] was given): not modelled"] if shaped else []
    if held:
        return None, ["toolhead vibration: a held or overridden run plays on a dilated clock (verify without "
                      "--hold, --override and M0/M1 models it)"]
    return VibrationCheck.of(host, resonances), []

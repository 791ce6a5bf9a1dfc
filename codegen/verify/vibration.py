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
own ringing.

Samples are taken SAMPLES_PER_PERIOD a period; those later than the pulses a chapter has wait for the next one,
so memory holds a chapter and a few periods.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.blocks import bresenham
from codegen.motion.planner import Plan
from codegen.motion.shaped_motion import Motion, ShapingSettings, planned_motion
from codegen.motion.shapers import remaining_vibration
from codegen.motion.stepgen import generate, segment_steps
from codegen.toolpath.segments import Segments
from codegen.verify.resonance import AxisResonance, Oscillator, job_resonances

SAMPLES_PER_PERIOD = 8
RMS_PERIODS = 8  # a place's RMS: over this many damped periods from its start (or the place, if shorter)
SAME = 1e-9  # relative: a piece continues its neighbour's acceleration and velocity this closely
LATE_PULSE_S = 1e-3  # a simulated pulse comes at most this long after the twin's time (the next chapter's too)
UM = 1000.0


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
    """One run's toolhead on one axis and its samples still to measure; per place, the sums of what was measured."""

    def __init__(self, resonance: AxisResonance, level: float):
        self.oscillator = Oscillator(resonance, level)
        self.waiting = Samples.empty()
        self.amplitude = np.zeros(0, complex)  # per place from `base` on: the sum of z turned back to its start
        self.amplitude_n = np.zeros(0)
        self.squares = np.zeros(0)
        self.squares_n = np.zeros(0)

    def measure(self, times: np.ndarray, steps: np.ndarray, samples: Samples, known: float, base: int,
                places: int) -> None:
        """Play the chapter's changes of the command, then measure the samples up to `known` (s)."""
        self.oscillator.play(times, steps)
        grow = places - len(self.amplitude)
        self.amplitude, self.amplitude_n, self.squares, self.squares_n = (
            np.concatenate([a, np.zeros(grow, a.dtype)])
            for a in (self.amplitude, self.amplitude_n, self.squares, self.squares_n))
        every = Samples.join([self.waiting, samples])
        # a moment before the chapter's last change has every change before it
        now = every.t <= max(known, float(times[-1]) if len(times) else -math.inf)
        self.waiting, s = every.take(~now), every.take(now)
        z = self.oscillator.ringing(s.t, s.u, s.du, s.ddu)
        index = (s.place - base).astype(np.int64)
        start = z * np.exp(-self.oscillator.pole * s.since)
        self.amplitude += np.bincount(index, start.real * s.first, places) \
            + 1j * np.bincount(index, start.imag * s.first, places)
        self.amplitude_n += np.bincount(index, s.first.astype(float), places)
        self.squares += np.bincount(index, z.real**2, places)
        self.squares_n += np.bincount(index, None, places)

    def drop(self, count: int) -> None:
        self.amplitude, self.amplitude_n, self.squares, self.squares_n = (
            a[count:] for a in (self.amplitude, self.amplitude_n, self.squares, self.squares_n))


class AxisVibration:
    """One axis's residual vibration, shaped (as played) and unshaped, place by place."""

    def __init__(self, resonance: AxisResonance, shaping: ShapingSettings | None, level: float):
        self.resonance = resonance
        axis = resonance.axis
        self.shaper = None if shaping is None or axis >= len(shaping.shapers) else shaping.shapers[axis]
        amplitudes, delays = (np.ones(1), np.zeros(1)) if shaping is None else shaping.offsets(axis)
        self.shift = 0.0 if shaping is None else shaping.shift
        self.first_delay, self.last_delay = float(delays.min()), float(delays.max())
        self.smoothing = 0.5 * float(amplitudes @ delays**2)  # how far the shaped command lies off at constant a
        self.played = _Run(resonance, level)
        self.unshaped = _Run(resonance, level) if shaping is not None else None
        self.base = self.places = 0  # places measured and dropped; places made
        self.meta: dict[str, list] = {"time": [], "line": [], "length": []}
        self.peak = self.unshaped_peak = 0.0
        self.squares = np.zeros(2)
        self.squares_n = np.zeros(2)
        self.worst: dict | None = None

    @property
    def period(self) -> float:
        return self.played.oscillator.period

    def add(self, pieces: Motion, line: np.ndarray, played: tuple[np.ndarray, np.ndarray],
            unshaped: tuple[np.ndarray, np.ndarray] | None, last: bool) -> None:
        """A chapter: its planned motion in `pieces` (each piece's G-code line in `line`), the changes of this
        axis's commanded position as played and (a shaped job's) unshaped: times and steps (mm)."""
        axis = self.resonance.axis
        begin, end = self._places(pieces)
        if last:  # the program's end: the tool rests, and rings on
            begin, end = np.append(begin, pieces.breaks[-1]), np.append(end, math.inf)
        shaped_begin, shaped_end = begin + self.shift + self.last_delay, end + self.shift + self.first_delay
        keep = shaped_end >= shaped_begin
        begin, end, shaped_begin, shaped_end = begin[keep], end[keep], shaped_begin[keep], shaped_end[keep]
        ids = self.places + np.arange(len(begin))
        self.places += len(begin)
        self.meta["time"] += shaped_begin.tolist()
        self.meta["line"] += line[pieces.piece_of(begin)].tolist()
        self.meta["length"] += np.minimum(end - begin, RMS_PERIODS * self.period).tolist()
        known = pieces.breaks[-1] - LATE_PULSE_S if not last else math.inf
        offset = self.smoothing if self.shaper is not None else 0.0
        self.played.measure(*played, self._samples(pieces, axis, ids, shaped_begin, shaped_end, self.shift, offset),
                            known, self.base, self.places - self.base)
        if self.unshaped is not None:
            self.unshaped.measure(*unshaped, self._samples(pieces, axis, ids, begin, end, 0.0, 0.0), known,
                                  self.base, self.places - self.base)
        self._settle()

    def _places(self, pieces: Motion) -> tuple[np.ndarray, np.ndarray]:
        """Where the axis's planned acceleration or velocity changes (a chapter's first piece too), to the next."""
        axis = self.resonance.axis
        a, v, length = pieces.accel[:, axis], pieces.velocity[:, axis], np.diff(pieces.breaks)
        scale = SAME * (1.0 + np.abs(a[1:]) + np.abs(v[1:]))
        changes = (np.abs(a[1:] - a[:-1]) > scale) | (np.abs(v[:-1] + a[:-1] * length[:-1] - v[1:]) > scale)
        first = np.flatnonzero(np.concatenate([[True], changes]))
        breaks = pieces.breaks[np.append(first, len(pieces))]
        return breaks[:-1], breaks[1:]

    def _samples(self, pieces: Motion, axis: int, ids: np.ndarray, begin: np.ndarray, end: np.ndarray,
                 shift: float, offset: float) -> Samples:
        """Each place's samples from `begin` to `end` (the run's clock, `shift` after the plan's): the command
        there (the shaped one `offset` off the plan's)."""
        step = self.period / SAMPLES_PER_PERIOD
        count = np.minimum(np.floor((end - begin) / step), RMS_PERIODS * SAMPLES_PER_PERIOD).astype(np.int64) + 1
        place = np.repeat(ids, count)
        since = (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)) * step
        t = np.repeat(begin, count) + since
        plan_t = t - shift
        piece = pieces.piece_of(plan_t)
        moving = plan_t < pieces.breaks[-1]  # after the plan's end the tool rests at its end
        dt = plan_t - pieces.breaks[piece]
        a = np.where(moving, pieces.accel[piece, axis], 0.0)
        du = np.where(moving, pieces.velocity[piece, axis] + a * dt, 0.0)
        u = np.where(moving, pieces.position[piece, axis] + pieces.velocity[piece, axis] * dt + 0.5 * a * dt * dt,
                     pieces.end[axis]) + offset * a
        return Samples(t, u, du, a, place, since, since < self.period)

    def _settle(self) -> None:
        """Fold the places no sample waits for any more into the figures, and drop them."""
        waiting = [r.waiting.place for r in (self.played, self.unshaped) if r is not None and len(r.waiting.t)]
        done = int(min((w.min() for w in waiting), default=self.places)) - self.base
        if done <= 0:
            return
        runs = [self.played] if self.unshaped is None else [self.played, self.unshaped]
        amplitude = [r.amplitude[:done] / np.maximum(r.amplitude_n[:done], 1) for r in runs]
        for k, r in enumerate(runs):
            self.squares[k] += r.squares[:done].sum()
            self.squares_n[k] += r.squares_n[:done].sum()
            r.drop(done)
        worst = int(np.argmax(np.abs(amplitude[0])))
        unshaped = amplitude[-1]
        self.unshaped_peak = max(self.unshaped_peak, float(np.abs(unshaped).max()))
        if abs(amplitude[0][worst]) > self.peak or self.worst is None:
            self.peak = max(self.peak, float(abs(amplitude[0][worst])))
            self.worst = {"time_s": self.meta["time"][worst], "line": int(self.meta["line"][worst]),
                          "residual_um": abs(amplitude[0][worst]) * UM, "unshaped_um": abs(unshaped[worst]) * UM,
                          "residual_phase_rad": float(np.angle(amplitude[0][worst])),
                          "unshaped_phase_rad": float(np.angle(unshaped[worst])),
                          "residual_delay_s": self.last_delay - self.first_delay if self.shaper else 0.0,
                          "length_s": self.meta["length"][worst]}
        for values in self.meta.values():
            del values[:done]
        self.base += done

    def figures(self) -> dict:
        """verify --json's `vibration.<axis>`."""
        rms = np.sqrt(self.squares / np.maximum(self.squares_n, 1)) * UM
        r = self.resonance
        theory = None if self.shaper is None else float(remaining_vibration(self.shaper, r.freq, r.damping)[0])
        unshaped_rms = rms[-1] if self.unshaped is not None else rms[0]
        return {"freq_hz": r.freq, "damping": r.damping, "shaper": None if self.shaper is None else self.shaper.name,
                "places": self.base, "residual_peak_um": self.peak * UM, "residual_rms_um": float(rms[0]),
                "unshaped_peak_um": self.unshaped_peak * UM, "unshaped_rms_um": float(unshaped_rms),
                "ratio": self.peak / self.unshaped_peak if self.unshaped_peak > 0 else None,
                "theory_ratio": theory, "worst": self.worst}


class VibrationCheck:
    """Every resonating axis's residual vibration over a run, a chapter at a time: `add` each chapter with its
    simulated pulses (or the twin's), then `figures`."""

    def __init__(self, kin: Kinematics, resonances: tuple[AxisResonance, ...], shaping: ShapingSettings | None,
                 start_steps: np.ndarray, max_gap: float):
        self.kin, self.max_gap = kin, max_gap
        self.played_steps = np.asarray(start_steps, dtype=np.int64).copy()  # the motors after the last pulse
        level = self._axes(self.played_steps[None, :])[0]
        self.played_axes, self.unshaped_axes = level.copy(), level.copy()
        self.axes = [AxisVibration(r, shaping, level[r.axis]) for r in resonances]

    def _axes(self, steps: np.ndarray) -> np.ndarray:
        return self.kin.to_axes(steps / self.kin.limits.steps_per_mm, np.zeros((len(steps), 4)))

    def add(self, chapter, times: np.ndarray, motor: np.ndarray, direction: np.ndarray) -> None:
        """`chapter` (codegen/verify/chapters.py) and its pulses: times (s, the twin's clock), motors, directions."""
        segments, plan = chapter.planned or (chapter.segments, chapter.plan)
        if not len(plan.duration):
            return
        pieces = planned_motion(segments, plan)
        line = segments.line[pieces.origin]
        moved = np.zeros((len(times), len(self.kin.motors)), dtype=np.int64)
        moved[np.arange(len(times)), motor] = direction
        played = self._changes(times, np.cumsum(moved, axis=0) + self.played_steps, "played_axes")
        if len(times):
            self.played_steps = self.played_steps + moved.sum(axis=0)
        unshaped = None if chapter.planned is None else self._unshaped(segments, plan)
        for vibration in self.axes:
            a = vibration.resonance.axis
            vibration.add(pieces, line, (played[0][a], played[1][a]),
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
    `held` run (its clock dilated by holds and overrides) or one with M593s (its shapers change by era)."""
    resonances = job_resonances(host.job, resonance)
    if not resonances or held:
        return None, ["toolhead vibration: a held or overridden run plays on a dilated clock (verify without "
                      "--hold, --override and M0/M1 models it)"] if resonances else []
    if len(host.shapings) > 1:
        return None, ["toolhead vibration: the program changes its input shapers (M593), and the model takes one "
                      "shaper an axis for the whole run (not yet)"]
    return VibrationCheck(host.kin, resonances, host.settings.stages.shaping, host.start_steps,
                          host.target.max_gap_s), []

"""The residual vibration era by era: a program's input shapers change at every M593 (codegen/gcode/shaper_codes.py,
the machine at rest there), the frame's resonance does not. So codegen/verify/vibration.py measures each place
with the shapers of the era its change lies in (their delays decide where its shaped stretch begins), and sums
its figures per era beside the whole run's: the residual peak and RMS, shaped and unshaped, against the era's
shaper's theoretical remaining vibration at the resonance (an unshaped era's is 1: it rings as the unshaped run).
A ringing tower (codegen/calibrate/ringing.py) changes the frequency every band: the era whose ratio is least is
the band whose shaper cancels the resonance best.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from codegen.motion.shaped_motion import ShapingSettings
from codegen.motion.shapers import UNSHAPED, Shaper, remaining_vibration
from codegen.verify.resonance import AxisResonance

UM = 1000.0


@dataclass(frozen=True)
class EraShaping:
    """One axis's shaping in one era: its shaper (None: unshaped) and how the job or the M593 set it (type, Hz,
    damping), the s its shaped clock runs behind the plan's, its impulses' delays from their mean (s), and how
    far its shaped command lies off the plan's per mm/s^2 of constant acceleration."""

    shaper: Shaper | None
    spec: tuple | None
    shift: float
    first_delay: float
    last_delay: float
    smoothing: float

    @staticmethod
    def of(shaping: ShapingSettings | None, specs: tuple, axis: int) -> EraShaping:
        if shaping is None:
            return EraShaping(None, None, 0.0, 0.0, 0.0, 0.0)
        shaper = shaping.shapers[axis] if axis < len(shaping.shapers) else None
        amplitudes, delays = shaping.offsets(axis)
        spec = specs[axis] if shaper is not None and axis < len(specs) else None
        return EraShaping(shaper, spec, shaping.shift, float(delays.min()), float(delays.max()),
                          0.5 * float(amplitudes @ delays**2))

    def describe(self) -> dict:
        """The era's `shaper`, `shaper_freq_hz` and `shaper_damping` (None: unshaped)."""
        kind, freq, damping = self.spec or (None if self.shaper is None else self.shaper.name, None, None)
        return {"shaper": kind, "shaper_freq_hz": freq, "shaper_damping": damping}


class Carry:
    """What a run's toolhead still rings with from the eras before: the ringing at the last M593 (its era's last
    place, a rest, so free ringing), decaying on. By linearity a later place's ringing is its own era's changes'
    plus that, which `own` takes out."""

    def __init__(self, pole: complex):
        self.pole = pole
        self.z, self.t = 0j, 0.0  # the ringing's complex amplitude (mm) at t (s, the run's clock)

    def own(self, amplitude: np.ndarray, start: np.ndarray, straddle: np.ndarray,
            sums: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Places in order: their amplitudes at their `start`, whether each is an era's last (`straddle`), and their
        sums (vibration.py _Run): their amplitudes and sums of squares less the ringing carried into their era."""
        n = len(amplitude)
        last = np.maximum.accumulate(np.where(straddle, np.arange(n), -1))
        before = np.concatenate([[-1], last[:-1]])[:n]  # the last era's end before each place
        z = np.where(before >= 0, amplitude[before], self.z)
        t = np.where(before >= 0, start[before], self.t)
        if n and last[-1] >= 0:
            self.z, self.t = complex(amplitude[last[-1]]), float(start[last[-1]])
        carried = z * np.exp(self.pole * (start - t))  # at each place's start; e = exp(p since) on from there
        squares = sums["squares"] - 2 * (carried * sums["cross"]).real \
            + ((carried**2 * sums["double"]).real + np.abs(carried)**2 * sums["decay"]) / 2
        return amplitude - carried, squares


@dataclass
class Tally:
    """What the places measured so far left: the largest residual amplitude (mm) shaped and unshaped, the sums of
    squares and counts of their samples (shaped, unshaped), and how many places."""

    peak: float = 0.0
    unshaped_peak: float = 0.0
    squares: np.ndarray = field(default_factory=lambda: np.zeros(2))
    squares_n: np.ndarray = field(default_factory=lambda: np.zeros(2))
    places: int = 0
    line: int = 0  # the G-code line of its first place (0: none, or not written in the G-code)

    def add(self, shaped: np.ndarray, unshaped: np.ndarray, squares: np.ndarray, squares_n: np.ndarray,
            lines: np.ndarray) -> None:
        """Places: their amplitudes |z| (mm) shaped and unshaped, their (2, P) sums of squares and counts."""
        if not len(shaped):
            return
        self.peak = max(self.peak, float(shaped.max()))
        self.unshaped_peak = max(self.unshaped_peak, float(unshaped.max()))
        self.squares += squares.sum(axis=1)
        self.squares_n += squares_n.sum(axis=1)
        self.line = self.line if self.places else int(lines[0])
        self.places += len(shaped)

    def figures(self) -> dict:
        rms = np.sqrt(self.squares / np.maximum(self.squares_n, 1)) * UM
        return {"places": self.places, "residual_peak_um": self.peak * UM, "residual_rms_um": float(rms[0]),
                "unshaped_peak_um": self.unshaped_peak * UM, "unshaped_rms_um": float(rms[1]),
                "ratio": self.peak / self.unshaped_peak if self.unshaped_peak > 0 else None}


def era_figures(era: int, shaping: EraShaping, tally: Tally, resonance: AxisResonance) -> dict:
    """verify --json's `vibration.<axis>.eras[era]`: the era's shaper, the G-code line of its first place, its
    figures and its shaper's theory (1 unshaped)."""
    theory = remaining_vibration(shaping.shaper or UNSHAPED, resonance.freq, resonance.damping)[0]
    return {"era": era, **shaping.describe(), "line": tally.line, **tally.figures(), "theory_ratio": float(theory)}


def shaper_names(eras: tuple[EraShaping, ...]) -> str | None:
    """The whole run's `shaper`: the eras' shaper types in their order, "/" between ("none": an unshaped era's);
    None where no era shapes the axis."""
    if all(e.shaper is None for e in eras):
        return None
    names = [e.describe()["shaper"] or "none" for e in eras]
    return "/".join(dict.fromkeys(names))


def least_ringing(eras: list[dict]) -> dict | None:
    """The era whose residual is the smallest share of the unshaped run's (None: no era measured)."""
    measured = [e for e in eras if e["ratio"] is not None]
    return min(measured, key=lambda e: e["ratio"], default=None)

"""Klipper's input shapers as impulse trains, their remaining vibration and smoothing, and shaping a sampled motion.

An input shaper replaces every commanded position x(t) by a weighted sum of delayed copies, sum A_i x(t - T_i):
the impulses are timed so the ringing each copy excites in a damped second-order system (the toolhead on its
frame) cancels the others' at the resonance frequency. Here every shaper is an impulse train with amplitudes
A_i > 0 summing to 1 (so a move still ends where it was commanded) and times T_i from 0, a function of the
resonance frequency (Hz) and damping ratio zeta (Klipper's default 0.1). Our own code from the published formulas:
- ZV and ZVD: Singer & Seering, "Preshaping command inputs to reduce system vibration" (ASME J. Dyn. Sys. 1990):
  K = exp(-zeta pi / sqrt(1 - zeta^2)), impulses half a damped period apart, amplitudes 1, K (ZVD 1, 2K, K^2).
- MZV: Klipper (D. Butyugin, klippy/extras/shaper_defs.py, its default n=3, t=0.75): three impulses over 3/4 of
  a damped period, amplitudes 1 - 1/sqrt(2), (sqrt(2) - 1) K', (1 - 1/sqrt(2)) K'^2 with K' = K^(3/4).
- EI, 2HUMP_EI, 3HUMP_EI: Singhose, Seering & Singer, "Residual vibration reduction using vector diagrams to
  generate shaping inputs" (ASME J. Mech. Design 1994), with the damped curve fits of Singhose's thesis "Command
  generation for flexible systems" (MIT 1997) as Klipper uses them, for a vibration tolerance of 5 % (Klipper's
  1 / SHAPER_VIBRATION_REDUCTION = 1/20). EI and 3HUMP_EI keep 5 % at the design frequency, between zeros either
  side; 2HUMP_EI has a zero there between two humps of 5 %. The fits hold up to the damping Klipper allows.

Shaping is applied as Klipper's klippy/chelper/kin_shaper.c does: the impulses are shifted by their weighted mean
time sum A_i T_i, so x_s(t) = sum A_i x(t - T_i + mean): constant-velocity motion passes unchanged and undelayed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import polynomial

DEFAULT_DAMPING = 0.1
VIBRATION_TOLERANCE = 0.05  # the EI family's designed remaining vibration (Klipper: 1 / SHAPER_VIBRATION_REDUCTION)
# Klipper's calibration reports smoothing for this acceleration (mm/s^2) and square corner velocity (mm/s).
SMOOTHING_ACCEL, SMOOTHING_SCV = 5000.0, 5.0

# Singhose's damped fits for the hump EI shapers at 5 %: per impulse, polynomial coefficients in zeta (constant
# first) of its time (in undamped periods 1 / freq) and of its amplitude (normalised to sum 1 afterwards).
TWO_HUMP_TIMES = ((0.0, 0.0, 0.0, 0.0),
                  (0.49890, 0.16270, -0.54262, 6.16180),
                  (0.99748, 0.18382, -1.58270, 8.17120),
                  (1.49920, -0.09297, -0.28338, 1.85710))
TWO_HUMP_AMPLITUDES = ((0.16054, 0.76699, 2.26560, -1.22750),
                       (0.33911, 0.45081, -2.58080, 1.73650),
                       (0.34089, -0.61533, -0.68765, 0.42261),
                       (0.15997, -0.60246, 1.00280, -0.93145))
THREE_HUMP_TIMES = ((0.0, 0.0, 0.0, 0.0),
                    (0.49974, 0.23834, 0.44559, 12.4720),
                    (0.99849, 0.29808, -2.36460, 23.3990),
                    (1.49870, 0.10306, -2.01390, 17.0320),
                    (1.99960, -0.28231, 0.61536, 5.40450))
THREE_HUMP_AMPLITUDES = ((0.11275, 0.76632, 3.29160, -1.44380),
                         (0.23698, 0.61164, -2.57850, 4.85220),
                         (0.30008, -0.19062, -2.14560, 0.13744),
                         (0.23775, -0.73297, 0.46885, -2.08650),
                         (0.11244, -0.45439, 0.96382, -1.46000))


@dataclass(frozen=True)
class Shaper:
    """An impulse train: amplitudes summing to 1 at increasing times (s) from 0."""

    name: str
    amplitudes: np.ndarray
    times: np.ndarray

    @property
    def mean_time(self) -> float:
        """The impulses' weighted mean time: the delay an unshifted shaper puts on constant-velocity motion."""
        return float(self.amplitudes @ self.times)

    @property
    def duration(self) -> float:
        return float(self.times[-1])


UNSHAPED = Shaper("none", np.ones(1), np.zeros(1))


def _train(name: str, amplitudes, times) -> Shaper:
    amplitudes = np.asarray(amplitudes, dtype=float)
    return Shaper(name, amplitudes / amplitudes.sum(), np.asarray(times, dtype=float))


def _damped(freq: float, damping: float) -> tuple[float, float]:
    """The damped period 1 / (freq sqrt(1 - zeta^2)) and the decay of a half damped period, K."""
    root = math.sqrt(1.0 - damping**2)
    return 1.0 / (freq * root), math.exp(-damping * math.pi / root)


def zv(freq: float, damping: float) -> Shaper:
    period, k = _damped(freq, damping)
    return _train("zv", [1.0, k], [0.0, period / 2])


def zvd(freq: float, damping: float) -> Shaper:
    period, k = _damped(freq, damping)
    return _train("zvd", [1.0, 2 * k, k**2], [0.0, period / 2, period])


def mzv(freq: float, damping: float) -> Shaper:
    period, k = _damped(freq, damping)
    k = k**0.75  # the decay over 3/8 of a damped period
    edge = 1.0 - 1.0 / math.sqrt(2.0)
    return _train("mzv", [edge, (math.sqrt(2.0) - 1.0) * k, edge * k**2], [0.0, 0.375 * period, 0.75 * period])


def ei(freq: float, damping: float) -> Shaper:
    period, _ = _damped(freq, damping)
    v = VIBRATION_TOLERANCE
    first = polynomial.polyval(damping, [0.24968 + 0.24961 * v, 0.80008 + 1.23328 * v, 0.49599 + 3.17316 * v])
    last = polynomial.polyval(damping, [0.25149 + 0.21474 * v, -0.83249 + 1.41498 * v, 0.85181 - 4.90094 * v])
    middle = polynomial.polyval(damping, [0.4999, v * (0.46159 + 8.57843 * v), v * (4.26169 - 108.644 * v),
                                          v * (1.75601 + 336.989 * v)])
    return _train("ei", [first, 1.0 - first - last, last], [0.0, middle * period, period])


def _hump_ei(name: str, freq: float, damping: float, times, amplitudes) -> Shaper:
    return _train(name, polynomial.polyval(damping, np.transpose(amplitudes)),
                  polynomial.polyval(damping, np.transpose(times)) / freq)


def two_hump_ei(freq: float, damping: float) -> Shaper:
    return _hump_ei("2hump_ei", freq, damping, TWO_HUMP_TIMES, TWO_HUMP_AMPLITUDES)


def three_hump_ei(freq: float, damping: float) -> Shaper:
    return _hump_ei("3hump_ei", freq, damping, THREE_HUMP_TIMES, THREE_HUMP_AMPLITUDES)


# Per shaper: its constructor and the largest damping ratio it accepts (Klipper's: where the EI fits still hold).
SHAPERS = {"zv": (zv, 0.99), "mzv": (mzv, 0.99), "zvd": (zvd, 0.99), "ei": (ei, 0.4),
           "2hump_ei": (two_hump_ei, 0.3), "3hump_ei": (three_hump_ei, 0.2)}


def make_shaper(name: str, freq: float, damping: float = DEFAULT_DAMPING) -> Shaper:
    """The named shaper (Klipper's names, any case) for a resonance at freq Hz with damping ratio zeta."""
    key = name.lower()
    if key not in SHAPERS:
        raise ValueError(f"unknown input shaper {name!r}: one of {', '.join(SHAPERS)}")
    build, max_damping = SHAPERS[key]
    if not freq > 0:
        raise ValueError(f"input shaper frequency must be > 0 Hz, not {freq}")
    if not 0 <= damping <= max_damping:
        raise ValueError(f"{key} damping ratio must be in [0, {max_damping}], not {damping}")
    return build(freq, damping)


def remaining_vibration(shaper: Shaper, freqs, damping: float = DEFAULT_DAMPING) -> np.ndarray:
    """The residual vibration amplitude the shaped input leaves in a second-order system at each frequency (Hz)
    with damping ratio zeta, as a fraction of what a single unit impulse leaves (so 1 unshaped):
    V = exp(-zeta w T_n) sqrt(S^2 + C^2), S = sum A_i exp(zeta w T_i) sin(w_d T_i), C likewise with cos.
    This is Klipper's ShaperCalibrate._estimate_shaper; Klipper applies no vibration tolerance here (only when
    it sums a measured spectrum, it ignores what lies below 1/20 of the peak)."""
    omega = 2 * math.pi * np.atleast_1d(np.asarray(freqs, dtype=float))[:, None]
    omega_d = omega * math.sqrt(1.0 - damping**2)
    # Each impulse's ringing, decayed until the last impulse: exp(-zeta w (T_n - T_i)).
    weights = shaper.amplitudes * np.exp(-damping * omega * (shaper.duration - shaper.times))
    sines = (weights * np.sin(omega_d * shaper.times)).sum(axis=1)
    cosines = (weights * np.cos(omega_d * shaper.times)).sum(axis=1)
    return np.hypot(sines, cosines)


def smoothing(shaper: Shaper, accel: float = SMOOTHING_ACCEL, scv: float = SMOOTHING_SCV) -> float:
    """Klipper's smoothing figure (mm, ShaperCalibrate._get_shaper_smoothing): the larger of how far the centred
    shaper pulls the path off a 180-degree reversal at accel and (times sqrt 2) off a 90-degree corner taken at
    the square corner velocity scv while accelerating, counting there only the impulses after the mean time."""
    delays = shaper.times - shaper.mean_time
    reversal = float(shaper.amplitudes @ (accel / 2 * delays**2))
    late = delays >= 0
    corner = math.sqrt(2.0) * float(shaper.amplitudes[late] @ ((scv + accel / 2 * delays[late]) * delays[late]))
    return max(corner, reversal)


def shape_positions(positions, sample_rate: float, shaper: Shaper, centred: bool = True) -> np.ndarray:
    """A 1-D motion sampled at sample_rate (Hz) from t = 0, shaped: x_s(t) = sum A_i x(t - T_i + shift), the
    shift the mean time when centred (Klipper's), else 0. Between samples the motion is linear; before the first
    sample and after the last it holds still, so the motion should start and end at rest for a shaper duration."""
    positions = np.asarray(positions, dtype=float)
    t = np.arange(len(positions)) / sample_rate
    offsets = shaper.times - (shaper.mean_time if centred else 0.0)
    delayed = np.interp(t[None, :] - offsets[:, None], t, positions)
    return shaper.amplitudes @ delayed

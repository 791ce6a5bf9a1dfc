"""The toolhead on a spring: each resonating axis as a damped second-order system driven by the motors' steps.

The toolhead x follows the commanded position u through a spring and a damper (a belt: both act on the stretch
x - u), x'' = w^2 (u - x) + 2 zeta w (u' - x'), so X/U = H(s) = (2 zeta w s + w^2) / (s^2 + 2 zeta w s + w^2):
at constant velocity the toolhead keeps up, at constant acceleration a it lags a / w^2, and every change of
acceleration leaves a ringing at the damped frequency that decays as exp(-zeta w t). Split into its poles,
H(s) = R / (s - p) + conj, so x = 2 Re(y) with y' = p y + R u: one complex first-order state.

The steps make u a staircase, constant between pulses. Over such an interval the solution is exact: the state's
distance from rest at the current level, v = y + R u / p, decays as exp(p t), and a step du adds R du / p to it.
So after the changes k, v(t) = exp(p (t - t0)) (v0 + R / p sum_k du_k exp(-p (t_k - t0))): a cumulative sum
(numpy), in chunks over which exp(zeta w t) grows at most exp(CHUNK_DECAYS), so the sum keeps its precision.

The ringing itself is y less its particular part for the smooth commanded motion (u, u', u'' at that moment):
y_p = -R (u / p + u' / p^2 + u'' / p^3). Its complex amplitude z = 2 (y - y_p) turns as exp(p t): Re z is the
toolhead's vibration about where the command puts it (lag included), |z| its envelope
(codegen/verify/vibration.py measures it after every acceleration change).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from codegen.motion.shapers import DEFAULT_DAMPING

CHUNK_DECAYS = 20.0  # exp(zeta w t) grows at most e^20 over one cumulative sum: ~1e-16 of a step's ringing lost
AXES = ("x", "y", "z")


@dataclass(frozen=True)
class AxisResonance:
    """An axis's resonance: its natural frequency (Hz) and damping ratio."""

    axis: int  # 0 x, 1 y, 2 z
    freq: float
    damping: float = DEFAULT_DAMPING

    @property
    def name(self) -> str:
        return AXES[self.axis]


def resonance_option(text: str) -> AxisResonance:
    """verify's `--resonance AXIS=HZ[,ZETA]`, e.g. x=48,0.1 (argparse's type: ValueError for a bad one)."""
    match = re.fullmatch(r"\s*([xyzXYZ])\s*=\s*([^,]+?)\s*(?:,\s*(.+?)\s*)?", text)
    if match is None:
        raise ValueError(f"{text!r}: expected AXIS=HZ[,ZETA], e.g. x=48,0.1")
    freq = float(match.group(2))
    damping = DEFAULT_DAMPING if match.group(3) is None else float(match.group(3))
    if not freq > 0 or not 0 <= damping < 1:
        raise ValueError(f"{text!r}: the frequency must be > 0 Hz and the damping ratio in [0, 1)")
    return AxisResonance(AXES.index(match.group(1).lower()), freq, damping)


def job_resonances(job, overrides: tuple[AxisResonance, ...] = ()) -> tuple[AxisResonance, ...]:
    """The resonances verify models: each axis the job's input shaper shapes (its frequency and damping), and
    `overrides` (the command line's) in place of those or beside them; in x, y, z order."""
    found: dict[int, AxisResonance] = {}
    shaper = job.machine.input_shaper
    if shaper is not None:
        for name, axis in shaper.axes.items():
            found[AXES.index(name)] = AxisResonance(AXES.index(name), axis.freq, axis.damping)
    found.update({r.axis: r for r in overrides})
    return tuple(found[a] for a in sorted(found))


class Oscillator:
    """One axis's toolhead, played through the changes of its commanded position in time order (`play`), any
    number of times; `ringing` then gives the vibration's complex amplitude at moments after the last play's
    start."""

    def __init__(self, resonance: AxisResonance, level: float):
        omega = 2 * math.pi * resonance.freq
        zeta = resonance.damping
        self.omega_d = omega * math.sqrt(1.0 - zeta**2)
        self.pole = complex(-zeta * omega, self.omega_d)
        self.residue = (2 * zeta * omega * self.pole + omega**2) / (2j * self.omega_d)
        self.time, self.state, self.level = 0.0, 0j, float(level)  # v = y + R u / p at `time`, and u there
        self.played = (np.zeros(0), np.zeros(0, complex), np.zeros(0))  # the last play's changes

    @property
    def decay_rate(self) -> float:
        """1/s: zeta w."""
        return -self.pole.real

    @property
    def period(self) -> float:
        """s: the damped period."""
        return 2 * math.pi / self.omega_d

    def play(self, times: np.ndarray, steps: np.ndarray) -> None:
        """Changes of the commanded position by `steps` (mm) at `times` (s, in order, none before the last play's)."""
        p, gain = self.pole, self.residue / self.pole
        before = (self.time, self.state, self.level)
        state = np.empty(len(times), dtype=complex)
        first, t_ref, v_ref = 0, self.time, self.state
        while first < len(times):
            t0 = float(times[first])
            span = math.inf if self.decay_rate == 0 else CHUNK_DECAYS / self.decay_rate
            last = max(int(np.searchsorted(times, t0 + span, side="right")), first + 1)
            offset = times[first:last] - t0
            total = v_ref * np.exp(p * (t0 - t_ref)) + gain * np.cumsum(steps[first:last] * np.exp(-p * offset))
            state[first:last] = np.exp(p * offset) * total
            first, t_ref, v_ref = last, float(times[last - 1]), complex(state[last - 1])
        levels = self.level + np.cumsum(steps)
        if len(times):
            self.time, self.state, self.level = float(times[-1]), complex(state[-1]), float(levels[-1])
        self.played = (np.concatenate([[before[0]], times]), np.concatenate([[before[1]], state]),
                       np.concatenate([[before[2]], levels]))

    def ringing(self, t: np.ndarray, u: np.ndarray, du: np.ndarray, ddu: np.ndarray) -> np.ndarray:
        """The vibration's complex amplitude z at moments `t` (s, from the last play's start on) where the smooth
        command is at u (mm), u' and u''. Where it rests (u' = u'' = 0) the motors' steps are where it rests."""
        times, state, levels = self.played
        k = np.maximum(np.searchsorted(times, t, side="right") - 1, 0)
        p, r = self.pole, self.residue
        v = state[k] * np.exp(p * (t - times[k]))
        level = levels[k]
        u = np.where((du == 0) & (ddu == 0), level, u)
        return 2 * (v - r / p * (level - u) + r * du / p**2 + r * ddu / p**3)

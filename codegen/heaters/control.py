"""The heaters' integer control laws; the firmware runs exactly these (a test compares the duty sequences).

Units: temperatures `t` (the latest reading, through the ADC table) and targets `s` are int16 deci-degrees
(0.1 degC); `s == 0` means off. Duties are 8-bit PWM, 0..255. Every PID_PERIOD_S the firmware calls the
heater's law once with the newest `t` and the current `s` and writes the duty to the heater's PWM.

PID (`FixedPid`: kp_q, ki_q, kd_q, shift, i_max, max_duty; state: I, D (int32), t_prev, s_in (int16)):
    if s == 0:                              duty = 0;         I = 0; s_in = 0
    elif t < s - PID_FUNCTIONAL_RANGE_DC:   duty = max_duty;  I = 0; s_in = 0
    elif t > s + PID_FUNCTIONAL_RANGE_DC:   duty = 0;         I = 0; s_in = 0
    else:
        if s_in != s: t_prev = t; D = 0; s_in = s         (entering the range or a new target: no derivative kick)
        e = s - t                                          (|e| <= PID_FUNCTIONAL_RANGE_DC)
        P = kp_q * e
        I = clamp(I + ki_q * e, 0, i_max)                  (anti-windup: the integrator alone gives 0..max_duty)
        D += (kd_q * (t_prev - t) - D) >> D_FILTER_SHIFT   (derivative on the measurement, low-passed)
        t_prev = t
        u = P + I + D
        duty = 0 if u <= 0 else min(u >> shift, max_duty)  (u > 0: the shift is a plain logical shift)
All arithmetic in int32; fixed_gains() proves that no product or sum can overflow. No division. `>>` of a
negative number is the arithmetic shift (floor), as avr-gcc does it and Python's `>>`.

The derivative is low-passed (D moves 1/2**D_FILTER_SHIFT of the way to the raw term each period: a time
constant of 1.6 s, like Marlin's K1 = 0.95 smoothing) because the reading moves in ADC steps: near 210 degC one
step of the EPCOS table is 0.5 degC, which Marlin's kd = 114 s would turn into a 570-duty spike for one period.
Unfiltered, both Marlin's default gains and DEFAULT_CONTROL chatter between full power and off in the default
plant, stuck at 200 and 204 degC, and never reach 210 degC (tests/heaters/test_heaters.py shows it).

Bang-bang (`FixedBangBang`: hysteresis_dc, max_duty; state: on (bool)), a watermark controller for a bed:
    if s == 0:                    on = false
    elif t < s - hysteresis_dc:   on = true
    elif t > s + hysteresis_dc:   on = false             (in between: unchanged)
    duty = max_duty if on else 0

The gains are Marlin's (M301 values): kp in duty (0..255) per degC, ki in duty per degC per second, kd in duty
per (degC per second). Per deci-degree and per period they become kp/10, ki*period/10, kd/(period*10), all
scaled by 2**shift.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Union

import numpy as np

PID_PERIOD_S = 0.1
PID_FUNCTIONAL_RANGE_DC = 100  # 10 degC, Marlin's PID_FUNCTIONAL_RANGE
D_FILTER_SHIFT = 4  # the derivative's low-pass: 1/16 of the way each period (1.6 s)
PWM_MAX = 255
INT32_MAX = 2**31 - 1
MAX_SHIFT = 30
MAX_GAIN_ERROR = 0.01  # the relative rounding error allowed for every non-zero gain

# The board's defaults, chosen with plant.simulate() on DEFAULT_PLANTS (figures in tests/heaters/test_heaters.py).
# Hot end: kp >= 25.5 makes P alone give full power at the bottom of the functional range (the heater never
# loiters at its edge, where the integrator is reset); ki and kd were picked on a grid for the least overshoot
# over 27 variants of the plant (half to twice the capacity, 0.7 to 1.4 times the loss, 30 to 60 W).
# Bed: a 0.5 degC watermark switches its MOSFET about every 7 s and holds within +-0.7 degC.
DEFAULT_CONTROL: dict[str, dict] = {
    "hotend": {"pid": {"kp": 35.0, "ki": 2.5, "kd": 80.0}},
    "bed": {"bang_bang": {"hysteresis_c": 0.5}},
}


@dataclass(frozen=True)
class FixedPid:
    kp_q: int
    ki_q: int
    kd_q: int
    shift: int
    i_max: int
    max_duty: int


@dataclass(frozen=True)
class FixedBangBang:
    hysteresis_dc: int
    max_duty: int


Fixed = Union[FixedPid, FixedBangBang]


def max_duty(max_power: float) -> int:
    """The PWM ceiling for a heater allowed max_power (0..1) of its full power."""
    if not 0.0 <= max_power <= 1.0:
        raise ValueError(f"max_power must be within 0..1, not {max_power:g}")
    return round(PWM_MAX * max_power)


def _worst_sum(kp_q: int, ki_q: int, kd_q: int, i_max: int) -> int:
    """The largest magnitude of any int32 intermediate of a PID step (|e| <= range; t, t_prev in s +- range)."""
    r = PID_FUNCTIONAL_RANGE_DC
    d = kd_q * 2 * r  # bounds both the raw derivative term and the filtered D
    return max(i_max + ki_q * r, 2 * d, kp_q * r + i_max + d)


def fixed_gains(kp: float, ki: float, kd: float, period_s: float = PID_PERIOD_S, max_power: float = 1.0) -> FixedPid:
    """Marlin-style gains as the firmware's integers, with the largest shift that keeps everything in int32.

    Raises ValueError when a gain is negative or not finite, too large for int32 even unscaled, or so small
    that it rounds to less than 99 % of itself at the largest possible shift."""
    for name, g in (("kp", kp), ("ki", ki), ("kd", kd)):
        if not (math.isfinite(g) and g >= 0):
            raise ValueError(f"PID gain {name} must be a finite number >= 0, not {g}")
    if not period_s > 0:
        raise ValueError("the PID period must be > 0")
    duty = max_duty(max_power)
    given = {"kp": kp, "ki": ki, "kd": kd}
    per_step = {"kp": kp / 10.0, "ki": ki * period_s / 10.0, "kd": kd / (period_s * 10.0)}
    for shift in range(MAX_SHIFT, -1, -1):
        q = {name: round(g * 2**shift) for name, g in per_step.items()}
        i_max = duty << shift
        if _worst_sum(q["kp"], q["ki"], q["kd"], i_max) <= INT32_MAX:
            break
    else:
        raise ValueError(f"PID gains kp={kp:g} ki={ki:g} kd={kd:g} overflow int32 even unscaled")
    for name, g in per_step.items():
        if g > 0 and abs(q[name] / 2**shift - g) > MAX_GAIN_ERROR * g:
            raise ValueError(f"PID gain {name}={given[name]:g} is too small to represent beside the others "
                             f"(it would be {q[name] / 2**shift:.3g} instead of {g:.3g} per step)")
    return FixedPid(q["kp"], q["ki"], q["kd"], shift, i_max, duty)


def fixed_bang_bang(hysteresis_c: float, max_power: float = 1.0) -> FixedBangBang:
    if not 0.0 <= hysteresis_c <= 50.0:
        raise ValueError(f"bang-bang hysteresis must be within 0..50 degC, not {hysteresis_c:g}")
    return FixedBangBang(round(hysteresis_c * 10), max_duty(max_power))


def fixed_control(control: dict, max_power: float = 1.0, period_s: float = PID_PERIOD_S) -> Fixed:
    """`{pid: {kp, ki, kd}}` or `{bang_bang: {hysteresis_c}}` (the job's form) as firmware integers."""
    if "pid" in control:
        g = control["pid"]
        return fixed_gains(g["kp"], g["ki"], g["kd"], period_s, max_power)
    return fixed_bang_bang(control["bang_bang"]["hysteresis_c"], max_power)


class Pid:
    """The integer PID's state and step (the module docstring is the specification)."""

    def __init__(self, fixed: FixedPid):
        self.fixed = fixed
        self.integral = 0
        self.t_prev = 0
        self.derivative = 0
        self.s_in = 0  # the target the PID entered its range with; 0 while outside

    def step(self, t: int, s: int) -> int:
        f = self.fixed
        if s == 0 or abs(s - t) > PID_FUNCTIONAL_RANGE_DC:
            self.integral, self.s_in = 0, 0
            return f.max_duty if s != 0 and t < s else 0
        if self.s_in != s:
            self.t_prev, self.derivative, self.s_in = t, 0, s
        e = s - t
        self.integral = min(max(self.integral + f.ki_q * e, 0), f.i_max)
        self.derivative += (f.kd_q * (self.t_prev - t) - self.derivative) >> D_FILTER_SHIFT
        u = f.kp_q * e + self.integral + self.derivative
        self.t_prev = t
        return 0 if u <= 0 else min(u >> f.shift, f.max_duty)


class BangBang:
    """The watermark controller's state and step."""

    def __init__(self, fixed: FixedBangBang):
        self.fixed = fixed
        self.on = False

    def step(self, t: int, s: int) -> int:
        h = self.fixed.hysteresis_dc
        if s == 0 or t > s + h:
            self.on = False
        elif t < s - h:
            self.on = True
        return self.fixed.max_duty if self.on else 0


def controller(fixed: Fixed) -> Union[Pid, BangBang]:
    """A fresh controller (state reset) for the fixed-point settings."""
    return Pid(fixed) if isinstance(fixed, FixedPid) else BangBang(fixed)


def _run(law: Union[Pid, BangBang], temps, target) -> np.ndarray:
    temps = np.asarray(temps, dtype=np.int64)
    targets = np.broadcast_to(np.asarray(target, dtype=np.int64), temps.shape)
    return np.array([law.step(int(t), int(s)) for t, s in zip(temps, targets)], dtype=np.int64)


def pid_reference(fixed: FixedPid, temps, target) -> np.ndarray:
    """The duties the firmware's PID gives for readings `temps` (deci-degrees, one per period) and the target(s)."""
    return _run(Pid(fixed), temps, target)


def bang_bang(fixed: FixedBangBang, temps, target) -> np.ndarray:
    """The duties the firmware's bang-bang controller gives for readings `temps` and the target(s)."""
    return _run(BangBang(fixed), temps, target)


def gains_from_relay(high_duty: float, low_duty: float, t_max: float, t_min: float,
                     period_s: float) -> tuple[float, float, float]:
    """Classic Ziegler-Nichols PID gains (kp, ki, kd) from a relay oscillation, as Marlin's M303 computes them.

    The relay switched the heater between high_duty and low_duty (0..255); the temperature swung between t_min
    and t_max (degC) with period period_s. Ultimate gain Ku = 4 d / (pi a), d = (high - low) / 2 and
    a = (t_max - t_min) / 2 (the describing function of a relay); ultimate period Tu = period_s. Then
    Kp = 0.6 Ku, Ki = 2 Kp / Tu, Kd = Kp Tu / 8.
    """
    if not (t_max > t_min and period_s > 0 and high_duty > low_duty):
        raise ValueError("a relay oscillation needs t_max > t_min, high_duty > low_duty and a period > 0")
    ku = 4.0 * ((high_duty - low_duty) / 2.0) / (math.pi * (t_max - t_min) / 2.0)
    kp = 0.6 * ku
    return kp, 2.0 * kp / period_s, kp * period_s / 8.0

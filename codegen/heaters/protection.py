"""Thermal protection: its parameters (Marlin's defaults as the floor) and the state machine the firmware mirrors.

Sources: Marlin 2.0's Marlin/Configuration_adv.h (THERMAL_PROTECTION_PERIOD 40 s, THERMAL_PROTECTION_HYSTERESIS
4 degC, WATCH_TEMP_PERIOD 20 s, WATCH_TEMP_INCREASE 2 degC; THERMAL_PROTECTION_BED_PERIOD 20 s,
THERMAL_PROTECTION_BED_HYSTERESIS 2 degC, WATCH_BED_TEMP_PERIOD 60 s, WATCH_BED_TEMP_INCREASE 2 degC) and
Marlin's temperature.cpp (a watch starts only when the reading is more than WATCH_TEMP_INCREASE +
TEMP_HYSTERESIS (3) + 1 degC below the new target, and restarts after every passed watch while still that far;
runaway watching starts once the target is first reached). Beyond Marlin: while heating towards a target it has
not reached, a reading that falls that far below it starts a watch too (Marlin watches only from the setting, so a
thermistor that falls out just before the target is reached leaves the heater on at full power, unwatched).

The state machine, once per control period, in integer units (deci-degrees; periods of PID_PERIOD_S), with the
reading `adc`, its temperature `t` from the table and the target `s` (0 = off). It runs before the control law;
the first reason it returns turns every heater off, stops the steppers and latches the error state.
    if adc <= adc_short:            "sensor_short"      (always: a short reads hot)
    if t > max_temp_dc:             "max_temp"          (always: also a heater stuck on)
    if s == 0:                      s_prev = 0; watch = 0; holding = false; below = 0; done
    if adc >= adc_open:             "sensor_open"       (only while heating: an unused input may be open)
    if t < min_temp_dc:             "min_temp"          (only while heating)
    if s != s_prev:                 s_prev = s; holding = false; below = 0; start_watch
    elif watch > 0:
        watch -= 1
        if watch == 0:
            if t < watch_goal:      "heating_failed"    (watch_periods after the watch began)
            start_watch
    elif not holding:               start_watch         (fell far below before reaching the target)
    if not holding and t >= s:      holding = true
    if holding:
        below = below + 1 if t < s - runaway_hysteresis_dc else 0
        if below > runaway_periods: "thermal_runaway"   (runaway_periods after the first reading below the band)
where start_watch is: if t < s - watch_margin_dc: watch = watch_periods; watch_goal = t + watch_increase_dc
                      else: watch = 0
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from codegen.heaters.control import PID_PERIOD_S
from codegen.heaters.sensors import SensorLimits

REASONS = ("min_temp", "max_temp", "sensor_open", "sensor_short", "heating_failed", "thermal_runaway")
TEMP_HYSTERESIS_C = 3.0  # Marlin's TEMP_HYSTERESIS, part of the margin below the target a watch needs


@dataclass(frozen=True)
class ProtectionSettings:
    """A heater's watch (while heating) and runaway (while holding) limits, in seconds and degC."""

    watch_period_s: float
    watch_increase_c: float
    runaway_period_s: float
    runaway_hysteresis_c: float


# Marlin's defaults (see the module docstring), the floor for this firmware.
DEFAULT_PROTECTION: dict[str, ProtectionSettings] = {
    "hotend": ProtectionSettings(watch_period_s=20.0, watch_increase_c=2.0, runaway_period_s=40.0,
                                 runaway_hysteresis_c=4.0),
    "bed": ProtectionSettings(watch_period_s=60.0, watch_increase_c=2.0, runaway_period_s=20.0,
                              runaway_hysteresis_c=2.0),
}


@dataclass(frozen=True)
class FixedProtection:
    """The firmware's integers: periods of the control law, deci-degrees, ADC readings."""

    watch_periods: int
    watch_increase_dc: int
    watch_margin_dc: int
    runaway_periods: int
    runaway_hysteresis_dc: int
    min_temp_dc: int
    max_temp_dc: int
    adc_open: int
    adc_short: int


def fixed_protection(settings: ProtectionSettings, min_temp_c: float, max_temp_c: float, limits: SensorLimits,
                     period_s: float = PID_PERIOD_S) -> FixedProtection:
    if not min_temp_c < max_temp_c:
        raise ValueError(f"min_temp_c ({min_temp_c:g}) must be below max_temp_c ({max_temp_c:g})")
    return FixedProtection(
        watch_periods=round(settings.watch_period_s / period_s),
        watch_increase_dc=round(settings.watch_increase_c * 10),
        watch_margin_dc=round((settings.watch_increase_c + TEMP_HYSTERESIS_C + 1.0) * 10),
        runaway_periods=round(settings.runaway_period_s / period_s),
        runaway_hysteresis_dc=round(settings.runaway_hysteresis_c * 10),
        min_temp_dc=round(min_temp_c * 10),
        max_temp_dc=round(max_temp_c * 10),
        adc_open=limits.adc_open,
        adc_short=limits.adc_short,
    )


class Protection:
    """One heater's protection state (the module docstring is the specification)."""

    def __init__(self, fixed: FixedProtection):
        self.fixed = fixed
        self.s_prev = 0
        self.watch = 0
        self.watch_goal = 0
        self.holding = False
        self.below = 0

    def _start_watch(self, t: int, s: int) -> None:
        f = self.fixed
        if t < s - f.watch_margin_dc:
            self.watch, self.watch_goal = f.watch_periods, t + f.watch_increase_dc
        else:
            self.watch = 0

    def step(self, adc: int, t: int, s: int) -> Optional[str]:
        f = self.fixed
        if adc <= f.adc_short:
            return "sensor_short"
        if t > f.max_temp_dc:
            return "max_temp"
        if s == 0:
            self.s_prev, self.watch, self.holding, self.below = 0, 0, False, 0
            return None
        if adc >= f.adc_open:
            return "sensor_open"
        if t < f.min_temp_dc:
            return "min_temp"
        if s != self.s_prev:
            self.s_prev, self.holding, self.below = s, False, 0
            self._start_watch(t, s)
        elif self.watch > 0:
            self.watch -= 1
            if self.watch == 0:
                if t < self.watch_goal:
                    return "heating_failed"
                self._start_watch(t, s)
        elif not self.holding:
            self._start_watch(t, s)
        self.holding = self.holding or t >= s
        if self.holding:
            self.below = self.below + 1 if t < s - f.runaway_hysteresis_dc else 0
            if self.below > f.runaway_periods:
                return "thermal_runaway"
        return None


def first_trip(fixed: FixedProtection, adcs, temps, targets) -> tuple[Optional[str], Optional[int]]:
    """The first reason the protection gives over per-period readings, temperatures (deci-degrees) and targets,
    and the period it gives it at; (None, None) when it never trips."""
    adcs = np.asarray(adcs, dtype=np.int64)
    temps = np.broadcast_to(np.asarray(temps, dtype=np.int64), adcs.shape)
    targets = np.broadcast_to(np.asarray(targets, dtype=np.int64), adcs.shape)
    guard = Protection(fixed)
    for k, (adc, t, s) in enumerate(zip(adcs, temps, targets)):
        reason = guard.step(int(adc), int(t), int(s))
        if reason is not None:
            return reason, k
    return None, None

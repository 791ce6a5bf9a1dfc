"""Thermistors: resistance and temperature, the ADC-to-temperature table in flash, and open/short limits.

The divider on RAMPS-like boards: the thermistor from the ADC pin to ground, a pull-up (4.7 kOhm) from the pin
to AVCC, and AVCC is the ADC reference. The 10-bit ADC reads `floor(1024 * V / AVCC)`, at most 1023, so a
reading `n` stands for the voltage fractions [n/1024, (n+1)/1024); the table takes the middle of that interval.

Every sensor is a Steinhart-Hart curve `1/T = a + b ln R + c (ln R)^3` (T in kelvin, R in ohms); a beta sensor
is the special case c = 0 (`a = 1/T25 - ln(R25)/beta`, `b = 1/beta`).

Temperatures that go to the firmware are int16 deci-degrees (0.1 degC units).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Union

import numpy as np

KELVIN = 273.15
T25_K = 25.0 + KELVIN
INT16_MAX = 32767
INT16_MIN = -32768
OPEN_BELOW_C = -20.0  # a reading colder than this is an open (or missing) thermistor
SHORT_ABOVE_C = 400.0  # a reading hotter than this is a shorted thermistor (no printer heater gets there)


@dataclass(frozen=True)
class Thermistor:
    """An NTC by its Steinhart-Hart coefficients."""

    name: str
    a: float
    b: float
    c: float = 0.0


def beta_thermistor(name: str, beta: float, r25_ohm: float) -> Thermistor:
    """The beta model `R = R25 exp(beta (1/T - 1/T25))` as a Steinhart-Hart curve with c = 0."""
    if not (beta > 0 and r25_ohm > 0):
        raise ValueError(f"{name}: beta and r25_ohm must be > 0")
    return Thermistor(name, 1.0 / T25_K - math.log(r25_ohm) / beta, 1.0 / beta, 0.0)


# EPCOS 100K B57560G104F is Marlin's thermistor type 1. The coefficients are a least-squares Steinhart-Hart fit
# (weighted by each point's ADC quantization) to Marlin's Marlin/src/module/thermistor/thermistor_1.h from 0 to
# 300 degC, its readings taken as 1023 * R / (R + 4.7k). The fit gives R25 = 99.0 kOhm (datasheet: 100 kOhm +-1 %)
# and stays within 1 % plus one ADC step of every point of that table.
THERMISTORS: dict[str, Thermistor] = {
    "EPCOS 100K B57560G104F": Thermistor("EPCOS 100K B57560G104F", 7.24166842e-04, 2.15344098e-04, 1.00327538e-07),
    "Generic 3950": beta_thermistor("Generic 3950", 3950.0, 100_000.0),  # Marlin's type 1000 default, too
}

SensorSpec = Union[Thermistor, str, Mapping]


def thermistor(spec: SensorSpec) -> Thermistor:
    """A preset name, `{beta, r25_ohm}`, `{steinhart_hart: [a, b, c]}` or a Thermistor, as a Thermistor."""
    if isinstance(spec, Thermistor):
        return spec
    if isinstance(spec, str):
        if spec not in THERMISTORS:
            raise ValueError(f"unknown thermistor '{spec}'; presets are {', '.join(THERMISTORS)}")
        return THERMISTORS[spec]
    if "steinhart_hart" in spec:
        a, b, c = (float(v) for v in spec["steinhart_hart"])
        return Thermistor("custom Steinhart-Hart", a, b, c)
    return beta_thermistor("custom beta", float(spec["beta"]), float(spec["r25_ohm"]))


def temperature_c(sensor: SensorSpec, r_ohm) -> np.ndarray:
    """Temperature in degC at resistance r_ohm (vectorized). inf where the curve has no finite temperature."""
    s = thermistor(sensor)
    log_r = np.log(np.asarray(r_ohm, dtype=float))
    inverse = s.a + s.b * log_r + s.c * log_r**3
    with np.errstate(divide="ignore"):
        return np.where(inverse > 0, 1.0 / np.where(inverse > 0, inverse, 1.0) - KELVIN, np.inf)


def resistance_ohm(sensor: SensorSpec, temp_c) -> np.ndarray:
    """Resistance in ohms at temp_c (vectorized): the Steinhart-Hart cubic in ln R solved by Cardano's formula."""
    s = thermistor(sensor)
    inverse_t = 1.0 / (np.asarray(temp_c, dtype=float) + KELVIN)
    if s.c == 0.0:
        return np.exp((inverse_t - s.a) / s.b)
    y = (s.a - inverse_t) / s.c  # c x^3 + b x + (a - 1/T) = 0, x = ln R
    x = np.sqrt((s.b / (3.0 * s.c)) ** 3 + y * y / 4.0)
    return np.exp(np.cbrt(x - y / 2.0) - np.cbrt(x + y / 2.0))


def divider_fraction(sensor: SensorSpec, temp_c, pullup_ohm: float = 4700.0) -> np.ndarray:
    """V / AVCC at the ADC pin (thermistor to ground, pull-up to AVCC)."""
    r = resistance_ohm(sensor, temp_c)
    return r / (r + pullup_ohm)


def millivolts(sensor: SensorSpec, temp_c, pullup_ohm: float = 4700.0, avcc_mv: float = 5000.0) -> np.ndarray:
    """The divider's output in mV at temp_c: what the simulated plant feeds the ADC."""
    return avcc_mv * divider_fraction(sensor, temp_c, pullup_ohm)


def adc_reading(sensor: SensorSpec, temp_c, pullup_ohm: float = 4700.0, adc_max: int = 1023) -> np.ndarray:
    """The ADC's reading at temp_c: floor((adc_max + 1) * V / AVCC), at most adc_max (an ideal converter)."""
    raw = np.floor((adc_max + 1) * divider_fraction(sensor, temp_c, pullup_ohm))
    return np.minimum(raw, adc_max).astype(np.int64)


def adc_temperature_table(sensor: SensorSpec, pullup_ohm: float = 4700.0, adc_max: int = 1023) -> np.ndarray:
    """int16 deci-degrees for every reading 0..adc_max, at the middle of each reading's voltage interval.

    Decreasing in the reading (an NTC): reading 0 (the pin at ground) is the hottest, clamped to INT16_MAX.
    """
    fraction = (np.arange(adc_max + 1) + 0.5) / (adc_max + 1)
    celsius = temperature_c(sensor, pullup_ohm * fraction / (1.0 - fraction))
    deci = np.round(np.clip(celsius * 10.0, INT16_MIN, INT16_MAX))
    return deci.astype(np.int16)


@dataclass(frozen=True)
class SensorLimits:
    """ADC readings that mean a broken sensor: `reading >= adc_open` is open, `reading <= adc_short` is shorted."""

    adc_open: int
    adc_short: int


def sensor_limits(sensor: SensorSpec, pullup_ohm: float = 4700.0, adc_max: int = 1023) -> SensorLimits:
    """adc_open: the first reading whose temperature is below OPEN_BELOW_C (an open thermistor reads adc_max);
    adc_short: the last reading whose temperature is above SHORT_ABOVE_C (a shorted one reads 0)."""
    table = adc_temperature_table(sensor, pullup_ohm, adc_max)
    colder = np.flatnonzero(table < round(OPEN_BELOW_C * 10))
    hotter = np.flatnonzero(table > round(SHORT_ABOVE_C * 10))
    adc_open = int(colder[0]) if colder.size else adc_max
    adc_short = int(hotter[-1]) if hotter.size else 0
    if not adc_short < adc_open - 1:
        raise ValueError(f"{thermistor(sensor).name} with a {pullup_ohm:g} ohm pull-up reads no valid temperature")
    return SensorLimits(adc_open, adc_short)

"""The thermal plant and a closed-loop simulation in Python: the same control law, ADC table and quantization
as the firmware, against a first-order heater.

The plant: `C dT/dt = P * duty/255 - k (T - T_ambient)`. Over one control period the duty is constant, so the
step is exact: T approaches `T_ambient + P * duty/255 / k` with time constant C/k.

The loop, once per period k: the ADC reads the plant's temperature T_k (an ideal 10-bit converter of the divider),
the table turns the reading into deci-degrees, the control law gives duty_k, and duty_k heats the plant until k+1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Protocol, Union

import numpy as np

from codegen.heaters.control import PID_PERIOD_S, PWM_MAX, Fixed, FixedBangBang, FixedPid, controller
from codegen.heaters.sensors import SensorSpec, adc_reading, adc_temperature_table


@dataclass(frozen=True)
class Plant:
    capacity_j_per_k: float
    loss_w_per_k: float
    heater_w: float
    ambient_c: float = 25.0

    @property
    def time_constant_s(self) -> float:
        return self.capacity_j_per_k / self.loss_w_per_k

    def steady_c(self, duty: float = PWM_MAX) -> float:
        """Where the temperature settles at a constant duty (0..255)."""
        return self.ambient_c + self.heater_w * duty / PWM_MAX / self.loss_w_per_k

    def advance(self, temp_c: float, duty: float, seconds: float) -> float:
        """The temperature after `seconds` at a constant duty, from temp_c (the exact first-order solution)."""
        steady = self.steady_c(duty)
        return steady + (temp_c - steady) * float(np.exp(-seconds / self.time_constant_s))


DEFAULT_PLANTS: dict[str, Plant] = {
    # A 40 W cartridge in an E3D-V6-like aluminium block (about 10 g: 9 J/K) with its brass nozzle, the cartridge
    # and the thermistor (about 3 J/K): 12 J/K. Losses of 0.12 W/K (convection, radiation and the heat break)
    # let full power settle at 358 degC; the time constant is 100 s, 25 -> 210 degC at full power takes 81 s.
    "hotend": Plant(capacity_j_per_k=12.0, loss_w_per_k=0.12, heater_w=40.0),
    # A 200 x 200 x 3 mm aluminium plate (324 g: 290 J/K) with its heater pad: 300 J/K, and a 12 V 120 W heater
    # (an MK2-style 1.2 ohm pad). Both faces (0.08 m^2) lose about 12 W/m^2K, plus radiation and the mounts:
    # 1.15 W/K, so full power settles at 129 degC (above the bed's 125 degC maximum: a stuck MOSFET trips it); the
    # time constant is 260 s, 25 -> 60 degC takes 1.8 min.
    "bed": Plant(capacity_j_per_k=300.0, loss_w_per_k=1.15, heater_w=120.0),
}


class Law(Protocol):
    def step(self, t: int, s: int) -> int: ...


@dataclass(frozen=True)
class Simulation:
    """One value per control period: the time it starts, the plant's temperature, the ADC's reading, its
    temperature through the table (deci-degrees: what the law saw) and the duty the law gave."""

    time_s: np.ndarray
    temp_c: np.ndarray
    adc: np.ndarray
    reading_dc: np.ndarray
    duty: np.ndarray


def simulate(plant: Plant, control: Union[Fixed, Law], seconds: float, sensor: SensorSpec, target_c: float,
             pullup_ohm: float = 4700.0, start_c: Optional[float] = None,
             period_s: float = PID_PERIOD_S) -> Simulation:
    """The closed loop for `seconds` towards target_c (0: off), from start_c (default: ambient)."""
    law = controller(control) if isinstance(control, (FixedPid, FixedBangBang)) else control
    table = adc_temperature_table(sensor, pullup_ohm)
    n = int(round(seconds / period_s))
    target_dc = int(round(target_c * 10))
    temps = np.empty(n)
    adcs, readings, duties = (np.empty(n, dtype=np.int64) for _ in range(3))
    temp = plant.ambient_c if start_c is None else start_c
    for k in range(n):
        temps[k] = temp
        adcs[k] = adc_reading(sensor, temp, pullup_ohm)
        readings[k] = table[adcs[k]]
        duties[k] = law.step(int(readings[k]), target_dc)
        temp = plant.advance(temp, duties[k], period_s)
    return Simulation(np.arange(n) * period_s, temps, adcs, readings, duties)


@dataclass(frozen=True)
class HeatingFigures:
    """time_to_target_s: when the temperature first comes within 1 degC of the target (None: never);
    overshoot_c: the highest temperature above the target (0 if never above);
    band_c: the largest |temperature - target| from `settle_s` after time_to_target_s to the end."""

    time_to_target_s: Optional[float]
    overshoot_c: float
    band_c: Optional[float]


def heating_figures(sim: Simulation, target_c: float, settle_s: float = 30.0) -> HeatingFigures:
    error = sim.temp_c - target_c
    reached = np.flatnonzero(error >= -1.0)
    overshoot = max(0.0, float(error.max()))
    if not reached.size:
        return HeatingFigures(None, overshoot, None)
    t_reach = float(sim.time_s[reached[0]])
    after = sim.time_s >= t_reach + settle_s
    band = float(np.abs(error[after]).max()) if after.any() else None
    return HeatingFigures(t_reach, overshoot, band)

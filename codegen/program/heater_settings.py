"""A job's heaters with every default filled in, and what the firmware needs of each.

    from codegen.program.heater_settings import heater_settings
    for name, h in heater_settings(job).items():     # "hotend", "bed"
        h.table(), h.limits(), h.fixed_control(), h.fixed_protection(), h.plant

A job without a `heaters:` section gets the board's defaults: the hot end and the bed, each with the EPCOS 100K
B57560G104F on a 4.7 kOhm pull-up and DEFAULT_CONTROL; their `board_defaults` is True, so that `plan` can say so
once. A job with `heaters:` gets exactly the heaters it lists.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import numpy as np

from codegen.heaters.control import DEFAULT_CONTROL, Fixed, fixed_control
from codegen.heaters.plant import DEFAULT_PLANTS, Plant
from codegen.heaters.protection import DEFAULT_PROTECTION, FixedProtection, ProtectionSettings, fixed_protection
from codegen.heaters.sensors import SensorLimits, Thermistor, adc_temperature_table, sensor_limits, thermistor
from codegen.job.schema import DEFAULT_MAX_TEMP_C, DEFAULT_SENSOR, HEATERS, CustomSensor, Heater, Job


@dataclass(frozen=True)
class HeaterSettings:
    name: str  # "hotend" or "bed"
    sensor: Thermistor
    pullup_ohm: float
    control: dict  # {"pid": {kp, ki, kd}} or {"bang_bang": {hysteresis_c}}
    max_power: float  # 0..1
    min_temp_c: float
    max_temp_c: float
    plant: Plant  # for simulation
    protection: ProtectionSettings
    board_defaults: bool  # True: the job has no `heaters:` section

    def table(self) -> np.ndarray:
        """int16 deci-degrees by 10-bit ADC reading (1024 entries)."""
        return adc_temperature_table(self.sensor, self.pullup_ohm)

    def limits(self) -> SensorLimits:
        return sensor_limits(self.sensor, self.pullup_ohm)

    def fixed_control(self) -> Fixed:
        return fixed_control(self.control, self.max_power)

    def fixed_protection(self) -> FixedProtection:
        return fixed_protection(self.protection, self.min_temp_c, self.max_temp_c, self.limits())


def _sensor(spec) -> Thermistor:
    if isinstance(spec, CustomSensor):
        return thermistor(spec.model_dump(exclude_none=True))
    return thermistor(spec)


def _settings(name: str, heater: Heater, board_defaults: bool) -> HeaterSettings:
    overrides = heater.plant.model_dump(exclude_none=True) if heater.plant is not None else {}
    return HeaterSettings(
        name=name,
        sensor=_sensor(heater.sensor),
        pullup_ohm=heater.pullup_ohm,
        control=heater.control.as_dict() if heater.control is not None else copy.deepcopy(DEFAULT_CONTROL[name]),
        max_power=heater.max_power,
        min_temp_c=heater.min_temp_c,
        max_temp_c=heater.max_temp_c if heater.max_temp_c is not None else DEFAULT_MAX_TEMP_C[name],
        plant=replace(DEFAULT_PLANTS[name], **overrides),
        protection=DEFAULT_PROTECTION[name],
        board_defaults=board_defaults,
    )


def heater_settings(job: Job) -> dict[str, HeaterSettings]:
    """Every heater of the job (in the order hotend, bed), defaults filled in."""
    given = job.machine.heaters
    if given is None:
        return {name: _settings(name, Heater(sensor=DEFAULT_SENSOR), True) for name in HEATERS}
    return {name: _settings(name, given[name], False) for name in HEATERS if name in given}

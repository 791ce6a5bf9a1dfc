"""The heaters' models: thermistors, control (PID or bang-bang), the plant's overrides."""

from __future__ import annotations

from typing import Annotated, Any, Optional, Union

from pydantic import AfterValidator, BeforeValidator, Discriminator, Field, Tag, model_validator

from codegen.errors import suggest
from codegen.heaters.control import fixed_gains
from codegen.heaters.sensors import OPEN_BELOW_C, SHORT_ABOVE_C, THERMISTORS
from codegen.job.schema.fields import Model, Positive, fail, number_value, numbers_of

HEATERS = ("hotend", "bed")
DEFAULT_SENSOR = "EPCOS 100K B57560G104F"
DEFAULT_MAX_TEMP_C = {"hotend": 275.0, "bed": 125.0}


class CustomSensor(Model):
    """A thermistor that is not a preset: `{beta, r25_ohm}` or `{steinhart_hart: [a, b, c]}`."""

    beta: Optional[Positive] = None  # K
    r25_ohm: Optional[Positive] = None  # ohms at 25 degC
    steinhart_hart: Optional[Annotated[tuple[float, float, float], numbers_of((3,), "a list of 3 numbers")]] = None

    @model_validator(mode="after")
    def _one_form(self) -> "CustomSensor":
        beta = (self.beta, self.r25_ohm)
        if (None in beta) if self.steinhart_hart is None else (beta != (None, None)):
            raise fail("sensor", "expected either {beta, r25_ohm} or {steinhart_hart: [a, b, c]}")
        if self.steinhart_hart is not None and not (self.steinhart_hart[1] > 0 and self.steinhart_hart[2] >= 0):
            raise fail("sensor", "expected b > 0 and c >= 0 (an NTC)", at=("steinhart_hart",))
        return self


def _preset(v: Any) -> str:
    if v in THERMISTORS:
        return v
    listed = ", ".join(f"'{name}'" for name in THERMISTORS)
    starting = [name for name in THERMISTORS if name.lower().startswith(v.strip().lower())]  # "epcos 100k"
    hint = f" (did you mean '{starting[0]}'?)" if len(starting) == 1 and v.strip() else suggest(v, THERMISTORS)
    raise fail("enum", f"unknown thermistor '{v}'{hint}; presets are {listed}")


def _sensor_item(v: Any) -> Any:
    if not isinstance(v, (str, dict, CustomSensor)):
        raise fail("sensor", "expected a thermistor preset's name or {beta, r25_ohm} or {steinhart_hart: [a, b, c]}")
    return v


SensorItem = Annotated[
    Union[Annotated[Annotated[str, AfterValidator(_preset)], Tag("preset")], Annotated[CustomSensor, Tag("custom")]],
    Discriminator(lambda v: "preset" if isinstance(v, str) else "custom"),
    BeforeValidator(_sensor_item),
]


class PidGains(Model):
    """Marlin's M301 values: kp in duty (0..255) per degC, ki per second, kd in seconds."""

    kp: Annotated[float, BeforeValidator(number_value), Field(ge=0)]
    ki: Annotated[float, BeforeValidator(number_value), Field(ge=0)]
    kd: Annotated[float, BeforeValidator(number_value), Field(ge=0)]


class BangBang(Model):
    # on below set - hysteresis, off above set + hysteresis
    hysteresis_c: Annotated[float, BeforeValidator(number_value), Field(ge=0, le=50)] = 1.0


class Control(Model):
    """Exactly one of `pid` and `bang_bang`."""

    pid: Optional[PidGains] = None
    bang_bang: Optional[BangBang] = None

    @model_validator(mode="after")
    def _one_law(self) -> "Control":
        if (self.pid is None) == (self.bang_bang is None):
            raise fail("control", "give either 'pid' or 'bang_bang'")
        return self

    def as_dict(self) -> dict:
        """The form codegen.heaters.control.fixed_control takes."""
        return self.model_dump(exclude_none=True)


class PlantOverrides(Model):
    """The simulated heater (codegen.heaters.plant.Plant); a key left out keeps the default plant's value."""

    capacity_j_per_k: Optional[Positive] = None
    loss_w_per_k: Optional[Positive] = None
    heater_w: Optional[Positive] = None
    ambient_c: Optional[Annotated[float, BeforeValidator(number_value), Field(ge=-20, le=60)]] = None


class Heater(Model):
    sensor: SensorItem = DEFAULT_SENSOR
    pullup_ohm: Positive = 4700.0
    control: Optional[Control] = None  # default: the board's (codegen.heaters.control.DEFAULT_CONTROL)
    max_power: Annotated[float, BeforeValidator(number_value), Field(gt=0, le=1)] = 1.0  # of the heater's full power
    min_temp_c: Annotated[float, BeforeValidator(number_value), Field(gt=OPEN_BELOW_C)] = 5.0
    max_temp_c: Optional[Annotated[float, BeforeValidator(number_value), Field(lt=SHORT_ABOVE_C)]] = None  # per heater
    plant: Optional[PlantOverrides] = None

    @model_validator(mode="after")
    def _gains_fit(self) -> "Heater":
        if self.control is not None and self.control.pid is not None:
            g = self.control.pid
            try:
                fixed_gains(g.kp, g.ki, g.kd, max_power=self.max_power)
            except ValueError as e:
                raise fail("control", str(e), at=("control", "pid")) from None
        return self



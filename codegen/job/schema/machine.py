"""The machine's models: steppers, delta geometry, homing, the link, the laser, jog keys and feed hold (the input
shaper's in shaping.py, pressure advance's in advance.py)."""

from __future__ import annotations

from typing import Annotated, Any, Optional

from pydantic import BeforeValidator, Field, PrivateAttr, ValidationInfo, field_validator, model_validator

from codegen.errors import SourceRef
from codegen.job.schema.advance import PressureAdvance
from codegen.job.schema.fields import (BACKOFF, DELTA_SIZE, HOMING_SPEED, JUNCTION, KINEMATICS, LEAST_ACCEL, MOTORS,
                                       REACH_MM, SLOWEST_TOP_SPEED, STEPS_PER_MM, TOLERANCE, XY, Angles, Flag, Model,
                                       Positive, choice, fail, number_value)
from codegen.job.schema.heaters import Heater
from codegen.job.schema.shaping import InputShaper


class Stepper(Model):
    steps_per_mm: Annotated[Positive, STEPS_PER_MM]
    max_velocity: Annotated[Positive, SLOWEST_TOP_SPEED]  # mm/s
    max_accel: Annotated[Positive, LEAST_ACCEL]  # mm/s^2
    range: Optional[XY] = None  # (min, max) in mm
    invert_dir: Flag = False  # the DIR pin is inverted on this motor
    _steps_source: SourceRef = PrivateAttr(default_factory=lambda: SourceRef("<job>"))

    @property
    def steps_source(self) -> SourceRef:
        """Where the job file gives `steps_per_mm` (set by the loader)."""
        return self._steps_source

    @steps_source.setter
    def steps_source(self, value: SourceRef) -> None:
        self._steps_source = value

    @field_validator("range")
    @classmethod
    def _ordered(cls, v: Optional[tuple[float, float]]) -> Optional[tuple[float, float]]:
        if v is not None and not v[0] < v[1]:
            raise fail("range", "must be [min, max] with min < max")
        if v is not None and not -REACH_MM <= v[0] < v[1] <= REACH_MM:  # homing's travel is a range's length
            raise fail("range", f"must be within {REACH_MM:g} mm of the origin (100 m is beyond any machine)")
        return v


MIN_TOWER_APART_DEG = 10.0  # nearer towers make the delta's inverse ill-conditioned: steps from rounding noise


class Delta(Model):
    radius: Annotated[Positive, DELTA_SIZE]
    diagonal_rod: Annotated[Positive, DELTA_SIZE]
    height: Annotated[Positive, DELTA_SIZE]
    tower_angles: Angles = (210.0, 330.0, 90.0)  # deg

    @field_validator("diagonal_rod")
    @classmethod
    def _longer_than_radius(cls, v: float, info: ValidationInfo) -> float:
        radius = info.data.get("radius")
        if radius is not None and not v > radius:
            raise fail("rod", f"must be > radius ({radius:g})")
        return v

    @field_validator("tower_angles")
    @classmethod
    def _three_directions(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        for i, j in ((0, 1), (0, 2), (1, 2)):
            apart = abs((v[i] - v[j] + 180.0) % 360.0 - 180.0)
            if apart < MIN_TOWER_APART_DEG:  # towers in one direction leave the effector's position undefined
                raise fail("number", f"towers {i + 1} and {j + 1} stand {apart:g} deg apart: the three towers must "
                                      f"stand in three directions at least {MIN_TOWER_APART_DEG:g} deg apart "
                                      f"(a delta's are usually 120 deg apart)")
        return v


class Homing(Model):
    """How the motors find their switches: fast towards them, back off, slowly towards them again."""

    speed: Annotated[Positive, HOMING_SPEED] = 20.0  # mm/s of motor travel on the first approach
    slow_speed: Annotated[Positive, HOMING_SPEED] = 2.0  # mm/s on the second approach
    backoff: Annotated[Positive, BACKOFF] = 3.0  # mm away from the switches between the approaches


class Link(Model):
    """The serial line a streaming firmware (`build --stream`) reads its records from."""

    baud: Optional[Annotated[int, Field(gt=0, le=2_000_000)]] = None  # default: the target's (AVR 250000, 8051 9600)


class Laser(Model):
    """A laser whose power input takes the board's PWM (`laser_pwm` in targets/<board>.yaml): G-code S sets its
    power (over program.s_max), M3 constant, M4 dynamic (Grbl's laser mode)."""

    pwm_hz: Annotated[float, BeforeValidator(number_value), Field(ge=50, le=50_000)] = 1000.0  # Grbl's default


JOG_KEYS = ("matrix", "direct")


def _speeds(v: Any) -> tuple[float, ...]:
    if not isinstance(v, (list, tuple)) or not 1 <= len(v) <= 8:
        raise fail("speeds", "expected a list of 1 to 8 speeds (mm/min), slowest first")
    out = tuple(number_value(s) for s in v)
    if any(s <= 0 for s in out):
        raise fail("speeds", "every speed must be > 0")
    if any(b <= a for a, b in zip(out, out[1:])):
        raise fail("speeds", "speeds must rise from the slowest to the fastest")
    return out


class Jog(Model):
    """Jog keys at power-up (codegen/motion/jog.py): 8 directions in x and y, speed up and down, start."""

    speeds: Annotated[tuple[float, ...], BeforeValidator(_speeds)] = (60.0, 300.0, 1200.0)  # mm/min, the levels
    accel: Optional[Positive] = None  # mm/s^2; default: the jogged motors' smallest max_accel
    keys: Optional[choice(*JOG_KEYS)] = None  # type: ignore[valid-type]  # default: the kind the board has


def _override(v: Any) -> int:
    n = number_value(v)
    if n != int(n) or not 10 <= n <= 200 or int(n) % 10:
        raise fail("override", "expected a percentage from 10 to 200 in steps of 10 (the feed keys' steps)")
    return int(n)


def _max_override(v: Any) -> int:
    n = number_value(v)
    if n != int(n) or not 100 <= n <= 200 or int(n) % 10:
        raise fail("override", "expected a percentage from 100 to 200 in steps of 10 (the feed keys' steps)")
    return int(n)


class FeedHold(Model):
    """Feed hold, resume and feed override keys (codegen/tables/hold.py): the player's clock slows down, stops and
    comes back within the motors' limits (the board's `hold_keys`). Above 100 % the override goes only as far as
    every motor's limits allow on the stretch being played (codegen/tables/headroom.py)."""

    override: Annotated[int, BeforeValidator(_override)] = 100  # % the job starts with; feed- and feed+ step by 10
    # % the feed+ key goes up to; None: as far as the player goes (200 % on the ATmega2560, 100 % on the 8051)
    max_override: Optional[Annotated[int, BeforeValidator(_max_override)]] = None

    @model_validator(mode="after")
    def _start_within(self) -> "FeedHold":
        if self.max_override is not None and self.override > self.max_override:
            raise fail("override", f"expected at most max_override ({self.max_override} %)", at=("override",))
        return self



class Machine(Model):
    kinematics: choice(*KINEMATICS)  # type: ignore[valid-type]
    steppers: dict[str, Stepper]
    junction_deviation: Annotated[Positive, JUNCTION] = 0.01  # mm, Grbl's $11
    tolerance: Annotated[Positive, TOLERANCE] = 0.002  # mm, Grbl's $12
    step_pulse_us: Annotated[float, BeforeValidator(number_value), Field(gt=0, le=100)] = 2.0  # STEP high time
    dir_setup_us: Annotated[float, BeforeValidator(number_value), Field(ge=0, le=100)] = 1.0  # DIR before STEP
    homing: Homing = Homing()
    delta: Optional[Delta] = None
    link: Link = Link()
    jog: Optional[Jog] = None  # jog keys before the job (codegen/motion/jog.py); None: no jog mode
    heaters: Optional[dict[str, Heater]] = None  # None: the board's defaults (codegen.program.heater_settings)
    laser: Optional[Laser] = None  # a PWM laser; None: the tool pin is only on or off
    feed_hold: Optional[FeedHold] = None  # hold, resume and override (keys or link frames); None: none
    input_shaper: Optional[InputShaper] = None  # shapers per axis (codegen/job/schema/shaping.py); None: unshaped
    pressure_advance: Optional[PressureAdvance] = None  # the extruder's lead (schema/advance.py); None: none

    @property
    def motor_names(self) -> tuple[str, ...]:
        """The motors present, in the kinematics' canonical order (cartesian x, y, z, e; ...)."""
        return tuple(n for n in MOTORS[self.kinematics] if n in self.steppers)

    @property
    def home_point(self) -> tuple[float, float, float]:
        """Where the tool is once homed (x, y, z, mm): a delta's nozzle at `height` above the bed centre; on
        cartesian and corexy machines each axis at its min switch, the low end of its motor's `range` (0 without
        one; a corexy's x and y at 0: its a and b ranges are the belts')."""
        if self.kinematics == "delta":
            return 0.0, 0.0, float(self.delta.height)
        low = [self.steppers[a].range[0] if a in self.steppers and self.steppers[a].range else 0.0 for a in "xyz"]
        return float(low[0]), float(low[1]), float(low[2])



"""The job file's models (pydantic v2): machine, steppers, delta geometry, program and its shapes.

Every error a model raises is worded for people (the loader adds file:line:col and the dotted path). The
checks that span several keys (the motors of a kinematics, `delta:` only with delta kinematics, exactly one of
`shapes` and `gcode`) run in loader.py over the parsed YAML, so they are reported even when other values in
the same mapping are wrong. `source`, `gcode_source` and `path` are set by the loader.
"""

from __future__ import annotations

import math
from functools import cached_property
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Optional, Union

from pydantic import (AfterValidator, BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, PrivateAttr, Tag,
                      ValidationInfo, field_validator, model_validator)
from pydantic_core import PydanticCustomError

from codegen.errors import SourceRef, suggest
from codegen.heaters.control import fixed_gains
from codegen.heaters.sensors import OPEN_BELOW_C, SHORT_ABOVE_C, THERMISTORS
from codegen.job.expr import Expr, ExprError, parse

TARGETS = ("avr", "mcs51")
DEFAULT_BOARDS = {"avr": "ramps-1.4", "mcs51": "at89c52"}
KINEMATICS = ("cartesian", "corexy", "delta")
MOTORS = {"cartesian": ("x", "y", "z", "e"), "corexy": ("a", "b", "z", "e"), "delta": ("a", "b", "c", "e")}
REQUIRED_MOTORS = {"cartesian": ("x", "y"), "corexy": ("a", "b"), "delta": ("a", "b", "c")}


def _fail(kind: str, message: str, **ctx: Any) -> PydanticCustomError:
    """A validation error whose message is final text; ctx may carry `offset`, `at` (a path below) and `where`."""
    return PydanticCustomError(kind, message, ctx or None)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _number(v: Any) -> float:
    if not _is_number(v):
        raise _fail("number", "expected a number")
    try:
        f = float(v)
    except OverflowError:
        f = math.inf
    if not math.isfinite(f):
        raise _fail("number", "expected a finite number")
    return f


def _text(v: Any) -> str:
    if not isinstance(v, str):
        raise _fail("text", "expected a string")
    if not v.strip():
        raise _fail("text", "must not be empty")
    return v


def _expression(v: Any) -> str:
    return repr(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else _text(v)  # `y: 2` is fine


def _flag(v: Any) -> bool:
    if not isinstance(v, bool):
        raise _fail("flag", "expected true or false")
    return v


def _choice(*values: str) -> Any:
    def check(v: Any) -> str:
        if isinstance(v, str) and v in values:
            return v
        listed = ", ".join(values)
        if isinstance(v, str):
            raise _fail("enum", f"'{v}' is not one of {listed}{suggest(v, values)}")
        raise _fail("enum", f"expected one of {listed}")

    return Annotated[Literal[values], BeforeValidator(check)]  # type: ignore[valid-type]


def _numbers(counts: tuple[int, ...], what: str) -> Any:
    def check(v: Any) -> tuple[float, ...]:
        if isinstance(v, (list, tuple)) and len(v) in counts and all(_is_number(c) for c in v):
            try:
                out = tuple(float(c) for c in v)
            except OverflowError:
                out = (math.inf,)
            if all(math.isfinite(c) for c in out):
                return out
        raise _fail("point", f"expected {what}")

    return BeforeValidator(check)


def _sweep(v: float) -> float:
    if not 0.0 < abs(v) <= 360.0:
        raise _fail("sweep", "must be non-zero and at most 360 in magnitude")
    return v


def _within(low: float, high: float, below: str, above: str = "") -> AfterValidator:
    """A machine number's sane range (issue 28: beyond it the planner or its tables run away), with the reason
    for each side."""
    def check(v: float) -> float:
        if not low <= v <= high:
            bound, why = (f"<= {high:g}", above) if v > high else (f">= {low:g}", below)
            raise _fail("range", f"must be {bound} ({why})")
        return v

    return AfterValidator(check)


# Machine numbers beyond these make the host's work grow with the number, not with the job's steps.
STEPS_PER_MM = _within(0.1, 1e5, "a step longer than 10 mm is no stepper drive's",
                       "a step finer than 10 nm is finer than any drive; positions in steps are int32")
# the planner cuts curves into pieces within the tolerance: a tolerance of atoms makes countless pieces
TOLERANCE = _within(1e-4, 10.0, "mm: finer than 0.1 um, curves would be cut into countless pieces",
                    "mm: coarser than 10 mm, a curve is no longer the curve")
JUNCTION = _within(0.0, 10.0, "", "mm: beyond 10 mm every corner is taken at full speed, and v^2 overflows")
SLOWEST_TOP_SPEED = _within(0.1, 1e5, "mm/s: an axis slower than 6 mm/min plans moves of days",
                            "mm/s: 100 m/s is beyond any motor, and its square overflows the planner")
HOMING_SPEED = _within(0.1, 1e4, "mm/s: a slower approach takes hours over a machine's length",
                       "mm/s: 10 m/s is beyond any motor")
BACKOFF = _within(0.0, 1e3, "", "mm: a backoff of a metre leaves any switch behind")
LEAST_ACCEL = _within(1.0, 1e8, "mm/s^2: a gentler ramp to full speed takes hours",
                      "mm/s^2: 10,000 g is beyond any machine, and its products overflow the planner")
DELTA_SIZE = _within(10.0, 1e5, "mm: smaller, a carriage's step moves the tool by millimetres",
                     "mm: 100 m is beyond any machine")
Number = Annotated[float, BeforeValidator(_number)]
Positive = Annotated[float, BeforeValidator(_number), Field(gt=0)]
Text = Annotated[str, BeforeValidator(_text)]
Flag = Annotated[bool, BeforeValidator(_flag)]
Point = Annotated[tuple[float, ...], _numbers((2, 3), "a list of 2 or 3 numbers")]
XY = Annotated[tuple[float, float], _numbers((2,), "a list of 2 numbers")]
Sweep = Annotated[float, BeforeValidator(_number), AfterValidator(_sweep)]
Angles = Annotated[tuple[float, float, float], _numbers((3,), "a list of 3 numbers")]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)


# ---- machine ----

class Stepper(_Model):
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
            raise _fail("range", "must be [min, max] with min < max")
        return v


MIN_TOWER_APART_DEG = 10.0  # nearer towers make the delta's inverse ill-conditioned: steps from rounding noise


class Delta(_Model):
    radius: Annotated[Positive, DELTA_SIZE]
    diagonal_rod: Annotated[Positive, DELTA_SIZE]
    height: Annotated[Positive, DELTA_SIZE]
    tower_angles: Angles = (210.0, 330.0, 90.0)  # deg

    @field_validator("diagonal_rod")
    @classmethod
    def _longer_than_radius(cls, v: float, info: ValidationInfo) -> float:
        radius = info.data.get("radius")
        if radius is not None and not v > radius:
            raise _fail("rod", f"must be > radius ({radius:g})")
        return v

    @field_validator("tower_angles")
    @classmethod
    def _three_directions(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        for i, j in ((0, 1), (0, 2), (1, 2)):
            apart = abs((v[i] - v[j] + 180.0) % 360.0 - 180.0)
            if apart < MIN_TOWER_APART_DEG:  # towers in one direction leave the effector's position undefined
                raise _fail("number", f"towers {i + 1} and {j + 1} stand {apart:g} deg apart: the three towers must "
                                      f"stand in three directions at least {MIN_TOWER_APART_DEG:g} deg apart "
                                      f"(a delta's are usually 120 deg apart)")
        return v


class Homing(_Model):
    """How the motors find their switches: fast towards them, back off, slowly towards them again."""

    speed: Annotated[Positive, HOMING_SPEED] = 20.0  # mm/s of motor travel on the first approach
    slow_speed: Annotated[Positive, HOMING_SPEED] = 2.0  # mm/s on the second approach
    backoff: Annotated[Positive, BACKOFF] = 3.0  # mm away from the switches between the approaches


class Link(_Model):
    """The serial line a streaming firmware (`build --stream`) reads its records from."""

    baud: Optional[Annotated[int, Field(gt=0, le=2_000_000)]] = None  # default: the target's (AVR 250000, 8051 9600)


class Laser(_Model):
    """A laser whose power input takes the board's PWM (`laser_pwm` in targets/<board>.yaml): G-code S sets its
    power (over program.s_max), M3 constant, M4 dynamic (Grbl's laser mode)."""

    pwm_hz: Annotated[float, BeforeValidator(_number), Field(ge=50, le=50_000)] = 1000.0  # Grbl's default


JOG_KEYS = ("matrix", "direct")


def _speeds(v: Any) -> tuple[float, ...]:
    if not isinstance(v, (list, tuple)) or not 1 <= len(v) <= 8:
        raise _fail("speeds", "expected a list of 1 to 8 speeds (mm/min), slowest first")
    out = tuple(_number(s) for s in v)
    if any(s <= 0 for s in out):
        raise _fail("speeds", "every speed must be > 0")
    if any(b <= a for a, b in zip(out, out[1:])):
        raise _fail("speeds", "speeds must rise from the slowest to the fastest")
    return out


class Jog(_Model):
    """Jog keys at power-up (codegen/motion/jog.py): 8 directions in x and y, speed up and down, start."""

    speeds: Annotated[tuple[float, ...], BeforeValidator(_speeds)] = (60.0, 300.0, 1200.0)  # mm/min, the levels
    accel: Optional[Positive] = None  # mm/s^2; default: the jogged motors' smallest max_accel
    keys: Optional[_choice(*JOG_KEYS)] = None  # type: ignore[valid-type]  # default: the kind the board has


def _override(v: Any) -> int:
    n = _number(v)
    if n != int(n) or not 10 <= n <= 200 or int(n) % 10:
        raise _fail("override", "expected a percentage from 10 to 200 in steps of 10 (the feed keys' steps)")
    return int(n)


def _max_override(v: Any) -> int:
    n = _number(v)
    if n != int(n) or not 100 <= n <= 200 or int(n) % 10:
        raise _fail("override", "expected a percentage from 100 to 200 in steps of 10 (the feed keys' steps)")
    return int(n)


class FeedHold(_Model):
    """Feed hold, resume and feed override keys (codegen/tables/hold.py): the player's clock slows down, stops and
    comes back within the motors' limits (the board's `hold_keys`). Above 100 % the override goes only as far as
    every motor's limits allow on the stretch being played (codegen/tables/headroom.py)."""

    override: Annotated[int, BeforeValidator(_override)] = 100  # % the job starts with; feed- and feed+ step by 10
    # % the feed+ key goes up to; None: as far as the player goes (200 % on the ATmega2560, 100 % on the 8051)
    max_override: Optional[Annotated[int, BeforeValidator(_max_override)]] = None

    @model_validator(mode="after")
    def _start_within(self) -> "FeedHold":
        if self.max_override is not None and self.override > self.max_override:
            raise _fail("override", f"expected at most max_override ({self.max_override} %)", at=("override",))
        return self


# ---- heaters ----

HEATERS = ("hotend", "bed")
DEFAULT_SENSOR = "EPCOS 100K B57560G104F"
DEFAULT_MAX_TEMP_C = {"hotend": 275.0, "bed": 125.0}


class CustomSensor(_Model):
    """A thermistor that is not a preset: `{beta, r25_ohm}` or `{steinhart_hart: [a, b, c]}`."""

    beta: Optional[Positive] = None  # K
    r25_ohm: Optional[Positive] = None  # ohms at 25 degC
    steinhart_hart: Optional[Annotated[tuple[float, float, float], _numbers((3,), "a list of 3 numbers")]] = None

    @model_validator(mode="after")
    def _one_form(self) -> "CustomSensor":
        beta = (self.beta, self.r25_ohm)
        if (None in beta) if self.steinhart_hart is None else (beta != (None, None)):
            raise _fail("sensor", "expected either {beta, r25_ohm} or {steinhart_hart: [a, b, c]}")
        if self.steinhart_hart is not None and not (self.steinhart_hart[1] > 0 and self.steinhart_hart[2] >= 0):
            raise _fail("sensor", "expected b > 0 and c >= 0 (an NTC)", at=("steinhart_hart",))
        return self


def _preset(v: Any) -> str:
    if v in THERMISTORS:
        return v
    listed = ", ".join(f"'{name}'" for name in THERMISTORS)
    starting = [name for name in THERMISTORS if name.lower().startswith(v.strip().lower())]  # "epcos 100k"
    hint = f" (did you mean '{starting[0]}'?)" if len(starting) == 1 and v.strip() else suggest(v, THERMISTORS)
    raise _fail("enum", f"unknown thermistor '{v}'{hint}; presets are {listed}")


def _sensor_item(v: Any) -> Any:
    if not isinstance(v, (str, dict, CustomSensor)):
        raise _fail("sensor", "expected a thermistor preset's name or {beta, r25_ohm} or {steinhart_hart: [a, b, c]}")
    return v


SensorItem = Annotated[
    Union[Annotated[Annotated[str, AfterValidator(_preset)], Tag("preset")], Annotated[CustomSensor, Tag("custom")]],
    Discriminator(lambda v: "preset" if isinstance(v, str) else "custom"),
    BeforeValidator(_sensor_item),
]


class PidGains(_Model):
    """Marlin's M301 values: kp in duty (0..255) per degC, ki per second, kd in seconds."""

    kp: Annotated[float, BeforeValidator(_number), Field(ge=0)]
    ki: Annotated[float, BeforeValidator(_number), Field(ge=0)]
    kd: Annotated[float, BeforeValidator(_number), Field(ge=0)]


class BangBang(_Model):
    hysteresis_c: Annotated[float, BeforeValidator(_number), Field(ge=0, le=50)] = 1.0  # on below s-h, off above s+h


class Control(_Model):
    """Exactly one of `pid` and `bang_bang`."""

    pid: Optional[PidGains] = None
    bang_bang: Optional[BangBang] = None

    @model_validator(mode="after")
    def _one_law(self) -> "Control":
        if (self.pid is None) == (self.bang_bang is None):
            raise _fail("control", "give either 'pid' or 'bang_bang'")
        return self

    def as_dict(self) -> dict:
        """The form codegen.heaters.control.fixed_control takes."""
        return self.model_dump(exclude_none=True)


class PlantOverrides(_Model):
    """The simulated heater (codegen.heaters.plant.Plant); a key left out keeps the default plant's value."""

    capacity_j_per_k: Optional[Positive] = None
    loss_w_per_k: Optional[Positive] = None
    heater_w: Optional[Positive] = None
    ambient_c: Optional[Annotated[float, BeforeValidator(_number), Field(ge=-20, le=60)]] = None


class Heater(_Model):
    sensor: SensorItem = DEFAULT_SENSOR
    pullup_ohm: Positive = 4700.0
    control: Optional[Control] = None  # default: the board's (codegen.heaters.control.DEFAULT_CONTROL)
    max_power: Annotated[float, BeforeValidator(_number), Field(gt=0, le=1)] = 1.0  # of the heater's full power
    min_temp_c: Annotated[float, BeforeValidator(_number), Field(gt=OPEN_BELOW_C)] = 5.0
    max_temp_c: Optional[Annotated[float, BeforeValidator(_number), Field(lt=SHORT_ABOVE_C)]] = None  # per heater
    plant: Optional[PlantOverrides] = None

    @model_validator(mode="after")
    def _gains_fit(self) -> "Heater":
        if self.control is not None and self.control.pid is not None:
            g = self.control.pid
            try:
                fixed_gains(g.kp, g.ki, g.kd, max_power=self.max_power)
            except ValueError as e:
                raise _fail("control", str(e), at=("control", "pid")) from None
        return self


class Machine(_Model):
    kinematics: _choice(*KINEMATICS)  # type: ignore[valid-type]
    steppers: dict[str, Stepper]
    junction_deviation: Annotated[Positive, JUNCTION] = 0.01  # mm, Grbl's $11
    tolerance: Annotated[Positive, TOLERANCE] = 0.002  # mm, Grbl's $12
    step_pulse_us: Annotated[float, BeforeValidator(_number), Field(gt=0, le=100)] = 2.0  # STEP high time
    dir_setup_us: Annotated[float, BeforeValidator(_number), Field(ge=0, le=100)] = 1.0  # DIR before STEP
    homing: Homing = Homing()
    delta: Optional[Delta] = None
    link: Link = Link()
    jog: Optional[Jog] = None  # jog keys before the job (codegen/motion/jog.py); None: no jog mode
    heaters: Optional[dict[str, Heater]] = None  # None: the board's defaults (codegen.program.heater_settings)
    laser: Optional[Laser] = None  # a PWM laser; None: the tool pin is only on or off
    feed_hold: Optional[FeedHold] = None  # hold, resume and override (keys or link frames); None: none

    @property
    def motor_names(self) -> tuple[str, ...]:
        """The motors present, in the kinematics' canonical order (cartesian x, y, z, e; ...)."""
        return tuple(n for n in MOTORS[self.kinematics] if n in self.steppers)


# ---- shapes ----

class _Shape(_Model):
    kind: ClassVar[str]
    _source: SourceRef = PrivateAttr(default_factory=lambda: SourceRef("<shape>"))

    @property
    def source(self) -> SourceRef:
        """Where the shape's kind key is in the job file (set by the loader; not a key of the file)."""
        return self._source

    @source.setter
    def source(self, value: SourceRef) -> None:
        self._source = value


class _Fed(_Shape):
    feed: Optional[Positive] = None  # mm/min


class _Flat(_Fed):
    z: Optional[Number] = None  # draw height for a 2-D shape


class Line(_Fed):
    kind: ClassVar[str] = "line"
    z: ClassVar[None] = None
    to: Point
    from_: Optional[Point] = Field(default=None, alias="from")


class Polyline(_Fed):
    kind: ClassVar[str] = "polyline"
    z: ClassVar[None] = None
    points: Annotated[list[Point], Field(min_length=2)]


class Points(_Shape):
    kind: ClassVar[str] = "points"
    feed: ClassVar[None] = None
    z: ClassVar[None] = None
    points: Annotated[list[Point], Field(min_length=1)]


class Arc(_Flat):
    kind: ClassVar[str] = "arc"
    center: XY
    radius: Positive
    start: Number  # deg
    sweep: Sweep  # deg, positive counter-clockwise


class Circle(_Flat):
    kind: ClassVar[str] = "circle"
    center: XY
    radius: Positive
    start: Number = 0.0  # deg
    direction: _choice("ccw", "cw") = "ccw"  # type: ignore[valid-type]

    @property
    def sweep(self) -> float:
        return 360.0 if self.direction == "ccw" else -360.0


class Ellipse(_Flat):
    kind: ClassVar[str] = "ellipse"
    center: XY
    a: Positive
    b: Positive
    rotation: Number = 0.0  # deg
    start: Number = 0.0  # deg
    sweep: Sweep = 360.0  # deg


class Sine(_Flat):
    kind: ClassVar[str] = "sine"
    origin: XY
    amplitude: Number
    omega: Number  # rad/mm
    phase: Number = 0.0  # deg
    length: Number  # mm, may be negative

    @field_validator("length")
    @classmethod
    def _nonzero(cls, v: float) -> float:
        if v == 0.0:
            raise _fail("length", "must not be 0")
        return v


class Function(_Flat):
    kind: ClassVar[str] = "function"
    y: Annotated[str, BeforeValidator(_expression)]  # an expression in x
    x: XY  # [from, to]
    origin: XY = (0.0, 0.0)

    @field_validator("y")
    @classmethod
    def _parses(cls, v: str) -> str:
        try:
            parse(v)
        except ExprError as e:
            raise _fail("expr", e.message, offset=e.offset) from None
        return v

    @field_validator("x")
    @classmethod
    def _interval(cls, v: tuple[float, float]) -> tuple[float, float]:
        if v[0] == v[1]:
            raise _fail("interval", "must be [from, to] with from != to")
        return v

    @cached_property
    def expr(self) -> Expr:
        """The parsed expression of y."""
        return parse(self.y)


class Travel(_Fed):
    kind: ClassVar[str] = "travel"
    z: ClassVar[None] = None
    to: Point


SHAPES: dict[str, type[_Shape]] = {
    cls.kind: cls for cls in (Line, Polyline, Points, Arc, Circle, Ellipse, Sine, Function, Travel)
}
Shape = Union[Line, Polyline, Points, Arc, Circle, Ellipse, Sine, Function, Travel]


class _Body(dict):
    """A shape's mapping, tagged with its kind for the discriminated union."""

    kind = ""


def _shape_item(v: Any) -> Any:
    if isinstance(v, _Shape):
        return v
    example = "a one-key mapping such as `line: {to: [10, 0]}`"
    if not isinstance(v, dict) or not v:
        raise _fail("shape", f"expected a shape, {example}")
    if len(v) > 1:
        keys = ", ".join(f"'{k}'" for k in v)
        kinds = [k for k in v if k in SHAPES]
        hint = f" (indent the other keys under '{kinds[0]}')" if len(kinds) == 1 else ""
        raise _fail("shape", f"a shape is a one-key mapping, its kind; found keys {keys}{hint}")
    ((kind, body),) = v.items()
    if kind not in SHAPES:
        hint = suggest(str(kind), SHAPES) or f"; shapes are {', '.join(SHAPES)}"
        raise _fail("shape", f"unknown shape '{kind}'{hint}", at=(kind,), where="key")
    if kind == "points":
        body = {"points": body}
    if not isinstance(body, dict):
        raise _fail("shape", f"expected the {kind}'s keys (a mapping)", at=(kind,), where="value")
    tagged = _Body(body)
    tagged.kind = kind
    return tagged


ShapeItem = Annotated[
    Union[tuple(Annotated[cls, Tag(kind)] for kind, cls in SHAPES.items())],  # type: ignore[misc]
    Discriminator(lambda v: getattr(v, "kind", None)),
    BeforeValidator(_shape_item),
]


# ---- program and job ----

class Program(_Model):
    start: Point = (0.0, 0.0)
    feed: Positive = 1200.0  # mm/min
    travel_feed: Optional[Positive] = None  # mm/min; None: as fast as the machine allows
    s_max: Optional[Positive] = None  # the G-code S of full power; default per dialect: 255 (Marlin), 1000 (Grbl's $30)
    dialect: Optional[_choice("marlin", "grbl")] = None  # type: ignore[valid-type]  # None: guessed from the G-code
    home: Flag = False  # home at power-up before the program (delta machines always do)
    shapes: Optional[Annotated[list[ShapeItem], Field(min_length=1)]] = None
    gcode: Optional[Text] = None  # a path relative to the job file, or the G-code itself
    _gcode_source: SourceRef = PrivateAttr(default_factory=lambda: SourceRef("<gcode>"))
    _start_source: Optional[SourceRef] = PrivateAttr(default=None)

    @property
    def start_source(self) -> Optional[SourceRef]:
        """Where the job file gives `start`; None when it does not (the default applies)."""
        return self._start_source

    @start_source.setter
    def start_source(self, value: Optional[SourceRef]) -> None:
        self._start_source = value

    @property
    def gcode_source(self) -> SourceRef:
        """Where the G-code starts: its first line for inline G-code, else the path's value in the job file."""
        return self._gcode_source

    @gcode_source.setter
    def gcode_source(self, value: SourceRef) -> None:
        self._gcode_source = value


class Job(_Model):
    name: Text = "job"  # the loader defaults it to the file's stem
    target: _choice(*TARGETS) = "avr"  # type: ignore[valid-type]
    board: Text = DEFAULT_BOARDS["avr"]  # default: per target
    machine: Machine
    program: Optional[Program] = None  # only `build --stream` goes without one (load_job checks)
    _path: Path = PrivateAttr(default_factory=Path)

    @property
    def path(self) -> Path:
        """The job file's absolute path."""
        return self._path

    @path.setter
    def path(self, value: Path) -> None:
        self._path = value

    @model_validator(mode="before")
    @classmethod
    def _default_board(cls, data: Any) -> Any:
        target = data.get("target", "avr") if isinstance(data, dict) else None
        if isinstance(target, str) and "board" not in data and target in DEFAULT_BOARDS:  # else: the target's error
            data = {**data, "board": DEFAULT_BOARDS[target]}
        return data

    @field_validator("name")
    @classmethod
    def _file_name(cls, v: str) -> str:
        if any(c in v for c in "/\\\0") or v in (".", ".."):
            raise _fail("name", "must be usable as a folder name (no '/' or '\\')")
        return v

"""The job file's field types (pydantic v2): numbers, texts, flags, points and the machine numbers' sane ranges."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field
from pydantic_core import PydanticCustomError

from codegen.errors import suggest

TARGETS = ("avr", "mcs51")
DEFAULT_BOARDS = {"avr": "ramps-1.4", "mcs51": "at89c52"}
KINEMATICS = ("cartesian", "corexy", "delta")
MOTORS = {"cartesian": ("x", "y", "z", "e"), "corexy": ("a", "b", "z", "e"), "delta": ("a", "b", "c", "e")}
REQUIRED_MOTORS = {"cartesian": ("x", "y"), "corexy": ("a", "b"), "delta": ("a", "b", "c")}


def fail(kind: str, message: str, **ctx: Any) -> PydanticCustomError:
    """A validation error whose message is final text; ctx may carry `offset`, `at` (a path below) and `where`."""
    return PydanticCustomError(kind, message, ctx or None)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def number_value(v: Any) -> float:
    if not _is_number(v):
        raise fail("number", "expected a number")
    try:
        f = float(v)
    except OverflowError:
        f = math.inf
    if not math.isfinite(f):
        raise fail("number", "expected a finite number")
    return f


def _text(v: Any) -> str:
    if not isinstance(v, str):
        raise fail("text", "expected a string")
    if not v.strip():
        raise fail("text", "must not be empty")
    return v


def expression_text(v: Any) -> str:
    return repr(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else _text(v)  # `y: 2` is fine


def _flag(v: Any) -> bool:
    if not isinstance(v, bool):
        raise fail("flag", "expected true or false")
    return v


def choice(*values: str) -> Any:
    def check(v: Any) -> str:
        if isinstance(v, str) and v in values:
            return v
        listed = ", ".join(values)
        if isinstance(v, str):
            raise fail("enum", f"'{v}' is not one of {listed}{suggest(v, values)}")
        raise fail("enum", f"expected one of {listed}")

    return Annotated[Literal[values], BeforeValidator(check)]  # type: ignore[valid-type]


def numbers_of(counts: tuple[int, ...], what: str) -> Any:
    def check(v: Any) -> tuple[float, ...]:
        if isinstance(v, (list, tuple)) and len(v) in counts and all(_is_number(c) for c in v):
            try:
                out = tuple(float(c) for c in v)
            except OverflowError:
                out = (math.inf,)
            if all(math.isfinite(c) for c in out):
                return out
        raise fail("point", f"expected {what}")

    return BeforeValidator(check)


def _sweep(v: float) -> float:
    if not 0.0 < abs(v) <= 360.0:
        raise fail("sweep", "must be non-zero and at most 360 in magnitude")
    return v


def _within(low: float, high: float, below: str, above: str = "") -> AfterValidator:
    """A machine number's sane range (issue 28: beyond it the planner or its tables run away), with the reason
    for each side."""
    def check(v: float) -> float:
        if not low <= v <= high:
            bound, why = (f"<= {high:g}", above) if v > high else (f">= {low:g}", below)
            raise fail("range", f"must be {bound} ({why})")
        return v

    return AfterValidator(check)


# Machine numbers beyond these make the host's work grow with the number, not with the job's steps.
REACH_MM = 1e5  # 100 m from the origin: beyond any machine, and far inside the planner's float precision
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
Number = Annotated[float, BeforeValidator(number_value)]
Positive = Annotated[float, BeforeValidator(number_value), Field(gt=0)]
Text = Annotated[str, BeforeValidator(_text)]
Flag = Annotated[bool, BeforeValidator(_flag)]
Point = Annotated[tuple[float, ...], numbers_of((2, 3), "a list of 2 or 3 numbers")]
XY = Annotated[tuple[float, float], numbers_of((2,), "a list of 2 numbers")]
Sweep = Annotated[float, BeforeValidator(number_value), AfterValidator(_sweep)]
Angles = Annotated[tuple[float, float, float], numbers_of((3,), "a list of 3 numbers")]


class Model(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)



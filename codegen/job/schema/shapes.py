"""The program's shapes: line, polyline, points, arc, circle, ellipse, sine, function and travel."""

from __future__ import annotations

from functools import cached_property
from typing import Annotated, Any, ClassVar, Optional, Union

from pydantic import BeforeValidator, Discriminator, Field, PrivateAttr, Tag, field_validator

from codegen.errors import SourceRef, suggest
from codegen.job.expr import Expr, ExprError, parse
from codegen.job.schema.fields import XY, Model, Number, Point, Positive, Sweep, choice, expression_text, fail


class _Shape(Model):
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
    direction: choice("ccw", "cw") = "ccw"  # type: ignore[valid-type]

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
            raise fail("length", "must not be 0")
        return v


class Function(_Flat):
    kind: ClassVar[str] = "function"
    y: Annotated[str, BeforeValidator(expression_text)]  # an expression in x
    x: XY  # [from, to]
    origin: XY = (0.0, 0.0)

    @field_validator("y")
    @classmethod
    def _parses(cls, v: str) -> str:
        try:
            parse(v)
        except ExprError as e:
            raise fail("expr", e.message, offset=e.offset) from None
        return v

    @field_validator("x")
    @classmethod
    def _interval(cls, v: tuple[float, float]) -> tuple[float, float]:
        if v[0] == v[1]:
            raise fail("interval", "must be [from, to] with from != to")
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
        raise fail("shape", f"expected a shape, {example}")
    if len(v) > 1:
        keys = ", ".join(f"'{k}'" for k in v)
        kinds = [k for k in v if k in SHAPES]
        hint = f" (indent the other keys under '{kinds[0]}')" if len(kinds) == 1 else ""
        raise fail("shape", f"a shape is a one-key mapping, its kind; found keys {keys}{hint}")
    ((kind, body),) = v.items()
    if kind not in SHAPES:
        hint = suggest(str(kind), SHAPES) or f"; shapes are {', '.join(SHAPES)}"
        raise fail("shape", f"unknown shape '{kind}'{hint}", at=(kind,), where="key")
    if kind == "points":
        body = {"points": body}
    if not isinstance(body, dict):
        raise fail("shape", f"expected the {kind}'s keys (a mapping)", at=(kind,), where="value")
    tagged = _Body(body)
    tagged.kind = kind
    return tagged


ShapeItem = Annotated[
    Union[tuple(Annotated[cls, Tag(kind)] for kind, cls in SHAPES.items())],  # type: ignore[misc]
    Discriminator(lambda v: getattr(v, "kind", None)),
    BeforeValidator(_shape_item),
]



"""The expression language of the `function` shape: y as a function of x. Parsed, never eval'd.

Grammar (Python's precedence; `**` is right-associative and binds tighter than a unary sign on its left):

    expr  := term (('+' | '-') term)*
    term  := unary (('*' | '/') unary)*
    unary := ('-' | '+') unary | power
    power := atom ('**' unary)?
    atom  := number | 'x' | 'pi' | 'e' | function '(' expr ')' | '(' expr ')'

An `Expr` evaluates vectorised with numpy, differentiates symbolically and bounds itself on an interval by
outward-rounded interval arithmetic; both live in calculus.py.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from codegen.errors import closest

FUNCTIONS = ("sin", "cos", "tan", "asin", "acos", "atan", "sqrt", "exp", "log", "abs")
CONSTANTS = {"pi": math.pi, "e": math.e}
NAMES = ("x", *CONSTANTS, *FUNCTIONS)

NUMPY = {"sin": np.sin, "cos": np.cos, "tan": np.tan, "asin": np.arcsin, "acos": np.arccos,
         "atan": np.arctan, "sqrt": np.sqrt, "exp": np.exp, "log": np.log, "abs": np.abs}
BINARY = {"+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide, "**": np.power}
_PREC = {"+": 1, "-": 1, "*": 2, "/": 2, "**": 4}
_ATOM, _UNARY = 5, 3
_MAX_DEPTH = 100  # nesting of parentheses and signs
_MAX_OPS = 200  # binary operators in one expression


class ExprError(ValueError):
    """A syntax error; `offset` is the 0-based index into the text of the offending character."""

    def __init__(self, message: str, offset: int):
        super().__init__(message)
        self.message = message
        self.offset = offset


class Expr:
    """A parsed expression in x. Immutable; equal trees compare equal."""

    has_x: bool  # whether the value depends on x

    def evaluate(self, x: np.ndarray) -> np.ndarray:
        """f at every element of x (NaN or inf where f is undefined); the result has x's shape."""
        x = np.asarray(x, dtype=float)
        with np.errstate(all="ignore"):
            return np.broadcast_to(self._eval(x), x.shape).astype(float)

    def _eval(self, x: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _prec(self) -> int:
        return _ATOM


@dataclass(frozen=True)
class Num(Expr):
    value: float
    name: str | None = None  # 'pi' or 'e' when written as a constant

    has_x = False

    def _eval(self, x):
        return np.float64(self.value)

    def _prec(self) -> int:
        return _UNARY if math.copysign(1.0, self.value) < 0 else _ATOM

    def __str__(self) -> str:
        if self.name:
            return self.name
        v = self.value
        return str(int(v)) if v.is_integer() and abs(v) < 1e16 else repr(v)


@dataclass(frozen=True)
class Var(Expr):
    has_x = True

    def _eval(self, x):
        return x

    def __str__(self) -> str:
        return "x"


@dataclass(frozen=True)
class Neg(Expr):
    arg: Expr

    @property
    def has_x(self) -> bool:
        return self.arg.has_x

    def _eval(self, x):
        return np.negative(self.arg._eval(x))

    def _prec(self) -> int:
        return _UNARY

    def __str__(self) -> str:
        return "-" + _wrap(self.arg, _UNARY)


@dataclass(frozen=True)
class Binary(Expr):
    op: str  # + - * / **
    left: Expr
    right: Expr

    @property
    def has_x(self) -> bool:
        return self.left.has_x or self.right.has_x

    def _eval(self, x):
        return BINARY[self.op](self.left._eval(x), self.right._eval(x))

    def _prec(self) -> int:
        return _PREC[self.op]

    def __str__(self) -> str:
        p = _PREC[self.op]
        if self.op == "**":
            return f"{_wrap(self.left, _ATOM)}**{_wrap(self.right, _UNARY)}"
        sep = f" {self.op} " if p == 1 else self.op
        return f"{_wrap(self.left, p)}{sep}{_wrap(self.right, p + 1)}"


@dataclass(frozen=True)
class Call(Expr):
    fn: str  # one of FUNCTIONS
    arg: Expr

    @property
    def has_x(self) -> bool:
        return self.arg.has_x

    def _eval(self, x):
        return NUMPY[self.fn](self.arg._eval(x))

    def __str__(self) -> str:
        return f"{self.fn}({self.arg})"


def _wrap(e: Expr, min_prec: int) -> str:
    return str(e) if e._prec() >= min_prec else f"({e})"


# ---- the parser ----

_TOKEN = re.compile(r"(?P<ws>\s+)|(?P<num>(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?)"
                    r"|(?P<name>[A-Za-z_][A-Za-z_0-9]*)|(?P<op>\*\*|[-+*/(),])")


@dataclass(frozen=True)
class _Tok:
    kind: str  # num | name | op | end
    text: str
    offset: int

    def describe(self) -> str:
        return "end of expression" if self.kind == "end" else f"'{self.text}'"


def _tokens(text: str) -> Iterator[_Tok]:
    """The tokens, made one at a time so that the first problem in the text is the one reported."""
    pos = 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if not m:
            raise ExprError(f"unexpected character {text[pos]!r}", pos)
        if m.lastgroup != "ws":
            yield _Tok(m.lastgroup, m.group(), pos)
        pos = m.end()
    while True:
        yield _Tok("end", "", len(text))


class _Parser:
    def __init__(self, text: str):
        self.stream = _tokens(text)
        self.tok = next(self.stream)
        self.started = False
        self.depth = 0
        self.ops = 0

    def take(self) -> _Tok:
        t, self.started = self.tok, True
        self.tok = next(self.stream)
        return t

    def at(self, *ops: str) -> bool:
        return self.tok.kind == "op" and self.tok.text in ops

    def unexpected(self) -> ExprError:
        t = self.tok
        hint = " (missing operator?)" if t.kind in ("num", "name") or t.text == "(" else ""
        return ExprError(f"unexpected {t.describe()}{hint}", t.offset)

    def operator(self) -> str:
        self.ops += 1
        if self.ops > _MAX_OPS:
            raise ExprError(f"expression too long (more than {_MAX_OPS} operators)", self.tok.offset)
        return self.take().text

    def expr(self) -> Expr:
        e = self.term()
        while self.at("+", "-"):
            op = self.operator()
            e = Binary(op, e, self.term())
        return e

    def term(self) -> Expr:
        e = self.unary()
        while self.at("*", "/"):
            op = self.operator()
            e = Binary(op, e, self.unary())
        return e

    def unary(self) -> Expr:
        self.depth += 1
        if self.depth > _MAX_DEPTH:
            raise ExprError("expression nested too deeply", self.tok.offset)
        if self.at("-", "+"):
            sign = self.take().text
            arg = self.unary()
            e = Neg(arg) if sign == "-" else arg
        else:
            e = self.power()
        self.depth -= 1
        return e

    def power(self) -> Expr:
        base = self.atom()
        if self.at("**"):
            self.operator()
            return Binary("**", base, self.unary())
        return base

    def atom(self) -> Expr:
        t = self.tok
        if t.kind == "num":
            self.take()
            value = float(t.text)
            if not math.isfinite(value):
                raise ExprError(f"number {t.text} is out of range", t.offset)
            return Num(value)
        if t.kind == "name":
            return self.name()
        if self.at("("):
            self.take()
            e = self.expr()
            self.close()
            return e
        if t.kind == "end":
            raise ExprError("expected an expression" if self.started else "empty expression", t.offset)
        raise ExprError(f"expected an expression, found {t.describe()}", t.offset)

    def name(self) -> Expr:
        t = self.take()
        if t.text in FUNCTIONS:
            if not self.at("("):
                raise ExprError(f"expected '(' after '{t.text}'", self.tok.offset)
            self.take()
            if self.at(")"):
                raise ExprError(f"'{t.text}' takes exactly one argument", self.tok.offset)
            arg = self.expr()
            if self.at(","):
                raise ExprError(f"'{t.text}' takes exactly one argument", self.tok.offset)
            self.close()
            return Call(t.text, arg)
        if t.text == "x":
            e: Expr = Var()
        elif t.text in CONSTANTS:
            e = Num(CONSTANTS[t.text], t.text)
        else:
            match = closest(t.text.lower(), NAMES) if t.text.lower() not in NAMES else t.text.lower()
            hint = f" (did you mean '{match}'?)" if match else ""
            raise ExprError(f"unknown name '{t.text}'{hint}", t.offset)
        if self.at("("):
            raise ExprError(f"'{t.text}' is not a function", self.tok.offset)
        return e

    def close(self) -> None:
        if self.at(")"):
            self.take()
            return
        if self.tok.kind == "end":
            raise ExprError("missing ')'", self.tok.offset)
        raise self.unexpected()


def parse(text: str) -> Expr:
    """Parse an expression in x; raises ExprError(message, offset) at the first problem."""
    if not isinstance(text, str):
        raise ExprError("expected an expression (a string)", 0)
    p = _Parser(text)
    e = p.expr()
    if p.tok.kind != "end":
        raise p.unexpected()
    return e

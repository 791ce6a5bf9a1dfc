"""Calculus on parsed expressions: symbolic derivatives and guaranteed bounds by interval arithmetic.

`derivative(e)` applies the usual rules and simplifies trivially, so the result is again an expression of the
language (its `str` parses back to the same value). `bound(e, lo, hi)` encloses e over [lo, hi].

An interval is a tuple `(lo, hi)` of finite floats with lo <= hi; `None` stands for "may be undefined or
unbounded here" (a domain problem, a pole, an overflow). Every operation returns an enclosure of the exact
result widened by a few units in the last place, so it also contains what numpy computes in floating point.
"""

from __future__ import annotations

import math
from typing import Callable, Optional

import numpy as np

from codegen.job.expr import BINARY, NUMPY, Binary, Call, Expr, Neg, Num, Var

Interval = tuple[float, float]
MaybeInterval = Optional[Interval]

_PI = math.pi
_HALF_PI = math.pi / 2
_TRIG_LIMIT = 1e8  # beyond this, argument reduction is too coarse to locate extrema: use [-1, 1]


def widen(lo: float, hi: float, ulps: int = 1) -> MaybeInterval:
    """[lo, hi] pushed outwards by `ulps` units in the last place; None when not finite."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return None
    if lo > hi:
        lo, hi = hi, lo
    lo -= ulps * math.ulp(lo)
    hi += ulps * math.ulp(hi)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return None
    return lo, hi


def _safe(fn: Callable[..., float], *args: float) -> float:
    try:
        return fn(*args)
    except (OverflowError, ValueError, ZeroDivisionError):
        return math.nan


def _sum_bounds(x: float, y: float) -> tuple[float, float]:
    """The float sum x + y and the float bounds of the exact sum: widened only when rounding happened
    (Knuth's two-sum gives the rounding error exactly), so that 4 - 4 stays exactly 0."""
    s = x + y
    if not math.isfinite(s):
        return s, s
    back = s - x
    error = (x - (s - back)) + (y - back)
    low = s if error >= 0 else math.nextafter(s, -math.inf)
    high = s if error <= 0 else math.nextafter(s, math.inf)
    return low, high


def add(a: Interval, b: Interval) -> MaybeInterval:
    lo, hi = _sum_bounds(a[0], b[0])[0], _sum_bounds(a[1], b[1])[1]
    return (lo, hi) if math.isfinite(lo) and math.isfinite(hi) else None


def sub(a: Interval, b: Interval) -> MaybeInterval:
    return add(a, (-b[1], -b[0]))


def neg(a: Interval) -> MaybeInterval:
    return -a[1], -a[0]


def mul(a: Interval, b: Interval) -> MaybeInterval:
    products = [a[0] * b[0], a[0] * b[1], a[1] * b[0], a[1] * b[1]]
    return widen(min(products), max(products))


def div(a: Interval, b: Interval) -> MaybeInterval:
    if b[0] <= 0.0 <= b[1]:
        return None
    quotients = [a[0] / b[0], a[0] / b[1], a[1] / b[0], a[1] / b[1]]
    return widen(min(quotients), max(quotients))


def _monotone(fn: Callable[[float], float], a: Interval, increasing: bool = True, ulps: int = 4) -> MaybeInterval:
    lo, hi = _safe(fn, a[0]), _safe(fn, a[1])
    if not increasing:
        lo, hi = hi, lo
    return widen(lo, hi, ulps)


def _clamp(r: MaybeInterval, lo: float, hi: float) -> MaybeInterval:
    if r is None:
        return None
    return max(r[0], lo), min(r[1], hi)


def power(a: Interval, p: float) -> MaybeInterval:
    """a ** p for a constant exponent p, with numpy's domain: a negative base needs an integer exponent."""
    if p == 0.0:
        return 1.0, 1.0
    if p.is_integer():
        n = int(p)
        if n < 0:
            if a[0] <= 0.0 <= a[1]:
                return None
            r = power(a, float(-n))
            return None if r is None else div((1.0, 1.0), r)
        if n % 2 == 0 and a[0] < 0.0 < a[1]:
            r = widen(0.0, _safe(math.pow, max(-a[0], a[1]), p), 4)
            return None if r is None else (0.0, r[1])
        if n % 2 == 0 and a[1] <= 0.0:
            return _monotone(lambda v: math.pow(v, p), a, increasing=False)
        return _monotone(lambda v: math.pow(v, p), a)
    if a[0] < 0.0:
        return None
    if p < 0.0:
        if a[0] == 0.0:
            return None
        return _monotone(lambda v: math.pow(v, p), a, increasing=False)
    r = _monotone(lambda v: math.pow(v, p), a)
    return None if r is None else (max(r[0], 0.0), r[1])


def general_power(a: Interval, b: Interval) -> MaybeInterval:
    """a ** b with a variable exponent: exp(b * log(a)), defined for a > 0 only."""
    la = log(a)
    if la is None:
        return None
    prod = mul(b, la)
    return None if prod is None else exp(prod)


def sqrt(a: Interval) -> MaybeInterval:
    if a[0] < 0.0:
        return None
    r = _monotone(math.sqrt, a)
    return None if r is None else (max(r[0], 0.0), r[1])


def log(a: Interval) -> MaybeInterval:
    if a[0] <= 0.0:
        return None
    return _monotone(math.log, a)


def exp(a: Interval) -> MaybeInterval:
    r = _monotone(math.exp, a)
    return None if r is None else (max(r[0], 0.0), r[1])


def asin(a: Interval) -> MaybeInterval:
    if a[0] < -1.0 or a[1] > 1.0:
        return None
    return _clamp(_monotone(math.asin, a), -_HALF_PI - 1e-15, _HALF_PI + 1e-15)


def acos(a: Interval) -> MaybeInterval:
    if a[0] < -1.0 or a[1] > 1.0:
        return None
    return _clamp(_monotone(math.acos, a, increasing=False), 0.0, _PI + 1e-15)


def atan(a: Interval) -> MaybeInterval:
    return _clamp(_monotone(math.atan, a), -_HALF_PI - 1e-15, _HALF_PI + 1e-15)


def fabs(a: Interval) -> MaybeInterval:
    if a[0] >= 0.0:
        return a
    if a[1] <= 0.0:
        return -a[1], -a[0]
    return 0.0, max(-a[0], a[1])


def _contains(a: Interval, offset: float, period: float) -> bool:
    """Whether [lo, hi] (slightly enlarged, to stay sound) contains offset + k * period for some integer k."""
    slack = 1e-9 * (1.0 + max(abs(a[0]), abs(a[1])))
    k = math.ceil((a[0] - slack - offset) / period)
    return offset + k * period <= a[1] + slack


def _periodic(fn: Callable[[float], float], a: Interval, peak: float) -> MaybeInterval:
    """sin or cos: `peak` is where fn has its maximum 1 (its minimum -1 lies half a period further)."""
    if a[1] - a[0] >= 2 * _PI or max(abs(a[0]), abs(a[1])) > _TRIG_LIMIT:
        return -1.0, 1.0
    values = (fn(a[0]), fn(a[1]))
    r = widen(min(values), max(values), 4)
    if r is None:
        return -1.0, 1.0
    lo, hi = r
    if _contains(a, peak, 2 * _PI):
        hi = 1.0
    if _contains(a, peak + _PI, 2 * _PI):
        lo = -1.0
    return max(lo, -1.0), min(hi, 1.0)


def sin(a: Interval) -> MaybeInterval:
    return _periodic(math.sin, a, _HALF_PI)


def cos(a: Interval) -> MaybeInterval:
    return _periodic(math.cos, a, 0.0)


def tan(a: Interval) -> MaybeInterval:
    if a[1] - a[0] >= _PI or max(abs(a[0]), abs(a[1])) > _TRIG_LIMIT:
        return None
    if _contains(a, _HALF_PI, _PI):
        return None
    return _monotone(math.tan, a)


_FUNCTIONS: dict[str, Callable[[Interval], MaybeInterval]] = {
    "sin": sin, "cos": cos, "tan": tan, "asin": asin, "acos": acos, "atan": atan,
    "sqrt": sqrt, "exp": exp, "log": log, "abs": fabs,
}
_OPS: dict[str, Callable[[Interval, Interval], MaybeInterval]] = {
    "+": add, "-": sub, "*": mul, "/": div, "**": general_power,
}


def bound(e: Expr, lo: float, hi: float) -> MaybeInterval:
    """An enclosure of e over [lo, hi] (the ends in either order), or None (see the module docstring)."""
    lo, hi = float(lo), float(hi)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return None
    return _bound(e, (min(lo, hi), max(lo, hi)))


def _bound(e: Expr, x: Interval) -> MaybeInterval:
    if isinstance(e, Num):
        return e.value, e.value
    if isinstance(e, Var):
        return x
    if isinstance(e, Neg):
        a = _bound(e.arg, x)
        return None if a is None else neg(a)
    if isinstance(e, Call):
        a = _bound(e.arg, x)
        return None if a is None else _FUNCTIONS[e.fn](a)
    assert isinstance(e, Binary)
    a = _bound(e.left, x)
    if a is None:
        return None
    if e.op == "**" and not e.right.has_x:  # a constant exponent: integer powers of negative bases are fine
        p = float(e.right.evaluate(np.zeros(())))
        return power(a, p) if math.isfinite(p) else None
    b = _bound(e.right, x)
    return None if b is None else _OPS[e.op](a, b)


# ---- symbolic derivative, with constructors that simplify trivially ----

ZERO, ONE, TWO = Num(0.0), Num(1.0), Num(2.0)


def derivative(e: Expr) -> Expr:
    """d/dx of e."""
    if isinstance(e, Num):
        return ZERO
    if isinstance(e, Var):
        return ONE
    if isinstance(e, Neg):
        return make_neg(derivative(e.arg))
    if isinstance(e, Call):
        return make_mul(_outer(e), derivative(e.arg))
    assert isinstance(e, Binary)
    u, v = e.left, e.right
    du, dv = derivative(u), derivative(v)
    if e.op == "+":
        return make_add(du, dv)
    if e.op == "-":
        return make_sub(du, dv)
    if e.op == "*":
        return make_add(make_mul(du, v), make_mul(u, dv))
    if e.op == "/":
        return make_div(make_sub(make_mul(du, v), make_mul(u, dv)), make_pow(v, TWO))
    if not v.has_x:  # u ** c
        return make_mul(make_mul(v, make_pow(u, make_sub(v, ONE))), du)
    # u ** v = exp(v log u): (u ** v) * (v' log u + v u' / u)
    return make_mul(e, make_add(make_mul(dv, make_call("log", u)), make_div(make_mul(v, du), u)))


def _outer(e: Call) -> Expr:
    """f'(u) for e = f(u)."""
    u = e.arg
    if e.fn == "sin":
        return make_call("cos", u)
    if e.fn == "cos":
        return make_neg(make_call("sin", u))
    if e.fn == "tan":
        return make_div(ONE, make_pow(make_call("cos", u), TWO))
    if e.fn in ("asin", "acos"):
        d = make_div(ONE, make_call("sqrt", make_sub(ONE, make_pow(u, TWO))))
        return d if e.fn == "asin" else make_neg(d)
    if e.fn == "atan":
        return make_div(ONE, make_add(ONE, make_pow(u, TWO)))
    if e.fn == "sqrt":
        return make_div(ONE, make_mul(TWO, e))
    if e.fn == "exp":
        return e
    if e.fn == "log":
        return make_div(ONE, u)
    return make_div(u, e)  # abs: sign(u), undefined at 0


def _is(e: Expr, value: float) -> bool:
    return isinstance(e, Num) and e.value == value


def _plain(e: Expr) -> float | None:
    """The value of a literal number, possibly signed (named constants stay symbolic)."""
    if isinstance(e, Num) and not e.name:
        return e.value
    if isinstance(e, Neg):
        v = _plain(e.arg)
        return None if v is None else -v
    return None


def _fold(op: str, a: Expr, b: Expr) -> Expr:
    va, vb = _plain(a), _plain(b)
    if va is not None and vb is not None:
        with np.errstate(all="ignore"):
            r = float(BINARY[op](np.float64(va), np.float64(vb)))
        if math.isfinite(r):
            return Num(r)
    return Binary(op, a, b)


def make_neg(a: Expr) -> Expr:
    if isinstance(a, Neg):
        return a.arg
    if isinstance(a, Num) and not a.name:
        return Num(-a.value)
    return Neg(a)


def make_add(a: Expr, b: Expr) -> Expr:
    if _is(a, 0.0):
        return b
    if _is(b, 0.0):
        return a
    if isinstance(b, Neg):
        return make_sub(a, b.arg)
    return _fold("+", a, b)


def make_sub(a: Expr, b: Expr) -> Expr:
    if _is(b, 0.0):
        return a
    if _is(a, 0.0):
        return make_neg(b)
    return _fold("-", a, b)


def make_mul(a: Expr, b: Expr) -> Expr:
    if _is(a, 0.0) or _is(b, 0.0):
        return ZERO
    if _is(a, 1.0):
        return b
    if _is(b, 1.0):
        return a
    if _is(a, -1.0):
        return make_neg(b)
    if _is(b, -1.0):
        return make_neg(a)
    return _fold("*", a, b)


def make_div(a: Expr, b: Expr) -> Expr:
    if _is(b, 1.0):
        return a
    if _is(a, 0.0):
        return ZERO
    return _fold("/", a, b)


def make_pow(a: Expr, b: Expr) -> Expr:
    if _is(b, 1.0):
        return a
    if _is(b, 0.0):
        return ONE
    return _fold("**", a, b)


def make_call(fn: str, a: Expr) -> Expr:
    if isinstance(a, Num):
        with np.errstate(all="ignore"):
            r = float(NUMPY[fn](np.float64(a.value)))
        if math.isfinite(r):
            return Num(r)
    return Call(fn, a)

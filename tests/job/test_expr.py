"""The expression language of the `function` shape: parsing, evaluation, derivatives, bounds, errors."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from codegen.job.calculus import bound, derivative
from codegen.job.expr import Expr, ExprError, parse

X = np.linspace(-3.0, 3.0, 61)


@pytest.mark.parametrize("text, expected", [
    ("2 + 3 * 4", 14.0),
    ("(2 + 3) * 4", 20.0),
    ("2 * 3 + 4", 10.0),
    ("10 - 4 - 3", 3.0),  # left-associative
    ("64 / 4 / 2", 8.0),
    ("2 ** 3 ** 2", 512.0),  # right-associative
    ("(2 ** 3) ** 2", 64.0),
    ("-2 ** 2", -4.0),  # ** binds tighter than unary minus
    ("(-2) ** 2", 4.0),
    ("2 ** -1", 0.5),  # a signed exponent
    ("2 ** -1 ** 2", 0.5),  # 2 ** (-(1 ** 2))
    ("--3", 3.0),
    ("+-+3", -3.0),
    ("-3 * -2", 6.0),
    (".5 + 2.5e1 + 1E-3 + 2.", 27.501),
    ("pi", math.pi),
    ("e", math.e),
    ("e ** 2", math.e ** 2),
    ("2 * pi / 4", math.pi / 2),
    ("3 - -2", 5.0),
    ("1 / 4 * 2", 0.5),
])
def test_precedence_and_associativity(text, expected):
    assert float(parse(text).evaluate(0.0)) == pytest.approx(expected, rel=1e-15)


@pytest.mark.parametrize("text, reference", [
    ("-x**2", lambda x: -(x ** 2)),
    ("x**2**-1", lambda x: x ** (2 ** -1)),
    ("1 - x + x**3/6", lambda x: 1 - x + x ** 3 / 6),
    ("x*x - 2*x/3", lambda x: x * x - 2 * x / 3),
    ("-(x - 1)*(x + 1)", lambda x: -(x - 1) * (x + 1)),
])
def test_evaluate_in_x(text, reference):
    x = np.abs(X) + 0.1
    np.testing.assert_allclose(parse(text).evaluate(x), reference(x), rtol=1e-14)


@pytest.mark.parametrize("fn, reference, x", [
    ("sin", np.sin, X), ("cos", np.cos, X), ("tan", np.tan, X), ("atan", np.arctan, X),
    ("asin", np.arcsin, np.linspace(-1, 1, 41)), ("acos", np.arccos, np.linspace(-1, 1, 41)),
    ("sqrt", np.sqrt, np.linspace(0, 9, 41)), ("exp", np.exp, X), ("log", np.log, np.linspace(0.1, 9, 41)),
    ("abs", np.abs, X),
])
def test_every_function(fn, reference, x):
    np.testing.assert_array_equal(parse(f"{fn}(x)").evaluate(x), reference(x))
    np.testing.assert_allclose(parse(f"2*{fn}(x/2 + x/2)").evaluate(x), 2 * reference(x), rtol=1e-14)


def test_evaluate_keeps_the_shape_and_gives_nan_where_undefined():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        y = parse("sqrt(x) + log(x) + 1/x").evaluate(np.array([[-1.0, 0.0], [1.0, 4.0]]))
    assert y.shape == (2, 2) and np.isnan(y[0, 0]) and not np.isfinite(y[0, 1])
    assert y[1, 0] == 2.0 and y[1, 1] == pytest.approx(2 + math.log(4) + 0.25)
    assert parse("3").evaluate(np.zeros(5)).tolist() == [3.0] * 5
    assert np.isnan(parse("asin(x)").evaluate(np.array([2.0]))).all()


@pytest.mark.parametrize("text", [
    "-x**2", "2**3**2", "(2**3)**2", "(-x)**2", "(x + 1)*(x - 1)", "x - (x - 1)", "x/(2*x)", "2**-x",
    "-(x*2)", "sin(x)**2 + cos(-x)", "e**-x", "x - -x", "1e-05*x", "2*pi*x",
])
def test_str_is_readable_and_parses_back(text):
    e = parse(text)
    assert str(e) == text
    assert parse(str(e)) == e


def test_str_adds_spaces_and_drops_redundant_parentheses():
    assert str(parse("((x))+(2*x)")) == "x + 2*x"
    assert str(parse("sin( x )*  3")) == "sin(x)*3"


# ---- derivative ----

DERIVATIVE_CASES = [
    ("x**3 - 2*x + 1", (-3, 3)),
    ("sin(3*x)*cos(x)", (-3, 3)),
    ("exp(-x**2/2)", (-3, 3)),
    ("tan(x/2)", (-2, 2)),
    ("asin(x/2) + acos(x/3)", (-1.5, 1.5)),
    ("atan(x**2)", (-3, 3)),
    ("sqrt(x + 4)", (-3, 3)),
    ("log(x + 4)/x", (0.5, 3)),
    ("abs(x - 0.01)", (0.5, 3)),
    ("x**x", (0.5, 3)),
    ("2**x + x**-2", (0.5, 3)),
    ("(x + 5)**0.5 * e**x", (-3, 3)),
    ("1/(1 + x**2)", (-3, 3)),
]


@pytest.mark.parametrize("text, span", DERIVATIVE_CASES)
def test_derivative_matches_finite_differences(text, span):
    f = parse(text)
    x = np.linspace(*span, 25)
    for order, h, tol in ((1, 1e-6, 1e-6), (2, 1e-4, 1e-5)):
        d = f
        for _ in range(order):
            d = derivative(d)
        if order == 1:
            numeric = (f.evaluate(x + h) - f.evaluate(x - h)) / (2 * h)
        else:
            numeric = (f.evaluate(x + h) - 2 * f.evaluate(x) + f.evaluate(x - h)) / h ** 2
        np.testing.assert_allclose(d.evaluate(x), numeric, rtol=tol, atol=tol)
        assert parse(str(d)).evaluate(x) == pytest.approx(d.evaluate(x), rel=1e-12)  # still the language


@pytest.mark.parametrize("text, expected", [
    ("7", "0"), ("x", "1"), ("3*x", "3"), ("x*3 + 0", "3"), ("x**2", "2*x"), ("x**3", "3*x**2"),
    ("sin(x)", "cos(x)"), ("cos(x)", "-sin(x)"), ("exp(x)", "exp(x)"), ("log(x)", "1/x"), ("-x", "-1"),
    ("x + pi", "1"), ("2*x - x/4", "1.75"), ("x**2 + 2*x", "2*x + 2"), ("e**x", "e**x"),
    ("2**x", "2**x*0.6931471805599453"),
])
def test_derivative_is_simplified(text, expected):
    assert str(derivative(parse(text))) == expected


# ---- bound ----

BOUND_CASES = [
    ("x**2 - 3*x", -5, 5), ("sin(x)*cos(2*x) + x/3", -10, 10), ("exp(x/3) - log(x + 20)", -10, 10),
    ("tan(x/3)", -4, 4), ("sqrt(x + 11)", -10, 10), ("1/(x**2 + 1)", -10, 10), ("abs(x - 1)**3", -5, 5),
    ("asin(x/11) + acos(x/12)", -10, 10), ("atan(5*x)", -10, 10), ("x**3 - x**-2", 0.2, 5),
    ("(x + 11)**x", -10, 3), ("2**-x**2", -5, 5), ("-x**4 + e**(x/4)*pi", -6, 6), ("x/(x + 20)", -10, 10),
]


@pytest.mark.parametrize("text, lo, hi", BOUND_CASES)
def test_bound_contains_sampled_values_on_random_intervals(text, lo, hi):
    rng = np.random.default_rng(abs(hash(text)) % 2**32)
    exprs = [parse(text), derivative(parse(text)), derivative(derivative(parse(text)))]
    for _ in range(40):
        a, b = np.sort(rng.uniform(lo, hi, 2))
        if rng.random() < 0.2:
            b = a + 1e-9 * rng.random()  # narrow intervals, where rounding matters most
        xs = np.concatenate([[a, b], np.linspace(a, b, 201), rng.uniform(a, b, 200)])
        for e in exprs:
            enclosure = bound(e, a, b)
            if e is exprs[0]:
                assert enclosure is not None, (text, a, b)
            if enclosure is None:
                continue
            y = e.evaluate(xs)
            assert np.all(np.isfinite(y)), (str(e), a, b)
            assert enclosure[0] <= y.min() and y.max() <= enclosure[1], (str(e), a, b, enclosure)


def test_bound_is_reasonably_tight():
    lo, hi = bound(parse("x**2"), -1, 2)
    assert lo == pytest.approx(0.0, abs=1e-300) and lo <= 0.0 and hi == pytest.approx(4.0) and hi >= 4.0
    lo, hi = bound(parse("sin(x)"), 0, math.pi)
    assert lo <= 0.0 and lo == pytest.approx(0.0, abs=1e-12) and hi == 1.0
    assert bound(parse("cos(x)"), -0.1, 7) == (-1.0, 1.0)
    lo, hi = bound(parse("3"), 5, 1)  # the ends in either order
    assert lo <= 3.0 <= hi


@pytest.mark.parametrize("text, lo, hi", [
    ("sqrt(x)", -1, 1), ("log(x)", 0, 1), ("log(x)", -2, -1), ("1/x", -1, 1), ("1/(x - 1)", 0, 2),
    ("asin(x)", 0, 1.5), ("acos(x)", -1.01, 0), ("tan(x)", 1, 2), ("tan(x)", 0, 4), ("exp(x)", 0, 1000),
    ("x**0.5", -1, 1), ("(x - 3)**x", 0, 1), ("x**-1", -1, 1), ("10**x", 0, 400), ("x**x", 0, 1),
    ("sqrt(sin(x))", 3, 4), ("1/abs(x)", -1, 1), ("x", 0, math.inf), ("x", math.nan, 1),
])
def test_bound_is_none_where_f_may_be_undefined(text, lo, hi):
    assert bound(parse(text), lo, hi) is None


def test_bound_of_integer_powers_of_negative_numbers():
    lo, hi = bound(parse("x**3"), -2, -1)
    assert lo <= -8 and hi >= -1 and lo == pytest.approx(-8) and hi == pytest.approx(-1)
    assert bound(parse("x**-2"), -2, -1) is not None
    assert bound(derivative(parse("abs(x)")), -1, 1) is None  # |x| has no derivative at 0


# ---- errors ----

@pytest.mark.parametrize("text, message, offset", [
    ("sinn(x)", "unknown name 'sinn' (did you mean 'sin'?)", 0),
    ("2*y", "unknown name 'y'", 2),
    ("Sin(x)", "unknown name 'Sin' (did you mean 'sin'?)", 0),
    ("x $ 2", "unexpected character '$'", 2),
    ("x + 2;", "unexpected character ';'", 5),
    ("sin(x", "missing ')'", 5),
    ("(x + (1)", "missing ')'", 8),
    ("(x 1)", "unexpected '1' (missing operator?)", 3),
    ("x 2", "unexpected '2' (missing operator?)", 2),
    ("2x", "unexpected 'x' (missing operator?)", 1),
    ("x)", "unexpected ')'", 1),
    ("sin x", "expected '(' after 'sin'", 4),
    ("sqrt", "expected '(' after 'sqrt'", 4),
    ("sin(x, 2)", "'sin' takes exactly one argument", 5),
    ("log()", "'log' takes exactly one argument", 4),
    ("x(2)", "'x' is not a function", 1),
    ("pi (2)", "'pi' is not a function", 3),
    ("", "empty expression", 0),
    ("   ", "empty expression", 3),
    ("x +", "expected an expression", 3),
    ("* x", "expected an expression, found '*'", 0),
    ("x ** * 2", "expected an expression, found '*'", 5),
    ("1e999", "number 1e999 is out of range", 0),
    ("2e", "unexpected 'e' (missing operator?)", 1),
    ("x ^ 2", "unexpected character '^'", 2),
    ("x, 1", "unexpected ','", 1),
    ("__import__('os')", "unknown name '__import__'", 0),
    ("x y $", "unexpected 'y' (missing operator?)", 2),  # the first problem in the text
])
def test_errors_point_at_the_offending_offset(text, message, offset):
    with pytest.raises(ExprError) as info:
        parse(text)
    assert (info.value.message, info.value.offset) == (message, offset)
    assert isinstance(info.value, ValueError) and str(info.value) == message


def test_too_deep_or_too_long_is_an_error_not_a_crash():
    with pytest.raises(ExprError, match="nested too deeply"):
        parse("(" * 500 + "x" + ")" * 500)
    with pytest.raises(ExprError, match="too long"):
        parse("+".join(["x"] * 1000))
    assert isinstance(parse("-" * 50 + "x"), Expr)

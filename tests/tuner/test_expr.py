"""The whitelisted expression parser: results checked by hand, hostile input rejected cleanly."""

from __future__ import annotations

import builtins

import numpy as np
import pytest
from numpy.testing import assert_allclose

from tuner.errors import InvalidExpressionError, TunerError
from tuner.expr import MAX_DEPTH, MAX_EXPR_LENGTH, parse_tf_expr

# -- what it computes ----------------------------------------------------------------------

@pytest.mark.parametrize(
    "text, num, den, var",
    [
        # 0.2843*18.611 = 5.2911073
        ("0.2843*18.611/(s+18.611)", [5.2911073], [1, 18.611], "s"),
        # (s+1)(s+2) = s^2 + 3s + 2, implicit multiplication between brackets
        ("(s+1)(s+2)", [1, 3, 2], [1], "s"),
        ("2s", [2, 0], [1], "s"),
        ("3(s+1)", [3, 3], [1], "s"),
        ("2s(s+1)", [2, 2, 0], [1], "s"),
        ("s**2+1", [1, 0, 1], [1], "s"),
        ("s ^ 2 + 1", [1, 0, 1], [1], "s"),
        # denominator made monic: 1/(2s+4) = 0.5/(s+2)
        ("1/(2s+4)", [0.5], [1, 2], "s"),
        # 14.8528^2 = 220.60566784
        ("14.8528^2/(s^2+14.195*s+14.8528^2)", [220.60566784], [1, 14.195, 220.60566784], "s"),
        # K(z^2 + a1 z + a2)/(z(z-1)): 3.868*-1.305 = -5.04774, 3.868*0.5668 = 2.1923824
        ("3.868*(z^2-1.305*z+0.5668)/(z*(z-1))", [3.868, -5.04774, 2.1923824], [1, -1, 0], "z"),
        # 5 + 2/(z-1) = (5z - 3)/(z - 1)
        ("5+2/(z-1)", [5, -3], [1, -1], "z"),
        ("(s+1)^0", [1], [1], "s"),
        ("1e-3*s", [1e-3, 0], [1], "s"),
        (".5/(s+.25)", [0.5], [1, 0.25], "s"),
        ("-s+1", [-1, 1], [1], "s"),
        ("s--1", [1, 1], [1], "s"),  # s - (-1)
        ("s*-1", [-1, 0], [1], "s"),
        ("((((s))))", [1, 0], [1], "s"),
        ("1/(s+1)\n", [1], [1, 1], "s"),
        ("7", [7], [1], None),
        ("(s^2-1)/(s-1)", [1, 0, -1], [1, -1], "s"),  # no silent cancellation
    ],
)
def test_parses_to_hand_computed_coefficients(text, num, den, var):
    p = parse_tf_expr(text)
    assert p.var == var
    assert_allclose(p.num, num, rtol=1e-12, atol=1e-15)
    assert_allclose(p.den, den, rtol=1e-12, atol=1e-15)


def test_ratio_of_ratios_matches_direct_evaluation():
    # evaluate the same expression by hand at a few complex points and compare with num/den
    text = "(2s+1)/(s^2+3s+5) - 4/(s+2) + (s+3)^2/((s+1)(s+4)(s+7))"

    def direct(s):
        return (2 * s + 1) / (s**2 + 3 * s + 5) - 4 / (s + 2) + (s + 3) ** 2 / ((s + 1) * (s + 4) * (s + 7))

    p = parse_tf_expr(text)
    for s in (0.3 + 1.1j, -0.7 + 2j, 5.0, 1j * 40):
        assert np.polyval(p.num, s) / np.polyval(p.den, s) == pytest.approx(direct(s), rel=1e-12)


def test_never_evaluates_python(monkeypatch):
    """Parsing must not go through eval/exec: make them explode and parse anyway."""

    def boom(*a, **k):  # pragma: no cover - reaching it is the failure
        raise AssertionError("eval/exec called by the parser")

    monkeypatch.setattr(builtins, "eval", boom)
    monkeypatch.setattr(builtins, "exec", boom)
    p = parse_tf_expr("3.868*(z^2-1.305*z+0.5668)/(z*(z-1))")
    assert p.var == "z"
    with pytest.raises(InvalidExpressionError):
        parse_tf_expr("__import__('os').system('true')")


def test_error_classes_are_value_errors():
    assert issubclass(InvalidExpressionError, ValueError)
    assert issubclass(InvalidExpressionError, TunerError)


# -- syntax errors name the position -------------------------------------------------------

@pytest.mark.parametrize(
    "text, words, pos",
    [
        ("s+*2", "unexpected '*'", 2),
        ("(s+1", "missing ')'", 4),
        ("s+1)", "unexpected ')'", 3),
        ("s(", "unexpected end", 2),
        ("()", "unexpected ')'", 1),
        ("2 3", "unexpected '3'", 2),
        ("s/0", "division by zero", 1),
        ("1/(s-s)", "division by zero", 1),
        ("s^-1", "non-negative integer", 2),
        ("s^0.5", "non-negative integer", 2),
        ("s^s", "non-negative integer", 2),
        ("s^2^2", "chained powers", 3),
        ("1.2.3", "unexpected", 3),
        ("s+1e", "unknown name 'e'", 3),
        ("0x10", "unknown name 'x10'", 1),
        ("s.__class__", "unexpected character '.'", 1),
        ("s/(z+1)", "mixes 's' and 'z'", 3),
        ("", "empty expression", 0),
        ("   ", "empty expression", 0),
    ],
)
def test_syntax_errors_name_problem_and_position(text, words, pos):
    with pytest.raises(InvalidExpressionError) as ei:
        parse_tf_expr(text)
    assert words in str(ei.value)
    assert ei.value.position == pos
    assert f"position {pos}" in str(ei.value)


# -- hostile input -------------------------------------------------------------------------

HOSTILE = [
    ("__import__('os')", "unknown name '__import__'"),
    ("os.system('rm -rf /')", "unknown name 'os'"),
    ("lambda s: s", "unknown name 'lambda'"),
    ("s.__class__", "unexpected character '.'"),
    ("s^99999", "exponent 99999 is above the limit"),
    ("10^400", "exponent 400 is above the limit"),
    ("(10^40)^40", "overflows"),  # 1e1600: within the exponent limit, overflows to inf
    ("1e200*1e200*s", "overflows"),
    ("(1e300*s+1)^2", "overflows"),
    ("1e999", "not finite"),
    ("(" * 10_000 + "s" + ")" * 10_000, "longer than"),
    ("(" * (MAX_DEPTH + 1) + "s" + ")" * (MAX_DEPTH + 1), "nesting deeper than"),
    ("(" * 900 + "s" + ")" * 900, "nesting deeper than"),
    ("-" * 1500 + "s", "nesting deeper than"),
    ("s" * 1_000_000, "longer than"),
    ("1/(s+1)" + " " * 1_000_000, "longer than"),
    ("\u017f+1", "unexpected character"),  # long s
    ("\uff11+s", "unexpected character"),  # fullwidth digit one
    ("\u0661\u0662+s", "unexpected character"),  # Arabic-Indic digits: not ASCII numbers
    ("s\u00a0+1", "unexpected character"),  # no-break space
    ("\x00", "unexpected character"),
    ("s\u202e+1", "unexpected character"),  # right-to-left override
    ("\U0001f600", "unexpected character"),
    ("1_000", "unknown name '_000'"),
    ("s; import os", "unexpected character ';'"),
    ("[s]", "unexpected character '['"),
    ("s if 1 else 2", "unknown name 'if'"),
]


@pytest.mark.parametrize("text, words", HOSTILE, ids=[repr(t[:20]) for t, _ in HOSTILE])
def test_hostile_expressions_raise_the_library_error(text, words):
    with pytest.raises(InvalidExpressionError) as ei:
        parse_tf_expr(text)
    assert words in str(ei.value)
    assert "\n" not in str(ei.value)


def test_deep_nesting_is_not_a_recursion_error():
    # the longest nesting that fits in the length limit still stops at MAX_DEPTH, not RecursionError
    k = (MAX_EXPR_LENGTH - 1) // 2
    with pytest.raises(InvalidExpressionError, match="nesting"):
        parse_tf_expr("(" * k + "s" + ")" * k)
    # and nesting up to the limit is fine
    assert parse_tf_expr("(" * MAX_DEPTH + "s" + ")" * MAX_DEPTH).var == "s"


def test_length_limit_is_the_documented_one():
    ok = "s" + "+0" * ((MAX_EXPR_LENGTH - 1) // 2)
    assert len(ok) <= MAX_EXPR_LENGTH
    assert_allclose(parse_tf_expr(ok).num, [1, 0])
    with pytest.raises(InvalidExpressionError, match="longer than"):
        parse_tf_expr(ok + "+0")


@pytest.mark.parametrize("bad", [None, 3.0, b"s+1", ["s"]])
def test_non_string_rejected(bad):
    with pytest.raises(InvalidExpressionError, match="string"):
        parse_tf_expr(bad)

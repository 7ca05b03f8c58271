"""Whitelisted parser for transfer-function expressions.

Accepted: numbers (``12``, ``0.5``, ``1e-3``), one variable ``s`` or ``z``,
``+ - * /``, powers ``^`` or ``**`` with a non-negative integer exponent,
parentheses, and implicit multiplication before a variable or ``(``
(``2s``, ``(s+1)(s+2)``). Nothing is ever handed to ``eval``/``exec``/``sympify``:
the text is tokenised by a regular expression and evaluated by a small
recursive-descent parser into a ratio of numpy polynomials.

>>> parse_tf_expr("0.2843*18.611/(s+18.611)").var
's'
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .errors import InvalidExpressionError

__all__ = ["ParsedTF", "parse_tf_expr", "MAX_EXPR_LENGTH", "MAX_DEPTH", "MAX_EXPONENT"]

MAX_EXPR_LENGTH = 2000
MAX_DEPTH = 40
MAX_EXPONENT = 40
MAX_DEGREE = 80

# ASCII only: without re.ASCII, \d and \s also match other scripts' digits ("١٢", "１") and
# spaces, and float()/int() would accept those digits: not the documented whitelist
_TOKEN = re.compile(
    r"\s*(?:(?P<num>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)|(?P<op>\*\*|[-+*/^()])|(?P<name>[A-Za-z_][A-Za-z_0-9]*))",
    re.ASCII,
)
_SPACE = re.compile(r"\s*", re.ASCII)


@dataclass(frozen=True)
class ParsedTF:
    """Numerator and denominator coefficients (highest power first) and the variable."""

    num: np.ndarray
    den: np.ndarray
    var: str | None  # None for a constant expression


@dataclass(frozen=True)
class _Tok:
    kind: str  # "num", "op", "var", "end"
    text: str
    pos: int


def _tokenise(text: str) -> list[_Tok]:
    toks: list[_Tok] = []
    pos = 0
    n = len(text)
    while pos < n:
        pos = _SPACE.match(text, pos).end()
        if pos == n:
            break
        m = _TOKEN.match(text, pos)
        if m is None or m.end() == pos:
            raise InvalidExpressionError(f"unexpected character {text[pos]!r}", position=pos)
        start = m.start(m.lastgroup)
        if m.lastgroup == "name":
            name = m.group("name")
            if name not in ("s", "z"):
                raise InvalidExpressionError(
                    f"unknown name {name!r}: only the variable 's' or 'z' is allowed", position=start
                )
            toks.append(_Tok("var", name, start))
        else:
            toks.append(_Tok(m.lastgroup, m.group(m.lastgroup), start))
        pos = m.end()
    toks.append(_Tok("end", "", n))
    return toks


def _trim(p: np.ndarray) -> np.ndarray:
    nz = np.flatnonzero(p)
    return p[nz[0]:] if nz.size else np.zeros(1)


class _Rat:
    """A ratio of polynomials in the single variable."""

    __slots__ = ("num", "den")

    def __init__(self, num: np.ndarray, den: np.ndarray) -> None:
        self.num = _trim(np.asarray(num, dtype=float))
        self.den = _trim(np.asarray(den, dtype=float))

    def degree(self) -> int:
        return max(self.num.size, self.den.size) - 1


class _Parser:
    def __init__(self, text: str) -> None:
        self.toks = _tokenise(text)
        self.i = 0
        self.var: str | None = None
        self.depth = 0

    # -- helpers -----------------------------------------------------------
    @property
    def tok(self) -> _Tok:
        return self.toks[self.i]

    def _eat(self) -> _Tok:
        t = self.toks[self.i]
        self.i += 1
        return t

    def _check(self, r: _Rat, pos: int) -> _Rat:
        if r.degree() > MAX_DEGREE:
            raise InvalidExpressionError(f"polynomial degree above {MAX_DEGREE}", position=pos)
        if not (np.all(np.isfinite(r.num)) and np.all(np.isfinite(r.den))):
            raise InvalidExpressionError("a coefficient overflows to a non-finite value", position=pos)
        return r

    # -- grammar -----------------------------------------------------------
    def parse(self) -> _Rat:
        if self.tok.kind == "end":
            raise InvalidExpressionError("empty expression", position=0)
        r = self.expr()
        if self.tok.kind != "end":
            raise InvalidExpressionError(f"unexpected {self.tok.text!r}", position=self.tok.pos)
        return r

    def expr(self) -> _Rat:
        r = self.term()
        while self.tok.kind == "op" and self.tok.text in "+-":
            t = self._eat()
            rhs = self.term()
            if t.text == "-":
                rhs = _Rat(-rhs.num, rhs.den)
            r = self._check(_add(r, rhs), t.pos)
        return r

    def term(self) -> _Rat:
        r = self.unary()
        while True:
            t = self.tok
            if t.kind == "op" and t.text in ("*", "/"):
                self._eat()
                rhs = self.unary()
                if t.text == "*":
                    r = _Rat(np.polymul(r.num, rhs.num), np.polymul(r.den, rhs.den))
                else:
                    if not np.any(rhs.num):
                        raise InvalidExpressionError("division by zero", position=t.pos)
                    r = _Rat(np.polymul(r.num, rhs.den), np.polymul(r.den, rhs.num))
                r = self._check(r, t.pos)
            elif t.kind == "var" or (t.kind == "op" and t.text == "("):
                # implicit multiplication: 2s, (s+1)(s+2), 3(s+1)
                rhs = self.power()
                r = self._check(_Rat(np.polymul(r.num, rhs.num), np.polymul(r.den, rhs.den)), t.pos)
            else:
                return r

    def unary(self) -> _Rat:
        t = self.tok
        if t.kind == "op" and t.text in "+-":
            self._eat()
            self._enter(t.pos)
            r = self.unary()
            self.depth -= 1
            return _Rat(-r.num, r.den) if t.text == "-" else r
        return self.power()

    def power(self) -> _Rat:
        base = self.atom()
        t = self.tok
        if t.kind == "op" and t.text in ("^", "**"):
            self._eat()
            e = self.tok
            if e.kind != "num" or not re.fullmatch(r"[0-9]+", e.text):
                raise InvalidExpressionError(
                    "an exponent must be a non-negative integer literal", position=e.pos
                )
            self._eat()
            k = int(e.text)
            if k > MAX_EXPONENT:
                raise InvalidExpressionError(f"exponent {k} is above the limit {MAX_EXPONENT}", position=e.pos)
            nxt = self.tok
            if nxt.kind == "op" and nxt.text in ("^", "**"):
                raise InvalidExpressionError("chained powers are ambiguous; use parentheses", position=nxt.pos)
            if k == 0:
                return _Rat(np.ones(1), np.ones(1))
            num, den = np.ones(1), np.ones(1)
            for _ in range(k):
                num, den = np.polymul(num, base.num), np.polymul(den, base.den)
                self._check(_Rat(num, den), e.pos)
            return _Rat(num, den)
        return base

    def _enter(self, pos: int) -> None:
        self.depth += 1
        if self.depth > MAX_DEPTH:
            raise InvalidExpressionError(f"nesting deeper than {MAX_DEPTH}", position=pos)

    def atom(self) -> _Rat:
        t = self._eat()
        if t.kind == "num":
            v = float(t.text)
            if not np.isfinite(v):
                raise InvalidExpressionError(f"number {t.text!r} is not finite", position=t.pos)
            return _Rat(np.array([v]), np.ones(1))
        if t.kind == "var":
            if self.var is not None and self.var != t.text:
                raise InvalidExpressionError(
                    "mixes 's' and 'z': a transfer function is either continuous (s) or discrete (z)",
                    position=t.pos,
                )
            self.var = t.text
            return _Rat(np.array([1.0, 0.0]), np.ones(1))
        if t.kind == "op" and t.text == "(":
            self._enter(t.pos)
            r = self.expr()
            self.depth -= 1
            if self.tok.kind != "op" or self.tok.text != ")":
                raise InvalidExpressionError("missing ')'", position=self.tok.pos)
            self._eat()
            return r
        if t.kind == "end":
            raise InvalidExpressionError("unexpected end of expression", position=t.pos)
        raise InvalidExpressionError(f"unexpected {t.text!r}", position=t.pos)


def _add(a: _Rat, b: _Rat) -> _Rat:
    if a.den.shape == b.den.shape and np.array_equal(a.den, b.den):
        return _Rat(np.polyadd(a.num, b.num), a.den)
    return _Rat(
        np.polyadd(np.polymul(a.num, b.den), np.polymul(b.num, a.den)), np.polymul(a.den, b.den)
    )


def parse_tf_expr(text: str) -> ParsedTF:
    """Parse ``text`` into numerator/denominator coefficients.

    Raises :class:`~tuner.errors.InvalidExpressionError` naming the position of
    the first problem.
    """
    if not isinstance(text, str):
        raise InvalidExpressionError("expression must be a string")
    if len(text) > MAX_EXPR_LENGTH:
        raise InvalidExpressionError(f"expression longer than {MAX_EXPR_LENGTH} characters")
    p = _Parser(text)
    with np.errstate(over="ignore", invalid="ignore"):
        r = p.parse()
    if not np.any(r.den):
        raise InvalidExpressionError("denominator is zero")
    lead = r.den[0]
    return ParsedTF(num=r.num / lead, den=r.den / lead, var=p.var)

"""Whitelisted parser for transfer-function expressions.

Accepted: numbers (``12``, ``0.5``, ``1e-3``), one variable ``s`` or ``z``,
``+ - * /``, powers ``^`` or ``**`` with a non-negative integer exponent,
parentheses, and implicit multiplication before a variable or ``(``
(``2s``, ``(s+1)(s+2)``). Nothing is ever handed to ``eval``/``exec``/``sympify``:
the text is tokenised by a regular expression and evaluated by a small
recursive-descent parser into a ratio of numpy polynomials.

>>> from tuner.expr import parse_tf_expr
>>> parse_tf_expr("0.2843*18.611/(s+18.611)").var
's'
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .errors import InvalidExpressionError
from .lti import roots_of
from .lti import trim_or_zero as _trim  # (a factor: its leading zeros dropped, all-zero as [0.])

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
    """Numerator and denominator coefficients (highest power first, denominator monic), the variable,
    and the zeros, poles and gain found from the factors as written (each a small polynomial)."""

    num: np.ndarray
    den: np.ndarray
    var: str | None  # None for a constant expression
    zeros: np.ndarray
    poles: np.ndarray
    gain: float


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


def _prod(factors: tuple[np.ndarray, ...]) -> np.ndarray:
    out = np.ones(1)
    for f in factors:
        out = np.polymul(out, f)
    return out


class _Rat:
    """A ratio of products of polynomials in the single variable.

    The factors are kept as written (``(s+1)^8`` is eight factors ``s+1``) so that the roots of the
    result are the roots of small polynomials, not of one expanded high-degree one; a sum combines
    its terms into one numerator over the (still factored) common denominator.
    """

    __slots__ = ("nf", "df", "_num", "_den")

    def __init__(self, nf: tuple[np.ndarray, ...], df: tuple[np.ndarray, ...]) -> None:
        self.nf = tuple(_trim(np.asarray(f, dtype=float)) for f in nf)
        self.df = tuple(_trim(np.asarray(f, dtype=float)) for f in df)
        self._num: np.ndarray | None = None
        self._den: np.ndarray | None = None

    @classmethod
    def const(cls, c: float) -> _Rat:
        return cls((np.array([c]),), ())

    @property
    def num(self) -> np.ndarray:
        if self._num is None:
            self._num = _trim(_prod(self.nf))
        return self._num

    @property
    def den(self) -> np.ndarray:
        if self._den is None:
            self._den = _trim(_prod(self.df))
        return self._den

    def degree(self) -> int:
        return max(sum(f.size - 1 for f in self.nf), sum(f.size - 1 for f in self.df))

    def __mul__(self, other: _Rat) -> _Rat:
        return _Rat(self.nf + other.nf, self.df + other.df)

    def __truediv__(self, other: _Rat) -> _Rat:
        return _Rat(self.nf + other.df, self.df + other.nf)

    def __neg__(self) -> _Rat:
        return _Rat((np.array([-1.0]),) + self.nf, self.df)


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
                rhs = -rhs
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
                    r = r * rhs
                else:
                    if not np.any(rhs.num):
                        raise InvalidExpressionError("division by zero", position=t.pos)
                    r = r / rhs
                r = self._check(r, t.pos)
            elif t.kind == "var" or (t.kind == "op" and t.text == "("):
                # implicit multiplication: 2s, (s+1)(s+2), 3(s+1)
                rhs = self.power()
                r = self._check(r * rhs, t.pos)
            else:
                return r

    def unary(self) -> _Rat:
        t = self.tok
        if t.kind == "op" and t.text in "+-":
            self._eat()
            self._enter(t.pos)
            r = self.unary()
            self.depth -= 1
            return -r if t.text == "-" else r
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
                return _Rat.const(1.0)
            if base.degree() * k > MAX_DEGREE:
                raise InvalidExpressionError(f"polynomial degree above {MAX_DEGREE}", position=e.pos)
            return self._check(_Rat(base.nf * k, base.df * k), e.pos)
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
            return _Rat.const(v)
        if t.kind == "var":
            if self.var is not None and self.var != t.text:
                raise InvalidExpressionError(
                    "mixes 's' and 'z': a transfer function is either continuous (s) or discrete (z)",
                    position=t.pos,
                )
            self.var = t.text
            return _Rat((np.array([1.0, 0.0]),), ())
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
    """``a + b`` over a factored common denominator (shared factors are not repeated)."""
    rest_b = list(b.df)
    common: list[np.ndarray] = []
    only_a: list[np.ndarray] = []
    for f in a.df:
        j = next((j for j, g in enumerate(rest_b) if g.shape == f.shape and np.array_equal(g, f)), None)
        if j is None:
            only_a.append(f)
        else:
            common.append(rest_b.pop(j))
    num = np.polyadd(np.polymul(a.num, _prod(tuple(rest_b))), np.polymul(b.num, _prod(tuple(only_a))))
    return _Rat((num,), tuple(common + only_a + rest_b))


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
    with np.errstate(over="ignore", invalid="ignore"):
        gain = float(np.prod([f[0] for f in r.nf]) / np.prod([f[0] for f in r.df])) if r.df else \
            float(np.prod([f[0] for f in r.nf]))
    with np.errstate(over="ignore", invalid="ignore"):
        num, den = r.num / lead, r.den / lead
    if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))):
        raise InvalidExpressionError("coefficients overflow when the denominator is made monic (they span too many "
                                     "decades): rescale them")
    return ParsedTF(num=num, den=den, var=p.var, zeros=_roots(r.nf), poles=_roots(r.df), gain=gain)


def _roots(factors: tuple[np.ndarray, ...]) -> np.ndarray:
    """The roots of each factor; a factor whose roots cannot be computed in double precision (``1e-300*s + 1e300``:
    a root at -1e600; see :func:`~tuner.lti.roots_of`) is refused by name."""
    rs = [roots_of(f) for f in factors if f.size > 1 and np.any(f)]
    if any(r is None for r in rs):
        raise InvalidExpressionError("a factor's roots cannot be computed in double precision (its coefficients span "
                                     "too many decades): rescale it, or write it as a product of smaller factors")
    return np.concatenate(rs).astype(complex) if rs else np.zeros(0, complex)

"""The generated code's name: a C identifier (and a Python class name). Below :mod:`~tuner.export.codegen` and
:mod:`~tuner.export.twodof`, which both check it (no import cycle between them)."""

from __future__ import annotations

import keyword
import re

from ..errors import TunerError

__all__ = ["check_name", "MAX_NAME"]

_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*", re.ASCII)
_C_KEYWORDS = frozenset((
    "auto", "break", "case", "char", "const", "continue", "default", "do", "double", "else", "enum", "extern",
    "float", "for", "goto", "if", "inline", "int", "long", "register", "restrict", "return", "short", "signed",
    "sizeof", "static", "struct", "switch", "typedef", "union", "unsigned", "void", "volatile", "while", "_Bool",
    "_Complex", "_Imaginary",
))
MAX_NAME = 63  # significant characters of an internal identifier in C99


def check_name(name: str) -> str:
    """``name`` if it is usable as a C identifier (and a Python class name) for the generated code."""
    if not isinstance(name, str) or not _IDENT.fullmatch(name):
        raise TunerError(f"name must be a C identifier (a letter or _, then letters, digits, _), got {name!r}",
                         field="name")
    if len(name) > MAX_NAME - len("_update"):
        raise TunerError(f"name must be at most {MAX_NAME - len('_update')} characters (C99 identifiers with the "
                         f"suffix _update), got {len(name)}", field="name")
    if name in _C_KEYWORDS or keyword.iskeyword(name):
        raise TunerError(f"name {name!r} is a C or Python keyword: choose another",
                         field="name")
    if name.startswith("_"):  # C99 7.1.3: every identifier with a leading _ is reserved at file scope
        raise TunerError(f"name {name!r} is reserved in C (the generated N_state, N_init, N_update are file-scope "
                         "names, and those starting with _ belong to the implementation): start with a letter",
                         field="name")
    return name

"""Reading numbers, pairs and matrices out of parsed JSON with errors that name the field and
the bound (`objects[0].mass_kg: 1e+308 is outside (0, 100]`); every scene loader uses these.

A `Bound` is one rule for one number (its range, open or closed at each end, and whether it
must be an integer). A scenario declares its bounds once, as named constants next to their
reasons, and checks them both where a file is parsed (`number`) and where a scene built in
code or changed by values is validated (`Bound.check`), so one rule holds everywhere.
"""
from __future__ import annotations

import math
import re
import reprlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import SceneError

_SHOW_CHARS = 60   # a value shown in a message is cut to this many characters
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxtuple, _REPR.maxdict, _REPR.maxstring, _REPR.maxlong = 3, 6, 6, 4, 40, 24


def show(v: Any) -> str:
    """`v` for a one-line message: numbers as Python writes them (1e+308, 0.1), anything else
    as a short repr (a 1 MB list or a list nested 900 deep is not echoed back)."""
    if isinstance(v, (np.integer, np.floating)) and not isinstance(v, np.bool_):
        v = v.item()
    s = " ".join(_REPR.repr(v).split())
    return s if len(s) <= _SHOW_CHARS else s[:_SHOW_CHARS - 3] + "..."


def fmt(x: float) -> str:
    """A bound as written in a message: 0, 100, 0.001, 2e+06, inf."""
    return f"{x:g}"


def is_number(v: Any) -> bool:
    """A number (a JSON int or float, or NumPy's; not a bool; finite or not)."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def is_finite_number(v: Any) -> bool:
    if not is_number(v):
        return False
    if isinstance(v, (int, np.integer)):
        try:   # an integer of 400 digits is no float, and would overflow where one is made of it
            float(v)
        except OverflowError:
            return False
        return True
    return math.isfinite(v)


@dataclass(frozen=True)
class Bound:
    """Where a number may lie: [lo, hi], either end open; `integer` numbers must be whole
    (2.0 is 2, 2.5 is refused, never truncated)."""
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False

    def __str__(self) -> str:
        return f"{'(' if self.lo_open else '['}{fmt(self.lo)}, {fmt(self.hi)}{')' if self.hi_open else ']'}"

    def contains(self, v: float) -> bool:
        return (self.lo < v if self.lo_open else self.lo <= v) and (v < self.hi if self.hi_open else v <= self.hi)

    def check(self, v: Any, where: str) -> float | int:
        """`v` as a float (an int for an integer bound); SceneError naming `where` and the
        bound if it is no finite number, not whole where it must be, or outside."""
        if type(v) is not float and not is_number(v):
            raise SceneError(f"{where}: expected {'an integer' if self.integer else 'a number'}, got {show(v)}")
        whole = isinstance(v, (int, np.integer))
        if not whole and not math.isfinite(v):
            raise SceneError(f"{where}: expected a finite number, got {show(v)}")
        if self.integer and not whole and not float(v).is_integer():
            raise SceneError(f"{where}: expected an integer, got {show(v)}")
        if not self.contains(v):
            raise SceneError(f"{where}: {show(v)} is outside {self}")
        if self.integer:
            return int(v)
        try:
            return float(v)
        except OverflowError:   # an integer of 400 digits in an unbounded range
            raise SceneError(f"{where}: expected a finite number, got {show(v)}") from None


def field_value(d: dict, key: str, path: str, default: Any = ...) -> Any:
    if not isinstance(d, dict):
        raise SceneError(f"{path or 'the file'}: expected an object, got {show(d)}")
    if key not in d:
        if default is ...:
            raise SceneError(f"{path}.{key}: missing".lstrip("."))
        return default
    return d[key]


_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def where_of(path: str, key: Any) -> str:
    """The path of `key` in the object at `path`: objects[0].mass_kg, or priors[''] for a key
    that is no plain name."""
    if isinstance(key, str) and _NAME.match(key):
        return f"{path}.{key}".lstrip(".")
    return f"{path}[{show(key)}]"


def number(d: dict, key: str, path: str, default: Any = ..., lo: float = -math.inf, hi: float = math.inf,
           lo_open: bool = False, integer: bool = False, *, bound: Bound | None = None) -> float:
    """`d[key]` checked against `bound` (or the bound that lo, hi, lo_open, integer make)."""
    b = bound if bound is not None else Bound(lo, hi, lo_open=lo_open, integer=integer)
    return b.check(field_value(d, key, path, default), where_of(path, key))


def pair(d: dict, key: str, path: str, default: Any, integer: bool = False) -> tuple[float, float]:
    """[low, high] with low <= high, both finite numbers (whole numbers if `integer`)."""
    v = field_value(d, key, path, default)
    where = where_of(path, key)
    kind = "integers" if integer else "numbers"
    if (not isinstance(v, (list, tuple)) or len(v) != 2 or not all(is_finite_number(x) for x in v)
            or (integer and not all(isinstance(x, int) or float(x).is_integer() for x in v))):
        raise SceneError(f"{where}: expected [low, high], two {kind}, got {show(v)}")
    if v[0] > v[1]:
        raise SceneError(f"{where}: expected [low, high] with low <= high, got {show(v)}")
    if integer:
        return int(v[0]), int(v[1])
    return float(v[0]), float(v[1])


def matrix(d: dict, key: str, path: str, shape: tuple[int, int]) -> np.ndarray:
    """A matrix of finite JSON numbers (a list of rows); strings such as "560" are refused,
    not converted."""
    v = field_value(d, key, path)
    where = where_of(path, key)
    rows, cols = shape
    ok = (isinstance(v, list) and len(v) == rows
          and all(isinstance(r, list) and len(r) == cols and all(is_number(x) for x in r) for r in v))
    if not ok:
        raise SceneError(f"{where}: expected a {rows}x{cols} matrix (a list of {rows} rows of {cols} numbers), "
                         f"got {show(v)}")
    try:
        a = np.array(v, dtype=float)
    except OverflowError:   # an integer beyond a float's range
        a = np.full(shape, np.inf)
    if not np.all(np.isfinite(a)):
        raise SceneError(f"{where}: expected finite numbers, got {show(v)}")
    return a


def unknown_fields(d: dict, known, path: str) -> None:
    """SceneError naming the first key of `d` not in `known` (a misspelt optional field
    would otherwise be ignored silently)."""
    extra = [k for k in d if k not in known]
    if extra:
        raise SceneError(f"{where_of(path, extra[0])}: unknown field; expected one of {', '.join(known)}")

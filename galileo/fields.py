"""Reading numbers, pairs and matrices out of parsed JSON with errors that name the field
(`objects[0].mass_kg: -1 is outside (0, inf]`); every scene loader uses these."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .errors import SceneError


def field_value(d: dict, key: str, path: str, default: Any = ...) -> Any:
    if not isinstance(d, dict):
        raise SceneError(f"{path}: expected an object")
    if key not in d:
        if default is ...:
            raise SceneError(f"{path}.{key}: missing".lstrip("."))
        return default
    return d[key]


def number(d: dict, key: str, path: str, default: Any = ..., lo: float = -math.inf, hi: float = math.inf,
         lo_open: bool = False, integer: bool = False) -> float:
    v = field_value(d, key, path, default)
    where = f"{path}.{key}".lstrip(".")
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise SceneError(f"{where}: expected a number, got {v!r}")
    if integer and int(v) != v:
        raise SceneError(f"{where}: expected an integer, got {v!r}")
    if v < lo or v > hi or (lo_open and v == lo):
        bound = f"({lo}, {hi}]" if lo_open else f"[{lo}, {hi}]"
        raise SceneError(f"{where}: {v} is outside {bound}")
    return int(v) if integer else float(v)


def pair(d: dict, key: str, path: str, default: Any) -> tuple[float, float]:
    v = field_value(d, key, path, default)
    where = f"{path}.{key}".lstrip(".")
    if (not isinstance(v, (list, tuple)) or len(v) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
            or v[0] > v[1]):
        raise SceneError(f"{where}: expected [low, high] with low <= high, got {v!r}")
    return float(v[0]), float(v[1])


def matrix(d: dict, key: str, path: str, shape: tuple[int, int]) -> np.ndarray:
    v = field_value(d, key, path)
    where = f"{path}.{key}".lstrip(".")
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != shape or not np.all(np.isfinite(a)):
        raise SceneError(f"{where}: expected a {shape[0]}x{shape[1]} matrix of numbers")
    return a



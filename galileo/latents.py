"""Latents and priors: what a scenario infers, declared once, validated in one place.

A scenario declares its latents as `Latent`s (name with its unit, default uniform prior
bounds, the range any bounds must stay in, proposal half-widths) and its likelihood's
noise as a `Noise`. Everything that takes bounds or widths from a user (scene files,
`galileo infer` flags, the app's live edits, a reopened session) checks them with
`check_bounds` / `check_noise` / `check_widths` here, so one rule holds everywhere.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np


@dataclass(frozen=True)
class Latent:
    """One latent variable with a uniform prior U(bounds).

    `limits` is where any prior bounds must lie (a mass above 0, a friction at or above
    0); `limits_open_low` says whether the low limit itself is excluded. `narrow` and
    `broad` are the single-site proposal half-widths (U(-w, w)) of the usual and of the
    periodic broad sweep; an `integer` latent instead moves by -w or +w with equal odds (w = 1:
    one step up or down)."""
    name: str
    unit: str                       # "kg", "1" (dimensionless), ...
    bounds: tuple[float, float]     # default prior bounds
    doc: str = ""
    limits: tuple[float, float] = (-math.inf, math.inf)
    limits_open_low: bool = False
    narrow: float = 0.05
    broad: float = 0.5
    integer: bool = False           # takes integer values; proposals move it by +-1 (equal odds)
    observation: bool = False       # a parameter of the observation noise, not of the physics (noise-free
                                    # observations do not peak at its value: less noise always fits them better)

    def to_json(self) -> dict:
        return {"name": self.name, "unit": self.unit, "bounds": list(self.bounds), "doc": self.doc,
                "limits": [_json_num(x) for x in self.limits], "narrow": self.narrow, "broad": self.broad,
                "integer": self.integer, **({"observation": True} if self.observation else {})}


@dataclass(frozen=True)
class Noise:
    """The likelihood's noise parameter (a standard deviation), e.g. sigma_mps = 0.05 m/s;
    any value must lie in (limits[0], limits[1]] (a sigma of 1e-300 or 1e308 is no
    measurement noise: the densities underflow or the data are ignored)."""
    name: str
    unit: str
    default: float
    doc: str = ""
    limits: tuple[float, float] = (0.0, math.inf)


def _json_num(x: float):
    return x if math.isfinite(x) else None


def as_number(x, what: str) -> float:
    """`x` as a finite float (ValueError naming `what` otherwise)."""
    if isinstance(x, bool):
        raise ValueError(f"{what}: expected a number, got {x!r}")
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected a number, got {x!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{what}: expected a finite number, got {x!r}")
    return v


def check_bounds(latent: Latent, lo, hi) -> tuple[float, float]:
    """The one rule for prior bounds: finite numbers, low strictly below high, inside the
    latent's limits. Returns (lo, hi) as floats; ValueError with a one-line reason."""
    lo, hi = as_number(lo, f"{latent.name} low bound"), as_number(hi, f"{latent.name} high bound")
    if not lo < hi:
        raise ValueError(f"{latent.name}: the low bound ({lo:g}) must be below the high bound ({hi:g})")
    low, high = latent.limits
    unit = "" if latent.unit == "1" else f" {latent.unit}"      # (a dimensionless latent's unit is "1")
    if lo < low or (latent.limits_open_low and lo == low):
        rel = ">" if latent.limits_open_low else ">="
        raise ValueError(f"{latent.name}: bounds must be {rel} {low:g}{unit}, got a low bound of {lo:g}")
    if hi > high:
        raise ValueError(f"{latent.name}: bounds must be <= {high:g}{unit}, got a high bound of {hi:g}")
    return lo, hi


def check_noise(noise: Noise, value) -> float:
    v = as_number(value, noise.name)
    low, high = noise.limits
    if v <= low:
        raise ValueError(f"{noise.name} must be > {low:g} {noise.unit}, got {v:g}")
    if v > high:
        raise ValueError(f"{noise.name} must be <= {high:g} {noise.unit}, got {v:g}")
    return v


def check_widths(narrow, broad, broad_every) -> tuple:
    """Proposal half-widths (a number, or one per latent) and the broad period (0: never)."""
    def width(w, what):
        if isinstance(w, (list, tuple, np.ndarray)):
            ws = tuple(as_number(x, what) for x in w)
            if not ws or min(ws) <= 0:
                raise ValueError(f"{what} widths must be > 0, got {list(ws)}")
            return ws
        v = as_number(w, what)
        if v <= 0:
            raise ValueError(f"proposal widths must be > 0, got {what}={v:g}")
        return v
    n, b = width(narrow, "narrow"), width(broad, "broad")
    e = as_number(broad_every, "broad_every")
    if e < 0 or e != int(e):
        raise ValueError(f"broad_every must be an integer >= 0 (0: never broad), got {broad_every!r}")
    return n, b, int(e)


def by_name(latents: Iterable[Latent]) -> dict[str, Latent]:
    return {lat.name: lat for lat in latents}


def default_widths(latents: Sequence[Latent]):
    """(narrow, broad): one number when every latent shares it, else one per latent."""
    narrow = [lat.narrow for lat in latents]
    broad = [lat.broad for lat in latents]
    one = (lambda ws: ws[0] if ws and all(w == ws[0] for w in ws) else tuple(ws))
    return one(narrow), one(broad)


def initial_positions(bounds: np.ndarray, n_chains: int, seed: int) -> np.ndarray:
    """Chain starts drawn uniformly from the prior (reproducible from the seed)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2**31,)))
    lo, hi = bounds[:, 0], bounds[:, 1]
    return lo + (hi - lo) * rng.uniform(size=(n_chains, len(bounds)))

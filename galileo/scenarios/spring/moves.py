"""Exact joint moves along what spring videos leave open (`identify.py`), over a whole problem.

* `RidgeMove`, per spring: its own mass ms changes by d ~ U(-w, w) while everything the
  videos pin stays put: the reference's k / M and c / M (M = m_ref + ms/3), its rest position
  rest + (m_ref + ms/2) g / k, and every other object's (m + ms/3) / M on that spring. In those
  coordinates the move is a shift of ms alone (symmetric); back in the latents the Jacobian
  is M^n (n: the stiffness, the damping and the other free masses that scale with M), so the
  Hastings factor is n log(M' / M). The reference is the spring's object of known mass, else its
  first video's object (whose mass the move then keeps).
* `ScaleMove`, per video without a metric camera: its `scale` times exp(u) and its spring's
  unloaded length such that the rest position in the video stays put (the bounce unchanged;
  only the sway's period moves). rest' + h = s'/s (rest + h + e), so the Jacobian is s'/s and
  with the log-scale step the Hastings factor is 2u.
* `LogScale` over every mass, stiffness, spring mass and damping (only where no mass is known:
  then nothing the videos show changes, `galileo.mcmc.LogScale`).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .scene import object_latent, spring_latents

RIDGE_WIDTH_KG = 0.01     # the first half-width of the spring-mass shift (adapted in warm-up)
RIDGE_TARGET = 0.3        # warm-up adapts the width towards this acceptance
SCALE_WIDTH = 0.1


def _adapted(width: float, accepted: bool, eta: float, lo: float, hi: float) -> float:
    """A warm-up update of a move's width towards acceptance RIDGE_TARGET, kept in [lo, hi]."""
    return float(min(hi, max(lo, width * math.exp(eta * (float(accepted) - RIDGE_TARGET)))))


def one_video(latents) -> tuple:
    """The `sources` of a problem of one video whose latents are all free (`galileo.joint.Layout`'s)."""
    return (tuple((lat.name, "free", j) for j, lat in enumerate(latents)),)


class RidgeMove(NamedTuple):
    ms: int                       # site of the spring's own mass
    k: int                        # site of its stiffness (-1: fixed)
    c: int                        # site of its damping (-1: fixed)
    rest: int                     # site of its unloaded length (-1: fixed)
    ref: int                      # site of the reference object's mass (-1: fixed at ref_kg)
    ref_kg: float
    others: tuple[int, ...]       # sites of the other free masses on this spring
    gravity_mps2: float
    width: float = RIDGE_WIDTH_KG
    every: int = 1
    name: str = "spring_mass_ridge"

    def propose(self, rng: np.random.Generator, position) -> tuple[np.ndarray, float]:
        x = np.asarray(position, float).copy()
        d = rng.uniform(-self.width, self.width)
        ms = x[self.ms]
        ms2 = ms + d
        m_ref = x[self.ref] if self.ref >= 0 else self.ref_kg
        big, big2 = m_ref + ms / 3, m_ref + ms2 / 3
        if big <= 0 or big2 <= 0:
            return x, -math.inf
        lam = big2 / big
        g = self.gravity_mps2
        k = x[self.k] if self.k >= 0 else None
        if k is not None:
            k2 = k * lam
            if self.rest >= 0:
                x[self.rest] = x[self.rest] + (m_ref + ms / 2) * g / k - (m_ref + ms2 / 2) * g / k2
            x[self.k] = k2
        if self.c >= 0:
            x[self.c] = x[self.c] * lam
        for j in self.others:
            x[j] = (x[j] + ms / 3) * lam - ms2 / 3
        x[self.ms] = ms2
        n = (self.k >= 0) + (self.c >= 0) + len(self.others)
        return x, n * math.log(lam)

    def adapted(self, accepted: bool, eta: float) -> RidgeMove:
        return self._replace(width=_adapted(self.width, accepted, eta, 1e-6, 1.0))


class ScaleMove(NamedTuple):
    scale: int                    # site of the video's scale
    rest: int                     # site of its spring's unloaded length (-1: fixed; then none is made)
    k: int                        # site of the stiffness (-1: fixed at k_Npm)
    k_Npm: float
    weight: tuple                 # (mass site or -1, mass value, spring-mass site or -1, its value)
    hang_m: float
    gravity_mps2: float
    width: float = 0.05
    every: int = 1
    name: str = "scale"

    def propose(self, rng: np.random.Generator, position) -> tuple[np.ndarray, float]:
        x = np.asarray(position, float).copy()
        u = rng.uniform(-self.width, self.width)
        s = x[self.scale]
        if s <= 0:
            return x, -math.inf
        mi, mv, si, sv = self.weight
        m = x[mi] if mi >= 0 else mv
        ms = x[si] if si >= 0 else sv
        k = x[self.k] if self.k >= 0 else self.k_Npm
        ext = (m + ms / 2) * self.gravity_mps2 / k
        lam = math.exp(u)
        x[self.rest] = lam * (x[self.rest] + self.hang_m + ext) - self.hang_m - ext
        x[self.scale] = s * lam
        return x, 2 * u

    def adapted(self, accepted: bool, eta: float) -> ScaleMove:
        return self._replace(width=_adapted(self.width, accepted, eta, 1e-5, 2.0))


def problem_moves(scenes, sources, names, bounds) -> tuple:
    """The moves for a problem: `sources` per video (name, "free"|"fixed", site | value), `names`
    the chain's flat latent names."""
    from ...mcmc import LogScale

    def site(v: int, name: str):
        for n, kind, j in sources[v]:
            if n == name:
                return (int(j), None) if kind == "free" else (-1, float(j))
        return -1, None

    moves = []
    springs: dict[str, list[int]] = {}
    for v, s in enumerate(scenes):
        springs.setdefault(s.spring, []).append(v)
    any_known = False
    for spring, vs in springs.items():
        sp = spring_latents(spring)
        refs = [v for v in vs if site(v, object_latent(scenes[v].object))[0] < 0]
        any_known |= bool(refs)
        r = refs[0] if refs else vs[0]
        ms, _ = site(r, sp["ms"])
        k, _ = site(r, sp["k"])
        if ms < 0 or k < 0:
            continue
        ref, ref_kg = site(r, object_latent(scenes[r].object))
        others = sorted({site(v, object_latent(scenes[v].object))[0] for v in vs} - {-1, ref})
        moves.append(RidgeMove(ms, k, site(r, sp["c"])[0], site(r, sp["rest"])[0], ref, ref_kg or 0.0,
                               tuple(others), scenes[r].gravity_mps2, name=f"{spring}_mass_ridge"))
    for v, s in enumerate(scenes):
        sc = site(v, "scale")[0]
        rest = site(v, spring_latents(s.spring)["rest"])[0]
        if sc >= 0 and rest >= 0:
            k, k_val = site(v, spring_latents(s.spring)["k"])
            mi, mv = site(v, object_latent(s.object))
            si, sv = site(v, spring_latents(s.spring)["ms"])
            moves.append(ScaleMove(sc, rest, k, k_val or 0.0, (mi, mv or 0.0, si, sv or 0.0), s.hang_m,
                                   s.gravity_mps2, name=f"scale_{v + 1}"))
    if not any_known:
        import re

        scaled = re.compile(r"^(m|k|ms|c)_[a-z][a-z0-9]*_(kg|Npm|Nspm)(@\d+)?$")
        sites = tuple(j for j, n in enumerate(names) if scaled.match(n))
        if len(sites) >= 2:
            moves.append(LogScale(sites, (1.0,) * len(sites), SCALE_WIDTH, every=1, name="scale_masses"))
    return tuple(moves)

"""Moves that help the ramp's chains mix (each exact: it carries its own Hastings factor).

Two features of the ramp's posterior defeat single-site random walks (issue 12):

* the "at rest" plateau: any k1 above tan(angle) leaves the object on the ramp, so the
  likelihood is flat there and far below the mode; a chain that starts there has no
  gradient to follow. The video's ramp phase says where k1 is: the object accelerates
  down the slope at a = g (sin(angle) - k1 cos(angle)), so the tracked velocity along the
  slope against time gives k1_hat = tan(angle) - a / (g cos(angle)). `k1_move` proposes k1
  from a mixture of N(k1_hat, sd) and the prior's uniform (a defensive component, so that
  the move stays useful when the estimate is off), the other latents unchanged.
* the mass-ratio ridge: a collision identifies m1 / m2, not the masses, so the posterior
  of (m1, m2) lies along a ray from the origin. `RayMove` redraws the masses along their
  ray from the uniform prior's own conditional there (at a fixed ratio: always accepted when
  only the ratio matters, and exact either way), and a `LogScale` move changes the ratio at a
  fixed product (across the ridge).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ...datatypes import Tracks
from ...mcmc import LogScale, RayMove, SiteMixture
from .scene import Scene

K1_SD_MIN = 0.01        # the k1 proposal's normal is never narrower than this
K1_SD_SE = 3.0          # ... and at least this many standard errors of the estimate wide
K1_WEIGHT = 0.5         # the share of proposals from the normal (the rest: the prior's uniform)
ON_RAMP_MARGIN_M = 0.05  # frames whose centre is this far up the slope from the foot count as the ramp phase
MIN_FRAMES = 4
RATIO_WIDTH = 0.2       # initial log-space width of the mass-ratio move (adapted in warm-up)


def k1_from_acceleration(scene: Scene, tracks: Tracks) -> tuple[float, float] | None:
    """(k1_hat, its standard error) from the ramp object's tracked velocity along the slope
    in the frames it is on the ramp (least squares v = a t + b); None with fewer than
    MIN_FRAMES such frames. The scene's gravity is above 0 (scene.GRAVITY_MPS2: without it
    nothing slides and k1 is not identified; the estimate divides by g)."""
    tr = tracks.by_role("ramp")
    if tr is None:
        return None
    theta = math.radians(scene.ramp.angle_deg)
    g = scene.gravity_mps2
    on = tr.visible & np.isfinite(tr.position_m[:, 0]) & (tr.position_m[:, 0] < -ON_RAMP_MARGIN_M * math.cos(theta))
    # the ramp phase: from the start to the last frame still up the slope
    idx = np.flatnonzero(on)
    if len(idx) < MIN_FRAMES:
        return None
    t = tracks.time_s[idx]
    v = tr.velocity_mps[idx, 0] * math.cos(theta) - tr.velocity_mps[idx, 2] * math.sin(theta)
    A = np.stack([t, np.ones_like(t)], axis=1)
    coef, *_ = np.linalg.lstsq(A, v, rcond=None)
    resid = v - A @ coef
    dof = max(1, len(t) - 2)
    s2 = float(resid @ resid) / dof
    var_a = s2 / float(((t - t.mean()) ** 2).sum()) if np.ptp(t) > 0 else math.inf
    a = float(coef[0])
    k1 = math.tan(theta) - a / (g * math.cos(theta))
    se = math.sqrt(var_a) / (g * math.cos(theta)) if math.isfinite(var_a) else math.inf
    return k1, se


def k1_move(scene: Scene, tracks: Tracks, site: int, bounds: np.ndarray) -> SiteMixture:
    """The data-driven independence move on k1 (see the module docstring)."""
    lo, hi = (float(x) for x in bounds[site])
    est = k1_from_acceleration(scene, tracks)
    if est is None or not math.isfinite(est[0]):
        return SiteMixture(site, 0.0, 0.5 * (lo + hi), 1.0, lo, hi, name="k1_from_acceleration")
    k1, se = est
    sd = max(K1_SD_MIN, K1_SD_SE * se) if math.isfinite(se) else 0.1
    return SiteMixture(site, K1_WEIGHT, float(k1), float(sd), lo, hi, name="k1_from_acceleration")


def ramp_moves(scene: Scene, tracks: Tracks, names: Sequence[str], bounds: np.ndarray) -> tuple:
    moves = []
    if "k1" in names:
        moves.append(k1_move(scene, tracks, names.index("k1"), bounds))
    if "m1_kg" in names and "m2_kg" in names:
        pair = (names.index("m1_kg"), names.index("m2_kg"))
        box = tuple(tuple(float(v) for v in bounds[k]) for k in pair)
        moves.append(RayMove(pair, box, name="mass_ray"))
        moves.append(LogScale(pair, (1.0, -1.0), RATIO_WIDTH, name="mass_ratio"))
    return tuple(moves)

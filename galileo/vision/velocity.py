"""Velocities from tracked positions: central differences that keep a jump sharp."""
from __future__ import annotations

import math

import numpy as np

from . import MAD_TO_SD

JUMP_MPS = 0.1        # one-sided velocity estimates that disagree by more than this mark a jump ...
JUMP_NOISE_SDS = 6.0  # ... or by more than this many SDs of the velocity noise


def velocity_from_positions(pos: np.ndarray, visible: np.ndarray, fps: float) -> np.ndarray:
    """Velocities from positions: central differences, except across a velocity jump.

    A collision or the landing at the ramp's foot changes velocity within one frame;
    a central difference there averages the velocities before and after. Where the
    velocities extrapolated to the frame from each side (leaving out the two adjacent
    intervals) disagree by more than max(JUMP_MPS, JUMP_NOISE_SDS x the noise), the jump is placed in
    the adjacent interval whose difference strays further from its own side's trend, and
    the frame takes the extrapolation from the other side. One-sided differences at
    the ends of visible runs; NaN where the object is not visible.
    """
    n = len(pos)
    vel = np.full_like(pos, np.nan)
    step = np.full_like(pos, np.nan)               # step[i]: velocity over (i-1, i)
    ok_step = np.zeros(n, bool)
    ok_step[1:] = visible[1:] & visible[:-1]
    step[1:][ok_step[1:]] = (pos[1:] - pos[:-1])[ok_step[1:]] * fps

    def s(i):
        return step[i] if 0 <= i < n and ok_step[i] else None

    # noise of the step velocities, from their second differences (robust to the jumps)
    good = ok_step[1:-1] & ok_step[2:] & ok_step[:-2]
    dd = (step[2:] - 2 * step[1:-1] + step[:-2])[good]
    noise = MAD_TO_SD * float(np.median(np.linalg.norm(dd, axis=1))) / math.sqrt(6) if len(dd) else 0.0
    threshold = max(JUMP_MPS, JUMP_NOISE_SDS * noise)

    def extrapolate(a, b_, k):  # velocity at the frame from steps a (nearer) and b_ (further), k steps away
        return a + k * (a - b_)

    for i in range(n):
        if not visible[i]:
            continue
        b, f = s(i), s(i + 1)
        if b is None and f is None:
            vel[i] = 0.0
            continue
        if b is None or f is None:
            vel[i] = b if f is None else f
            continue
        bb, ff, bbb, fff = s(i - 1), s(i + 2), s(i - 2), s(i + 3)
        central = (b + f) / 2
        if bb is None or ff is None or bbb is None or fff is None:
            vel[i] = central
            continue
        # velocities at the frame from each side, leaving out the two adjacent intervals
        if np.linalg.norm(extrapolate(bb, bbb, 1.5) - extrapolate(ff, fff, 1.5)) <= threshold:
            vel[i] = central
            continue
        # the jump lies in the interval whose difference strays further from its own
        # side's trend (it mixes the velocities before and after); the frame takes the other side
        b_off = np.linalg.norm(b - extrapolate(bb, bbb, 1.0))
        f_off = np.linalg.norm(f - extrapolate(ff, fff, 1.0))
        vel[i] = extrapolate(b, bb, 0.5) if f_off > b_off else extrapolate(f, ff, 0.5)
    return vel


THIRD_DIFF_VAR = 20.0   # var(e[i+3] - 3 e[i+2] + 3 e[i+1] - e[i]) over var(e) for white noise e
NOISE_MOVING_MPS = 0.02  # position noise is measured where the object moves at least this fast (at rest a tracker
# may repeat a position exactly, and what matters is the noise of the motion)
NOISE_MIN_SAMPLES = 10


def position_noise(pos: np.ndarray, visible: np.ndarray, fps: float) -> float | None:
    """The SD of a track's position noise (per component, in metres) from its third differences
    over runs of four visible frames in which it moves (each step at least NOISE_MOVING_MPS):
    they cancel any constant acceleration (a slide, a fall) and leave white noise with 20 times
    its variance; the median's robust spread ignores the few that straddle a jump (a collision,
    the landing). None with fewer than NOISE_MIN_SAMPLES of them."""
    step = np.linalg.norm(np.diff(pos, axis=0), axis=1) * fps          # (F-1,), NaN where not seen
    moving = np.nan_to_num(step) >= NOISE_MOVING_MPS
    ok = visible[3:] & visible[2:-1] & visible[1:-2] & visible[:-3] & moving[2:] & moving[1:-1] & moving[:-2]
    d3 = (pos[3:] - 3 * pos[2:-1] + 3 * pos[1:-2] - pos[:-3])[ok]
    if len(d3):
        d3 = d3[:, np.ptp(pos[visible], axis=0) > 0]    # components that vary (not a fixed y)
    if d3.size < NOISE_MIN_SAMPLES:
        return None
    d3 = d3.ravel()
    return float(MAD_TO_SD * np.median(np.abs(d3 - np.median(d3))) / math.sqrt(THIRD_DIFF_VAR))

"""What a ramp video identifies, and what it leaves to the prior.

Newton on the ramp: an object sliding with friction k accelerates at g (sin theta - k cos theta)
whatever its mass, so a video identifies the ramp object's friction k1 and never its mass m1.
A collision conserves momentum, m1 v1 = m1 v1' + m2 v2' (with restitution e fixing the
velocities' split), so it fixes the ratio m1 / m2 and never the two masses: both scaled together
make the same video. A video in which nothing moves (`moves`: the tracker held it still) says only that the ramp
object's friction holds it, k1 >= tan theta; there is no collision to weigh the objects by, and
a target that never moves shows nothing of its friction. A mass fixed by the problem (`--fix
m2_kg=...`) turns the ratio into the other mass.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ...datatypes import Tracks
from .scene import Scene


def moves(tracks: Tracks, role: str) -> bool:
    """Whether the tracks' object of this role ever leaves where it was first seen (the
    tracker holds an object that never moves at the scene file's pose)."""
    o = tracks.by_role(role)
    if o is None:
        return False
    pos = np.asarray(o.position_m, float)[np.asarray(o.visible, bool)]
    return bool(len(pos) and np.ptp(pos, axis=0).max() > 0)


def not_identified(scenes: Sequence[Scene], fixed: dict[str, float],
                   tracks: Sequence[Tracks] | None = None) -> dict[str, str]:
    """{name as the problem names it: why it is not identified} for a problem of these ramp
    videos (the module docstring), with these latents fixed and, where known, their tracks."""
    from ...joint import video_name

    n = len(scenes)
    out: dict[str, str] = {}
    for v, s in enumerate(scenes):
        def name(k: str) -> str:
            return video_name(k, v, n)

        def known(k: str) -> bool:
            return k in fixed or name(k) in fixed

        slid = tracks is None or moves(tracks[v], "ramp")
        hit = s.target is not None and (tracks is None or moves(tracks[v], "target"))
        if not slid:
            tan = math.tan(math.radians(s.ramp.angle_deg))
            out[name("k1")] = (f"nothing slides: only a bound, k1 >= tan({s.ramp.angle_deg:g} deg) = {tan:.3f} "
                               f"(above it the posterior is the prior)")
        if hit:
            if not (known("m1_kg") or known("m2_kg")):
                out[name("m1_kg")] = out[name("m2_kg")] = (
                    "only the ratio m1/m2 is identified: the collision fixes it, and both masses scaled together "
                    "make the same video (fix one, e.g. --fix m2_kg=0.1, to weigh the other)")
            continue
        why = ("no collision: an object's slide does not depend on its mass (gravity and friction both scale with it)"
               if s.target is None else "nothing moves: no collision to weigh the objects by" if not slid else
               "the target never moves: no collision to weigh the objects by")
        for k in ("m1_kg", "m2_kg", "mass_ratio") if s.target is not None else ("m1_kg",):
            if not known(k):
                out[name(k)] = why
        if s.target is not None:
            out[name("k2")] = "the target never moves: its friction does not enter the video"
            if "e_collision" in s.latent_names:
                out[name("e_collision")] = why
    return out

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


def not_identified(scenes: Sequence[Scene], fixed: dict[str, float], tracks: Sequence[Tracks] | None = None,
                   share: Sequence[str] = ()) -> dict[str, str]:
    """{name as the problem names it: why it is not identified} for a problem of these ramp
    videos (the module docstring), with these latents fixed and shared and, where known, their
    tracks. A shared latent is identified when any of its videos identifies it; masses are
    weighed along collisions: a known mass (fixed) and a collision's ratio give the other mass,
    which a shared mass carries into the videos that share it."""
    from ...joint import video_name

    n = len(scenes)

    def node(k: str, v: int) -> str:   # the problem's name of video v's latent k
        return k if k in share else video_name(k, v, n)

    def is_fixed(k: str, v: int) -> bool:
        return k in fixed or video_name(k, v, n) in fixed

    slid = [tracks is None or moves(tracks[v], "ramp") for v in range(n)]
    hit = [s.target is not None and (tracks is None or moves(tracks[v], "target")) for v, s in enumerate(scenes)]
    weighed = {node(k, v) for v in range(n) for k in ("m1_kg", "m2_kg") if is_fixed(k, v)}
    links = [(node("m1_kg", v), node("m2_kg", v)) for v in range(n) if hit[v]]
    grown = True
    while grown:   # a collision's ratio weighs one mass by the other
        grown = False
        for a, b in links:
            if (a in weighed) != (b in weighed):
                weighed |= {a, b}
                grown = True
    seen = {node("k1", v) for v in range(n) if slid[v]} | {node(k, v) for v in range(n) if hit[v]
                                                           for k in ("k2", "e_collision")}
    out: dict[str, str] = {}
    for v in sorted(range(n), key=lambda v: not hit[v]):   # (collisions first: theirs is the fuller reason)
        s = scenes[v]
        if node("k1", v) not in seen and not is_fixed("k1", v):
            tan = math.tan(math.radians(s.ramp.angle_deg))
            out.setdefault(node("k1", v), f"nothing slides: only a bound, k1 >= tan({s.ramp.angle_deg:g} deg) = "
                                          f"{tan:.3f} (above it the posterior is the prior)")
        if hit[v]:
            if node("m1_kg", v) not in weighed:
                for k in ("m1_kg", "m2_kg"):
                    out.setdefault(node(k, v), "only the ratio m1/m2 is identified: the collision fixes it, and both "
                                               "masses scaled together make the same video (fix one, e.g. --fix "
                                               "m2_kg=0.1, to weigh the other)")
            continue
        why = ("no collision: an object's slide does not depend on its mass (gravity and friction both scale with it)"
               if s.target is None else "nothing moves: no collision to weigh the objects by" if not slid[v] else
               "the target never moves: no collision to weigh the objects by")
        masses = ("m1_kg", "m2_kg") if s.target is not None else ("m1_kg",)
        for k in masses:
            if node(k, v) not in weighed and not is_fixed(k, v):
                out.setdefault(node(k, v), why)
        if s.target is not None:
            if not all(node(k, v) in weighed for k in masses):
                out.setdefault(video_name("mass_ratio", v, n), why)
            for k, what in (("k2", "the target never moves: its friction does not enter the video"),
                            ("e_collision", why)):
                if node(k, v) not in seen and not is_fixed(k, v) and (k == "k2" or k in s.latent_names):
                    out.setdefault(node(k, v), what)
    return out

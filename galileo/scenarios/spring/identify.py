"""What a problem of spring videos identifies, and what it does not (said in `result.json`).

One video's bounce gives its period 2 pi sqrt((m + ms/3) / k) and decay c / (2 (m + ms/3)):
stiffness over mass, not either. Scaling every mass, stiffness and damping together changes no
motion (the static extension (m + ms/2) g / k does not change either). So:

* a spring's stiffness, damping and own mass, and the masses of the objects on it, are
  identified only through an object of known mass on that spring (a reference, `--fix`);
* with one reference, an unknown mass m on the same spring is m = r m_ref + (r - 1) ms / 3
  (r: the squared ratio of their periods): exact where r = 1 (the same object), otherwise known
  up to the spring's own mass ms;
* the spring's own mass needs a second reference of another mass (two periods, two known
  masses: k and ms), or a metric camera and the unloaded spring's length (`rest_<spring>_m`
  fixed): the static extension (m + ms/2) g / k then differs from the bounce's (m + ms/3);
* the sway's period, 2 pi sqrt(L (m + ms/3) / ((m + ms/2) g)) in the equivalent-mass model,
  depends on ms / m a little: it pins the spring's mass weakly where ms is not small against m
  (on renders made by the same model), which is not counted as identifying it;
* without a metric camera (`metric: false`), lengths in metres (the unloaded length, the
  release state's) are known only through `scale`, which only the sway's pendulum period
  (2 pi sqrt(L / g)) pins, weakly.
"""
from __future__ import annotations

from collections.abc import Sequence

from .scene import SpringScene, object_latent, spring_latents


def not_identified(scenes: Sequence[SpringScene], fixed: dict[str, float]) -> dict[str, str]:
    """{latent name as the problem names it: why it is not identified} for a problem of these
    videos with these latents fixed (by name; per-video `name@v` too)."""
    from ...joint import split_name, video_name

    n = len(scenes)
    fixed_names = {split_name(k)[0] for k in fixed}
    where: dict[str, list[int]] = {}
    for v, s in enumerate(scenes):
        for name in s.names():
            where.setdefault(name, []).append(v)

    def flat(name: str) -> str:   # the problem's name for a latent (one video's own: name@v)
        vs = where.get(name, [0])
        return name if len(vs) > 1 else video_name(name, vs[0], n)

    out: dict[str, str] = {}
    springs: dict[str, list[SpringScene]] = {}
    for s in scenes:
        springs.setdefault(s.spring, []).append(s)
    known_mass = {s.object for s in scenes if object_latent(s.object) in fixed_names}
    for spring, group in springs.items():
        names = spring_latents(spring)
        refs = {s.object for s in group if s.object in known_mass}
        metric = all(s.metric for s in group)
        rest_known = names["rest"] in fixed_names
        ms_known = names["ms"] in fixed_names or len(refs) >= 2 or (refs and metric and rest_known)
        if not refs:
            why = (f"no object of known mass on the {spring!r} spring: its videos give stiffness over mass only "
                   f"(fix a reference, e.g. --fix {object_latent(group[0].object)}=0.1103)")
            for kind in ("k", "c", "ms"):
                if names[kind] not in fixed_names:
                    out[flat(names[kind])] = why
            for s in group:
                name = object_latent(s.object)
                if name not in fixed_names:
                    out.setdefault(flat(name), why)
        else:
            if not ms_known:
                out[flat(names["ms"])] = (f"one reference mass on the {spring!r} spring: its own mass needs a second "
                                    f"reference of another mass, or a metric camera and --fix {names['rest']}=... "
                                    f"(only the sway's period, through the equivalent-mass model, pins it, weakly)")
                for s in group:
                    name = object_latent(s.object)
                    if s.object not in refs and name not in fixed_names:
                        out.setdefault(flat(name), f"known up to the {spring!r} spring's own mass ({names['ms']}): "
                                             f"m = r m_ref + (r - 1) {names['ms']} / 3, r the squared period ratio")
        if not metric and names["rest"] not in fixed_names:
            out[flat(names["rest"])] = "the camera's scale is not known (metric: false): lengths in metres only through the sway"
    for v, s in enumerate(scenes):
        if not s.metric:
            out[video_name("scale", v, n)] = "pinned only by the sway's pendulum period (weakly)"
    return out

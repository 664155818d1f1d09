"""Between pixels and the likelihood: the tracker's pixel track as world tracks, the scene as
inferred on (`prepare`: the release frame, a damped sine fitted to the track, the release
state's priors around it), where chains start, and synthetic observations (for SBC and tests).

The bottom-up fit: the centre's height z(t) = z_c + A exp(-g t) cos(w t + phi) over the frames
seen after the release (least squares, the frequency started from the spectrum's peak), then
refined by the simulation itself (`refine`: k / M, c / (2 M), the rest position and the release
state that Bullet's motion fits best). It fixes nothing; it centres the release priors and starts
the chains near the answer: each chain draws the masses from their prior and takes the stiffness
and damping that give the fitted motion with them (k = M omega^2, c = 2 gamma M, M = m + ms/3).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ...camera import backproject_to_plane
from ...datatypes import ObjectTrack, Tracks
from ...errors import GalileoError, SceneError
from ...framelik import ar1_residuals
from ...shapes import Shape
from .scene import (
    LATENTS,
    NOISE_LATENTS,
    RELEASE_POS_PRIOR_M,
    RELEASE_SPEED_PRIOR_MPS,
    SpringScene,
    object_latent,
    px_per_m,
    spring_latents,
)

FIT_MIN_PERIODS = 1.5       # the track must span this many bounces after the release
FIT_MIN_FRAMES = 8          # ... and this many frames
START_JITTER = 1e-4         # chains start this fraction of a guessed value apart around the fit (the
                            # fit pins a period to ~0.1%: more would start them far down the likelihood)
START_RHO = 0.5
SWAY_FIT_FRAMES = 7         # the release's sideways position and speed: a parabola through this many frames
SCALE_TRIES = (0.5, 0.7, 1.0, 1.4, 2.0)   # scales the sway fit starts from, without a metric camera


def _camera(scene: SpringScene):
    if scene.camera is None:
        raise GalileoError("the spring scene has no camera: make one with `galileo scene VIDEO --scenario spring` "
                           "(clicks) or give \"camera\" in the scene file")
    return scene.camera


def from_pixels(center_px: np.ndarray, visible: np.ndarray, fps: float, scene: SpringScene, *,
                release_frame: int, bottom_up: dict | None = None, notes=(), detected_by: str = "spring tracker") -> Tracks:
    """World tracks from the object's centre in pixels: each seen centre back-projected onto the
    spring's plane (y = the hanging point's y) through the scene's camera; velocities by central
    differences inside runs of seen frames."""
    cam = _camera(scene)
    c = np.asarray(center_px, float)
    seen = np.asarray(visible, bool) & np.isfinite(c).all(axis=1)
    pos = np.full((len(c), 3), np.nan)
    if seen.any():
        pos[seen] = backproject_to_plane(cam, c[seen], scene.top_in_world_m[1])
    vel = np.full_like(pos, np.nan)
    for f in np.flatnonzero(seen):
        lo = f - 1 if f > 0 and seen[f - 1] else f
        hi = f + 1 if f + 1 < len(c) and seen[f + 1] else f
        if hi > lo:
            vel[f] = (pos[hi] - pos[lo]) * fps / (hi - lo)
    vel[seen & ~np.isfinite(vel).all(axis=1)] = 0.0
    bu = {"release_frame": int(release_frame), **(bottom_up or {})}
    obj = ObjectTrack(scene.object, "object", pos, vel, seen, Shape("box", tuple(scene.size_m)),
                      detected_by=detected_by, bottom_up=bu, center_px=c)
    return Tracks(float(fps), [obj], list(notes))


def track(video_path, scene: SpringScene, *, progress: bool = True, debug_video=None) -> Tracks:
    """Pixels -> observations: the tracker (`tracking.py`) from the hanging point the camera sees."""
    from .tracking import track_pixels

    cam = _camera(scene)
    top_px = tuple(float(v) for v in cam.project(np.asarray(scene.top_in_world_m, float)))
    pt = track_pixels(video_path, top_px=top_px, progress=progress, debug_video=debug_video)
    bu = {"top_px": list(pt.top_px) if pt.top_px is not None else None, "size_px": list(pt.size_px),
          "method": pt.method}
    return from_pixels(pt.center_px, pt.visible, pt.fps, scene, release_frame=pt.release_frame,
                       bottom_up={k: v for k, v in bu.items() if v is not None}, notes=pt.notes)


# -- the scene as inferred on ---------------------------------------------------------------------------

def fit_bounce(t_s: np.ndarray, z: np.ndarray) -> dict | None:
    """A damped sine z_c + A exp(-g t) cos(w t + phi) fitted to (t, z): {period_s, decay_per_s,
    centre, z0, vz0, rms} (z0, vz0: the fit at t = 0), or None where no bounce is seen."""
    from scipy.optimize import least_squares

    if len(t_s) < FIT_MIN_FRAMES:
        return None
    zc0 = float(np.median(z))
    dt = float(np.median(np.diff(t_s)))
    grid = np.arange(t_s[0], t_s[-1] + dt / 2, dt)
    zi = np.interp(grid, t_s, z) - zc0
    n = 1 << int(math.ceil(math.log2(max(len(zi), 8) * 8)))
    spec = np.abs(np.fft.rfft(zi * np.hanning(len(zi)), n))
    freqs = np.fft.rfftfreq(n, dt)
    spec[freqs < 1.0 / max(t_s[-1] - t_s[0], dt)] = 0.0   # less than one cycle in the clip
    if not spec.any():
        return None
    w0 = 2 * math.pi * float(freqs[int(np.argmax(spec))])
    a0 = float(np.percentile(np.abs(zi), 95))

    def resid(p):
        zc, a, g, w, ph = p
        return zc + a * np.exp(-g * t_s) * np.cos(w * t_s + ph) - z

    best = None
    for ph in (0.0, math.pi / 2, math.pi, 3 * math.pi / 2):
        r = least_squares(resid, [zc0, a0, 0.1, w0, ph], bounds=([-np.inf, 0, 0, 0.5 * w0, -10], [np.inf, np.inf, 50,
                                                                                                     2 * w0, 10]))
        if best is None or r.cost < best.cost:
            best = r
    zc, a, g, w, ph = (float(v) for v in best.x)
    span = (t_s[-1] - t_s[0]) * w / (2 * math.pi)
    if span < FIT_MIN_PERIODS or a <= 0:
        return None
    return {"period_s": 2 * math.pi / w, "decay_per_s": g, "centre_z_m": zc, "z0_m": zc + a * math.cos(ph),
            "vz0_mps": a * (-g * math.cos(ph) - w * math.sin(ph)),
            "rms_m": float(np.sqrt(np.mean(best.fun ** 2)))}


def prepare(scene: SpringScene, tracks: Tracks) -> SpringScene:
    """The scene as inferred on: the tracks' frame rate and length, the tracker's release frame, a
    damped sine fitted to the track (`bottom_up`) and the release latents' priors around it
    (where the scene file gives none); GalileoError where the tracks cannot be inferred from."""
    if len(tracks.objects) != 1:
        raise GalileoError(f"the spring scenario needs tracks of one object, got {len(tracks.objects)}")
    cam = _camera(scene)
    obj = tracks.objects[0]
    n = tracks.n_frames
    release = int(obj.bottom_up.get("release_frame", int(np.argmax(obj.visible)) if obj.visible.any() else 0))
    seen = np.asarray(obj.visible, bool).copy()
    seen[:release] = False
    if not 0 <= release < n - 1 or seen.sum() < FIT_MIN_FRAMES:
        raise GalileoError(f"the object is seen in {int(seen.sum())} frames after its release (frame {release}) of "
                           f"{n}: too few to infer from (at least {FIT_MIN_FRAMES})")
    fps = float(tracks.fps)
    sim_hz = scene.sim_hz if abs(scene.sim_hz / fps - round(scene.sim_hz / fps)) < 1e-9 else fps * max(
        1, round(scene.sim_hz / fps))
    tx, _, tz = scene.top_in_world_m
    idx = np.flatnonzero(seen)
    t = (idx - release) / fps
    pos = obj.position_m[idx]
    fit = fit_bounce(t, pos[:, 2] - tz)
    if fit is None:
        raise GalileoError(f"no bounce in the track: the object seen after its release (frame {release}) does not "
                           f"oscillate over {FIT_MIN_PERIODS:g} periods (is it the object on the spring?)")
    x_rel = pos[:, 0] - tx
    # the sway at release: a parabola through the first frames (finite differences of two noisy
    # frames would start it swinging at decimetres a second)
    head = min(len(idx), SWAY_FIT_FRAMES)
    coef = np.polyfit(t[:head], x_rel[:head], 2)
    x0, vx0 = float(coef[2]), float(coef[1])
    fit.update({"centre_x_m": float(np.median(x_rel))})
    priors = dict(scene.priors)
    cam = dataclasses.replace(cam, fps=fps, n_frames=n)
    prepared = dataclasses.replace(scene, fps=fps, n_frames=n, sim_hz=sim_hz, camera=cam, release_frame=release,
                                   x0_m=x0, z0_m=fit["z0_m"], vx0_mps=vx0, vz0_mps=fit["vz0_mps"])
    fit = refine(prepared, fit, idx, pos)
    for name, w in (("x0_m", RELEASE_POS_PRIOR_M), ("z0_m", RELEASE_POS_PRIOR_M),
                    ("vx0_mps", RELEASE_SPEED_PRIOR_MPS), ("vz0_mps", RELEASE_SPEED_PRIOR_MPS)):
        priors.setdefault(name, (fit[name] - w, fit[name] + w))
    return dataclasses.replace(prepared, x0_m=fit["x0_m"], z0_m=fit["z0_m"], vx0_mps=fit["vx0_mps"],
                               vz0_mps=fit["vz0_mps"], priors=priors, bottom_up=fit)


def refine(scene: SpringScene, fit: dict, idx: np.ndarray, pos: np.ndarray) -> dict:
    """The fit refined by the simulation itself: Bullet runs at the scene's masses (scale 1) with
    the stiffness, damping, unloaded length and release state that fit the tracked centre best
    (least squares over the frames seen: first the bounce from the up-down motion, then the
    sway's start from the motion across, the bounce held, then everything on both: near a 2:1
    ratio of bounce to sway frequency a sway started a few cm/s off grows through the coupling,
    and a joint fit from the first guess wanders off to bounces that feed it). Gives
    what the motion pins whatever the masses: omega2_per_s2 = k / M, gamma_per_s = c / (2 M),
    eq_below_top_m (the centre's rest distance below the hanging point), and the release state."""
    from scipy.optimize import least_squares

    from .physics import simulate

    tx, _, tz = scene.top_in_world_m
    big_m = scene.mass_kg + scene.spring_mass_kg / 3
    weight = (scene.mass_kg + scene.spring_mass_kg / 2) * scene.gravity_mps2
    w2 = (2 * math.pi / fit["period_s"]) ** 2 + fit["decay_per_s"] ** 2
    obs = pos[:, [0, 2]] - (tx, tz)
    names = ("omega2_per_s2", "gamma_per_s", "eq_below_top_m", "x0_m", "z0_m", "vx0_mps", "vz0_mps", "scale")
    p0 = np.array([w2, fit["decay_per_s"], -fit["centre_z_m"], scene.x0_m, scene.z0_m, scene.vx0_mps,
                   scene.vz0_mps, 1.0])
    step = np.array([1e-3 * w2, 1e-3, 1e-4, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3])
    # where a release can be: within the release priors' reach of the first guess
    reach = np.array([np.inf, np.inf, np.inf, RELEASE_POS_PRIOR_M, RELEASE_POS_PRIOR_M, RELEASE_SPEED_PRIOR_MPS,
                      RELEASE_SPEED_PRIOR_MPS, np.inf])
    lo_scale, hi_scale = scene.prior("scale", LATENTS["scale"])
    lower = np.maximum(p0 - reach, [1e-9, 0, 0, -np.inf, -np.inf, -np.inf, -np.inf, lo_scale])
    upper = np.minimum(p0 + reach, [np.inf, 50.0, 20.0, np.inf, np.inf, np.inf, np.inf, hi_scale])
    p0 = np.clip(p0, lower, upper)

    def values(p):
        k = big_m * p[0]
        return {"k_Npm": k, "damping_Nspm": 2 * p[1] * big_m,
                "rest_m": max(0.0, p[7] * p[2] - scene.hang_m - weight / k), "x0_m": p[3], "z0_m": p[4],
                "vx0_mps": p[5], "vz0_mps": p[6], "scale": p[7]}

    def resid(p, axes):
        try:
            traj = simulate(scene, scene.n_frames, values(p))
        except SceneError:
            return np.full(len(idx) * len(axes), 1e3)
        sim = (traj.position_m[0][idx][:, [0, 2]] - (tx, tz)) / p[7]   # in the scene's units
        return (sim - obs)[:, axes].ravel()

    p = p0.copy()
    p[[3, 5]] = 0.0     # the bounce alone first: hanging straight down, no sway
    try:
        sway = (3, 5) if scene.metric else (3, 5, 7)   # without a metric camera the sway's period gives the scale
        # last, everything on both directions from there (near the 2:1 resonance the bounce gives
        # the sway energy: the bounce alone was fitted with too fast a decay)
        for free, axes in (((0, 1, 2, 4, 6), [1]), (sway, [0]), ((0, 1, 2, 4, 6) + sway, [0, 1])):
            if axes == [0]:   # the sway from the best of a few starts (its objective is rugged)
                scales = SCALE_TRIES if not scene.metric else (1.0,)
                starts = [(x0, v0, sc) for x0, v0 in ((fit["centre_x_m"], 0.0), (p0[3], 0.0), (p0[3], p0[5]))
                          for sc in scales if lower[7] <= sc <= upper[7]] or [(p0[3], p0[5], p[7])]
                costs = [float(np.sum(resid(np.r_[p[:3], x0, p[4], v0, p[6], sc], [0]) ** 2)) for x0, v0, sc in starts]
                p[3], p[5], p[7] = starts[int(np.argmin(costs))]
            sub = np.array(free)

            def r(q, sub=sub, axes=axes):
                full = p.copy()
                full[sub] = q
                return resid(full, axes)

            before = float(np.sum(r(p[sub]) ** 2))
            out = least_squares(r, p[sub], diff_step=step[sub] / np.maximum(np.abs(p[sub]), 1e-9), max_nfev=40 * len(sub),
                                x_scale=step[sub] * 100, bounds=(lower[sub], upper[sub]))
            if 2 * out.cost <= before:
                p[sub] = out.x
    except (ValueError, np.linalg.LinAlgError):
        p = p0
    rms = float(np.sqrt(np.mean(resid(p, [0, 1]) ** 2)))
    return {**fit, **dict(zip(names, map(float, p))), "rms_m": rms}


def starts(scene: SpringScene, latents, bounds: np.ndarray, n_chains: int, seed: int) -> np.ndarray:
    """Where chain c of one video starts (c's start does not depend on n_chains): see `problem_starts`."""
    from .moves import one_video

    return _starts([scene], one_video(latents), np.asarray(bounds, float), n_chains, seed)


def problem_starts(scenes, lay, n_chains: int, seed: int) -> np.ndarray:
    """Where chain c of a problem of several videos starts (`galileo.joint`'s layout `lay`)."""
    bounds = np.array([lat.bounds for lat in lay.latents], float)
    return _starts(list(scenes), lay.sources, bounds, n_chains, seed)


def _starts(scenes: list, sources, bounds: np.ndarray, n_chains: int, seed: int) -> np.ndarray:
    """Each chain draws every latent from its prior, then, where a video's track was fitted
    (`bottom_up`), per spring: its own mass from the prior, the stiffness that gives the fitted
    period with the mass of its reference object (a fixed mass on it; else the first video's
    drawn mass), the damping that gives the fitted decay, the unloaded length that gives the
    fitted rest position; every other free mass on the spring from its own video's period; each
    video's release state and noise from its fit. Then a little jitter, inside the prior."""
    out = np.empty((n_chains, len(bounds)))
    width = bounds[:, 1] - bounds[:, 0]
    for c in range(n_chains):
        rng = np.random.default_rng([seed, c])
        x = bounds[:, 0] + rng.random(len(bounds)) * width
        guessed = np.zeros(len(bounds), bool)

        def get(v: int, name: str) -> float:
            for n, kind, j in sources[v]:
                if n == name:
                    return float(x[j]) if kind == "free" else float(j)
            raise KeyError(name)

        def put(v: int, name: str, value: float) -> None:
            for n, kind, j in sources[v]:
                if n == name and kind == "free" and not guessed[j]:
                    x[j], guessed[j] = value, True

        def fixed(v: int, name: str) -> bool:
            return any(n == name and kind == "fixed" for n, kind, _ in sources[v])

        springs: dict[str, list[int]] = {}
        for v, s in enumerate(scenes):
            if s.bottom_up:
                springs.setdefault(s.spring, []).append(v)
        for spring, vs in springs.items():
            sp = spring_latents(spring)
            ref = next((v for v in vs if fixed(v, object_latent(scenes[v].object))), vs[0])
            s, fit = scenes[ref], scenes[ref].bottom_up
            ms = get(ref, sp["ms"])
            m = get(ref, object_latent(s.object))
            k = (m + ms / 3) * fit["omega2_per_s2"]
            put(ref, sp["k"], k)
            put(ref, sp["c"], 2 * fit["gamma_per_s"] * (m + ms / 3))
            if not s.metric:
                put(ref, "scale", fit["scale"])
            scale = get(ref, "scale") if not s.metric else 1.0
            put(ref, sp["rest"], scale * fit["eq_below_top_m"] - s.hang_m - (m + ms / 2) * s.gravity_mps2 / k)
            rest = get(ref, sp["rest"])
            for v in vs:
                sv = scenes[v]
                put(v, object_latent(sv.object), k / sv.bottom_up["omega2_per_s2"] - ms / 3)
                if not sv.metric:   # the scale at which the shared unloaded length gives this video's rest position
                    mv = get(v, object_latent(sv.object))
                    put(v, "scale", (rest + sv.hang_m + (mv + ms / 2) * sv.gravity_mps2 / k) / sv.bottom_up["eq_below_top_m"])
        for v, s in enumerate(scenes):
            if s.bottom_up:
                for name in ("x0_m", "z0_m", "vx0_mps", "vz0_mps"):
                    put(v, name, getattr(s, name))
                rms = math.log10(max(1e-3, _rms_px(s, s.bottom_up)))
                put(v, "log10_sigma_x_px", rms)
                put(v, "log10_sigma_z_px", rms)
                put(v, "rho", START_RHO)
                put(v, "ox_px", 0.0)
                put(v, "oz_px", 0.0)
        x = np.where(guessed, x * (1 + START_JITTER * rng.standard_normal(len(x))), x)
        out[c] = np.clip(x, bounds[:, 0], bounds[:, 1])
    return out


def _rms_px(scene: SpringScene, fit: dict) -> float:
    """The fit's residual in pixels (its metres at the hanging point's scale)."""
    return fit["rms_m"] * px_per_m(scene.camera, scene.top_in_world_m)


# -- synthetic observations ----------------------------------------------------------------------------

def synthetic_tracks(scene: SpringScene, values: dict, rng: np.random.Generator, noise: float) -> Tracks:
    """What tracking would give at `values` under the likelihood's own model: the simulated centre
    projected to pixels plus AR(1) noise of SD sqrt(noise^2 + (10 ** log10_sigma_a_px)^2) across
    (a = x) and up-down (a = z) and correlation rho (values' or 1 px and 0), seen from the release on,
    back-projected."""
    from .physics import simulate

    cam = _camera(scene)
    sim_values = {k: v for k, v in values.items() if k not in NOISE_LATENTS}
    traj = simulate(scene, scene.n_frames, sim_values, scene.fps)
    s = scene.with_values(sim_values)
    top = np.asarray(s.top_in_world_m, float)
    shown = top + (traj.position_m[0] - top) / s.scale
    px = cam.project(shown)
    sigma = np.array([math.sqrt(noise ** 2 + 10.0 ** (2 * values.get(f"log10_sigma_{a}_px", 0.0))) for a in "xz"])
    rho = float(values.get("rho", 0.0))
    r = ar1_residuals(rng, px.shape, sigma, rho)
    px = px + (values.get("ox_px", 0.0), -values.get("oz_px", 0.0))   # (image y runs down)
    visible = np.arange(len(px)) >= s.release_frame
    return from_pixels(px + r, visible, scene.fps, s, release_frame=s.release_frame, detected_by="synthetic")


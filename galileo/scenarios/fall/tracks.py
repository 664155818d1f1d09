"""Between pixels and the likelihood: the tracker's pixel track as world tracks (lifted to 3-D),
the scene as inferred on (`prepare`: the release frame, the landing, the release state's priors
around it, a search that starts the chains), and synthetic observations (SBC, tests).

**Lifting a pixel to 3-D** needs one assumption about depth. Galileo uses the surface's plane
and the line of the fall:

* from the landing on (the first frame at which the centroid stops going down the image), the
  object is on or near the surface: its centre is where the pixel's ray meets the plane at the
  object's resting height (`rest_height_m`: half its least extent for a box, its radius for a
  cylinder, half its tube for a torus);
* before the landing, the object falls straight down onto the landing point (a hand lets go
  with a small horizontal speed: a few cm over a 30 cm fall): its centre is the point of the
  vertical line through the landing point nearest the pixel's ray.

The lift is for the user (3-D tracks, the drawn path, the resting place in cm) and for the
chains' starts; the likelihood does not use it (it projects the simulation back into the
image, `likelihood.py`), so the assumption costs the posterior nothing.

**Starts.** Before the chains, `prepare` fits the release position and velocity to the frames of
the fall alone (free fall, closed form: `ballistic`), then searches the rest with Bullet itself,
growing the stretch of track it fits from the first bounce to the whole clip (`search`); chains
start from its different fits.
"""
from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
from collections import OrderedDict

import numpy as np

from ...datatypes import ObjectTrack, Tracks
from ...errors import GalileoError
from ...framelik import ar1_residuals
from ...shapes import Shape
from ...vision.velocity import velocity_from_positions
from .scene import (
    NOISE_LATENTS,
    RELEASE_LATENTS,
    RELEASE_PRIOR,
    FallScene,
    pair_latents,
)

SEARCH_DRAWS = 3000         # prior draws scored (on the first stage's frames) before the chains start
# the search's stages (see `search`): (frames after the landing fitted (None: all), the noise SD assumed
# (px), Nelder-Mead evaluations per fit, fits kept)
SEARCH_STAGES = ((4, 8.0, 60, 24), (10, 4.0, 100, 10), (None, 2.0, 150, 8))
SEARCH_RHO = 0.5
PREPARED_KEPT = 8           # prepared scenes kept per process (`prepare`)
START_JITTER = 0.01         # chains start this fraction of each prior's width apart around the fit
START_NOISE = {"ox_px": 0.0, "oy_px": 0.0, "log10_sigma_px": 0.3, "rho": 0.5}
Z0_PRIOR_M = 0.10           # the tracked release height +- this (the lift's vertical-fall assumption;
XY_PRIOR_M = 0.10           # the landing point +- this  (a bouncy object is centimetres up at the landing frame)
BALLISTIC = ("x0_m", "y0_m", "z0_m", "vx0_mps", "vy0_mps", "vz0_mps")   # what the fall's own frames fit
RELEASE_LAG_FRAMES = 3      # the hand lets go at most this long before the tracked release frame


def _camera(scene: FallScene):
    if scene.camera is None:
        raise GalileoError("the fall scene has no camera: make one with `galileo scene VIDEO --scenario fall` "
                           "(four corners of the surface) or give \"camera\" in the scene file")
    return scene.camera


def rest_height_m(shape: Shape) -> float:
    """The centre's height when the object lies still in its most stable way."""
    if shape.type == "box":
        return min(shape.size_m) / 2
    if shape.type == "cylinder":
        return shape.size_m[1] / 2
    return shape.size_m[2] / 2


def rays(cam, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The camera's centre and the unit rays (N, 3) through pixels `uv` (N, 2), world frame
    (through the lens: `Camera.pixel_rays`)."""
    d = cam.pixel_rays(uv)
    return cam.position_in_world, d / np.linalg.norm(d, axis=1, keepdims=True)


def on_plane(cam, uv: np.ndarray, z_m: float) -> np.ndarray:
    """Where the pixels' rays meet the plane z = z_m (N, 3)."""
    o, d = rays(cam, uv)
    s = (z_m - o[2]) / d[:, 2]
    return o + s[:, None] * d


def on_vertical(cam, uv: np.ndarray, foot: np.ndarray) -> np.ndarray:
    """The points of the vertical line through `foot` nearest the pixels' rays (N, 3)."""
    o, d = rays(cam, uv)
    out = np.empty((len(d), 3))
    for i, di in enumerate(d):
        # closest points of o + s d and foot + h z: solve for h
        w0 = o - foot
        a, b, c = di @ di, di[2], 1.0
        dd, e = di @ w0, w0[2]
        den = a * c - b * b
        h = (a * e - b * dd) / den if abs(den) > 1e-12 else 0.0
        out[i] = (foot[0], foot[1], foot[2] + h)
    return out


def landing_frame(center_px: np.ndarray, seen: np.ndarray, release_frame: int) -> int:
    """The first frame after the release at which the centroid stops going down the image."""
    v = center_px[:, 1]
    frames = [f for f in range(release_frame, len(v)) if seen[f]]
    for a, b in itertools.pairwise(frames):
        if v[b] < v[a]:
            return a
    return frames[-1] if frames else release_frame


def from_pixels(center_px: np.ndarray, visible: np.ndarray, fps: float, scene: FallScene, *,
                release_frame: int, bottom_up: dict | None = None, notes=(), detected_by: str = "fall tracker") -> Tracks:
    """World tracks from the object's centroid in pixels, lifted as the module says; velocities
    by central differences that keep an impact's jump sharp (`galileo.vision.velocity`)."""
    cam = _camera(scene)
    c = np.asarray(center_px, float)
    seen = np.asarray(visible, bool) & np.isfinite(c).all(axis=1)
    pos = np.full((len(c), 3), np.nan)
    land = landing_frame(c, seen, release_frame)
    h = rest_height_m(scene.shape)
    if seen.any():
        pos[seen] = on_plane(cam, c[seen], h)
        before = seen & (np.arange(len(c)) < land)
        if before.any() and seen[land]:
            pos[before] = on_vertical(cam, c[before], pos[land])
    vel = velocity_from_positions(pos, seen, fps)      # (sharp across the impacts)
    vel[seen & ~np.isfinite(vel).all(axis=1)] = 0.0     # a frame seen alone
    bu = {"release_frame": int(release_frame), "landing_frame": int(land), **(bottom_up or {})}
    obj = ObjectTrack(scene.object, "object", pos, vel, seen, scene.shape, detected_by=detected_by, bottom_up=bu,
                      center_px=c)
    return Tracks(float(fps), [obj], list(notes))


def track(video_path, scene: FallScene, *, progress: bool = True, debug_video=None) -> Tracks:
    """Pixels -> observations: the tracker (`tracking.py`), looking inside the surface's outline."""
    from .scene import surface_corners_m
    from .tracking import track_pixels

    cam = _camera(scene)
    region = cam.project(surface_corners_m(scene))
    pt = track_pixels(video_path, region_px=region, progress=progress, debug_video=debug_video)
    bu = {"method": pt.method, "rest_frame": pt.rest_frame}
    return from_pixels(pt.center_px, pt.visible, pt.fps, scene, release_frame=pt.release_frame,
                       bottom_up={k: v for k, v in bu.items() if v is not None}, notes=pt.notes)


# -- the scene as inferred on ----------------------------------------------------------------------

def _release_of(tracks: Tracks) -> int:
    obj = tracks.objects[0]
    rf = obj.bottom_up.get("release_frame") if obj.bottom_up else None
    seen = np.flatnonzero(np.asarray(obj.visible, bool))
    if rf is None:
        if not len(seen):
            raise GalileoError("the object is never seen: nothing to infer from")
        rf = int(seen[0])
    return int(rf)


_PREPARED: OrderedDict[str, FallScene] = OrderedDict()   # the last few prepared scenes, by their inputs


def prepare(scene: FallScene, tracks: Tracks) -> FallScene:
    """The scene as inferred on: the tracked release frame, the release state's priors around
    the tracked release (the lift: the landing point, the height on the line of the fall), and
    the search's fits in `bottom_up` (see the module docstring). Deterministic, and seconds of
    search: the process keeps the last PREPARED_KEPT (a session reopened, a run resumed, a
    problem's videos prepared again in its workers)."""
    key = hashlib.sha256(json.dumps([scene.to_json(), tracks.to_json()], sort_keys=True).encode()).hexdigest()
    if key in _PREPARED:
        _PREPARED.move_to_end(key)
        return _PREPARED[key]
    out = _prepare(scene, tracks)
    _PREPARED[key] = out
    while len(_PREPARED) > PREPARED_KEPT:
        _PREPARED.popitem(last=False)
    return out


def _prepare(scene: FallScene, tracks: Tracks) -> FallScene:
    obj = tracks.objects[0]
    n = tracks.n_frames
    rf = _release_of(tracks)
    if not 0 <= rf < n - 1:
        raise GalileoError(f"the release frame ({rf}) leaves no frame after it in the {n}-frame tracks")
    seen = np.asarray(obj.visible, bool) & np.isfinite(np.asarray(obj.position_m, float)).all(axis=1)
    after = np.flatnonzero(seen & (np.arange(n) >= rf))
    if len(after) < 3:
        raise GalileoError(f"the object is seen in {len(after)} frames after the release (frame {rf}): too few to "
                           "infer from (is anything falling?)")
    pos = np.asarray(obj.position_m, float)
    land = int(obj.bottom_up.get("landing_frame", after[-1])) if obj.bottom_up else int(after[-1])
    land = land if seen[land] else int(after[-1])
    x, y = float(pos[land, 0]), float(pos[land, 1])
    z0 = float(pos[after[0], 2]) if after[0] < land else rest_height_m(scene.shape) + 0.01
    z0 = max(z0, rest_height_m(scene.shape) + 0.005)
    rest = pos[after[-1]]
    s = dataclasses.replace(scene, release_frame=rf, n_frames=n, fps=float(tracks.fps),
                            camera=None if scene.camera is None else dataclasses.replace(
                                scene.camera, fps=float(tracks.fps), n_frames=n))
    centre = {"x0_m": (x, XY_PRIOR_M), "y0_m": (y, XY_PRIOR_M), "z0_m": (z0, Z0_PRIOR_M)}
    priors = dict(s.priors)
    for name in RELEASE_LATENTS:
        if name in scene.priors:
            continue
        mid, w = centre.get(name, (0.0, RELEASE_PRIOR[name]))
        lo, hi = mid - w, mid + w
        if name == "z0_m":
            lo = max(lo, 0.0)
        priors[name] = (lo, hi)
    values = {name: float(np.clip(c[0], priors[name][0], priors[name][1])) for name, c in centre.items()}
    s = dataclasses.replace(s, priors=priors, x0_m=values["x0_m"], y0_m=values["y0_m"], z0_m=values["z0_m"],
                            roll0_rad=0.0, pitch0_rad=0.0, yaw0_rad=0.0, vx0_mps=0.0, vy0_mps=0.0, vz0_mps=0.0,
                            wx0_radps=0.0, wy0_radps=0.0, wz0_radps=0.0)
    s.validate()
    bu = {"landing_frame": float(land), "landing_x_m": x, "landing_y_m": y, "release_height_m": z0,
          "rest_x_m": float(rest[0]), "rest_y_m": float(rest[1])}
    fall = ballistic(s, tracks, rf, land)
    if fall is not None:
        s = dataclasses.replace(s, **{k: float(np.clip(fall[k], *priors[k])) for k in BALLISTIC})
        bu["ballistic_rms_px"] = fall["rms_px"]
    for i, fit in enumerate(search(s, tracks, land)):
        bu.update({f"fit{i}_{k}": v for k, v in fit.items()})
    return dataclasses.replace(s, bottom_up=bu)


def ballistic(scene: FallScene, tracks: Tracks, release: int, landing: int) -> dict | None:
    """The release position and velocity from the frames of the fall alone (release to landing):
    a fall from rest let go at a time t_r up to RELEASE_LAG_FRAMES before the tracked release frame
    (a tracker finds the object once it has parted from the hand), drifting sideways at a constant
    small speed: p(t) = p_r + v_h (t - t_r) - g (t - t_r)^2 / 2 z, projected and fitted to the
    tracked pixels (least squares, inside the scene's priors); then the state it gives at the
    release frame. A fall with a free vertical speed would leave the depth along the camera's rays
    loose over a few noisy frames (a nearer, lower, slower fall looks much the same); a fall from
    rest does not. None with fewer than 3 frames. {x0_m, ..., vz0_mps, rms_px}."""
    from scipy.optimize import least_squares

    cam = _camera(scene)
    obj = tracks.objects[0]
    seen = np.asarray(obj.visible, bool)
    frames = np.array([f for f in range(release, landing) if seen[f]])
    if len(frames) < 3:
        return None
    obs = cam.project(np.asarray(obj.position_m, float)[frames])
    t = (frames - release) / tracks.fps
    g = scene.gravity_mps2
    lag = RELEASE_LAG_FRAMES / tracks.fps
    drift = RELEASE_PRIOR["vx0_mps"]

    def state(p):
        x, y, z, tr, vx, vy = p
        return x - vx * tr, y - vy * tr, z - 0.5 * g * tr * tr, vx, vy, g * tr     # at t = 0 (tr <= 0)

    def resid(p):
        x, y, z, tr, vx, vy = p
        dt = t - tr
        pos = np.c_[x + vx * dt, y + vy * dt, z - 0.5 * g * dt * dt]
        return (cam.project(pos) - obs).ravel()

    box = {lat.name: lat.bounds for lat in scene.latent_specs()}
    lo = [box["x0_m"][0], box["y0_m"][0], box["z0_m"][0], -lag, -drift, -drift]
    hi = [box["x0_m"][1], box["y0_m"][1], box["z0_m"][1] + 0.5 * g * lag * lag, 0.0, drift, drift]
    p0 = np.clip([scene.x0_m, scene.y0_m, scene.z0_m, -0.5 / tracks.fps, 0.0, 0.0], lo, hi)
    r = least_squares(resid, p0, bounds=(lo, hi))
    return {**dict(zip(BALLISTIC, map(float, state(r.x)))), "rms_px": float(np.sqrt(np.mean(r.fun ** 2)))}


def first_frames(tracks: Tracks, last_frame: int) -> Tracks:
    """The tracks of frames 0..last_frame only (a prediction's input; the search's early stages)."""
    n = min(tracks.n_frames, last_frame + 1)
    objs = [dataclasses.replace(o, position_m=np.asarray(o.position_m)[:n], velocity_mps=np.asarray(o.velocity_mps)[:n],
                                visible=np.asarray(o.visible)[:n],
                                center_px=None if o.center_px is None else np.asarray(o.center_px)[:n])
            for o in tracks.objects]
    return dataclasses.replace(tracks, objects=objs)


def search(scene: FallScene, tracks: Tracks, landing: int, *, draws: int = SEARCH_DRAWS, seed: int = 0) -> list[dict]:
    """The best fits of the release state and the coefficients to the track, best first:
    [{latent: value, "log_lik": its value at the tracker's noise}] for up to SEARCH_STAGES[-1]'s
    keep places. A tumble is chaotic: a fit to the whole track from a guess is lost among the
    local optima that the later frames make. So the search grows the track it fits (continuation):
    `draws` draws from the priors (the release position and velocity at the fall's own fit) are
    scored on the frames up to a few after the landing; the best are polished by Nelder-Mead there,
    the best of those on more frames, and so on to the whole track, each stage at a finer noise
    (`SEARCH_STAGES`). Chains start from the different fits (`starts`): a landing can be explained
    several ways, and the chains should find each that the whole track allows."""
    from scipy.optimize import minimize

    from .likelihood import FallLikelihood

    specs = [lat for lat in scene.latent_specs() if lat.name not in NOISE_LATENTS]
    lo = np.array([lat.bounds[0] for lat in specs])
    hi = np.array([lat.bounds[1] for lat in specs])
    names = [lat.name for lat in specs] + list(NOISE_LATENTS)
    land = landing
    rng = np.random.default_rng(seed)

    def scorer(after_landing, sigma_px):
        last = tracks.n_frames - 1 if after_landing is None else min(tracks.n_frames - 1, land + after_landing)
        lik = FallLikelihood(scene, first_frames(tracks, last), names, 0.5)
        noise = np.array([0.0, 0.0, math.log10(sigma_px), SEARCH_RHO])

        def value(x, limit=math.inf) -> float:
            if np.any(x < lo) or np.any(x > hi):
                return math.inf
            v, _ = lik(np.r_[x, noise], None if not math.isfinite(limit) else -limit)
            return -v if math.isfinite(v) else math.inf
        return value

    xs = lo + (hi - lo) * rng.random((draws, len(lo)))
    here = np.array([scene.latents()[lat.name] for lat in specs])
    kept = [j for j, lat in enumerate(specs) if lat.name in BALLISTIC]
    xs[::2, kept] = here[kept]      # half the draws at the fall's own fit (prepare), half anywhere
    xs[0] = here                    # the tracked release, level and still
    after, sigma, _, keep = SEARCH_STAGES[0]
    value = scorer(after, sigma)
    vals = np.empty(draws)
    worst = math.inf                # early rejection against the keep-th best so far
    for i, x in enumerate(xs):
        vals[i] = value(x, worst)
        if i >= keep:
            worst = float(np.partition(vals[: i + 1], keep - 1)[keep - 1])
    found = [xs[i] for i in np.argsort(vals)[:keep] if math.isfinite(vals[i])]
    if not found:
        raise GalileoError("no release state in the priors starts a fall that can be simulated: the object starts "
                           "inside the surface (check the scene's camera and the object's size)")
    for after, sigma, evals, keep in SEARCH_STAGES:
        value = scorer(after, sigma)
        polished = []
        for x in found:
            v0 = value(x)
            r = minimize(value, x, method="Nelder-Mead",
                         options={"maxfev": evals, "initial_simplex": _simplex(x, lo, hi, 0.05 if after else 0.02)})
            polished.append((r.x, float(r.fun)) if r.fun < v0 else (x, v0))
        polished.sort(key=lambda p: p[1])
        found = [x for x, v in polished[:keep] if math.isfinite(v)] or [polished[0][0]]
        best = polished[:keep]
    return [{**{lat.name: float(a) for lat, a in zip(specs, x)}, "log_lik": -v} for x, v in best]


def _simplex(x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, width: float) -> np.ndarray:
    step = width * (hi - lo)
    out = [x0]
    for j in range(len(x0)):
        x = x0.copy()
        x[j] = x[j] + step[j] if x[j] + step[j] <= hi[j] else x[j] - step[j]
        out.append(x)
    return np.array(out)


def starts(scene: FallScene, latents, bounds: np.ndarray, n_chains: int, seed: int) -> np.ndarray:
    """Chain c starts around the search's fit c (mod their number; `bottom_up`), START_JITTER of
    each prior's width away; the noise latents at START_NOISE; without fits, from the prior.
    Chain c's start depends on c and the seed alone."""
    bounds = np.asarray(bounds, float)
    names = [lat.name for lat in latents]
    fits = fits_of(scene)
    out = np.empty((n_chains, len(names)))
    for c in range(n_chains):
        rng = np.random.default_rng([seed, c])
        fit = fits[c % len(fits)] if fits else {}
        for j, name in enumerate(names):
            lo, hi = bounds[j]
            mid = fit.get(name, START_NOISE.get(name))
            if mid is None:
                out[c, j] = lo + (hi - lo) * rng.random()
            else:
                out[c, j] = float(np.clip(mid + START_JITTER * (hi - lo) * rng.standard_normal(), lo, hi))
    return out


def fits_of(scene: FallScene) -> list[dict]:
    """The search's fits kept in a prepared scene's `bottom_up`, best first."""
    out: dict[int, dict] = {}
    for k, v in scene.bottom_up.items():
        head, _, name = k.partition("_")
        if head.startswith("fit") and head[3:].isdigit():
            out.setdefault(int(head[3:]), {})[name] = v
    return [out[i] for i in sorted(out)]


def synthetic_tracks(scene: FallScene, values: dict, rng: np.random.Generator, noise: float) -> Tracks:
    """What tracking would give at `values` under the likelihood's own model: the simulated centre
    projected to pixels, plus the offsets and AR(1) noise of SD sqrt(noise^2 + 10^(2 log10_sigma_px))
    and correlation rho (values' or 1 px and 0), seen from the release on, lifted."""
    from .physics import simulate

    cam = _camera(scene)
    sim_values = {k: v for k, v in values.items() if k not in NOISE_LATENTS}
    traj = simulate(scene, scene.n_frames, sim_values, scene.fps)
    s = scene.with_values(sim_values)
    px = cam.project(traj.position_m[0])
    sigma = math.sqrt(noise ** 2 + 10.0 ** (2 * values.get("log10_sigma_px", 0.0)))
    rho = float(values.get("rho", 0.0))
    r = ar1_residuals(rng, px.shape, sigma, rho)
    px = px + (values.get("ox_px", 0.0), values.get("oy_px", 0.0))
    visible = np.arange(len(px)) >= s.release_frame
    return from_pixels(px + r, visible, scene.fps, s, release_frame=s.release_frame, detected_by="synthetic")


def pair_names(scene: FallScene) -> dict[str, str]:
    return pair_latents(scene.object, scene.surface)

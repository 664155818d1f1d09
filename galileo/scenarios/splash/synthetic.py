"""Observations the splash likelihood assumes, simulated (for simulation-based calibration,
`galileo calibrate --scenario splash`, and the scenario contract tests).

The likelihood (`likelihood.py`) compares the tracked position (x, z) and velocity (vx, vz) of
the object at every frame where it was seen with the simulation's, with Gaussian noise of SD
sigma_px pixels (positions) and pixels per frame (velocities) at the release point's depth. Here
the simulation's motion at the given values (`SplashLikelihood.motion`: the same start step,
rest rule and frames) gets exactly that noise, every frame seen; the shape kind and volume the
tracker would report are the scene's own (`bottom_up`), so `prepare` keeps the scene as it is."""
from __future__ import annotations

import numpy as np

from ...datatypes import ObjectTrack, Tracks
from ...errors import GalileoError
from .physics import Body
from .scene import CM2


def skeleton(scene) -> Tracks:
    """Tracks of the object held at its release point, every frame seen (what a likelihood needs
    to be built before there are observations)."""
    cam = scene.camera
    if cam is None:
        raise GalileoError("splash observations are in the camera's pixels: the scene needs a camera")
    n = int(cam.n_frames)
    o = scene.obj
    shape = Body.of(o.kind, scene.volume_m3, o.area_cm2 * CM2, scene.max_dim_m()).shape
    pos = np.tile(np.asarray(scene.release_m, float), (n, 1))
    obj = ObjectTrack(o.name, "object", pos, np.zeros((n, 3)), np.ones(n, bool), shape, None, "motion",
                      {"kind": o.kind, "volume_cm3": o.volume_cm3})
    return Tracks(float(cam.fps), [obj])


def synthetic_tracks(scene, values: dict, rng: np.random.Generator, noise: float) -> Tracks:
    """The likelihood's motion at `values` plus N(0, noise^2) pixels on x, z and px/frame on vx, vz."""
    from .likelihood import SplashLikelihood, metres_per_pixel

    if not (isinstance(noise, (int, float)) and noise >= 0):
        raise GalileoError(f"noise must be a number >= 0, got {noise!r}")
    base = skeleton(scene)
    lik = SplashLikelihood(scene, base, 1.0)
    missing = [n for n in lik.names if n not in values]
    if missing:
        raise GalileoError(f"synthetic tracks need values for {', '.join(missing)}")
    traj = lik.motion([float(values[n]) for n in lik.names])
    mpp = metres_per_pixel(scene)
    n = traj.position_m.shape[1]
    pos = np.array(traj.position_m[0], float)
    vel = np.array(traj.velocity_mps[0], float)
    pos[:, [0, 2]] += rng.normal(0.0, noise * mpp, size=(n, 2))
    vel[:, [0, 2]] += rng.normal(0.0, noise * mpp * base.fps, size=(n, 2))
    obj = base.objects[0]
    out = ObjectTrack(obj.name, obj.role, pos, vel, obj.visible, obj.shape, None, "motion", dict(obj.bottom_up))
    return Tracks(base.fps, [out], [f"synthetic: the likelihood's motion plus N(0, {noise:g}^2) px on x, z, vx, vz"])

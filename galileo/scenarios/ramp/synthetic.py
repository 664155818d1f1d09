"""Synthetic observations for calibration (`galileo calibrate`): tracks simulated from the
very model the ramp's likelihood scores, and random scenes like the dataset's.

`synthetic_tracks(scene, values, rng, noise)`: the tracks the likelihood assumes. The
velocities are the likelihood's own `VelocityLikelihood.motion` at `values` (both phases,
the rest rule: exactly the motion it scores, not a plain Bullet run) plus iid noise of the
scene's observation model (`priors.observation`: a Student-t of `student_t_dof` degrees of
freedom and scale `noise`, or N(0, noise^2) for the Gaussian; with the sigma latent,
`priors.infer_sigma`, its value in `values` sets the scale instead) on the x and z
components of every frame (y is 0, as the tracker reports it); positions
are the motion's, noise-free (the likelihood does not score them; the k1 move reads them to
find the ramp phase); every frame is visible; shapes and the offset are the scene's. No
rendering and no tracking: the observation model alone, so a calibration run isolates the
inference (the sampler, its moves) from the tracker.

`random_scene(rng)`: a scene like the `small` / `full` presets' (`dataset.scene_for`): angle
10 or 20 degrees, target none / cardboard / foam (its shape, and distance from the ramp's
foot, drawn as the dataset draws them), the ramp object's shape that of a random catalogue
object, offset uniform in -5..5, the default priors and a 30 fps camera of FRAMES frames.
Its frame count is fixed, not the dataset's `video_length` (which depends on the true
latents: data the likelihood does not model, so a posterior would not be exact for it).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ...datatypes import ObjectTrack, Tracks
from ...errors import GalileoError

FPS = 30.0
FRAMES = 61          # 2 s at 30 fps: the dataset's shortest video
ANGLES_DEG = (10.0, 20.0)
TARGETS = ("none", "cardboard", "foam")


def timing(scene) -> tuple[float, int]:
    """(fps, frames) of the observations: the scene camera's, else FPS and FRAMES."""
    cam = scene.camera
    return (float(cam.fps), int(cam.n_frames)) if cam is not None else (FPS, FRAMES)


def skeleton(scene, n_frames: int, fps: float) -> Tracks:
    """Tracks of the scene's objects at rest where it puts them, every frame visible, zero
    velocities (what a likelihood needs to be built before there are observations)."""
    objects = []
    for i, obj in enumerate(scene.objects):
        pos, _ = scene.initial_pose(i)
        ramp = obj.role == "ramp"
        objects.append(ObjectTrack(obj.name, obj.role, np.tile(np.asarray(pos, float), (n_frames, 1)),
                                   np.zeros((n_frames, 3)), np.ones(n_frames, bool), obj.shape,
                                   int(obj.offset_units) if ramp else None, "motion" if ramp else "scene"))
    return Tracks(float(fps), objects)


def noise_free_motion(scene, values: dict):
    """(tracks skeleton, the likelihood's motion at `values`, the values in the likelihood's
    order by name): `VelocityLikelihood.motion`."""
    from .likelihood import VelocityLikelihood

    fps, n = timing(scene)
    base = skeleton(scene, n, fps)
    lik = VelocityLikelihood(scene, base, 1.0)
    full = {**scene.latents(), **{k: float(v) for k, v in values.items()}}
    missing = [name for name in lik.names if name not in full]
    if missing:
        raise GalileoError(f"synthetic tracks need values for {', '.join(missing)}")
    used = {name: full[name] for name in lik.names}
    return base, lik.motion(list(used.values())), used


def synthetic_tracks(scene, values: dict, rng: np.random.Generator, noise: float) -> Tracks:
    """The observations the likelihood assumes, simulated at `values` (see the module)."""
    from .likelihood import SIGMA_LATENT

    if not (isinstance(noise, (int, float)) and noise >= 0):
        raise GalileoError(f"noise must be a number >= 0, got {noise!r}")
    base, traj, used = noise_free_motion(scene, values)
    # the scale: the sigma latent's value where the scene infers sigma, else `noise`
    scale = 10.0 ** used[SIGMA_LATENT] if SIGMA_LATENT in used else float(noise)
    n_obj, n = traj.velocity_mps.shape[:2]
    priors = scene.priors
    if priors.observation == "student_t":   # the scene's observation model
        eps = rng.standard_t(priors.student_t_dof, size=(n_obj, n, 2)) * scale
        what = "t(%g) noise of scale %g" % (priors.student_t_dof, scale)
    else:
        eps = rng.normal(0.0, 1.0, size=(n_obj, n, 2)) * scale
        what = "N(0, %g^2)" % scale
    out = []
    for i, tr in enumerate(base.objects):
        vel = np.zeros((n, 3))
        vel[:, 0] = traj.velocity_mps[i, :, 0] + eps[i, :, 0]
        vel[:, 2] = traj.velocity_mps[i, :, 2] + eps[i, :, 1]
        out.append(dataclasses.replace(tr, position_m=np.array(traj.position_m[i], float), velocity_mps=vel))
    return Tracks(base.fps, out, ["synthetic: the likelihood's motion plus %s on vx, vz" % what])


def random_scene(rng: np.random.Generator):
    """A scene like the dataset presets' (see the module docstring)."""
    from ...errors import SceneError
    from .materials import catalogue, sample_target
    from .scene import Ramp, Scene, SceneObject, default_camera

    objs = catalogue(0)
    for _ in range(100):   # a long object with a high offset may not fit on the ramp: draw again
        obj = objs[int(rng.integers(len(objs)))]
        angle = ANGLES_DEG[int(rng.integers(len(ANGLES_DEG)))]
        target = TARGETS[int(rng.integers(len(TARGETS)))]
        offset = int(rng.integers(-5, 6))
        objects = [SceneObject("ramp_object", "ramp", obj.shape, obj.mass_kg, obj.friction,
                               material=obj.material, offset_units=offset)]
        if target != "none":
            shape, mass, friction = sample_target(target, rng)
            objects.append(SceneObject("target", "target", shape, mass, friction, material=target, kind=target,
                                       distance_m=float(rng.uniform(0.08, 0.14))))
        scene = Scene(Ramp(angle_deg=angle), tuple(objects), camera=default_camera(FPS, FRAMES))
        try:
            scene.validate()
        except SceneError:
            continue
        return scene
    raise GalileoError("no valid random ramp scene in 100 draws")


def describe(scene) -> dict:
    """A short description of a scene for calibration reports."""
    ro = scene.ramp_object
    return {"angle_deg": scene.ramp.angle_deg, "target": scene.target.kind if scene.target is not None else "none",
            "shape": ro.shape.to_json(), "offset_units": ro.offset_units}

"""Rendered Physics-101-style ramp videos with ground truth (`galileo dataset`).

Presets:
* demo  - the app's default video: a wooden block sliding down the 20 degree ramp into
          a cardboard box.
* small - 20 videos: 10 objects (10 materials) each filmed at 10 and 20 degrees; for tests.
* full  - 150 videos: the whole catalogue of 75 objects (15 materials, 4-6 objects each)
          each filmed at 10 and 20 degrees, targets cycling cardboard / foam / none.

Each video folder holds video.mp4 (H.264, 640x480, 30 fps), scene.json (everything to
simulate it and its camera) and truth.json (latents and the simulated trajectory).
The output folder also gets index.json listing the videos. Filmed through a camera's
effects (`galileo.footage`, the plan's camera; clean by default) the video is that camera's,
scene.json's camera carries its lens (k1) and truth.json what the camera did ("camera");
the latents and the trajectory are the clean video's. Deterministic per seed; built by
`galileo.dataset.build` (parallel, resumable) from `DATASET`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ... import dataset
from ...errors import GalileoError
from ...jsonio import write_json
from .materials import MATERIALS, MATERIALS_BY_NAME, CatalogueObject, catalogue, sample_target
from .physics import Simulator
from .scene import Ramp, Scene, SceneObject, default_camera
from ...shapes import Shape

PRESETS = ("demo", "small", "full", "bounce")
BOUNCE_RESTITUTION = (0.2, 0.4)   # "bounce": the collision's restitution, uniform over this (issue 30) ...
BOUNCE_MAX_FRICTION = 0.28        # ... the objects of friction below this (at 20 degrees all but one reach the target)
TARGET_CYCLE = ("cardboard", "foam", "none")
FPS = 30.0
MIN_DURATION_S, MAX_DURATION_S, TAIL_S = 2.0, 4.0, 0.5
REST_SPEED_MPS = 0.003


@dataclass(frozen=True)
class VideoSpec:
    name: str
    obj: CatalogueObject
    angle_deg: float
    target: str  # cardboard | foam | none
    seed: int
    camera: str = "clean"   # the camera effects it is filmed through (galileo.footage's name)
    restitution: float | None = None   # the collision's restitution (None: the objects' own, 0); the scene
                                       # file leaves it out: a user's does not know it (truth.json has it)


def _demo_object() -> CatalogueObject:
    return CatalogueObject("wooden block", 0, Shape("box", (0.07, 0.05, 0.05)), 0.16, 0.22)


def plan(preset: str, seed: int = 0, camera: str = "clean") -> list[VideoSpec]:
    """The videos a preset renders (names, objects, angles, targets, per-video seeds), filmed
    through `camera`'s effects."""
    if preset not in PRESETS:
        raise GalileoError(f"unknown preset {preset!r}; expected one of {', '.join(PRESETS)}")
    if preset == "demo":
        return [VideoSpec("demo", _demo_object(), 20.0, "cardboard", seed, camera)]
    objs = catalogue(seed)
    if preset == "bounce":
        # every catalogue object that slides at 20 degrees into the target (friction below BOUNCE_MAX_FRICTION:
        # above it most stop before the target), the collision bouncing
        specs = []
        sliding = [o for o in objs if o.friction < BOUNCE_MAX_FRICTION]
        for i, obj in enumerate(sliding):
            target = TARGET_CYCLE[i % 2]
            vseed = int(np.random.SeedSequence([seed, 1000 + i]).generate_state(1)[0])
            e = float(np.random.default_rng([vseed, 7]).uniform(*BOUNCE_RESTITUTION))
            slug = obj.material.replace(" ", "-")
            specs.append(VideoSpec(f"{i:03d}_{slug}{obj.index}_20deg_{target}_e{round(100 * e):02d}", obj, 20.0,
                                   target, vseed, camera, e))
        return specs
    if preset == "small":
        # one object from each of 10 materials, spread over the friction range
        picks = ["metal coin", "metal pole", "porcelain", "plastic block", "plastic ring",
                 "wooden block", "hollow wood", "plastic toy", "dough", "rubber"]
        objs = [next(o for o in objs if o.material == m) for m in picks]
    specs = []
    for i, obj in enumerate(objs):
        target = TARGET_CYCLE[i % 3] if preset == "full" else ("none" if i % 5 == 4 else TARGET_CYCLE[i % 2])
        for angle in (20.0, 10.0):
            slug = obj.material.replace(" ", "-")
            specs.append(VideoSpec(f"{len(specs):03d}_{slug}{obj.index}_{int(angle)}deg_{target}",
                                   obj, angle, target, int(np.random.SeedSequence([seed, len(specs)]).generate_state(1)[0]),
                                   camera))
    return specs


def scene_for(spec: VideoSpec) -> Scene:
    """The scene of a planned video (camera frame count still to be set)."""
    rng = np.random.default_rng(spec.seed)
    offset = int(rng.integers(-5, 6))
    ramp_obj = SceneObject("ramp_object", "ramp", spec.obj.shape, spec.obj.mass_kg, spec.obj.friction,
                           material=spec.obj.material, offset_units=offset)
    objects = [ramp_obj]
    if spec.target != "none":
        shape, mass, friction = sample_target(spec.target, rng)
        objects.append(SceneObject("target", "target", shape, mass, friction, material=spec.target,
                                   kind=spec.target, distance_m=float(rng.uniform(0.08, 0.14))))
    scene = Scene(Ramp(angle_deg=spec.angle_deg), tuple(objects), camera=default_camera(FPS),
                  collision_restitution=spec.restitution)
    scene.validate()
    return scene


def video_length(scene: Scene) -> int:
    """Frames until every object has been at rest for TAIL_S (within [MIN, MAX] duration)."""
    max_frames = int(MAX_DURATION_S * FPS) + 1
    traj = Simulator(scene).run(max_frames, fps=FPS)
    speed = np.linalg.norm(traj.velocity_mps, axis=2).max(axis=0)
    moving = np.nonzero(speed > REST_SPEED_MPS)[0]
    last = int(moving[-1]) if len(moving) else 0
    n = last + 1 + int(TAIL_S * FPS)
    return int(np.clip(n, int(MIN_DURATION_S * FPS) + 1, max_frames))


def truth_json(scene: Scene, spec: VideoSpec, traj) -> dict:
    ro = scene.ramp_object
    latents = {"m1_kg": ro.mass_kg, "k1": ro.friction, "shape1": ro.shape.to_json(),
               "offset_units": ro.offset_units, "material": ro.material, "angle_deg": scene.ramp.angle_deg,
               "target": spec.target}
    if scene.target is not None:
        t = scene.target
        latents.update({"m2_kg": t.mass_kg, "k2": t.friction, "shape2": t.shape.to_json()})
        latents["e_collision"] = scene.collision_e()   # the preset's, else the objects' pair's
    return {"latents": latents, "trajectory": traj.to_json()}


def render_one(spec: VideoSpec, out_dir: str) -> dict:
    """Render one video folder; returns its index entry."""
    from ...footage import Footage, effects_from_name
    from ...render import Look
    from .render import render_to_video

    folder = Path(out_dir) / spec.name
    scene = scene_for(spec)
    n = video_length(scene)
    scene = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, n_frames=n))
    rng = np.random.default_rng([spec.seed, 1])
    footage = None if spec.camera == "clean" else Footage(effects_from_name(spec.camera), scene.camera, spec.seed)
    traj = render_to_video(scene, folder / "video.mp4", n, look=Look.random(rng), texture_seed=spec.seed,
                           footage=footage)
    truth = truth_json(scene, spec, traj)
    if footage is not None:
        scene = dataclasses.replace(scene, camera=footage.camera)
        truth["camera"] = {"name": spec.camera, **footage.to_json()}
    dataclasses.replace(scene, collision_restitution=None).save(folder / "scene.json")   # (the user's: unknown)
    write_json(folder / "truth.json", truth, indent=None)
    return {"name": spec.name, "material": spec.obj.material, "object": f"{spec.obj.material}#{spec.obj.index}",
            "angle_deg": spec.angle_deg, "target": spec.target, "n_frames": n,
            **({"restitution": spec.restitution} if spec.restitution is not None else {})}


DATASET = dataset.DatasetSpec("ramp", PRESETS, plan, render_one, index_names_scenario=False, cameras=True,
                              describe="objects sliding down a 10 or 20 degree ramp: demo (1 video), small (20), full (150)")


def build(preset: str, out: str | Path, **kw) -> list[dict]:
    """`galileo.dataset.build` of the ramp's `DATASET` (kept for the callers from before it)."""
    return dataset.build(DATASET, preset, out, **kw)


def material_table() -> list[dict]:
    return [{"name": m.name, "density_kgpm3": m.density_kgpm3, "friction": m.friction,
             "shapes": sorted({s[0] for s in m.shapes}), "n_objects": m.n_objects} for m in MATERIALS]


__all__ = ["DATASET", "PRESETS", "VideoSpec", "plan", "scene_for", "build", "render_one", "MATERIALS_BY_NAME", "material_table"]

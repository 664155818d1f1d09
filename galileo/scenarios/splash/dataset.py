"""Rendered splash videos with ground truth (`galileo dataset --scenario splash`).

Presets:
* demo  - one video (2 s): a 3 cm plastic block (1.3 g/cm^3) dropped 15 cm into the water; it sinks.
* small - 8 videos: one object of each of 4 sinking and 4 floating materials; for tests.
* full  - 72 videos: the catalogue's 36 objects (13 materials, see materials.py), each
          filmed twice (release point, start frame, light and noise drawn anew).

Per video: the release point x ~ U(-5, 5) cm, 12-20 cm above the water (0.16-0.2 s of
fall, 37-48 physics steps); the start t (the physics step shown as the video's frame 0) ~
U{5, ..., 30} as the seed's prior says, so every video opens with the object falling
through the air (1-5 frames) before it meets the water. The video runs until the object
has been at rest for TAIL_S, within [MIN_FRAMES, MAX_DURATION_S].

Each video folder holds video.mp4 (H.264, 640x480, 30 fps), scene.json (the splash scene,
its camera and the true latents) and truth.json (latents and the shown frames' trajectory);
the output folder gets index.json. Deterministic per seed; built by `galileo.dataset.build`
(parallel, resumable) from `DATASET`.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ... import dataset
from ...errors import GalileoError
from ...jsonio import write_json
from .materials import FLOATERS, SINKERS, CatalogueObject, catalogue
from .physics import Simulator
from .scene import SplashObject, SplashScene, Tank, default_camera

PRESETS = ("demo", "small", "full")
FPS = 30.0
START_STEPS = (5, 30)           # the seed's prior on the start (physics steps)
REST_SPEED_MPS = 0.005          # below this the object counts as at rest
TAIL_S, MAX_DURATION_S, MIN_FRAMES = 0.5, 3.0, 30
DEMO_FRAMES = 60
RELEASE_X_M, RELEASE_HEIGHT_M = (-0.05, 0.05), (0.12, 0.20)
SMALL_PICKS = ("plastic block", "metal pole", "porcelain", "rubber",            # sinkers
               "wooden block", "foam", "hollow plastic", "wooden pole")         # floaters


@dataclass(frozen=True)
class VideoSpec:
    name: str
    obj: CatalogueObject
    seed: int
    demo: bool = False


def _demo_object() -> CatalogueObject:
    return CatalogueObject("plastic block", 0, "box", 27.0, 9.0, 1.3, 1.05)


def _seed(seed: int, i: int) -> int:
    return int(np.random.SeedSequence([seed, i]).generate_state(1)[0])


def plan(preset: str, seed: int = 0) -> list[VideoSpec]:
    """The videos a preset renders (names, objects, per-video seeds)."""
    if preset not in PRESETS:
        raise GalileoError(f"unknown preset {preset!r}; expected one of {', '.join(PRESETS)}")
    if preset == "demo":
        return [VideoSpec("demo", _demo_object(), seed, demo=True)]
    objs = catalogue(seed)
    takes = 2
    if preset == "small":
        objs = [next(o for o in objs if o.material == m) for m in SMALL_PICKS]
        takes = 1
    specs: list[VideoSpec] = []
    for obj in objs:
        for _ in range(takes):
            specs.append(VideoSpec(f"{len(specs):03d}_{obj.name}", obj, _seed(seed, len(specs))))
    return specs


def _settle_frame(scene: SplashScene) -> int:
    """The last video frame (from the scene's start step) in which the object still moves."""
    n = int(MAX_DURATION_S * FPS)
    speed = np.linalg.norm(Simulator(scene).run(n, start_step=scene.start_step).velocity_mps[0], axis=1)
    moving = np.nonzero(speed > REST_SPEED_MPS)[0]
    return int(moving[-1]) if len(moving) else 0


def scene_for(spec: VideoSpec) -> SplashScene:
    """The planned video's scene, with its start frame and its camera's frame count."""
    o = spec.obj
    tank = Tank()
    rng = np.random.default_rng(spec.seed)
    if spec.demo:
        release, start = (0.0, 0.0, tank.water_level_m + 0.15), START_STEPS[0]
    else:
        release = (float(rng.uniform(*RELEASE_X_M)), 0.0, tank.water_level_m + float(rng.uniform(*RELEASE_HEIGHT_M)))
        start = int(rng.integers(START_STEPS[0], START_STEPS[1] + 1))
    obj = SplashObject(o.name, o.kind, o.volume_cm3, o.area_cm2, o.density_g_cm3, o.drag_water, o.material)
    scene = SplashScene(tank, obj, release, start, default_camera(tank, FPS))
    scene.validate()
    n = DEMO_FRAMES if spec.demo else int(np.clip(_settle_frame(scene) + 1 + TAIL_S * FPS, MIN_FRAMES,
                                                   MAX_DURATION_S * FPS))
    return dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, n_frames=n))


def truth_json(scene: SplashScene, traj) -> dict:
    o = scene.obj
    latents = {"kind": o.kind, "volume_cm3": o.volume_cm3, "area_cm2": o.area_cm2,
               "density_g_cm3": o.density_g_cm3, "drag_water": o.drag_water, "start_step": scene.start_step,
               "mass_kg": o.mass_kg, "material": o.material}
    return {"latents": latents, "trajectory": traj.to_json()}


def render_one(spec: VideoSpec, out_dir: str) -> dict:
    """Render one video folder; returns its index entry."""
    from ...render import Look
    from .render import render_to_video

    folder = Path(out_dir) / spec.name
    scene = scene_for(spec)
    n = scene.camera.n_frames
    look = Look.random(np.random.default_rng([spec.seed, 1]))
    traj = render_to_video(scene, folder / "video.mp4", n, look=look, texture_seed=spec.seed)
    scene.save(folder / "scene.json")
    write_json(folder / "truth.json", truth_json(scene, traj), indent=None)
    o = spec.obj
    return {"name": spec.name, "material": o.material, "object": o.name, "kind": o.kind,
            "volume_cm3": o.volume_cm3, "density_g_cm3": o.density_g_cm3, "sinks": o.density_g_cm3 > 1.0,
            "start_step": scene.start_step, "n_frames": n}


DATASET = dataset.DatasetSpec("splash", PRESETS, plan, render_one,
                              describe="objects dropped into a tank of water: demo (1 video), small (8), full (72)")


def build(preset: str, out: str | Path, **kw) -> list[dict]:
    """`galileo.dataset.build` of the splash's `DATASET` (kept for the callers from before it)."""
    return dataset.build(DATASET, preset, out, **kw)


__all__ = ["DATASET", "PRESETS", "FLOATERS", "SINKERS", "VideoSpec", "plan", "scene_for", "build", "render_one"]

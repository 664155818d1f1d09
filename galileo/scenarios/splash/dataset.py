"""Rendered splash videos with ground truth (`galileo dataset --scenario splash`).

Presets:
* demo  - one video (2 s): a 3 cm plastic block (1.3 g/cm^3) dropped 15 cm into the water; it sinks.
* small - 8 videos: one object of each of 4 sinking and 4 floating materials; for tests.
* full  - 72 videos: the catalogue's 36 objects (13 materials, see materials.py), each
          filmed twice (release point, start frame, light and noise drawn anew).
* looks - 36 videos in a second look (`render.Style`), the catalogue's objects once each, to
          benchmark on videos the splash was not built on: per video the object's texture
          (plain, stripes, wood grain, a printed label; white and light objects too) and
          yaw, the light (direction, strength, colour temperature, exposure), the room's wall
          and table, the tank (30-60 cm long, 12-25 cm deep, water 12-25 cm), the camera (0.6-1.3
          m away, 5 cm below to 15 cm above the water line, turned up to 20 degrees, focal
          length 700-1100 px), noise and drift, all drawn anew (`scene_for_look`).
* looks-small - 12 of the looks videos (the same files): the 6 sinking materials and 6
          floating ones, one object each; for quick runs.

Per video: the release point x ~ U(-5, 5) cm, 12-20 cm above the water (0.16-0.2 s of
fall, 37-48 physics steps). The release, as in drops by hand: in half the videos (drawn per
video) the object is held still for U(0, 0.5) s of video and let go with a downward push ~
U(0, 0.3) m/s; in the others it is let go at rest U{5, ..., 30} physics steps before frame 0
(the seed's observation start), so that the video opens with it falling (1-5 frames in the
air before it meets the water). The demo keeps the latter (5 steps). The video runs until
the object has been at rest for TAIL_S, within [MIN_FRAMES, MAX_DURATION_S] after the release.

Each video folder holds video.mp4 (H.264, 640x480, 30 fps), scene.json (the splash scene,
its camera and the true latents) and truth.json (latents and the shown frames' trajectory);
the output folder gets index.json. A looks video's scene.json is the scene a user would
write: its yaw_deg is 0 (the object's turn is not something a user measures; truth.json has
it) and the rest of what inference reads (camera, tank, water level, release point) is the
truth; the object's kind, volume and area, the latents and priors there are replaced by the
tracker's bottom-up ones and the video's priors when inference prepares the scene (the
splash's `prepare`). truth.json also says the look (`look`). Filmed through a camera's effects
(`galileo.footage`, the plan's camera; clean by default) the video is that camera's, scene.json's
camera carries its lens (k1) and truth.json what the camera did ("camera"); the latents and the
trajectory are the clean video's. Deterministic per seed; built by `galileo.dataset.build`
(parallel, resumable) from `DATASET`.
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
from .materials import FLOATERS, MATERIALS_BY_NAME, SINKERS, CatalogueObject, catalogue
from .physics import Simulator
from .scene import CM2, CM3, SplashObject, SplashScene, Tank, default_camera, dimensions

PRESETS = ("demo", "small", "full", "looks", "looks-small")
FPS = 30.0
START_STEPS = (5, 30)           # a release before frame 0: the seed's prior on the start (physics steps)
HELD_FRACTION = 0.5             # the videos whose object is held at the start, then pushed
HOLD_S, PUSH_MPS = (0.0, 0.5), (0.0, 0.3)
REST_SPEED_MPS = 0.005          # below this the object counts as at rest
TAIL_S, MAX_DURATION_S, MIN_FRAMES = 0.5, 3.0, 30
DEMO_FRAMES = 60
RELEASE_X_M, RELEASE_HEIGHT_M = (-0.05, 0.05), (0.12, 0.20)
SMALL_PICKS = ("plastic block", "metal pole", "porcelain", "rubber",            # sinkers
               "wooden block", "foam", "hollow plastic", "wooden pole")         # floaters
# the looks presets (`scene_for_look`): the draws' ranges
LOOKS_STREAM = 28                # their per-video seeds: SeedSequence([seed, LOOKS_STREAM, object index])
LOOKS_SMALL_PICKS = SINKERS + FLOATERS[:6]    # 6 sinking materials, 6 floating ones (all but plastic toys)
LOOK_TANK_LENGTH_M, LOOK_TANK_DEPTH_M, LOOK_WATER_M = (0.30, 0.60), (0.12, 0.25), (0.12, 0.25)
LOOK_TANK_HEADROOM_M = (0.04, 0.12)   # the tank's walls above the water
LOOK_WALL_M = (0.004, 0.010)
LOOK_RELEASE_Y_M = (-0.015, 0.015)
LOOK_CLEARANCE_M = 0.02          # the tank's inner depth at least the object's turned footprint + this each side
LOOK_YAW_DEG = (-45.0, 45.0)
LOOK_CAMERA_DISTANCE_M = (0.6, 1.3)   # horizontal, from the point it looks at
LOOK_CAMERA_HEIGHT_M = (-0.05, 0.15)  # above the water line
LOOK_CAMERA_YAW_DEG = (-20.0, 20.0)
LOOK_FOCAL_PX = (700.0, 1100.0)
LOOK_AIM_M = 0.03                # the camera aims within this of the middle of the object's fall
LOOK_MARGIN_PX = 16              # the object's whole fall (release to the floor) this far inside the image
LOOK_TRIES = 200                 # camera draws until one sees the fall (rejection sampling)
LOOK_LIGHT_AZIMUTH = (-1.4, 1.4)      # rad about the vertical from the camera's side (0: behind the camera)
LOOK_LIGHT_HEIGHT = (0.6, 2.5)        # the light direction's z (its horizontal part 1.2)
LOOK_AMBIENT, LOOK_DIFFUSE = (0.4, 0.8), (0.2, 0.6)
LOOK_DRIFT, LOOK_NOISE_SD = (0.0, 0.04), (1.0, 5.0)


@dataclass(frozen=True)
class VideoSpec:
    name: str
    obj: CatalogueObject
    seed: int
    demo: bool = False
    camera: str = "clean"   # the camera effects it is filmed through (galileo.footage's name)


@dataclass(frozen=True)
class LookSpec(VideoSpec):
    """A video of the looks presets (`scene_for_look`, `render.Style`)."""


def _demo_object() -> CatalogueObject:
    return CatalogueObject("plastic block", 0, "box", 27.0, 9.0, 1.3, 1.05)


def _seed(seed: int, i: int) -> int:
    return int(np.random.SeedSequence([seed, i]).generate_state(1)[0])


def plan(preset: str, seed: int = 0, camera: str = "clean") -> list[VideoSpec]:
    """The videos a preset renders (names, objects, per-video seeds), filmed through `camera`'s
    effects."""
    if preset not in PRESETS:
        raise GalileoError(f"unknown preset {preset!r}; expected one of {', '.join(PRESETS)}")
    if preset == "demo":
        return [VideoSpec("demo", _demo_object(), seed, demo=True, camera=camera)]
    objs = catalogue(seed)
    if preset in ("looks", "looks-small"):
        picks = range(len(objs)) if preset == "looks" else sorted(
            next(i for i, o in enumerate(objs) if o.material == m) for m in LOOKS_SMALL_PICKS)
        return [LookSpec(f"{i:03d}_{objs[i].name}", objs[i],
                         int(np.random.SeedSequence([seed, LOOKS_STREAM, i]).generate_state(1)[0]), camera=camera)
                for i in picks]
    takes = 2
    if preset == "small":
        objs = [next(o for o in objs if o.material == m) for m in SMALL_PICKS]
        takes = 1
    specs: list[VideoSpec] = []
    for obj in objs:
        for _ in range(takes):
            specs.append(VideoSpec(f"{len(specs):03d}_{obj.name}", obj, _seed(seed, len(specs)), camera=camera))
    return specs


def _settle_frame(scene: SplashScene) -> int:
    """The last video frame (from the scene's start step) in which the object still moves."""
    n = int((MAX_DURATION_S + max(0.0, scene.release_s)) * FPS)
    speed = np.linalg.norm(Simulator(scene).run(n).velocity_mps[0], axis=1)
    moving = np.nonzero(speed > REST_SPEED_MPS)[0]
    return int(moving[-1]) if len(moving) else 0


def scene_for(spec: VideoSpec) -> SplashScene:
    """The planned video's scene, with its release and its camera's frame count."""
    if isinstance(spec, LookSpec):
        return scene_for_look(spec)[0]
    o = spec.obj
    tank = Tank()
    rng = np.random.default_rng(spec.seed)
    push = 0.0
    if spec.demo:
        release, release_s = (0.0, 0.0, tank.water_level_m + 0.15), -START_STEPS[0] / 240.0
    else:
        release, release_s, push = _release(rng, tank.water_level_m)
    obj = SplashObject(o.name, o.kind, o.volume_cm3, o.area_cm2, o.density_g_cm3, o.drag_water, o.material)
    scene = SplashScene(tank, obj, release, release_s, default_camera(tank, FPS), push_mps=push)
    scene.validate()
    return _with_length(scene, DEMO_FRAMES if spec.demo else None)


def _with_length(scene: SplashScene, n: int | None = None) -> SplashScene:
    """The scene with its camera's frame count: `n`, or until the object has been at rest for
    TAIL_S (within [MIN_FRAMES, MAX_DURATION_S] after the release)."""
    if n is None:
        held = max(0.0, scene.release_s) * FPS
        n = int(np.clip(_settle_frame(scene) + 1 + TAIL_S * FPS, MIN_FRAMES + held, MAX_DURATION_S * FPS + held))
    return dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, n_frames=n))


def _release(rng: np.random.Generator, water_level_m: float) -> tuple[tuple, float, float]:
    """(release point, release_s, push_mps) as drops by hand (see the module): a point 12-20 cm
    above the water at x ~ U(RELEASE_X_M), y = 0; held and pushed in HELD_FRACTION of the
    videos (the hold a whole number of physics steps), else let go at rest before frame 0."""
    release = (float(rng.uniform(*RELEASE_X_M)), 0.0, water_level_m + float(rng.uniform(*RELEASE_HEIGHT_M)))
    release_s, push = -int(rng.integers(START_STEPS[0], START_STEPS[1] + 1)) / 240.0, 0.0
    if rng.uniform() < HELD_FRACTION:
        release_s, push = float(rng.uniform(*HOLD_S)), float(rng.uniform(*PUSH_MPS))
        release_s = round(release_s * 240.0) / 240.0   # on the physics grid: the renderer draws Bullet's steps
    return release, release_s, push


def _look_tank(rng: np.random.Generator, obj: CatalogueObject, yaw_deg: float, release_y_m: float) -> Tank:
    """A tank of a second look: sizes drawn (LOOK_*), its inner depth widened where the object,
    turned by yaw_deg at release_y_m, would not clear the front and back glass by
    LOOK_CLEARANCE_M (or not fit the scene's rule, SplashScene.max_dim_m)."""
    length, depth = float(rng.uniform(*LOOK_TANK_LENGTH_M)), float(rng.uniform(*LOOK_TANK_DEPTH_M))
    water, headroom = float(rng.uniform(*LOOK_WATER_M)), float(rng.uniform(*LOOK_TANK_HEADROOM_M))
    wall = float(rng.uniform(*LOOK_WALL_M))
    lx, ly, _ = dimensions(obj.kind, obj.volume_cm3 * CM3, obj.area_cm2 * CM2)
    yaw = math.radians(yaw_deg)
    footprint_y = lx * abs(math.sin(yaw)) + ly * abs(math.cos(yaw))
    depth = max(depth, footprint_y + 2 * abs(release_y_m) + 2 * LOOK_CLEARANCE_M, max(lx, ly) / 0.9 + 1e-3)
    return Tank((length, depth, water + headroom), wall, water)


def _look_camera(rng: np.random.Generator, tank: Tank, release_m: tuple, radius_m: float):
    """A camera of a second look (LOOK_CAMERA_*, LOOK_FOCAL_PX): drawn, as a user places one,
    until the object's whole fall (a box around its release point and the floor below it, grown
    by its bounding radius) lies LOOK_MARGIN_PX inside the image; the camera aims at the
    middle of the fall (within LOOK_AIM_M)."""
    from ...camera import look_at_camera

    x, y, z = release_m
    r = radius_m + 0.03     # it may drift in the water
    fall = np.array([(x + sx * r, y + sy * r, zz) for sx in (-1, 1) for sy in (-1, 1) for zz in (0.0, z + r)])
    for _ in range(LOOK_TRIES):
        dist, height = rng.uniform(*LOOK_CAMERA_DISTANCE_M), rng.uniform(*LOOK_CAMERA_HEIGHT_M)
        yaw, focal = math.radians(rng.uniform(*LOOK_CAMERA_YAW_DEG)), rng.uniform(*LOOK_FOCAL_PX)
        aim = np.array([x, y, z / 2]) + rng.uniform(-LOOK_AIM_M, LOOK_AIM_M, 3) * (1, 0, 1)
        eye = (aim[0] + dist * math.sin(yaw), aim[1] - dist * math.cos(yaw), tank.water_level_m + height)
        cam = look_at_camera(eye, aim, focal_px=float(focal), fps=FPS)
        pc = fall @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
        uv = pc[:, :2] / pc[:, 2:] * np.diag(cam.K)[:2] + cam.K[:2, 2]
        if (pc[:, 2] > 0).all() and (uv >= LOOK_MARGIN_PX).all() and (
                uv < np.array([cam.width_px, cam.height_px]) - LOOK_MARGIN_PX).all():
            return cam
    raise RuntimeError(f"no camera of {LOOK_TRIES} draws sees the whole fall")   # pragma: no cover


def _look_light(rng: np.random.Generator):
    """A second look's light (`galileo.render.Look`): from any side of the camera's half of the
    room, high or low (LOOK_LIGHT_*), its ambient and diffuse strengths, exposure drift and
    sensor noise drawn wider than `Look.random`."""
    from ...render import Look

    az = rng.uniform(*LOOK_LIGHT_AZIMUTH)
    return Look((1.2 * math.sin(az), -1.2 * math.cos(az), float(rng.uniform(*LOOK_LIGHT_HEIGHT))),
                float(rng.uniform(*LOOK_AMBIENT)), float(rng.uniform(*LOOK_DIFFUSE)), float(rng.uniform(*LOOK_DRIFT)),
                float(rng.uniform(*LOOK_NOISE_SD)), int(rng.integers(2**31)))


def scene_for_look(spec: VideoSpec):
    """A looks video's scene (as rendered: the object turned by its yaw_deg), its `render.Style`
    and its `galileo.render.Look`, drawn from the spec's seed (see the module)."""
    from .render import Style

    o = spec.obj
    rng = np.random.default_rng(spec.seed)
    yaw_deg = float(rng.uniform(*LOOK_YAW_DEG))
    release_y = float(rng.uniform(*LOOK_RELEASE_Y_M))
    tank = _look_tank(rng, o, yaw_deg, release_y)
    (x, _, z), release_s, push = _release(rng, tank.water_level_m)
    release = (x, release_y, z)
    radius = 0.5 * float(np.linalg.norm(dimensions(o.kind, o.volume_cm3 * CM3, o.area_cm2 * CM2)))
    camera = _look_camera(rng, tank, release, radius)
    obj = SplashObject(o.name, o.kind, o.volume_cm3, o.area_cm2, o.density_g_cm3, o.drag_water, o.material)
    scene = SplashScene(tank, obj, release, release_s, camera, push_mps=push, yaw_deg=yaw_deg)
    scene.validate()
    style = Style.random(np.random.default_rng([spec.seed, 2]), MATERIALS_BY_NAME[o.material].color_rgb)
    return _with_length(scene), style, _look_light(np.random.default_rng([spec.seed, 1]))


def truth_json(scene: SplashScene, traj) -> dict:
    o = scene.obj
    latents = {"kind": o.kind, "volume_cm3": o.volume_cm3, "area_cm2": o.area_cm2,
               "density_g_cm3": o.density_g_cm3, "drag_water": o.drag_water, "release_s": scene.release_s,
               "push_mps": scene.push_mps, "log_volume_factor": scene.log_volume_factor, "yaw_deg": scene.yaw_deg,
               "mass_kg": o.mass_kg, "material": o.material}
    return {"latents": latents, "trajectory": traj.to_json()}


def render_one(spec: VideoSpec, out_dir: str) -> dict:
    """Render one video folder; returns its index entry."""
    from ...footage import Footage, effects_from_name
    from ...render import Look
    from .render import render_to_video

    folder = Path(out_dir) / spec.name
    if isinstance(spec, LookSpec):
        scene, style, look = scene_for_look(spec)
        written = dataclasses.replace(scene, yaw_deg=0.0)   # what a user writes (see the module)
    else:
        scene, style = scene_for(spec), None
        look, written = Look.random(np.random.default_rng([spec.seed, 1])), scene
    n = scene.camera.n_frames
    footage = None if spec.camera == "clean" else Footage(effects_from_name(spec.camera), scene.camera, spec.seed)
    traj = render_to_video(scene, folder / "video.mp4", n, look=look, texture_seed=spec.seed, style=style,
                           footage=footage)
    if footage is not None:
        written = dataclasses.replace(written, camera=footage.camera)
    written.save(folder / "scene.json")
    truth = truth_json(scene, traj)
    if footage is not None:
        truth["camera"] = {"name": spec.camera, **footage.to_json()}
    if style is not None:
        truth["look"] = {**style.to_json(), "light": dataclasses.asdict(look), "tank": scene.tank.to_json(),
                         "camera_eye_m": [float(v) for v in scene.camera.position_in_world],
                         "focal_px": float(scene.camera.K[0, 0])}
    write_json(folder / "truth.json", truth, indent=None)
    o = spec.obj
    return {"name": spec.name, "material": o.material, "object": o.name, "kind": o.kind,
            "volume_cm3": o.volume_cm3, "density_g_cm3": o.density_g_cm3, "sinks": o.density_g_cm3 > 1.0,
            "release_s": scene.release_s, "push_mps": scene.push_mps, "n_frames": n}


DATASET = dataset.DatasetSpec("splash", PRESETS, plan, render_one, cameras=True,
                              describe="objects dropped into a tank of water: demo (1 video), small (8), full (72); "
                                       "in a second look: looks (36), looks-small (12)")


def build(preset: str, out: str | Path, **kw) -> list[dict]:
    """`galileo.dataset.build` of the splash's `DATASET` (kept for the callers from before it)."""
    return dataset.build(DATASET, preset, out, **kw)


__all__ = ["DATASET", "PRESETS", "FLOATERS", "SINKERS", "VideoSpec", "LookSpec", "plan", "scene_for", "scene_for_look",
           "build", "render_one"]

"""Rendered spring videos with ground truth (`galileo dataset --scenario spring`).

Presets:
* demo  - one video: a 110 g wooden block in a clear bag on the tight spring (like the real
          Physics 101 clips).
* small - 8 videos: 4 objects that fit both springs (of 4 materials, spread over their masses),
          each on both; for tests and quick experiments (pairs on one spring, or one object on two).
* full  - every catalogue object (36, 13 materials, 5-500 g, `materials.py`) on each spring it
          fits, 2 takes each (release, framing, light and noise drawn anew): the light objects
          hang on the loose spring only, the heavy ones on the tight one only, those between on
          both.

An object fits a spring when the video can show its bounce (`fit_problem`): a period of at
least MIN_PERIOD_S, a static extension of at most MAX_EXTENSION_M (the bounce stays in a frame
filmed from at most 2 m), and no 2:1 resonance between the bounce and the sway: where the
bounce is twice the sway's frequency (the length from the hanging point to the centre about
4 times the static extension) the bounce pumps the sway up and a slight sway grows into a
swing; RESONANCE bounds that ratio's band, found by simulation (tests/test_spring_dataset.py).

Per video: the hand holds the object still for `release_frame` frames (5-15), pulled 2-6 cm
below its rest position (a fifth of the videos: lifted 1-2 cm; either at most 0.6 and 0.3 of
the static extension, so the spring stays taut), 0.2-1 cm to one side (and let go with up to
2 cm/s sideways), so that it sways slightly; then lets go and pulls away.
The video runs 5-8 s. The hanging point is the scene's default, (0, 0, 1) m (the table lies
8-20 cm below the object's lowest point). The camera looks at the spring's plane from the side
from 1-2 m (a focal length of 600-800 px, yaw up to 8 degrees, looking down by up to 6), far
enough that the hanging point and the whole simulated motion are inside the picture; the
demo's is square to the plane (no yaw or pitch), the model of the click calibration
(`clicks.py`), whose four clicks give back its camera exactly.

Each video folder holds video.mp4 (H.264, 640x480, 30 fps), scene.json (the spring scene with
its camera; its values are the truth) and truth.json: the latents by the scene's names (the
tracking-noise latents null: no truth), the release frame, the frame from which the hand is
clear of the object (`hand_gone_frame`), the object and spring, the bounce's period, damping
ratio and static extension, the trajectory and the object's projected centre per frame
(`center_px`). The output folder gets index.json. Deterministic per seed; built by
`galileo.dataset.build` (parallel, resumable) from `DATASET`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ... import dataset
from ...camera import look_at_camera
from ...errors import GalileoError
from ...jsonio import write_json
from .materials import (
    BAG_SLACK_M,
    MATERIALS_BY_NAME,
    SPRINGS,
    SPRINGS_BY_NAME,
    CatalogueObject,
    Spring,
    catalogue,
)
from .physics import equilibrium_below_top_m, params, period_s, simulate
from .scene import NOISE_LATENTS, SpringScene

PRESETS = ("demo", "small", "full")
FPS, SIM_HZ = 30.0, 240.0
WIDTH_PX, HEIGHT_PX = 640, 480
MIN_PERIOD_S = 0.3              # at least 9 frames a bounce
MAX_EXTENSION_M = 0.6           # the static extension: with the bounce, a 1 m tall picture from 2 m
RESONANCE = (2.8, 4.8)          # (hanging point to centre) / static extension: the 2:1 band to avoid
MAX_DECAY = 0.05                # at most this share of the amplitude lost per period
RELEASE_FRAMES = (5, 15)
N_FRAMES = (150, 240)           # 5-8 s
PULL_M, LIFT_M = (0.02, 0.06), (0.01, 0.02)
LIFT_SHARE = 0.2
PULL_MAX_OF_EXTENSION = 0.6     # the pull at most this share of the static extension (the spring stays taut)
LIFT_MAX_OF_EXTENSION = 0.3
SIDE_M, SIDE_SPEED_MPS = (0.002, 0.01), 0.02
TAKES = 2                       # full: videos per object and spring
SMALL_OBJECTS = 4
FOCAL_PX, YAW_DEG, PITCH_DEG = (600.0, 800.0), 8.0, (0.0, 6.0)   # pitch: looking down, from above the table
DISTANCE_M = (1.0, 2.0)
FILL = (0.7, 0.85)              # the motion's height over the picture's
MARGIN_PX = 12                  # what must be seen stays this far inside the picture
TABLE_CLEARANCE_M = (0.08, 0.2)  # the table's top below the object's lowest point
ARM_M, WALL_M = (0.16, 0.26), (0.3, 0.6)
DEMO = CatalogueObject("wooden block", 0, "box", (0.065, 0.05, 0.056), 0.110, "bag")


@dataclass(frozen=True)
class VideoSpec:
    name: str
    obj: CatalogueObject
    spring: Spring           # (the whole spring: its constants are part of the plan)
    seed: int
    square: bool = False     # the camera square to the spring's plane (no yaw or pitch)


def _seed(seed: int, i: int) -> int:
    return int(np.random.SeedSequence([seed, i]).generate_state(1)[0])


def base_scene(spring: Spring, obj: CatalogueObject) -> SpringScene:
    """The object on the spring, at rest (no camera, release or framing yet)."""
    return SpringScene(object=obj.name, spring=spring.name, hang_m=obj.hang_m, size_m=obj.size_m, mass_kg=obj.mass_kg,
                       k_Npm=spring.k_Npm, spring_mass_kg=spring.mass_kg, damping_Nspm=spring.damping_Nspm,
                       rest_m=spring.rest_m, fps=FPS, sim_hz=SIM_HZ)


def fit_problem(spring: Spring, obj: CatalogueObject) -> str | None:
    """Why the object's bounce on the spring would film badly (None: it fits; see the module)."""
    p = params(base_scene(spring, obj))
    extension = p.weight_N / p.k_Npm
    ratio = equilibrium_below_top_m(p) / extension
    decay = 1 - math.exp(-p.damping_Nspm * period_s(p) / (2 * p.inertial_kg))
    if period_s(p) < MIN_PERIOD_S:
        return f"period {period_s(p):.2f} s < {MIN_PERIOD_S} s"
    if extension > MAX_EXTENSION_M:
        return f"static extension {extension:.2f} m > {MAX_EXTENSION_M} m"
    if RESONANCE[0] < ratio < RESONANCE[1]:
        return f"length / extension {ratio:.2f} in the 2:1 resonance band {RESONANCE}"
    if decay > MAX_DECAY:
        return f"{decay:.1%} of the amplitude lost per period > {MAX_DECAY:.0%}"
    return None


def plan(preset: str, seed: int = 0) -> list[VideoSpec]:
    """The videos a preset renders (names, objects, springs, per-video seeds)."""
    if preset not in PRESETS:
        raise GalileoError(f"unknown preset {preset!r}; expected one of {', '.join(PRESETS)}")
    if preset == "demo":
        return [VideoSpec("demo", DEMO, SPRINGS_BY_NAME["tight"], seed, square=True)]
    objs = catalogue(seed)
    fitting = {o: [s for s in SPRINGS if fit_problem(s, o) is None] for o in objs}
    takes = TAKES
    if preset == "small":
        both = sorted((o for o in objs if len(fitting[o]) == len(SPRINGS)), key=lambda o: o.mass_kg)
        picks: list[CatalogueObject] = []
        for target in np.linspace(0, len(both) - 1, min(SMALL_OBJECTS, len(both))):   # spread over the masses
            free = [i for i, o in enumerate(both) if o not in picks]
            other = [i for i in free if both[i].material not in {p.material for p in picks}] or free
            picks.append(both[min(other, key=lambda i: abs(i - target))])
        objs, takes = sorted(picks, key=lambda o: o.mass_kg), 1
    specs: list[VideoSpec] = []
    for o in objs:
        for spring in fitting[o]:
            for _ in range(takes):
                specs.append(VideoSpec(f"{len(specs):03d}_{o.name}_{spring.name}", o, spring,
                                       _seed(seed, len(specs))))
    return specs


def _camera(top: np.ndarray, points: np.ndarray, rng: np.random.Generator, n_frames: int, square: bool):
    """A side view of the spring's plane with mild perspective (`square`: none) that sees all of
    `points` (world)."""
    focal = float(rng.uniform(*FOCAL_PX))
    yaw, pitch = np.radians(rng.uniform(-YAW_DEG, YAW_DEG)), np.radians(rng.uniform(*PITCH_DEG))
    if square:
        yaw = pitch = 0.0
    fill = float(rng.uniform(*FILL))
    lo, hi = points.min(axis=0), points.max(axis=0)
    target = np.array([0.5 * (lo[0] + hi[0]), top[1], 0.5 * (lo[2] + hi[2])])
    d = float(np.clip(focal * (hi[2] - lo[2]) / (fill * HEIGHT_PX), *DISTANCE_M))
    ahead = np.array([math.sin(yaw) * math.cos(pitch), math.cos(yaw) * math.cos(pitch), -math.sin(pitch)])
    for _ in range(100):
        cam = look_at_camera(target - d * ahead, target, focal_px=focal, width_px=WIDTH_PX, height_px=HEIGHT_PX,
                             fps=FPS, n_frames=n_frames)
        uv = cam.project(points)
        if (uv.min(axis=0) >= MARGIN_PX).all() and (uv.max(axis=0) <= (WIDTH_PX - MARGIN_PX,
                                                                      HEIGHT_PX - MARGIN_PX)).all():
            return cam
        if d >= DISTANCE_M[1]:
            focal *= 0.95       # too tall for the furthest camera: a wider lens
        else:
            d = min(d * 1.05, DISTANCE_M[1])
    raise RuntimeError("no camera frames the spring")   # pragma: no cover - a shorter focal length always does


def scene_for(spec: VideoSpec):
    """The planned video's scene (with its camera) and how it looks (`render.Setup`)."""
    from .render import SKINS, SLEEVES, Setup

    spring, o = spec.spring, spec.obj
    rng = np.random.default_rng(spec.seed)
    scene = base_scene(spring, o)
    p = params(scene)
    extension, eq = p.weight_N / p.k_Npm, equilibrium_below_top_m(p)

    def up_to(lo: float, hi: float, share: float) -> float:     # U(lo, hi), hi at most share x the extension
        return float(rng.uniform(lo, max(lo, min(hi, share * extension))))

    lifted = rng.random() < LIFT_SHARE
    pull = -up_to(*LIFT_M, LIFT_MAX_OF_EXTENSION) if lifted else up_to(*PULL_M, PULL_MAX_OF_EXTENSION)
    x0 = float(rng.choice([-1.0, 1.0]) * rng.uniform(*SIDE_M))
    vx0 = float(rng.uniform(-SIDE_SPEED_MPS, SIDE_SPEED_MPS))
    release = int(rng.integers(RELEASE_FRAMES[0], RELEASE_FRAMES[1] + 1))
    n = int(rng.integers(N_FRAMES[0], N_FRAMES[1] + 1))
    sx, sy, sz = o.size_m
    lowest = eq + abs(pull) + sz / 2 + BAG_SLACK_M          # below the hanging point
    table_z = scene.top_in_world_m[2] - lowest - float(rng.uniform(*TABLE_CLEARANCE_M))
    scene = dataclasses.replace(scene, x0_m=x0, z0_m=-(eq + pull), vx0_mps=vx0, vz0_mps=0.0, release_frame=release,
                                n_frames=n)
    stand_side = int(rng.choice([-1, 1]))
    arm = float(rng.uniform(*ARM_M))
    setup = Setup(o, spring, MATERIALS_BY_NAME[o.material].color_rgb, stand_side, arm, table_z,
                  float(rng.uniform(*WALL_M)), -stand_side, SKINS[int(rng.integers(len(SKINS)))],
                  SLEEVES[int(rng.integers(len(SLEEVES)))])
    # what the camera must see: the hanging point and the stand's arm, the object's box over the whole motion
    pos = simulate(scene, n).position_m[0]
    top = np.array(scene.top_in_world_m)
    half = np.array([sx / 2 + BAG_SLACK_M, sy / 2, sz / 2 + 2 * BAG_SLACK_M])
    corners = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)]) * half
    seen = np.vstack([top + (0.0, 0.0, 0.03), top + (stand_side * 0.5 * arm, 0.0, 0.03),
                      (pos.min(axis=0) + corners), (pos.max(axis=0) + corners)])
    cam = _camera(top, seen, rng, n, spec.square)
    return dataclasses.replace(scene, camera=cam), setup


def truth_json(scene: SpringScene, setup, traj, hand_gone_frame: int) -> dict:
    """What the video shows, for the tracker's and the inference's evaluation (see the module)."""
    p = params(scene)
    o, sp = setup.obj, setup.spring
    return {"latents": {**scene.latents(), **{n: None for n in NOISE_LATENTS}},
            "release_frame": scene.release_frame, "hand_gone_frame": hand_gone_frame,
            "object": {"name": o.name, "material": o.material, "kind": o.kind, "mount": o.mount,
                       "size_m": list(o.size_m), "mass_kg": o.mass_kg},
            "spring": {"name": sp.name, "k_Npm": sp.k_Npm, "mass_kg": sp.mass_kg, "damping_Nspm": sp.damping_Nspm,
                       "rest_m": sp.rest_m},
            "period_s": period_s(p), "extension_m": p.weight_N / p.k_Npm,
            "damping_ratio": p.damping_Nspm / (2 * math.sqrt(p.k_Npm * p.inertial_kg)),
            "trajectory": traj.to_json(), "center_px": scene.camera.project(traj.position_m[0]).tolist()}


def renderer_for(spec: VideoSpec):
    """(scene, its simulated trajectory, the `render.Renderer` that draws the planned video)."""
    from ...render import Look
    from .render import Renderer

    scene, setup = scene_for(spec)
    look = Look.random(np.random.default_rng([spec.seed, 1]))
    return scene, simulate(scene, scene.n_frames), Renderer(scene, setup, look, texture_seed=spec.seed)


def render_one(spec: VideoSpec, out_dir: str) -> dict:
    """Render one video folder; returns its index entry."""
    from .render import render_to_video

    folder = Path(out_dir) / spec.name
    scene, traj, renderer = renderer_for(spec)
    gone = render_to_video(renderer, traj, folder / "video.mp4")
    scene.save(folder / "scene.json")
    truth = truth_json(scene, renderer.setup, traj, gone)
    write_json(folder / "truth.json", truth, indent=None)
    o = spec.obj
    return {"name": spec.name, "object": o.name, "material": o.material, "mass_kg": o.mass_kg, "mount": o.mount,
            "spring": spec.spring.name, "k_Npm": scene.k_Npm, "period_s": truth["period_s"],
            "release_frame": scene.release_frame, "hand_gone_frame": gone, "n_frames": scene.n_frames}


DATASET = dataset.DatasetSpec("spring", PRESETS, plan, render_one,
                              describe="objects bouncing on a loose or a tight spring: demo (1 video), small (8), "
                                       "full (every object on each spring it fits, 2 takes)")


__all__ = [
    "DATASET",
    "PRESETS",
    "VideoSpec",
    "base_scene",
    "fit_problem",
    "plan",
    "render_one",
    "renderer_for",
    "scene_for",
]

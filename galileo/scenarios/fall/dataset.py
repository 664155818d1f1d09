"""Rendered fall videos with ground truth (`galileo dataset --scenario fall`).

Presets:
* demo  - 3 videos: a 9 x 4.5 x 4.5 cm wooden block (like the real Physics 101 clips) dropped
          twice onto the table (one pair, its e and mu shared) and once onto foam.
* small - 24 videos: 6 objects (boxes, cylinders, a torus; 6 materials) each dropped once onto
          each of the 4 surfaces; for tests and quick experiments (which surface is bouncier).
* full  - every catalogue object (26: 13 materials x 2, `materials.py`) on every surface, 2
          takes each (208 videos).

Truth: the object-surface pair's restitution and friction (`materials.pair_truth`, shared by
every video of the pair and seed), and per video the release state: the centre 15-50 cm above
the surface (`HEIGHT_M`, somewhere over the surface's near and middle part), turned by up to
ORIENT_RAD about x and y and YAW_RAD about z (from level; a short cylinder, a cup or a coin,
from upright: `UPRIGHT_MAX_ASPECT`), moving sideways at up to SIDE_SPEED_MPS and
spinning at up to SPIN_RADPS about each axis, let go at frame 3-8. A release is redrawn
(at most MAX_TRIES times, the speeds and spins drawn from ever narrower ranges: a cylinder
or a torus rolls on and on) until the object comes to rest on the surface, at least EDGE_M
from its edges, before the video's end (36-45 frames at 30 fps): a drop onto the floor or a
roll off the edge is no video of the surface. The hand holds the object until the release, then
pulls away (`render.py`).

The camera stands above the surface's near end looking along it, as in the real clips (the
surface fills the picture's lower part): BEHIND_M behind the near edge, UP_M above the
surface, looking at a point TARGET_M in from the near edge, a horizontal field of view of
HFOV_DEG; drawn per video (then moved back if the object's whole motion is not inside the
picture). 640 x 360 at 30 fps.

Each video folder holds video.mp4 (H.264, motion-blurred: `render.py`), scene.json (the fall
scene with its camera; its values are the truth; `object` the object's id, `surface` the
surface kind, so that the videos of a pair share e and mu) and truth.json (`truth_json`). The
output folder gets index.json. Deterministic per seed; built by `galileo.dataset.build`
(parallel, resumable) from `DATASET`.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ... import dataset
from ...camera import look_at_camera
from ...datatypes import Trajectory
from ...errors import GalileoError
from ...jsonio import write_json
from ...render import blur_offsets
from ...shapes import Shape
from .materials import (
    SURFACES,
    SURFACES_BY_KIND,
    FallObject,
    Surface,
    catalogue,
    pair_truth,
)
from .physics import BODY, lowest_point_m, params, simulate
from .scene import NOISE_LATENTS, FallScene, surface_corners_m

PRESETS = ("demo", "small", "full")
FPS, SIM_HZ = 30.0, 240.0
WIDTH_PX, HEIGHT_PX = 640, 360
N_FRAMES = (36, 45)
RELEASE_FRAMES = (3, 8)
HEIGHT_M = (0.15, 0.5)             # the centre's height above the surface at release
CLEARANCE_M = 0.03                 # ... its lowest point at least this high
RELEASE_X = (-0.3, 0.1)            # the release over this share of the surface's length from its centre ...
RELEASE_Y = 0.25                   # ... and up to this share of its width
ORIENT_RAD, YAW_RAD = 0.3, 0.6
UPRIGHT_MAX_ASPECT = 2.0           # a cylinder at most this long for its diameter (a cup, a coin) is held upright
SIDE_SPEED_MPS, SPIN_RADPS = 0.15, 3.0
EDGE_M = 0.04                      # the object stays this far inside the surface's edges
REST_SPEED_MPS = 0.005             # at rest: the centre slower than this over the last REST_FRAMES
REST_FRAMES = 3
MAX_TRIES = 60
BEHIND_M, UP_M, TARGET_M = (0.4, 0.6), (0.7, 1.0), (0.55, 0.8)
HFOV_DEG, SIDE_M = (70.0, 80.0), 0.08   # the camera up to SIDE_M off the surface's midline
MARGIN_PX = 10                     # the object's motion stays this far inside the picture
IMPACT_MPS = 0.05                  # an impact: the centre's vertical speed jumps up by more than this in a step ...
IMPACT_S = 0.03                    # ... (jumps closer than this in time: one impact, its corners landing one by one)
APEX_MIN_RISE_M = 0.001            # ... and a bounce: the centre rises more than this after it
TAKES = 2                          # full: videos per object and surface
DEMO = FallObject("wooden block", 0, Shape("box", (0.09, 0.045, 0.045)), 0.11)
SMALL_OBJECTS = (("wooden block", 0), ("rubber", 0), ("plastic rings", 0), ("porcelain", 0), ("foam", 0),
                 ("metal coin", 0))


@dataclass(frozen=True)
class VideoSpec:
    name: str
    obj: FallObject
    surface: Surface             # (the whole kind: its truth ranges are part of the plan)
    seed: int                    # the video's draws (release, camera, look)
    truth_seed: int              # the pair's e and mu (the dataset's seed: shared by the pair's videos)


def _seed(seed: int, i: int) -> int:
    return int(np.random.SeedSequence([seed, i]).generate_state(1)[0])


def plan(preset: str, seed: int = 0) -> list[VideoSpec]:
    """The videos a preset renders (names, objects, surfaces, per-video seeds)."""
    if preset not in PRESETS:
        raise GalileoError(f"unknown preset {preset!r}; expected one of {', '.join(PRESETS)}")
    if preset == "demo":
        pairs = [(DEMO, SURFACES_BY_KIND["table"]), (DEMO, SURFACES_BY_KIND["table"]), (DEMO, SURFACES_BY_KIND["foam"])]
    else:
        objs = catalogue(seed)
        if preset == "small":
            by_key = {(o.material, o.index): o for o in objs}
            objs, takes = [by_key[k] for k in SMALL_OBJECTS], 1
        else:
            takes = TAKES
        pairs = [(o, s) for o in objs for s in SURFACES for _ in range(takes)]
    return [VideoSpec(f"{i:03d}_{o.name}_{s.kind}", o, s, _seed(seed, i), seed) for i, (o, s) in enumerate(pairs)]


def sub_motion(scene: FallScene) -> Trajectory:
    """The motion sampled at the motion blur's sub-frame rate (`galileo.render.blur_offsets`):
    sample j at video time j / (n fps), as far as the last frame's exposure reaches."""
    n, k = blur_offsets()
    return simulate(scene, n * (scene.n_frames - 1) + int(k.max()) + 1, fps=n * scene.fps)


def frames_of(motion: Trajectory, scene: FallScene) -> Trajectory:
    """The video frames' samples of a sub-frame motion (`sub_motion`)."""
    n = round(motion.fps / scene.fps)
    sl = slice(0, n * (scene.n_frames - 1) + 1, n)
    return Trajectory(scene.fps, [BODY], motion.position_m[:, sl], motion.velocity_mps[:, sl],
                      motion.orientation_xyzw[:, sl])


def _release(scene: FallScene, rng: np.random.Generator, motion_share: float = 1.0) -> FallScene:
    """The scene with a release state drawn (see the module), its speeds and spins from
    `motion_share` of their ranges."""
    L, W = scene.surface_size_m
    u = rng.uniform
    v, w = motion_share * SIDE_SPEED_MPS, motion_share * SPIN_RADPS
    sx, sy, _ = scene.shape.size_m
    upright = math.pi / 2 if scene.shape.type == "cylinder" and sx <= UPRIGHT_MAX_ASPECT * sy else 0.0
    turn = {"roll0_rad": float(u(-ORIENT_RAD, ORIENT_RAD)),
            "pitch0_rad": upright + float(u(-ORIENT_RAD, ORIENT_RAD)), "yaw0_rad": float(u(-YAW_RAD, YAW_RAD))}
    s = dataclasses.replace(scene, **turn)
    low = lowest_point_m(s.shape, (0.0, 0.0, 0.0), params(s).orn0)
    z0 = max(float(u(*HEIGHT_M)), CLEARANCE_M - low)
    return dataclasses.replace(
        s, x0_m=float(u(*RELEASE_X)) * L, y0_m=float(u(-RELEASE_Y, RELEASE_Y)) * W, z0_m=z0,
        vx0_mps=float(u(-v, v)), vy0_mps=float(u(-v, v)), vz0_mps=0.0, wx0_radps=float(u(-w, w)),
        wy0_radps=float(u(-w, w)), wz0_radps=float(u(-w, w)))


def release_problem(scene: FallScene, motion: Trajectory) -> str | None:
    """Why a drawn release makes no video of the surface (None: it does; see the module)."""
    L, W = scene.surface_size_m
    xy = motion.position_m[0, :, :2]
    if (np.abs(xy) > (L / 2 - EDGE_M, W / 2 - EDGE_M)).any():
        return "the object leaves the surface"
    frames = frames_of(motion, scene)
    speed = np.linalg.norm(np.diff(frames.position_m[0, -REST_FRAMES - 1:], axis=0), axis=1) * scene.fps
    if (speed > REST_SPEED_MPS).any():
        return f"the object still moves at the end ({speed.max():.3f} m/s)"
    return None


def _camera(scene: FallScene, motion: Trajectory, rng: np.random.Generator):
    """A camera above the surface's near end looking along it (see the module) that sees the
    object's whole motion (its centre, grown by its size) inside the picture."""
    L, _ = scene.surface_size_m
    behind, up, into = (float(rng.uniform(*r)) for r in (BEHIND_M, UP_M, TARGET_M))
    side = float(rng.uniform(-SIDE_M, SIDE_M))
    focal = WIDTH_PX / (2 * math.tan(math.radians(float(rng.uniform(*HFOV_DEG))) / 2))
    r = 0.5 * float(np.linalg.norm(scene.shape.size_m))
    pos = motion.position_m[0]
    box = np.array([[a, b, c] for a in (-r, r) for b in (-r, r) for c in (-r, r)])
    # the whole motion, and the surface's four corners (a user calibrates from them, `clicks.py`)
    seen = np.vstack([pos.min(axis=0) + box, pos.max(axis=0) + box, surface_corners_m(scene)])
    for _ in range(100):
        cam = look_at_camera((-L / 2 - behind, side, up), (-L / 2 + into, 0.0, 0.0), focal_px=focal,
                             width_px=WIDTH_PX, height_px=HEIGHT_PX, fps=scene.fps, n_frames=scene.n_frames)
        uv = cam.project(seen)
        if (uv.min(axis=0) >= MARGIN_PX).all() and (uv.max(axis=0) <= (WIDTH_PX - MARGIN_PX,
                                                                      HEIGHT_PX - MARGIN_PX)).all():
            return cam
        behind, up, into = behind + 0.03, up + 0.03, into + 0.02
    raise RuntimeError("no camera frames the fall")   # pragma: no cover - a camera far enough always does


def scene_for(spec: VideoSpec):
    """The planned video's scene (with its camera), its sub-frame motion and how it looks
    (`render.Setup`)."""
    from .render import SKINS, SLEEVES, Setup

    o, sf = spec.obj, spec.surface
    rng = np.random.default_rng(spec.seed)
    e, mu = pair_truth(o, sf, spec.truth_seed)
    scene = FallScene(object=o.name, surface=sf.kind, surface_kind=sf.kind, surface_size_m=sf.size_m, shape=o.shape,
                      mass_kg=o.mass_kg, restitution=e, friction=mu, fps=FPS, sim_hz=SIM_HZ,
                      release_frame=int(rng.integers(RELEASE_FRAMES[0], RELEASE_FRAMES[1] + 1)),
                      n_frames=int(rng.integers(N_FRAMES[0], N_FRAMES[1] + 1)))
    for i in range(MAX_TRIES):
        drawn = _release(scene, rng, 1.0 - i / MAX_TRIES)
        motion = sub_motion(drawn)
        if release_problem(drawn, motion) is None:
            break
    else:   # a still, level release: it lands flat where it is let go and stays
        drawn = dataclasses.replace(scene, x0_m=-0.1 * sf.size_m[0], z0_m=HEIGHT_M[0] + scene.shape.size_m[2] / 2)
        motion = sub_motion(drawn)
    scene = dataclasses.replace(drawn, camera=_camera(drawn, motion, rng))
    setup = Setup(o, sf, sf.colors_rgb[int(rng.integers(len(sf.colors_rgb)))], int(rng.choice([-1, 1])),
                  SKINS[int(rng.integers(len(SKINS)))], SLEEVES[int(rng.integers(len(SLEEVES)))])
    return scene, motion, setup


def bounce_apexes_m(motion: Trajectory, rest_z_m: float) -> list[float | None]:
    """The centre's highest point after the first and the second impact (until the next one),
    above its resting height; None where it does not rise by APEX_MIN_RISE_M after that impact
    (or there is none). An impact: the centre's vertical speed jumps up by more than IMPACT_MPS
    in one sample, jumps less than IMPACT_S apart counting as one (a tilted object's corners
    landing one after the other)."""
    z, vz = motion.position_m[0, :, 2], motion.velocity_mps[0, :, 2]
    jumps = np.flatnonzero(np.diff(vz) > IMPACT_MPS) + 1
    gap = max(1, round(IMPACT_S * motion.fps))
    impacts = [(a, b) for a, b in itertools.pairwise(jumps) if b - a > gap]     # (last of one, first of the next)
    starts = [int(j) for j in jumps[:1]] + [b for _, b in impacts]
    ends = [a for a, _ in impacts] + [int(j) for j in jumps[-1:]]
    out: list[float | None] = []
    for i in range(2):
        if i >= len(starts):
            out.append(None)
            continue
        stop = starts[i + 1] if i + 1 < len(starts) else len(z)
        top = float(z[ends[i]:stop].max())
        out.append(float(top - rest_z_m) if top - z[ends[i]] > APEX_MIN_RISE_M else None)
    return out


def silhouette_centres_px(masks: list[np.ndarray]) -> list[list[float] | None]:
    """Each frame's blurred object mask's centroid (u right, v down; None: not drawn)."""
    out = []
    for m in masks:
        total = float(m.sum())
        if total <= 0:
            out.append(None)
            continue
        v, u = np.indices(m.shape)
        out.append([float((u * m).sum() / total), float((v * m).sum() / total)])
    return out


def truth_json(scene: FallScene, setup, motion: Trajectory, masks, seen) -> dict:
    """What the video shows, for the tracker's and the inference's evaluation (see docs/formats.md)."""
    traj = frames_of(motion, scene)
    pos = traj.position_m[0]
    first, second = bounce_apexes_m(motion, float(pos[-1, 2]))
    o, sf = setup.obj, setup.surface
    return {"latents": {**scene.latents(), **{n: None for n in NOISE_LATENTS}},
            "release_frame": scene.release_frame,
            "object": {"name": o.name, "material": o.material, "shape": o.shape.to_json(), "mass_kg": o.mass_kg},
            "surface": {"name": scene.surface, "kind": sf.kind, "size_m": list(sf.size_m),
                        "color_rgb": list(setup.surface_rgb)},
            "center_px": scene.camera.project(pos).tolist(),
            "silhouette_center_px": silhouette_centres_px(masks),
            "visible": [bool(s) for s in seen],
            "rest_pos_m": pos[-1, :2].tolist(), "rest_height_m": float(pos[-1, 2]),
            "first_bounce_apex_m": first, "second_bounce_apex_m": second,
            "trajectory": traj.to_json(), "orientation_xyzw": traj.orientation_xyzw[0].tolist()}


def renderer_for(spec: VideoSpec):
    """(scene, its sub-frame motion, the `render.Renderer` that draws the planned video)."""
    from ...render import Look
    from .render import Renderer

    scene, motion, setup = scene_for(spec)
    look = Look.random(np.random.default_rng([spec.seed, 1]))
    return scene, motion, Renderer(scene, setup, look, texture_seed=spec.seed)


def render_one(spec: VideoSpec, out_dir: str) -> dict:
    """Render one video folder; returns its index entry."""
    from .render import render_to_video

    folder = Path(out_dir) / spec.name
    scene, motion, renderer = renderer_for(spec)
    masks, seen = render_to_video(renderer, motion.position_m[0], motion.orientation_xyzw[0], folder / "video.mp4")
    scene.save(folder / "scene.json")
    truth = truth_json(scene, renderer.setup, motion, masks, seen)
    write_json(folder / "truth.json", truth, indent=None)
    o = spec.obj
    return {"name": spec.name, "object": o.name, "material": o.material, "shape": o.shape.type,
            "surface": spec.surface.kind, "restitution": scene.restitution, "friction": scene.friction,
            "z0_m": scene.z0_m, "release_frame": scene.release_frame, "n_frames": scene.n_frames}


DATASET = dataset.DatasetSpec("fall", PRESETS, plan, render_one,
                              describe="objects dropped by hand onto a table, foam, carpet or cloth: demo (3 "
                                       "videos), small (24: 6 objects on each surface), full (26 objects on each "
                                       "surface, 2 takes)")

__all__ = [
    "DATASET",
    "PRESETS",
    "VideoSpec",
    "bounce_apexes_m",
    "frames_of",
    "plan",
    "render_one",
    "renderer_for",
    "scene_for",
    "sub_motion",
]

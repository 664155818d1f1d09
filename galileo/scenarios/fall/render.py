"""The fall's videos: its scene rendered through the scene's camera (galileo.render's pieces),
with motion blur.

What is drawn (TinyRenderer, visual bodies only: the physics is `physics.simulate`'s, run first):

* the room: a floor, a back wall beyond the surface's far end, the surface (a slab whose top is
  z = 0, its kind's look: `surface_texture`) and, under a foam mat or a cloth, a table;
* the object (a `galileo.shapes` shape in its material's colour, block-textured: corners for a
  tracker) at the simulated pose (centre and orientation) of every sub-frame;
* a hand: a skin-coloured palm against the object's side, fingers over its top edge, a thumb,
  a forearm and a sleeve rising from the image's side (`Setup.hand_side`: +1 from +y, the
  image's left) out of the picture. It holds the object at its release state until the release
  (the physics holds it there too), then pulls away, up and outwards, and stops HAND_TRAVEL_M
  off, still in view (as in the real clips). It starts above and beside the object and only
  moves up and out, so it never touches the falling object again;
* per-video light, exposure drift and sensor noise (`galileo.render.Look`).

**Motion blur** (`galileo.render.blur_offsets`): video frame f (time t = f / fps) is the mean
of renders at t + k / (n fps), k = -2..2, n = 8: an exposure of half the frame interval
centred on the frame's time. `Renderer.render` takes the motion sampled at n times the video's
rate (`physics.simulate` at that fps) and returns per frame the blurred object's silhouette
(the mean of its sub-frame masks, the renderer's segmentation) besides the image.

The hand and the object are separate bodies in the renderer's segmentation (`body_id`,
`hand_ids`), which the dataset's truth and the tests read.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ...render import (
    DEFAULT_LOOK,
    Look,
    average_renders,
    block_texture,
    blur_offsets,
    camera_image,
    gl_view_projection,
    grain_texture,
    load_texture,
)
from ...sim.bullet import cached_world, new_world, pb, visual_shape
from .materials import FallObject, Surface
from .scene import FallScene

FLOOR_RGB, WALL_RGB, TABLE_RGB = (96, 92, 88), (222, 224, 228), (168, 160, 150)
WALL_BEYOND_M = 0.6                         # the back wall this far beyond the surface's far end
TABLE_MARGIN_M = 0.06                       # a table under a mat or cloth reaches this far beyond it
SKINS = ((224, 172, 140), (198, 140, 104), (150, 102, 72), (236, 192, 164))
SLEEVES = ((30, 30, 34), (52, 70, 120), (90, 90, 96), (150, 40, 40))
PALM_HALF_M = (0.045, 0.012, 0.042)         # half its width (x), thickness (y), height (z)
HAND_GAP_M = 0.008                          # between the object's side (its turned box) and the palm
FINGER_RADIUS_M, FINGER_LENGTH_M = 0.009, 0.04
THUMB_RADIUS_M, THUMB_LENGTH_M = 0.01, 0.035
FOREARM_RADIUS_M, FOREARM_LENGTH_M = 0.03, 0.24
SLEEVE_RADIUS_M, SLEEVE_LENGTH_M = 0.045, 0.8
ARM_RISE_RAD = math.radians(35.0)           # the arm rises this steeply from the wrist, outwards
HAND_ACCEL_MPS2, HAND_SPEED_MPS = 10.0, 1.0  # the hand's pull-away: this acceleration up to this speed, ...
HAND_TRAVEL_M = 0.25                        # ... this far, then it stops (in view)
HAND_AWAY = np.array([0.0, 0.6, 0.8])       # its direction (y times the hand's side)
HAND_CLEAR_PX = 4                           # the object counts as seen once no hand pixel is this close to it
SPECKLE_SD, FIBRE_SD, WEAVE_PERIOD_PX, WEAVE_DEPTH = 12.0, 22.0, 8, 0.22   # the surfaces' textures
IDENTITY = (0.0, 0.0, 0.0, 1.0)
PARKED_M = (0.0, 0.0, -100.0)               # the moving bodies while the room is drawn alone
ALONG_X = (0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5))   # a capsule's axis z turned onto x
ALONG_Y = (math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5))   # ... onto y
_WORLDS = itertools.count()                 # each renderer builds a world of its own (textures differ)


@dataclass(frozen=True)
class Setup:
    """How a video looks beyond its scene: the object (shape, colour), the surface kind and its
    colour, the hand's side (+1: +y, the image's left), its skin and sleeve."""
    obj: FallObject
    surface: Surface
    surface_rgb: tuple[int, int, int]
    hand_side: int
    skin_rgb: tuple[int, int, int]
    sleeve_rgb: tuple[int, int, int]


def surface_texture(surface: Surface, rgb, rng: np.random.Generator, px: int = 256) -> np.ndarray:
    """A tile of the surface kind's look around `rgb`: a table's wood-like grain, a foam mat's
    fine speckle, a carpet's coarse fibres, a cloth's woven checks."""
    if surface.texture == "grain":
        return grain_texture(rgb, rng, px=px, strength=7.0, streaks=True)
    base = np.asarray(rgb, float)
    if surface.texture == "speckle":
        img = base + cv2.GaussianBlur(rng.normal(0, SPECKLE_SD, (px, px)), (0, 0), 0.8)[..., None]
    elif surface.texture == "fibre":
        img = base * (1 + rng.normal(0, FIBRE_SD / 255, (px, px, 1))) + rng.normal(0, 4, (px, px, 3))
    elif surface.texture == "weave":
        i = (np.arange(px) // WEAVE_PERIOD_PX) % 2
        dark = 1 - WEAVE_DEPTH * 0.5 * (i[:, None] + i[None, :])
        img = base * dark[..., None] + rng.normal(0, 3, (px, px, 3))
    else:
        raise ValueError(f"unknown surface texture {surface.texture!r}")
    return np.clip(img, 0, 255).astype(np.uint8)


def hand_offset_m(scene: FallScene, side: int, time_s: float) -> np.ndarray:
    """The hand's displacement (world, m) at `time_s` (video time) from where it holds the
    object: none until the release, then the pull-away."""
    t = time_s - scene.release_frame / scene.fps
    if t <= 0:
        return np.zeros(3)
    t_acc = HAND_SPEED_MPS / HAND_ACCEL_MPS2
    s = 0.5 * HAND_ACCEL_MPS2 * min(t, t_acc) ** 2 + HAND_SPEED_MPS * max(0.0, t - t_acc)
    d = HAND_AWAY * (1.0, side, 1.0)
    return min(s, HAND_TRAVEL_M) * d / np.linalg.norm(d)


def hand_parts(scene: FallScene, side: int) -> list[tuple[str, tuple, np.ndarray, tuple]]:
    """The hand holding the object at its release state: (part, its size, centre (world),
    orientation) for the palm (a box of half extents), the fingers, the thumb, the forearm and
    the sleeve (capsules: radius, length)."""
    c = np.array([scene.x0_m, scene.y0_m, scene.z0_m])
    rot = np.array(pb.getMatrixFromQuaternion(pb.getQuaternionFromEuler(
        (scene.roll0_rad, scene.pitch0_rad, scene.yaw0_rad)))).reshape(3, 3)
    corners = scene.shape.box_corners() @ rot.T
    half_y, top = float(np.abs(corners[:, 1]).max()), float(corners[:, 2].max())
    inner = c[1] + side * (half_y + HAND_GAP_M)            # the palm's face towards the object
    palm = np.array([c[0], inner + side * PALM_HALF_M[1], c[2] + 0.005])
    parts = [("palm", PALM_HALF_M, palm, IDENTITY)]
    for i in range(4):
        x = c[0] + (i - 1.5) * 2.3 * FINGER_RADIUS_M
        y = inner + side * (2 * PALM_HALF_M[1] - FINGER_LENGTH_M / 2 - FINGER_RADIUS_M)
        parts.append(("finger", (FINGER_RADIUS_M, FINGER_LENGTH_M), np.array([x, y, c[2] + top + FINGER_RADIUS_M
                                                                                + 0.004]), ALONG_Y))
    parts.append(("thumb", (THUMB_RADIUS_M, THUMB_LENGTH_M),
                  np.array([c[0] - PALM_HALF_M[0] - THUMB_LENGTH_M / 2, inner + side * THUMB_RADIUS_M,
                            c[2] - 0.01]), ALONG_X))
    d = np.array([0.0, side * math.cos(ARM_RISE_RAD), math.sin(ARM_RISE_RAD)])
    arm_orn = tuple(pb.getQuaternionFromEuler((-side * (math.pi / 2 - ARM_RISE_RAD), 0.0, 0.0)))
    wrist = palm + (0.0, side * PALM_HALF_M[1], 0.01)
    parts.append(("forearm", (FOREARM_RADIUS_M, FOREARM_LENGTH_M),
                  wrist + d * (FOREARM_LENGTH_M / 2 + FOREARM_RADIUS_M), arm_orn))
    parts.append(("sleeve", (SLEEVE_RADIUS_M, SLEEVE_LENGTH_M),
                  wrist + d * (FOREARM_LENGTH_M + SLEEVE_LENGTH_M / 2 + 0.02), arm_orn))
    return parts


class _World:
    """The visual world of one video (no physics runs in it): the object and the hand, made first
    and parked out of sight, then the room (`static`), which the renderer draws once and removes."""

    def __init__(self, key, scene: FallScene, setup: Setup, texture_seed: int):
        self.key = key
        self.cid = cid = new_world(scene.sim_hz, 0.0, 1)
        rng = np.random.default_rng(texture_seed)

        def body(shape: int, pos, orn=IDENTITY, texture: np.ndarray | None = None, tag: str = "") -> int:
            b = pb.createMultiBody(0, -1, shape, basePosition=list(map(float, pos)), baseOrientation=list(orn),
                                   physicsClientId=cid)
            if texture is not None:
                pb.changeVisualShape(b, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                                     textureUniqueId=load_texture(texture, f"fall_{tag}_{texture_seed}", cid))
            return b

        def solid(geom: int, rgb=(255, 255, 255), **size) -> int:
            return pb.createVisualShape(geom, rgbaColor=[*np.divide(rgb, 255), 1], physicsClientId=cid, **size)

        def box(half, rgb=(255, 255, 255)) -> int:
            return solid(pb.GEOM_BOX, rgb, halfExtents=list(map(float, half)))

        self.object = body(visual_shape(scene.shape, cid), PARKED_M, IDENTITY,
                           block_texture(setup.obj.color_rgb, rng), "object")
        self.hand = []
        for part, size, pos, orn in hand_parts(scene, setup.hand_side):
            rgb = setup.sleeve_rgb if part == "sleeve" else setup.skin_rgb
            shape = box(size, rgb) if part == "palm" else solid(pb.GEOM_CAPSULE, rgb, radius=size[0], length=size[1])
            self.hand.append((body(shape, PARKED_M, orn), pos, orn))
        # the room
        sf = setup.surface
        L, W = scene.surface_size_m
        floor_z = -sf.floor_below_m
        wall_x = L / 2 + WALL_BEYOND_M
        self.static = [
            body(box((6.0, 6.0, 0.01)), (0.0, 0.0, floor_z - 0.01), texture=grain_texture(FLOOR_RGB, rng, strength=8),
                 tag="floor"),
            body(box((0.01, 6.0, 2.5)), (wall_x + 0.01, 0.0, floor_z + 2.5),
                 texture=grain_texture(WALL_RGB, rng, strength=4), tag="wall"),
            body(box((L / 2, W / 2, sf.thickness_m / 2)), (0.0, 0.0, -sf.thickness_m / 2),
                 texture=surface_texture(sf, setup.surface_rgb, rng), tag="surface")]
        if sf.on_table:
            self.static.append(body(box((L / 2 + TABLE_MARGIN_M, W / 2 + TABLE_MARGIN_M, 0.015)),
                                    (0.0, 0.0, -sf.thickness_m - 0.015),
                                    texture=grain_texture(TABLE_RGB, rng, strength=6), tag="table"))


class Renderer:
    """Renders a fall scene's motion through its camera, with motion blur."""

    def __init__(self, scene: FallScene, setup: Setup, look: Look | None = None, texture_seed: int = 0):
        if scene.camera is None:
            raise ValueError("rendering needs a scene with a camera")
        self.scene, self.setup = scene, setup
        self.cam = cam = scene.camera
        self.look = look or DEFAULT_LOOK
        self.view, self.proj = gl_view_projection(cam)
        self.sub, self.offsets = blur_offsets()
        key = ("fall render", next(_WORLDS))
        self.world = cached_world(key, lambda: _World(key, scene, setup, texture_seed))
        self.body_id = self.world.object
        self.hand_ids = np.array([b for b, _, _ in self.world.hand])
        self._noise_rng = np.random.default_rng(self.look.seed)
        # the room never moves: drawn once (the moving bodies parked), then removed, so that each
        # render draws the object and the hand alone over it
        rgba, depth, _ = camera_image(cam, self.view, self.proj, self.look, self.world.cid)
        self.background = (rgba[..., :3].astype(np.float32), depth)
        for b in self.world.static:
            pb.removeBody(b, physicsClientId=self.world.cid)
        self._last = None

    def render_pose(self, time_s: float, pos, orn) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One (sharp) render at video time `time_s` with the object at (pos, orn): RGB float32
        (H, W, 3), the object's mask and the hand's (bool (H, W)). Equal consecutive poses are
        drawn once."""
        off = hand_offset_m(self.scene, self.setup.hand_side, time_s)
        key = (tuple(map(float, pos)), tuple(map(float, orn)), tuple(off))
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        cid = self.world.cid
        pb.resetBasePositionAndOrientation(self.body_id, list(key[0]), list(key[1]), physicsClientId=cid)
        for b, p, o in self.world.hand:
            pb.resetBasePositionAndOrientation(b, list(map(float, p + off)), o, physicsClientId=cid)
        rgba, depth, seg = camera_image(self.cam, self.view, self.proj, self.look, cid)
        bg_rgb, bg_depth = self.background
        moving = (seg >= 0) & (depth < bg_depth)
        img = bg_rgb.copy()
        img[moving] = rgba[..., :3][moving]
        out = (img, moving & (seg == self.body_id), moving & np.isin(seg, self.hand_ids))
        self._last = (key, out)
        return out

    def render(self, position_m: np.ndarray, orientation_xyzw: np.ndarray, on_image=None):
        """Render the video from the motion sampled at `self.sub` times its rate (position (N, 3),
        orientation (N, 4), sample j at video time j / (sub fps); frames past its end are held),
        calling on_image(frame, rgb uint8) for each frame. Returns per frame the blurred
        object's mask (the mean of its sub-frame masks, float32 (H, W)) and whether the object
        is seen clear of the hand (after the release, in every sub-frame some of it drawn and no
        hand pixel within HAND_CLEAR_PX of it)."""
        sc, lk = self.scene, self.look
        n_samples = len(position_m)
        masks, seen = [], []
        for f in range(sc.n_frames):
            imgs, obj_masks, hand_near = [], [], False
            for k in self.offsets:
                j = min(max(self.sub * f + int(k), 0), n_samples - 1)
                img, obj, hand = self.render_pose((self.sub * f + int(k)) / (self.sub * sc.fps), position_m[j],
                                                  orientation_xyzw[j])
                imgs.append(img)
                obj_masks.append(obj)
                hand_near = hand_near or not obj.any() or _near(obj, hand, HAND_CLEAR_PX)
            img = average_renders(imgs)
            masks.append(average_renders([m[..., None] for m in obj_masks])[..., 0])
            seen.append(f > sc.release_frame and not hand_near)
            if on_image is not None:
                img *= lk.gain(f)
                img += 0.5
                if lk.noise_sd:
                    img += lk.noise_sd * self._noise_rng.standard_normal(img.shape, dtype=np.float32)
                on_image(f, np.clip(img, 0, 255, out=img).astype(np.uint8))
        return masks, seen


def _near(a: np.ndarray, b: np.ndarray, px: int) -> bool:
    """Whether any pixel of mask b lies within `px` of the box around mask a's pixels."""
    ys, xs = np.nonzero(a)
    h, w = a.shape
    return bool(b[max(0, ys.min() - px):min(h, ys.max() + px + 1), max(0, xs.min() - px):min(w, xs.max() + px + 1)]
                .any())


def render_to_video(renderer: Renderer, position_m: np.ndarray, orientation_xyzw: np.ndarray,
                    path: str | Path):
    """Render the motion (as `Renderer.render` takes it) to an H.264 MP4 at the scene's fps;
    `Renderer.render`'s masks and seen flags."""
    from ...video import write_video

    frames: list[np.ndarray] = []
    out = renderer.render(position_m, orientation_xyzw, on_image=lambda f, rgb: frames.append(rgb))
    write_video(path, frames, renderer.scene.fps)
    return out

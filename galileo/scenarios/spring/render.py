"""The spring's videos: its scene rendered through the scene's camera (galileo.render's pieces).

What is drawn (TinyRenderer, visual bodies only: the physics is `physics.simulate`'s, run first):

* a wall and a table with grain, a stand on the table: a base plate, a vertical pole beside
  the spring and an arm from it to the hanging point;
* the object (a `galileo.shapes` shape in its material's colour, block-textured: corners for a
  tracker) posed at the simulated centre in every frame (it does not turn);
* a hand: a skin-coloured palm, fingers and thumb in front of the object, a forearm and sleeve
  coming from one side. It holds the object at its release state until `release_frame` (the
  physics holds it there too), then accelerates away, sideways, down and towards the camera,
  and leaves the picture. Every part of it stays in front of the object's front face (y below
  it) and it only moves further forward, so it never touches the object again;
* after rendering, with the depth buffer (what is nearer stays in front): the spring, a helix
  (`galileo.drawing.connector_points`) from the hanging point to its lower end (the object's
  centre less `hang_m` along the spring, as the physics has it), its coils shaded lighter in
  front and darker behind, its wire as thin as it looks from the camera; the hook or the
  bag's knot at its end; a clear bag over the object (a faint haze with brighter edges and
  creases);
* per-video light, exposure drift and sensor noise (`galileo.render.Look`).

The hand and the object are separate bodies in the renderer's segmentation (`body_id`,
`hand_ids`), which the tests read: the object's pixels centre on the projected truth.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from statistics import NormalDist

import cv2
import numpy as np

from ...datatypes import Trajectory
from ...drawing import Anchor, Connector, connector_points
from ...render import (
    DEFAULT_LOOK,
    FAR_M,
    NEAR_M,
    Look,
    block_texture,
    camera_image,
    gl_view_projection,
    grain_texture,
    load_texture,
)
from ...sim.bullet import cached_world, new_world, pb, visual_shape
from .materials import BAG_SLACK_M, HOOK_M, CatalogueObject, Spring
from .scene import SpringScene

WALL_RGB, TABLE_RGB, STAND_RGB = (214, 212, 204), (150, 124, 96), (62, 62, 68)
POLE_RADIUS_M, ARM_RADIUS_M = 0.007, 0.006
BASE_M = (0.16, 0.12, 0.012)                # the stand's base plate
SKINS = ((224, 172, 140), (198, 140, 104), (150, 102, 72), (236, 192, 164))
SLEEVES = ((52, 70, 120), (90, 90, 96), (40, 96, 70), (150, 40, 40))
PALM_M = (0.085, 0.028, 0.09)               # width (x), thickness (y), height (z)
FINGER_RADIUS_M, FINGER_LENGTH_M, THUMB_LENGTH_M = 0.009, 0.065, 0.045
FOREARM_RADIUS_M, FOREARM_LENGTH_M = 0.032, 0.24
SLEEVE_RADIUS_M, SLEEVE_LENGTH_M = 0.045, 0.4
HAND_GAP_M = 0.012                          # between the object's (or its bag's) front face and the palm
HAND_ACCEL_MPS2, HAND_SPEED_MPS = 20.0, 1.6  # the hand's pull-away: this acceleration up to this speed,
HAND_TRAVEL_M = 1.5                         # ... this far (out of the picture, still in front of the camera)
HAND_AWAY = np.array([0.8, -0.45, -0.4])    # its direction (x times the hand's side), normalised below
HAND_AWAY = HAND_AWAY / np.linalg.norm(HAND_AWAY)
HAND_CLEAR_PX = 8                           # the hand counts as gone once this far from the object's pixels
SPRING_SHADE = 0.3                          # a coil's near side this much lighter, its far side darker
SHADE_EDGES = np.linspace(-1.0, 1.0001, 7)  # ... in this many steps (from the far side to the near)
SPRING_MIN_OPACITY = 0.35                   # a wire thinner than a pixel: this plus its width in px
HOOK_RGB, HOOK_WIRE_M = (70, 70, 74), 0.0015
KNOT_RADIUS_M = 0.004
BAG_RGB = np.array([236.0, 240.0, 245.0])
BAG_ALPHA, BAG_EDGE_ALPHA, BAG_CREASE_ALPHA = 0.16, 0.45, 0.22
BAG_BOTTOM_M = 0.012                        # the bag's loose film below the object
DEPTH_EPS_M = 0.004                         # an overlay hides behind what is nearer than it by this
SUBPIXEL_BITS = 4                           # cv2's fractional bits for overlay lines
OVERLAY_PAD_PX = 4
GAUSSIAN_LEVELS = np.array([NormalDist().inv_cdf((i + 0.5) / 256) for i in range(256)], np.float32)
_WORLDS = itertools.count()                 # each renderer builds a world of its own (textures differ)
IDENTITY = (0.0, 0.0, 0.0, 1.0)
PARKED_M = (0.0, 0.0, -100.0)               # the moving bodies while the room is drawn alone
ALONG_X = (0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5))   # a capsule's or cylinder's axis z turned onto x


@dataclass(frozen=True)
class Setup:
    """How a video looks beyond its scene: what hangs (shape, colour, bag or hook), the spring's
    drawing, the stand (its pole `stand_side` (+1: +x) of the hanging point, `arm_m` from it),
    the table's top (world z), the wall (`wall_m` behind the spring's plane), the hand (from
    side `hand_side`), its skin and sleeve."""
    obj: CatalogueObject
    spring: Spring
    color_rgb: tuple[int, int, int]
    stand_side: int
    arm_m: float
    table_z_m: float
    wall_m: float
    hand_side: int
    skin_rgb: tuple[int, int, int]
    sleeve_rgb: tuple[int, int, int]


def hand_offset_m(scene: SpringScene, side: int, frame: int) -> np.ndarray:
    """The hand's displacement (world, m) in video frame `frame` from where it holds the object:
    none until the frame after the release, then the pull-away."""
    t = (frame - scene.release_frame) / scene.fps
    if t <= 0:
        return np.zeros(3)
    t_acc = HAND_SPEED_MPS / HAND_ACCEL_MPS2
    s = 0.5 * HAND_ACCEL_MPS2 * min(t, t_acc) ** 2 + HAND_SPEED_MPS * max(0.0, t - t_acc)
    return min(s, HAND_TRAVEL_M) * HAND_AWAY * (side, 1.0, 1.0)


def spring_end_m(scene: SpringScene, center_m: np.ndarray) -> np.ndarray:
    """The spring's lower end for the object's centre at `center_m`: `hang_m` from the centre
    towards the hanging point (the physics' geometry)."""
    top = np.asarray(scene.top_in_world_m, float)
    d = top - center_m
    n = float(np.linalg.norm(d))
    return center_m + (d / n if n > 1e-9 else np.array([0.0, 0.0, 1.0])) * scene.hang_m


def _depth_m(depth_buffer: np.ndarray) -> np.ndarray:
    """OpenGL depth buffer -> distance along the optical axis (m)."""
    zb = 2.0 * depth_buffer.astype(np.float64) - 1.0
    return 2.0 * FAR_M * NEAR_M / (FAR_M + NEAR_M - zb * (FAR_M - NEAR_M))


class _World:
    """The visual world of one video (no physics runs in it): the object and the hand, made first
    and parked out of sight, then the room and the stand (`static`), which the renderer draws
    once and removes."""

    def __init__(self, key, scene: SpringScene, setup: Setup, texture_seed: int):
        self.key = key
        self.cid = cid = new_world(scene.sim_hz, 0.0, 1)
        rng = np.random.default_rng(texture_seed)
        tx, ty, tz = scene.top_in_world_m
        zt = setup.table_z_m

        def body(shape: int, pos, orn=IDENTITY, texture: np.ndarray | None = None, tag: str = "") -> int:
            b = pb.createMultiBody(0, -1, shape, basePosition=list(pos), baseOrientation=list(orn),
                                   physicsClientId=cid)
            if texture is not None:
                pb.changeVisualShape(b, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                                     textureUniqueId=load_texture(texture, f"spring_{tag}_{texture_seed}", cid))
            return b

        def solid(geom: int, rgb=(255, 255, 255), **size) -> int:
            return pb.createVisualShape(geom, rgbaColor=[*np.divide(rgb, 255), 1], physicsClientId=cid, **size)

        def box(half, rgb=(255, 255, 255)) -> int:
            return solid(pb.GEOM_BOX, rgb, halfExtents=list(half))

        def capsule(radius, length, rgb) -> int:      # (and the cylinder below: their axis is z)
            return solid(pb.GEOM_CAPSULE, rgb, radius=radius, length=length)

        # the object
        shape, self.orientation = setup.obj.shape()
        tex = block_texture(setup.color_rgb, rng)
        self.object = body(visual_shape(shape, cid), PARKED_M, self.orientation, tex, "object")
        # the hand, where it holds the object at its release position: all of it in front of the
        # object's (or its bag's) front face, y = `front`
        sx, sy, sz = scene.size_m
        side, skin = setup.hand_side, setup.skin_rgb
        c0 = np.array([tx + scene.scale * scene.x0_m, ty, tz + scene.scale * scene.z0_m])
        front = ty - sy / 2 - (BAG_SLACK_M if setup.obj.mount == "bag" else 0.0) - HAND_GAP_M
        palm = np.array([c0[0] + side * 0.015, front - PALM_M[1] / 2, c0[2] - 0.2 * sz])
        fingers_x = palm[0] - side * (PALM_M[0] / 2 + FINGER_LENGTH_M / 2 - 0.01)     # across the object
        fingers_y = front - PALM_M[1] - FINGER_RADIUS_M + 0.006
        fore_x = palm[0] + side * (PALM_M[0] / 2 + FOREARM_LENGTH_M / 2)
        sleeve_x = fore_x + side * (FOREARM_LENGTH_M / 2 + SLEEVE_LENGTH_M / 2)
        parts = [(box(np.divide(PALM_M, 2), skin), palm, IDENTITY),
                 *[(capsule(FINGER_RADIUS_M, FINGER_LENGTH_M, skin),
                    (fingers_x, fingers_y, palm[2] + PALM_M[2] / 2 - (1 + 2.15 * i) * FINGER_RADIUS_M), ALONG_X)
                   for i in range(4)],
                 (capsule(1.15 * FINGER_RADIUS_M, THUMB_LENGTH_M, skin),
                  (palm[0] + side * 0.02, front - PALM_M[1] - 0.012, palm[2] + PALM_M[2] / 2 + 0.02), IDENTITY),
                 (capsule(FOREARM_RADIUS_M, FOREARM_LENGTH_M, skin),
                  (fore_x, front - FOREARM_RADIUS_M - 0.002, palm[2]), ALONG_X),
                 (capsule(SLEEVE_RADIUS_M, SLEEVE_LENGTH_M, setup.sleeve_rgb),
                  (sleeve_x, front - SLEEVE_RADIUS_M - 0.002, palm[2] - 0.01), ALONG_X)]
        self.hand = [(body(shape, PARKED_M, orn), np.asarray(pos, float), orn) for shape, pos, orn in parts]
        # the room and the stand
        wall_y = ty + setup.wall_m
        px = tx + setup.stand_side * setup.arm_m
        pole_top = tz + 0.06
        arm_len = setup.arm_m + 0.03
        self.static = [
            body(box((3.0, 0.01, 2.0)), (tx, wall_y + 0.01, zt + 1.0),
                 texture=grain_texture(WALL_RGB, rng, strength=6), tag="wall"),
            body(box((3.0, 1.5, 0.02)), (tx, wall_y - 1.5, zt - 0.02),
                 texture=grain_texture(TABLE_RGB, rng, strength=14, streaks=True), tag="table"),
            body(box(np.divide(BASE_M, 2), STAND_RGB), (px, ty + 0.02, zt + BASE_M[2] / 2)),
            body(solid(pb.GEOM_CYLINDER, STAND_RGB, radius=POLE_RADIUS_M, length=pole_top - zt),
                 (px, ty, (pole_top + zt) / 2)),
            body(solid(pb.GEOM_CYLINDER, STAND_RGB, radius=ARM_RADIUS_M, length=arm_len),
                 (tx + setup.stand_side * (arm_len / 2 - 0.03), ty, tz + ARM_RADIUS_M), ALONG_X),
            body(box((0.018, 0.018, 0.022), STAND_RGB), (px, ty, tz + ARM_RADIUS_M))]      # the clamp


class Renderer:
    """Renders a spring scene's trajectory through its camera."""

    def __init__(self, scene: SpringScene, setup: Setup, look: Look | None = None, texture_seed: int = 0):
        if scene.camera is None:
            raise ValueError("rendering needs a scene with a camera")
        self.scene, self.setup = scene, setup
        self.cam = cam = scene.camera
        self.look = look or DEFAULT_LOOK
        self.view, self.proj = gl_view_projection(cam)
        key = ("spring render", next(_WORLDS))
        self.world = cached_world(key, lambda: _World(key, scene, setup, texture_seed))
        self.body_id = self.world.object
        self.hand_ids = [b for b, _, _ in self.world.hand]
        sp = setup.spring
        self.connector = Connector("spring", Anchor.fixed(scene.top_in_world_m), Anchor.on(0), sp.color_rgb,
                                   coils=sp.coils, radius_m=sp.radius_m)
        self._noise_rng = np.random.default_rng(self.look.seed)
        # the room and the stand never move: drawn once (the moving bodies parked), then removed, so
        # that each frame draws the object and the hand alone over them (no shadows: the same pixels)
        rgba, depth, seg = camera_image(cam, self.view, self.proj, self.look, self.world.cid)
        self.background = (rgba[..., :3].copy(), depth, seg)
        for b in self.world.static:
            pb.removeBody(b, physicsClientId=self.world.cid)

    # -- posing ------------------------------------------------------------------------------
    def pose(self, frame: int, center_m: np.ndarray) -> None:
        """The object at `center_m`, the hand where it is in video frame `frame`."""
        cid = self.world.cid
        pb.resetBasePositionAndOrientation(self.body_id, list(map(float, center_m)), self.world.orientation,
                                           physicsClientId=cid)
        off = hand_offset_m(self.scene, self.setup.hand_side, frame)
        for b, pos, orn in self.world.hand:
            pb.resetBasePositionAndOrientation(b, list(map(float, pos + off)), orn, physicsClientId=cid)

    # -- overlays ------------------------------------------------------------------------------
    def _camera_depth(self, pts: np.ndarray) -> np.ndarray:
        r, t = self.cam.world_to_camera[:3, :3], self.cam.world_to_camera[:3, 3]
        return pts @ r[2] + t[2]

    def _px_per_m(self, depth_m: float) -> float:
        return float(self.cam.K[0, 0]) / depth_m

    def _overlay(self, img: np.ndarray, depth_buffer: np.ndarray, items: list, layer_depth_m: float) -> None:
        """Draw `items` over `img` in order, antialiased, except where the image (its depth buffer)
        holds something nearer than `layer_depth_m` (m along the optical axis): each ("fill",
        polygon (N, 2) px, rgb, opacity) or ("lines", polylines (K, N, 2) px, rgb, opacity,
        thickness px)."""
        pts = np.concatenate([np.reshape(it[1], (-1, 2)) for it in items])
        h, w = img.shape[:2]
        x0, y0 = np.maximum(np.floor(pts.min(axis=0)).astype(int) - OVERLAY_PAD_PX, 0)
        x1, y1 = np.minimum(np.ceil(pts.max(axis=0)).astype(int) + OVERLAY_PAD_PX, (w, h))
        if x1 <= x0 or y1 <= y0:
            return
        shape = (y1 - y0, x1 - x0)
        layer = np.zeros((*shape, 3), np.float32)     # colour x alpha
        alpha = np.zeros(shape, np.float32)
        cov = np.zeros(shape, np.uint8)
        scale = 1 << SUBPIXEL_BITS

        def fixed(p):
            return np.round((np.asarray(p) - (x0, y0)) * scale).astype(np.int32)

        for kind, geom, rgb, opacity, *thickness in items:
            cov[:] = 0
            if kind == "fill":
                cv2.fillPoly(cov, [fixed(geom)], 255, cv2.LINE_AA, SUBPIXEL_BITS)
            else:
                cv2.polylines(cov, list(fixed(geom)), False, 255, thickness[0], cv2.LINE_AA, SUBPIXEL_BITS)
            a = (cov.astype(np.float32) * (opacity / 255.0))[..., None]
            layer = np.asarray(rgb, np.float32) * a + layer * (1 - a)
            alpha = a[..., 0] + alpha * (1 - a[..., 0])
        alpha[_depth_m(depth_buffer[y0:y1, x0:x1]) < layer_depth_m - DEPTH_EPS_M] = 0.0
        layer[alpha == 0] = 0.0
        sub = img[y0:y1, x0:x1]
        img[y0:y1, x0:x1] = sub * (1 - alpha[..., None]) + layer

    def _spring_items(self, center_m: np.ndarray) -> tuple[list, float]:
        """The helix from the hanging point to the spring's end (the far side of each coil first,
        darker, then the near side), the hook or the knot; and the nearest depth of them."""
        sp, obj = self.setup.spring, self.setup.obj
        end = spring_end_m(self.scene, center_m)
        pts = connector_points(self.connector, end[None])
        uv = self.cam.project(pts)
        z = self._camera_depth(pts)
        n = len(pts) - 2                                   # the coil's points, between the two anchors
        s = np.r_[0.0, np.arange(n) / (n - 1), 1.0]
        radial = pts - (pts[0] + s[:, None] * (end - pts[0]))
        near = -(radial @ self.cam.world_to_camera[2, :3]) / sp.radius_m     # +1: the coil's side nearest us
        near = 0.5 * (near[1:] + near[:-1])                # per segment
        opacity = min(1.0, SPRING_MIN_OPACITY + sp.wire_m * self._px_per_m(float(z.mean())))
        rgb = np.asarray(sp.color_rgb, float)
        items = []
        for lo, hi in zip(SHADE_EDGES[:-1], SHADE_EDGES[1:]):
            idx = np.flatnonzero((near >= lo) & (near < hi))
            if len(idx):
                shade = 1.0 + SPRING_SHADE * 0.5 * (lo + hi)
                items.append(("lines", np.stack([uv[idx], uv[idx + 1]], axis=1), np.clip(rgb * shade, 0, 255), opacity,
                              1))
        if obj.mount == "hook":        # a wire bent into a hook, into an eye on the object's top
            eye = center_m + (0.0, 0.0, obj.size_m[2] / 2)
            bend = [(0.0, -0.55), (0.16, -0.75), (0.0, -0.9), (-0.16, -0.75), (-0.04, -0.6)]
            hook = np.array([end] + [end + (HOOK_M * dx, 0.0, HOOK_M * dz) for dx, dz in bend] + [eye])
            thick = max(1, int(round(HOOK_WIRE_M * self._px_per_m(float(z[-1])))))
            items.append(("lines", self.cam.project(hook)[None], HOOK_RGB, 1.0, thick))
        else:                          # the bag's knot: a twist of film at the spring's end
            a = np.linspace(0, 2 * math.pi, 16, endpoint=False)
            knot = end + KNOT_RADIUS_M * np.c_[np.cos(a), np.zeros_like(a), 1.4 * np.sin(a)]
            items.append(("fill", self.cam.project(knot), BAG_RGB * 0.85, 0.7))
        return items, float(z.min())

    def _bag_items(self, center_m: np.ndarray) -> tuple[list, float]:
        """A clear bag in front of the object, from the knot down over its top corners and sides to
        a loose bottom: a faint haze with brighter edges and creases; and its depth."""
        sx, sy, sz = self.scene.size_m
        end = spring_end_m(self.scene, center_m)
        cx, cy, cz = center_m
        w, top, bottom = sx / 2 + BAG_SLACK_M, cz + sz / 2, cz - sz / 2 - BAG_SLACK_M
        neck = top + 0.3 * (end[2] - top)
        r = min(BAG_BOTTOM_M, w)
        arc = np.linspace(0, math.pi / 2, 5)
        outline = ([(end[0] - 0.003, end[2]), (cx - 0.6 * w, neck), (cx - w, top)]
                   + [(cx - w + r - r * math.cos(a), bottom - 0.8 * r * math.sin(a)) for a in arc]
                   + [(cx + w - r + r * math.sin(a), bottom - 0.8 * r * math.cos(a)) for a in arc]
                   + [(cx + w, top), (cx + 0.6 * w, neck), (end[0] + 0.003, end[2])])
        y = cy - sy / 2 - BAG_SLACK_M
        world = np.array([(x, y, z) for x, z in outline])
        creases = [((-0.3, neck), (-0.25, bottom)), ((0.35, top), (0.4, bottom + 0.3 * sz))]
        px = self.cam.project
        items = [("fill", px(world), BAG_RGB, BAG_ALPHA), ("lines", px(world)[None], BAG_RGB, BAG_EDGE_ALPHA, 1),
                 ("lines", px(np.array([[(cx + f * w, y, z) for f, z in c] for c in creases])), BAG_RGB,
                  BAG_CREASE_ALPHA, 1)]
        return items, float(self._camera_depth(world).min())

    # -- frames ----------------------------------------------------------------------------------
    def render_current(self, frame: int, center_m: np.ndarray, with_segmentation: bool = False):
        """The image of video frame `frame` with the object at `center_m` (and its pose set):
        RGB uint8 (H, W, 3) [, segmentation (H, W) of body ids]."""
        self.pose(frame, center_m)
        lk = self.look
        rgba, depth, seg = camera_image(self.cam, self.view, self.proj, lk, self.world.cid)
        bg_rgb, bg_depth, bg_seg = self.background
        moving = (seg >= 0) & (depth < bg_depth)
        img = bg_rgb.astype(np.float32)
        img[moving] = rgba[..., :3][moving]
        depth = np.where(moving, depth, bg_depth)
        if self.setup.obj.mount == "bag":
            self._overlay(img, depth, *self._bag_items(center_m))
        self._overlay(img, depth, *self._spring_items(center_m))
        img *= lk.gain(frame)
        img += 0.5
        if lk.noise_sd:     # Gaussian by its inverse CDF at 256 levels: a quarter of the cost of exact draws
            img += lk.noise_sd * GAUSSIAN_LEVELS[self._noise_rng.integers(0, 256, img.shape, dtype=np.uint8)]
        rgb = np.clip(img, 0, 255, out=img).astype(np.uint8)
        return (rgb, np.where(moving, seg, bg_seg)) if with_segmentation else rgb

    def render(self, traj: Trajectory, on_image=None, with_segmentation: bool = False) -> int:
        """Render every frame of `traj` (the object's simulated centre), calling on_image(frame,
        rgb[, seg]) for each; the first frame after the release from which no pixel of the hand
        comes within HAND_CLEAR_PX of the box around the object's (the video's length if none)."""
        gone = None
        hand = np.asarray(self.hand_ids)
        h, w = self.cam.height_px, self.cam.width_px
        for f in range(traj.n_frames):
            rgb, seg = self.render_current(f, traj.position_m[0, f], with_segmentation=True)
            ys, xs = np.nonzero(seg == self.body_id)
            touching = f <= self.scene.release_frame or not len(ys)
            if not touching:
                y0, x0 = max(0, ys.min() - HAND_CLEAR_PX), max(0, xs.min() - HAND_CLEAR_PX)
                touching = bool(np.isin(seg[y0:min(h, ys.max() + HAND_CLEAR_PX + 1),
                                            x0:min(w, xs.max() + HAND_CLEAR_PX + 1)], hand).any())
            gone = None if touching else (f if gone is None else gone)
            if on_image is not None:
                on_image(f, rgb, seg) if with_segmentation else on_image(f, rgb)
        return traj.n_frames if gone is None else gone


def render_to_video(renderer: Renderer, traj: Trajectory, path: str | Path) -> int:
    """Render `traj` to an H.264 MP4 at the scene's fps; the frame from which the hand is gone."""
    from ...video import write_video

    frames: list[np.ndarray] = []
    gone = renderer.render(traj, on_image=lambda f, rgb: frames.append(rgb))
    write_video(path, frames, renderer.scene.fps)
    return gone

"""Rendering splash scenes into Physics-101-style side-view videos (TinyRenderer).

The camera is the scene's calibrated pinhole camera (`galileo.render.gl_view_projection`, so
that `Camera.project` of the object's centre lands on the object in the image). What is drawn:

* the tank: its front and back glass are not drawn (the object stays visible behind the
  front glass; the back wall of the room shows through the back glass); the side walls and
  floor in a light glass colour; a faint glass tint over every pixel whose ray crosses the tank;
* a textured back wall of the room and a table under the tank (visual only, no collision);
* the water, by tinting after rendering: the depth buffer gives the 3-D point every pixel
  sees; the length L of its ray's path through the water (the box of the tank's inside up to
  the water level) tints it, colour = c exp(-L / WATER_EXTINCTION_M) + water (1 - exp(...))
  (Beer-Lambert). Pixels seen through the water's top (the surface, a band a few pixels
  high from this camera) get a light sheen, and a dark line marks the waterline on the
  front glass. No fluid is simulated or drawn (no splash, no ripples);
* the object with a block texture in its material's colour (corners for KLT);
* per-video light, exposure drift and sensor noise (`galileo.render.Look`).

Video frame 0 is physics step `scene.start_step` after the release (frame f: step
start_step + f * sim_hz / fps); the steps before it are simulated but not shown.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...datatypes import Trajectory
from ...render import (DEFAULT_LOOK, FAR_M, NEAR_M, Look, block_texture, camera_image, gl_view_projection,
                       grain_texture, load_texture)
from ...sim.bullet import pb
from .physics import Simulator
from .scene import SplashScene

WATER_RGB = np.array([60.0, 135.0, 165.0])
WATER_EXTINCTION_M = 0.35      # tint 1 - exp(-L / this): about 0.37 through 16 cm of water
GLASS_RGB = np.array([205.0, 225.0, 235.0])
GLASS_TINT = 0.06              # every ray through the tank's glass
SHEEN_RGB = np.array([235.0, 245.0, 250.0])
SHEEN = 0.3                    # rays entering the water through its surface
WATERLINE_M = 0.0015           # the dark waterline on the front glass: this far below the level
WATERLINE_DARK = 0.45
BACKDROP_Y_M = 0.30            # the room's back wall, this far behind the tank's centre
WALL_RGB, TABLE_RGB = (222, 220, 212), (150, 128, 105)
DEFAULT_OBJECT_RGB = (200, 80, 60)


def object_color(scene: SplashScene) -> tuple[int, int, int]:
    from .materials import MATERIALS_BY_NAME

    m = MATERIALS_BY_NAME.get(scene.obj.material or "")
    return m.color_rgb if m is not None else DEFAULT_OBJECT_RGB


def _slab(origin: np.ndarray, d: np.ndarray, lo, hi) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Entry and exit parameters t of the rays origin + t d (d: (N, 3)) through the box
    [lo, hi], and the axis each ray enters through (t_in > t_out: no hit)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1 = (np.asarray(lo) - origin) * inv
        t2 = (np.asarray(hi) - origin) * inv
    near, far = np.minimum(t1, t2), np.maximum(t1, t2)
    near = np.where(np.isnan(near), -np.inf, near)
    far = np.where(np.isnan(far), np.inf, far)
    return near.max(axis=1), far.min(axis=1), near.argmax(axis=1)


class Renderer:
    """Renders a splash scene's simulation through its camera."""

    def __init__(self, scene: SplashScene, look: Look | None = None, texture_seed: int = 0,
                 color: tuple[int, int, int] | None = None):
        if scene.camera is None:
            raise ValueError("rendering needs a scene with a camera")
        self.scene = scene
        self.cam = cam = scene.camera
        self.look = look or DEFAULT_LOOK
        self.sim = Simulator(scene, visual=True)
        self.view, self.proj = gl_view_projection(cam)
        w = self.sim.world
        cid = w.cid
        rng = np.random.default_rng(texture_seed)
        floor, left, right, front, back = w.statics
        for b in (front, back):
            pb.changeVisualShape(b, -1, rgbaColor=[1, 1, 1, 0], physicsClientId=cid)   # not drawn
        for b in (floor, left, right):
            pb.changeVisualShape(b, -1, rgbaColor=[*(GLASS_RGB / 255), 1], physicsClientId=cid)
        if getattr(w, "splash_room", None) is None:   # the room: visual only, once per world
            t = scene.tank
            sy = t.size_m[1]
            wall = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[2.0, 0.01, 1.5], physicsClientId=cid)
            table = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[2.0, BACKDROP_Y_M + 0.5, 0.01], physicsClientId=cid)
            w.splash_room = (
                pb.createMultiBody(0, -1, wall, basePosition=[0, sy / 2 + BACKDROP_Y_M, 1.0], physicsClientId=cid),
                pb.createMultiBody(0, -1, table, basePosition=[0, 0, -t.wall_m - 0.01], physicsClientId=cid))
        for b, tex in zip(w.splash_room, (grain_texture(WALL_RGB, rng, strength=6),
                                          grain_texture(TABLE_RGB, rng, strength=14, streaks=True))):
            pb.changeVisualShape(b, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                                 textureUniqueId=load_texture(tex, f"splash_room{b}_{texture_seed}", cid))
        self.texture = load_texture(block_texture(color or object_color(scene), rng), f"splash_obj_{texture_seed}", cid)
        # every pixel's ray (world frame) with unit depth along the optical axis
        r, t = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
        v, u = np.mgrid[0:cam.height_px, 0:cam.width_px].astype(float)
        self.origin = -r.T @ t
        self.rays = (np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3) @ np.linalg.inv(cam.K).T) @ r
        self._noise_rng = np.random.default_rng(self.look.seed)
        self._cache = None
        self.body_id: int | None = None     # the object's body in the last render

    # -- the water and glass, after rendering ----------------------------------------------------
    def water_alpha(self, depth_buffer: np.ndarray, rays: np.ndarray | None = None):
        """Per pixel (of `rays`, all by default): the water tint, whether the ray enters the
        water through its surface, whether it meets the waterline on the front glass, and
        whether it crosses the tank's glass."""
        t = self.scene.tank
        sx, sy, sz = t.size_m
        rays = self.rays if rays is None else rays
        zb = 2.0 * depth_buffer.astype(float) - 1.0
        depth = 2.0 * FAR_M * NEAR_M / (FAR_M + NEAR_M - zb * (FAR_M - NEAR_M))
        seg = rays * depth[:, None]                      # origin -> seen point
        t_in, t_out, axis = _slab(self.origin, seg, (-sx / 2, -sy / 2, 0.0), (sx / 2, sy / 2, t.water_level_m))
        a, b = np.maximum(t_in, 0.0), np.minimum(t_out, 1.0)
        length = np.where(b > a, (b - a) * np.linalg.norm(seg, axis=1), 0.0)
        alpha = 1.0 - np.exp(-length / WATER_EXTINCTION_M)
        wet = length > 0
        entry = self.origin + seg * a[:, None]
        surface = wet & (axis == 2)
        waterline = wet & (axis == 1) & (entry[:, 2] > t.water_level_m - WATERLINE_M)
        w = t.wall_m
        g_in, g_out, _ = _slab(self.origin, seg, (-sx / 2 - w, -sy / 2 - w, -w), (sx / 2 + w, sy / 2 + w, sz))
        glass = (g_out > np.maximum(g_in, 0.0)) & (g_in < 1.0)
        return alpha, surface, waterline, glass

    def _tint(self, depth_buffer: np.ndarray):
        """water_alpha for the whole image, recomputed only where the depth changed since
        the last frame (the object moves; the tank stands still)."""
        d = depth_buffer.reshape(-1)
        if self._cache is None:
            self._cache = (d, *self.water_alpha(d))
            return self._cache[1:]
        prev, *parts = self._cache
        idx = np.nonzero(d != prev)[0]
        if len(idx):
            for part, new in zip(parts, self.water_alpha(d[idx], self.rays[idx])):
                part[idx] = new
        self._cache = (d, *parts)
        return parts

    def render_current(self, frame_index: int = 0, with_segmentation: bool = False):
        """Render the world as it is now: RGB uint8 (H, W, 3) [, segmentation (H, W) of body ids]."""
        lk, cam = self.look, self.cam
        h, w = cam.height_px, cam.width_px
        rgba, depth, seg = camera_image(cam, self.view, self.proj, lk, self.sim.world.cid)
        img = rgba.reshape(-1, 4)[:, :3].astype(float)
        alpha, surface, waterline, glass = self._tint(depth)
        img += alpha[:, None] * (WATER_RGB - img)
        img[surface] += SHEEN * (SHEEN_RGB - img[surface])
        img[waterline] *= WATERLINE_DARK
        img[glass] += GLASS_TINT * (GLASS_RGB - img[glass])
        img = img * lk.gain(frame_index)
        if lk.noise_sd:
            img += self._noise_rng.normal(0, lk.noise_sd, img.shape)
        rgb = np.clip(img + 0.5, 0, 255).astype(np.uint8).reshape(h, w, 3)
        if with_segmentation:
            return rgb, seg
        return rgb

    def render(self, n_frames: int, values: dict[str, float] | None = None, on_image=None,
               with_segmentation: bool = False) -> Trajectory:
        """Simulate from the release and render `n_frames` video frames, video frame 0 being
        physics step start_step; on_image(frame, rgb[, seg]) for each. Returns the trajectory
        of the shown frames."""
        start = int(round((values or {}).get("start_step", self.scene.start_step)))
        cid = self.sim.world.cid

        def on_frame(i, pos, vel):
            if i == 0:   # the object's body is made for the run: texture it before the first frame
                self.body_id = self.sim.world.body
                pb.changeVisualShape(self.body_id, -1, rgbaColor=[1, 1, 1, 1], textureUniqueId=self.texture,
                                     physicsClientId=cid)
            out = self.render_current(i, with_segmentation)
            if on_image is not None:
                on_image(i, *out) if with_segmentation else on_image(i, out)
            return False

        return self.sim.run(n_frames, values, on_frame=on_frame, start_step=start)


def render_to_video(scene: SplashScene, path: str | Path, n_frames: int, look: Look | None = None,
                    texture_seed: int = 0, values: dict[str, float] | None = None) -> Trajectory:
    """Render the scene to an H.264 MP4 of `n_frames` frames; the shown frames' trajectory."""
    from ...video import write_video

    frames: list[np.ndarray] = []
    traj = Renderer(scene, look, texture_seed).render(n_frames, values, on_image=lambda f, rgb: frames.append(rgb))
    write_video(path, frames, scene.fps)
    return traj

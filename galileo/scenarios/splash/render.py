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

That is the default look (the demo, small and full presets). A `Style` gives a video another
look (the `looks` presets): the object's texture (`object_texture`: fine-grained plain colour,
stripes, wood grain or a printed label, in any colour, white included) in place of the block
texture, the room's wall and table (colours, textures, how far the wall stands behind the
tank) and a colour temperature and exposure (a per-channel gain after rendering: the light's
colour, the camera's white balance).

Frames are in video time (`Simulator.run`): before the scene's release_s the object is held
still at the release point; a release before frame 0 is simulated but not shown.

A video may be filmed through a real camera's effects (`galileo.footage`: `render_to_video`'s
footage), with motion blur from renders of the physics steps around each frame
(`Renderer.render`'s blur).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ...camera import steps_per_frame
from ...datatypes import Trajectory
from ...errors import GalileoError
from ...footage import Footage
from ...render import (DEFAULT_LOOK, FAR_M, NEAR_M, Look, average_renders, block_texture, camera_image,
                       gl_view_projection, grain_texture, load_texture)
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
TABLE_HALF_Y_M = BACKDROP_Y_M + 0.5   # the table under the tank: its half depth
WALL_RGB, TABLE_RGB = (222, 220, 212), (150, 128, 105)
DEFAULT_OBJECT_RGB = (200, 80, 60)
OBJECT_PATTERNS = ("plain", "stripes", "wood", "label")   # a second look's object textures (`object_texture`)
WALL_PATTERNS = ("grain", "stripes")
TABLE_PATTERNS = ("wood", "grain")
TEXTURE_PX = 128                 # an object texture's tile
WOOD_HUE_DEG = (15.0, 40.0)      # a wooden table's hues: reddish to yellowish browns


def object_color(scene: SplashScene) -> tuple[int, int, int]:
    from .materials import MATERIALS_BY_NAME

    m = MATERIALS_BY_NAME.get(scene.obj.material or "")
    return m.color_rgb if m is not None else DEFAULT_OBJECT_RGB


def _stripes(rgb_a, rgb_b, rng: np.random.Generator, px: int, period_px: tuple[float, float],
             duty: tuple[float, float]) -> np.ndarray:
    """A tile of straight stripes of two colours: period, angle (0, 45 or 90 degrees) and the
    first colour's share drawn."""
    period, share = rng.uniform(*period_px), rng.uniform(*duty)
    angle = math.radians(45.0 * int(rng.integers(3)))
    v, u = np.mgrid[0:px, 0:px].astype(float)
    first = np.mod((u * math.cos(angle) + v * math.sin(angle)) / period, 1.0) < share
    return np.where(first[..., None], np.asarray(rgb_a, float), np.asarray(rgb_b, float))


def object_texture(pattern: str, rgb: tuple[int, int, int], rng: np.random.Generator,
                   px: int = TEXTURE_PX) -> np.ndarray:
    """An object's texture of a second look (uint8 (px, px, 3)) around `rgb`: "plain" (fine
    grain, hardly a corner for the tracker), "stripes" (with a darker shade), "wood" (grain
    streaks) or "label" (a printed label: a light or dark panel with lines of dark "text")."""
    base = np.asarray(rgb, float)
    if pattern == "plain":
        return grain_texture(rgb, rng, px=px, strength=4.0)
    if pattern == "wood":
        return grain_texture(rgb, rng, px=px, strength=float(rng.uniform(12, 24)), streaks=True)
    if pattern == "stripes":
        dark = base * rng.uniform(0.45, 0.75)
        img = _stripes(base, dark, rng, px, (px / 10, px / 3), (0.3, 0.7))
        return np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)
    if pattern == "label":
        img = grain_texture(rgb, rng, px=px, strength=4.0).astype(float)
        paper = np.array([245.0, 243.0, 235.0]) if base.mean() < 170 else np.array([40.0, 45.0, 70.0])
        ink = np.array([25.0, 25.0, 30.0]) if base.mean() < 170 else np.array([235.0, 235.0, 225.0])
        h0, h1 = int(px * rng.uniform(0.2, 0.35)), int(px * rng.uniform(0.65, 0.8))
        img[h0:h1, :] = paper
        for k in range(int(rng.integers(2, 5))):          # lines of "text"
            row = h0 + int((k + 1) * (h1 - h0) / 6)
            a, b = int(px * rng.uniform(0.05, 0.3)), int(px * rng.uniform(0.6, 0.95))
            img[row:row + max(2, px // 40), a:b] = ink
        return img.astype(np.uint8)
    raise ValueError(f"unknown object pattern {pattern!r}; expected one of {', '.join(OBJECT_PATTERNS)}")


def surface_texture(pattern: str, rgb: tuple[int, int, int], rng: np.random.Generator) -> np.ndarray:
    """A wall's or table's texture of a second look: "grain" (mild noise), "wood" (streaks) or
    "stripes" (a wallpaper of two close shades)."""
    if pattern == "grain":
        return grain_texture(rgb, rng, strength=float(rng.uniform(3, 10)))
    if pattern == "wood":
        return grain_texture(rgb, rng, strength=float(rng.uniform(10, 18)), streaks=True)
    if pattern == "stripes":
        other = np.asarray(rgb, float) * rng.uniform(0.85, 0.95)
        img = _stripes(rgb, other, rng, 256, (16.0, 64.0), (0.4, 0.6))
        img = cv2.GaussianBlur(img, (0, 0), 1.0)
        return np.clip(img, 0, 255).astype(np.uint8)
    raise ValueError(f"unknown surface pattern {pattern!r}; expected grain, wood or stripes")


def _light_rgb(rng: np.random.Generator) -> tuple[int, int, int]:
    """A white or near-white colour (a light wall, a white object)."""
    grey = rng.uniform(220, 250)
    return tuple(int(np.clip(grey + rng.uniform(-8, 8), 0, 255)) for _ in range(3))


def _hue_rgb(rng: np.random.Generator, saturation: tuple[float, float], value: tuple[float, float],
             hue_deg: tuple[float, float] = (0.0, 360.0)):
    """A colour of hue (degrees), saturation and value (0-1) drawn in the given ranges."""
    hsv = np.array([[[rng.uniform(*hue_deg) / 2, rng.uniform(*saturation) * 255, rng.uniform(*value) * 255]]],
                   np.uint8)
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0])


@dataclass(frozen=True)
class Style:
    """A video's look other than the default one (see the module): what the object, the room and
    the camera's colour response look like. `random` draws one."""
    object_pattern: str
    object_rgb: tuple[int, int, int]
    wall_pattern: str
    wall_rgb: tuple[int, int, int]
    table_pattern: str
    table_rgb: tuple[int, int, int]
    backdrop_y_m: float                      # the room's wall, this far behind the tank's centre
    rgb_gain: tuple[float, float, float]     # colour temperature x exposure, per channel

    # the draws' ranges
    BACKDROP_Y_M = (0.15, 0.6)
    WARMTH = (-1.0, 1.0)        # colour temperature: -1 cool (bluish) to +1 warm (a tungsten lamp)
    WARMTH_GAIN = 0.15          # ... the red and blue gains at its ends: 1 -+ this
    EXPOSURE = (0.85, 1.15)

    @classmethod
    def random(cls, rng: np.random.Generator, material_rgb: tuple[int, int, int]) -> "Style":
        """A look: the object white (20%), a light pastel (20%), its material's colour (30%) or any
        colour (30%); any of OBJECT_PATTERNS; a light wall (40%) or a coloured one; a wooden table
        (brown) or a plain one (grey, from dark to white)."""
        u = rng.uniform()
        if u < 0.2:
            obj = _light_rgb(rng)
        elif u < 0.4:
            obj = _hue_rgb(rng, (0.15, 0.35), (0.85, 1.0))
        elif u < 0.7:
            obj = tuple(int(np.clip(c * rng.uniform(0.85, 1.15), 0, 255)) for c in material_rgb)
        else:
            obj = _hue_rgb(rng, (0.4, 1.0), (0.3, 0.95))
        pattern = OBJECT_PATTERNS[int(rng.integers(len(OBJECT_PATTERNS)))]
        wall = _light_rgb(rng) if rng.uniform() < 0.4 else _hue_rgb(rng, (0.05, 0.6), (0.3, 0.9))
        wall_pattern = WALL_PATTERNS[int(rng.integers(len(WALL_PATTERNS)))]
        table_pattern = TABLE_PATTERNS[int(rng.integers(len(TABLE_PATTERNS)))]
        table = (_hue_rgb(rng, (0.3, 0.6), (0.3, 0.75), WOOD_HUE_DEG) if table_pattern == "wood"
                 else _hue_rgb(rng, (0.0, 0.1), (0.15, 0.9)))
        warmth = rng.uniform(*cls.WARMTH)
        exposure = rng.uniform(*cls.EXPOSURE)
        gain = (exposure * (1 + cls.WARMTH_GAIN * warmth), exposure, exposure * (1 - cls.WARMTH_GAIN * warmth))
        return cls(pattern, obj, wall_pattern, wall, table_pattern, table, float(rng.uniform(*cls.BACKDROP_Y_M)),
                   tuple(float(g) for g in gain))

    def to_json(self) -> dict:
        return {"object_pattern": self.object_pattern, "object_rgb": list(self.object_rgb),
                "wall_pattern": self.wall_pattern, "wall_rgb": list(self.wall_rgb),
                "table_pattern": self.table_pattern, "table_rgb": list(self.table_rgb),
                "backdrop_y_m": self.backdrop_y_m, "rgb_gain": list(self.rgb_gain)}


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
                 color: tuple[int, int, int] | None = None, style: Style | None = None):
        """`style`: another look than the default (see the module); None: the default look, the
        object block-textured in `color` (default: its material's)."""
        if scene.camera is None:
            raise ValueError("rendering needs a scene with a camera")
        self.scene = scene
        self.cam = cam = scene.camera
        self.look = look or DEFAULT_LOOK
        self.style = style
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
        t = scene.tank
        if getattr(w, "splash_room", None) is None:   # the room: visual only, once per world
            wall = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[2.0, 0.01, 1.5], physicsClientId=cid)
            table = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[2.0, TABLE_HALF_Y_M, 0.01], physicsClientId=cid)
            w.splash_room = (pb.createMultiBody(0, -1, wall, physicsClientId=cid),
                             pb.createMultiBody(0, -1, table, physicsClientId=cid))
        # the room where this look puts it (a world is shared by the videos of one tank): the
        # default look's table is centred under the tank; another's reaches back to its wall
        wall_y_m = t.size_m[1] / 2 + (BACKDROP_Y_M if style is None else style.backdrop_y_m)
        table_y_m = 0.0 if style is None else wall_y_m - TABLE_HALF_Y_M
        for b, pos in zip(w.splash_room, ([0, wall_y_m, 1.0], [0, table_y_m, -t.wall_m - 0.01])):
            pb.resetBasePositionAndOrientation(b, pos, [0, 0, 0, 1], physicsClientId=cid)
        if style is None:
            surfaces = (grain_texture(WALL_RGB, rng, strength=6), grain_texture(TABLE_RGB, rng, strength=14, streaks=True))
        else:
            surfaces = (surface_texture(style.wall_pattern, style.wall_rgb, rng),
                        surface_texture(style.table_pattern, style.table_rgb, rng))
        for b, tex in zip(w.splash_room, surfaces):
            pb.changeVisualShape(b, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                                 textureUniqueId=load_texture(tex, f"splash_room{b}_{texture_seed}", cid))
        tex = (block_texture(color or object_color(scene), rng) if style is None
               else object_texture(style.object_pattern, style.object_rgb, rng))
        self.texture = load_texture(tex, f"splash_obj_{texture_seed}", cid)
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

    def _sharp(self) -> tuple[np.ndarray, np.ndarray]:
        """The world as it is now with its water and glass, before the camera's exposure: RGB
        float (H * W, 3), segmentation (H, W) of body ids."""
        rgba, depth, seg = camera_image(self.cam, self.view, self.proj, self.look, self.sim.world.cid)
        img = rgba.reshape(-1, 4)[:, :3].astype(float)
        alpha, surface, waterline, glass = self._tint(depth)
        img += alpha[:, None] * (WATER_RGB - img)
        img[surface] += SHEEN * (SHEEN_RGB - img[surface])
        img[waterline] *= WATERLINE_DARK
        img[glass] += GLASS_TINT * (GLASS_RGB - img[glass])
        return img, seg

    def _exposed(self, img: np.ndarray, frame_index: int) -> np.ndarray:
        """`_sharp`'s image (or a blurred frame's mean of them) through the look's drift and noise
        and the style's gains in video frame `frame_index`: RGB uint8 (H, W, 3)."""
        lk, cam = self.look, self.cam
        img = img * lk.gain(frame_index)
        if self.style is not None:
            img *= np.asarray(self.style.rgb_gain)
        if lk.noise_sd:
            img += self._noise_rng.normal(0, lk.noise_sd, img.shape)
        return np.clip(img + 0.5, 0, 255).astype(np.uint8).reshape(cam.height_px, cam.width_px, 3)

    def render_current(self, frame_index: int = 0, with_segmentation: bool = False):
        """Render the world as it is now: RGB uint8 (H, W, 3) [, segmentation (H, W) of body ids]."""
        img, seg = self._sharp()
        rgb = self._exposed(img, frame_index)
        if with_segmentation:
            return rgb, seg
        return rgb

    def render(self, n_frames: int, values: dict[str, float] | None = None, on_image=None,
               with_segmentation: bool = False, blur: tuple[int, np.ndarray] | None = None) -> Trajectory:
        """Simulate from the release and render `n_frames` video frames (in video time, see
        `Simulator.run`); on_image(frame, rgb[, seg]) for each. Returns the trajectory of the
        shown frames. blur: motion blur's sampling (n, k) (`galileo.render.blur_offsets`, n the
        physics steps a frame): frame f the mean of the renders at steps n f + k of video time
        (frame 0's too: the run starts -min(k) steps before the video, as a camera's shutter
        opens before its first frame's time), seg frame f's own."""
        release_s = (values or {}).get("release_s", self.scene.release_s)
        if self.scene.frame_ticks(release_s)[1]:
            raise GalileoError(f"rendering needs the release on the physics grid (a whole number of 1/{self.scene.sim_hz:g} s "
                               f"steps of video time), got release_s {release_s:g}: the renderer draws Bullet's steps, "
                               "not the states between them")
        cid = self.sim.world.cid

        def texture(i):
            if i == 0:   # the object's body is made for the run: texture it before the first frame
                self.body_id = self.sim.world.body
                pb.changeVisualShape(self.body_id, -1, rgbaColor=[1, 1, 1, 1], textureUniqueId=self.texture,
                                     physicsClientId=cid)

        if blur is None:
            def on_frame(i, pos, vel):
                texture(i)
                out = self.render_current(i, with_segmentation)
                if on_image is not None:
                    on_image(i, *out) if with_segmentation else on_image(i, out)
                return False

            return self.sim.run(n_frames, values, on_frame=on_frame)

        # the run at one sample a physics step: its scene's camera at sub times the fps (the same
        # steps from the release; frame f is sample sub f)
        # (the run's sample j is video step j - pre: it starts pre steps before the video, the
        # release that much later in its time)
        sub, offsets = blur
        lo, hi = int(offsets.min()), int(offsets.max())
        pre = -lo
        cam = self.scene.camera
        fine = dataclasses.replace(self.scene, camera=dataclasses.replace(
            cam, fps=sub * cam.fps, n_frames=pre + sub * (n_frames - 1) + hi + 1))
        early = {**(values or {}), "release_s": release_s + pre / (sub * cam.fps)}
        sharp: dict[int, tuple[np.ndarray, np.ndarray]] = {}   # sample -> its render, while a frame needs it

        def on_sample(j, pos, vel):
            texture(j)
            if any((j - pre - int(k)) % sub == 0 for k in offsets):
                sharp[j] = self._sharp()
            f, r = divmod(j - pre - hi, sub)
            if r == 0 and 0 <= f < n_frames:
                img = average_renders([sharp[pre + sub * f + int(k)][0] for k in offsets])
                rgb = self._exposed(img.astype(float), f)
                if on_image is not None:
                    on_image(f, rgb, sharp[pre + sub * f][1]) if with_segmentation else on_image(f, rgb)
                for old in [i for i in sharp if i < pre + sub * (f + 1) + lo]:
                    del sharp[old]
            return False

        traj = Simulator(fine, visual=True).run(fine.camera.n_frames, early, on_frame=on_sample)
        frames = slice(pre, pre + sub * (n_frames - 1) + 1, sub)
        return Trajectory(cam.fps, traj.names, traj.position_m[:, frames], traj.velocity_mps[:, frames],
                          traj.orientation_xyzw[:, frames])


def render_to_video(scene: SplashScene, path: str | Path, n_frames: int, look: Look | None = None,
                    texture_seed: int = 0, values: dict[str, float] | None = None,
                    style: Style | None = None, footage: Footage | None = None) -> Trajectory:
    """Render the scene to an H.264 MP4 of `n_frames` frames (in the default look, or `style`'s;
    through `footage`'s camera effects, with its motion blur, if given: rendered through its
    `render_camera`); the shown frames' trajectory."""
    from ...video import write_video

    frames: list[np.ndarray] = []
    if footage is None:
        renderer = Renderer(scene, look, texture_seed, style=style)
        traj = renderer.render(n_frames, values, on_image=lambda f, rgb: frames.append(rgb))
        write_video(path, frames, scene.fps)
        return traj
    cam = footage.render_camera
    renderer = Renderer(dataclasses.replace(scene, camera=cam), look, texture_seed, style=style)
    objects = np.zeros((cam.height_px, cam.width_px), bool)

    def keep(f, rgb, seg):
        frames.append(rgb)
        objects[seg == renderer.body_id] = True

    traj = renderer.render(n_frames, values, on_image=keep, with_segmentation=True,
                           blur=footage.blur_sampling(steps_per_frame(scene.sim_hz, scene.fps)))
    write_video(path, footage.frames(frames, objects), scene.fps, bitrate_kbps=footage.bitrate_kbps)
    return traj

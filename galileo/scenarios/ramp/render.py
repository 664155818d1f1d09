"""The ramp's videos: its world rendered through the scene's camera (galileo.render's pieces).

Objects get block textures in their material's colour (corners for the KLT tracker), the
ramp, ground and back wall mild grain textures. Each video has its own `Look` (light
direction and ambient level, a slow brightness drift, Gaussian sensor noise). A video may be
filmed through a real camera's effects (`galileo.footage`: `render_to_video`'s footage), with
motion blur from renders at sub-frame times (`Renderer.render`'s blur).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ...camera import steps_per_frame
from ...datatypes import Trajectory
from ...footage import Footage
from ...render import (DEFAULT_LOOK, Look, average_renders, block_texture, camera_image, gl_view_projection,
                       grain_texture, load_texture)
from ...sim.bullet import pb
from .materials import MATERIALS_BY_NAME, TARGETS
from .physics import Simulator
from .scene import Scene


def object_color(scene: Scene, index: int) -> tuple[int, int, int]:
    obj = scene.objects[index]
    if obj.role == "target" and obj.kind in TARGETS:
        return TARGETS[obj.kind][3]
    if obj.material in MATERIALS_BY_NAME:
        return MATERIALS_BY_NAME[obj.material].color_rgb
    return (200, 80, 60) if index == 0 else (90, 140, 210)


class Renderer:
    """Renders frames of a scene's simulation through its camera."""

    def __init__(self, scene: Scene, look: Look | None = None, texture_seed: int = 0,
                 colors: dict[int, tuple[int, int, int]] | None = None):
        if scene.camera is None:
            raise ValueError("rendering needs a scene with a camera")
        self.scene = scene
        self.cam = scene.camera
        self.look = look or DEFAULT_LOOK
        self.sim = Simulator(scene, visual=True)
        self.view, self.proj = gl_view_projection(self.cam)
        w = self.sim.world
        cid = w.cid
        rng = np.random.default_rng(texture_seed)
        pb.changeVisualShape(w.ground, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                             textureUniqueId=load_texture(grain_texture((150, 150, 145), rng, strength=8), f"ground_{texture_seed}", cid))
        pb.changeVisualShape(w.ramp, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                             textureUniqueId=load_texture(grain_texture((196, 170, 130), rng, strength=14, streaks=True), f"ramp_{texture_seed}", cid))
        if w.backdrop is not None:
            pb.changeVisualShape(w.backdrop, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                                 textureUniqueId=load_texture(grain_texture((225, 228, 232), rng, strength=5), f"wall_{texture_seed}", cid))
        for i, b in enumerate(w.bodies):
            tex = block_texture((colors or {}).get(i) or object_color(scene, i), rng)
            pb.changeVisualShape(b, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                                 textureUniqueId=load_texture(tex, f"object{i}_{texture_seed}", cid))
        self._noise_rng = np.random.default_rng(self.look.seed)

    def _sharp(self) -> tuple[np.ndarray, np.ndarray]:
        """The world as it is now, before the look's drift and noise: RGB uint8, segmentation."""
        rgba, _, seg = camera_image(self.cam, self.view, self.proj, self.look, self.sim.world.cid)
        return rgba[..., :3], seg

    def _exposed(self, rgb: np.ndarray, frame_index: int) -> np.ndarray:
        """A render (uint8, or float32: a blurred frame's mean) with the look's drift and noise in
        video frame `frame_index`: RGB uint8."""
        lk = self.look
        if not (lk.gain_drift or lk.noise_sd) and rgb.dtype == np.uint8:
            return rgb
        noisy = rgb.astype(np.float32) * lk.gain(frame_index) + self._noise_rng.normal(0, lk.noise_sd, rgb.shape).astype(np.float32)
        return np.clip(noisy + 0.5, 0, 255).astype(np.uint8)

    def render_current(self, frame_index: int = 0, with_segmentation: bool = False):
        """Render the world as it is now: RGB uint8 (H, W, 3) [, segmentation (H, W) of body ids]."""
        rgb, seg = self._sharp()
        rgb = self._exposed(rgb, frame_index)
        if with_segmentation:
            return rgb, seg
        return rgb

    def render(self, n_frames: int, values: dict[str, float] | None = None, on_image=None,
               with_segmentation: bool = False, blur: tuple[int, np.ndarray] | None = None) -> Trajectory:
        """Simulate `n_frames` frames at the camera's fps, calling on_image(frame, rgb[, seg]) for each.
        blur: motion blur's sampling (n, k) (`galileo.render.blur_offsets`): the world simulated at
        n times the fps, frame f the mean of the renders of samples n f + k (those before t = 0
        drawn at t = 0: the objects are at rest before their release), seg sample n f's; the
        trajectory is still the frames'."""
        if blur is None:
            def on_frame(f, pos, vel):
                out = self.render_current(f, with_segmentation)
                if on_image is not None:
                    on_image(f, *out) if with_segmentation else on_image(f, out)
                return False

            return self.sim.run(n_frames, values, fps=self.cam.fps, on_frame=on_frame)

        sub, offsets = blur
        lo, hi = int(offsets.min()), int(offsets.max())
        sharp: dict[int, tuple[np.ndarray, np.ndarray]] = {}   # sample -> its render, while a frame needs it

        def on_sample(j, pos, vel):
            if j == 0 or any((j - int(k)) % sub == 0 for k in offsets):
                sharp[j] = self._sharp()
            f, r = divmod(j - hi, sub)
            if r == 0 and 0 <= f < n_frames:
                rgb = self._exposed(average_renders([sharp[max(0, sub * f + int(k))][0] for k in offsets]), f)
                if on_image is not None:
                    on_image(f, rgb, sharp[sub * f][1]) if with_segmentation else on_image(f, rgb)
                for old in [i for i in sharp if i < sub * (f + 1) + lo]:
                    del sharp[old]
            return False

        traj = self.sim.run(sub * (n_frames - 1) + hi + 1, values, fps=sub * self.cam.fps, on_frame=on_sample)
        frames = slice(0, sub * (n_frames - 1) + 1, sub)
        return Trajectory(self.cam.fps, traj.names, traj.position_m[:, frames], traj.velocity_mps[:, frames])

    @property
    def body_ids(self) -> list[int]:
        return list(self.sim.world.bodies)


def render_to_video(scene: Scene, path: str | Path, n_frames: int, look: Look | None = None,
                    texture_seed: int = 0, values: dict[str, float] | None = None,
                    footage: Footage | None = None) -> Trajectory:
    """Render the scene's simulation to an H.264 MP4 (through `footage`'s camera effects, with
    its motion blur, if given: rendered through its `render_camera`); returns the simulated
    trajectory (at the frame times)."""
    from ...video import write_video

    if footage is None:
        frames: list[np.ndarray] = []
        traj = Renderer(scene, look, texture_seed).render(n_frames, values, on_image=lambda f, rgb: frames.append(rgb))
        write_video(path, frames, scene.camera.fps)
        return traj
    cam = footage.render_camera
    renderer = Renderer(dataclasses.replace(scene, camera=cam), look, texture_seed)
    frames, objects = [], np.zeros((cam.height_px, cam.width_px), bool)

    def keep(f, rgb, seg):
        frames.append(rgb)
        objects[np.isin(seg, renderer.body_ids)] = True

    traj = renderer.render(n_frames, values, on_image=keep, with_segmentation=True,
                           blur=footage.blur_sampling(steps_per_frame(scene.sim_hz, scene.camera.fps)))
    write_video(path, footage.frames(frames, objects), scene.camera.fps, bitrate_kbps=footage.bitrate_kbps)
    return traj

"""The ramp's videos: its world rendered through the scene's camera (galileo.render's pieces).

Objects get block textures in their material's colour (corners for the KLT tracker), the
ramp, ground and back wall mild grain textures. Each video has its own `Look` (light
direction and ambient level, a slow brightness drift, Gaussian sensor noise).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...datatypes import Trajectory
from ...render import DEFAULT_LOOK, Look, block_texture, camera_image, gl_view_projection, grain_texture, load_texture
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

    def render_current(self, frame_index: int = 0, with_segmentation: bool = False):
        """Render the world as it is now: RGB uint8 (H, W, 3) [, segmentation (H, W) of body ids]."""
        lk = self.look
        rgba, _, seg = camera_image(self.cam, self.view, self.proj, lk, self.sim.world.cid)
        rgb = rgba[..., :3]
        if lk.gain_drift or lk.noise_sd:
            noisy = rgb.astype(np.float32) * lk.gain(frame_index) + self._noise_rng.normal(0, lk.noise_sd, rgb.shape).astype(np.float32)
            rgb = np.clip(noisy + 0.5, 0, 255).astype(np.uint8)
        if with_segmentation:
            return rgb, seg
        return rgb

    def render(self, n_frames: int, values: dict[str, float] | None = None, on_image=None,
               with_segmentation: bool = False) -> Trajectory:
        """Simulate `n_frames` frames at the camera's fps, calling on_image(frame, rgb[, seg]) for each."""

        def on_frame(f, pos, vel):
            out = self.render_current(f, with_segmentation)
            if on_image is not None:
                on_image(f, *out) if with_segmentation else on_image(f, out)
            return False

        return self.sim.run(n_frames, values, fps=self.cam.fps, on_frame=on_frame)

    @property
    def body_ids(self) -> list[int]:
        return list(self.sim.world.bodies)


def render_to_video(scene: Scene, path: str | Path, n_frames: int, look: Look | None = None,
                    texture_seed: int = 0, values: dict[str, float] | None = None) -> Trajectory:
    """Render the scene's simulation to an H.264 MP4; returns the simulated trajectory."""
    from ...video import write_video

    renderer = Renderer(scene, look, texture_seed)
    frames: list[np.ndarray] = []
    traj = renderer.render(n_frames, values, on_image=lambda f, rgb: frames.append(rgb))
    write_video(path, frames, scene.camera.fps)
    return traj

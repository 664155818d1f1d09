"""Rendering the simulation into Physics-101-style videos with pybullet's TinyRenderer.

The renderer looks through the scene's calibrated pinhole camera (OpenCV convention);
`gl_view_projection` converts K and the world->camera transform into the OpenGL
matrices pybullet expects, so that `Camera.project` of a body's centre lands on the
body in the rendered image (tested against the renderer's segmentation mask).

Objects get procedural block textures (corners for the KLT tracker), the ramp, ground
and back wall mild textures. Each video has its own light direction and ambient level,
a slow brightness drift, and Gaussian sensor noise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from ...sim.bullet import pb

from .materials import MATERIALS_BY_NAME, TARGETS
from ...datatypes import Trajectory
from ...sim.bullet import scratch_dir
from .physics import Simulator
from ...camera import Camera
from .scene import Scene

NEAR_M, FAR_M = 0.05, 20.0
# TinyRenderer's rasterisation puts a projected point this far (pixels) from where the
# OpenCV convention (pixel centres at integer coordinates) does; measured on silhouettes
# (tests/test_render.py) and compensated so renders agree with Camera.project.
RASTER_OFFSET_PX = (0.0, 1.0)


def gl_view_projection(cam: Camera, near: float = NEAR_M, far: float = FAR_M) -> tuple[list[float], list[float]]:
    """pybullet view and projection matrices (column-major) for an OpenCV pinhole camera."""
    flip = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV camera axes -> OpenGL camera axes
    view = flip @ cam.world_to_camera
    (fx, _, cx), (_, fy, cy), _ = cam.K
    cx, cy = cx + RASTER_OFFSET_PX[0], cy + RASTER_OFFSET_PX[1]
    w, h = cam.width_px, cam.height_px
    proj = np.array([
        [2 * fx / w, 0, 1 - 2 * cx / w, 0],
        [0, 2 * fy / h, 2 * cy / h - 1, 0],
        [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
        [0, 0, -1, 0]])
    return view.T.reshape(-1).tolist(), proj.T.reshape(-1).tolist()


def block_texture(rgb: tuple[int, int, int], rng: np.random.Generator, blocks: int = 4, px: int = 128,
                  contrast: float = 0.55) -> np.ndarray:
    """A tile of random light/dark blocks around `rgb`: strong corners for feature tracking."""
    base = np.asarray(rgb, float)
    levels = rng.uniform(1 - contrast, 1 + contrast * 0.6, (blocks, blocks, 1))
    tint = rng.uniform(0.85, 1.15, (blocks, blocks, 3))
    tile = np.clip(base * levels * tint, 0, 255)
    img = cv2.resize(tile.astype(np.uint8), (px, px), interpolation=cv2.INTER_NEAREST)
    return img


def grain_texture(rgb: tuple[int, int, int], rng: np.random.Generator, px: int = 256, strength: float = 10.0,
                  streaks: bool = False) -> np.ndarray:
    noise = rng.normal(0, 1, (px // 8, px // 8))
    noise = cv2.resize(noise, (px, px), interpolation=cv2.INTER_CUBIC)
    if streaks:
        noise = cv2.GaussianBlur(noise, (0, 0), sigmaX=px / 16, sigmaY=0.5)
        noise /= noise.std() + 1e-9
    img = np.asarray(rgb, float) + strength * noise[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def _load_texture(img_rgb: np.ndarray, name: str, cid: int) -> int:
    """Write the texture to a PNG (whole, then renamed into place) and load it."""
    import os

    path = scratch_dir() / f"{name}.png"
    tmp = path.with_name(f".{path.stem}.tmp.png")
    if not cv2.imwrite(str(tmp), img_rgb[..., ::-1]):
        raise RuntimeError(f"cannot write texture {tmp}")
    os.replace(tmp, path)
    tex = pb.loadTexture(str(path), physicsClientId=cid)
    if tex < 0:
        raise RuntimeError(f"pybullet could not load texture {path}")
    return tex


def object_color(scene: Scene, index: int) -> tuple[int, int, int]:
    obj = scene.objects[index]
    if obj.role == "target" and obj.kind in TARGETS:
        return TARGETS[obj.kind][3]
    if obj.material in MATERIALS_BY_NAME:
        return MATERIALS_BY_NAME[obj.material].color_rgb
    return (200, 80, 60) if index == 0 else (90, 140, 210)


@dataclass
class Look:
    """Per-video appearance: light, exposure drift and sensor noise."""
    light_dir: tuple[float, float, float]
    ambient: float
    diffuse: float
    gain_drift: float      # amplitude of slow brightness drift (fraction)
    noise_sd: float        # sensor noise, 8-bit levels
    seed: int

    @classmethod
    def random(cls, rng: np.random.Generator) -> "Look":
        az = rng.uniform(-0.8, 0.8)
        return cls((math.sin(az), -1.2, 2.0 + rng.uniform(-0.3, 0.3)), float(rng.uniform(0.55, 0.7)),
                   float(rng.uniform(0.35, 0.5)), float(rng.uniform(0.005, 0.02)), float(rng.uniform(1.5, 3.0)),
                   int(rng.integers(2**31)))


class Renderer:
    """Renders frames of a scene's simulation through its camera."""

    def __init__(self, scene: Scene, look: Look | None = None, texture_seed: int = 0,
                 colors: dict[int, tuple[int, int, int]] | None = None):
        if scene.camera is None:
            raise ValueError("rendering needs a scene with a camera")
        self.scene = scene
        self.cam = scene.camera
        self.look = look or Look((0.3, -1.2, 2.0), 0.6, 0.45, 0.0, 0.0, 0)
        self.sim = Simulator(scene, visual=True)
        self.view, self.proj = gl_view_projection(self.cam)
        w = self.sim.world
        cid = w.cid
        rng = np.random.default_rng(texture_seed)
        pb.changeVisualShape(w.ground, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                             textureUniqueId=_load_texture(grain_texture((150, 150, 145), rng, strength=8), f"ground_{texture_seed}", cid))
        pb.changeVisualShape(w.ramp, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                             textureUniqueId=_load_texture(grain_texture((196, 170, 130), rng, strength=14, streaks=True), f"ramp_{texture_seed}", cid))
        if w.backdrop is not None:
            pb.changeVisualShape(w.backdrop, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                                 textureUniqueId=_load_texture(grain_texture((225, 228, 232), rng, strength=5), f"wall_{texture_seed}", cid))
        for i, b in enumerate(w.bodies):
            tex = block_texture((colors or {}).get(i) or object_color(scene, i), rng)
            pb.changeVisualShape(b, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=cid,
                                 textureUniqueId=_load_texture(tex, f"object{i}_{texture_seed}", cid))
        self._noise_rng = np.random.default_rng(self.look.seed)

    def render_current(self, frame_index: int = 0, with_segmentation: bool = False):
        """Render the world as it is now: RGB uint8 (H, W, 3) [, segmentation (H, W) of body ids]."""
        lk = self.look
        _, _, rgba, _, seg = pb.getCameraImage(
            self.cam.width_px, self.cam.height_px, self.view, self.proj, renderer=pb.ER_TINY_RENDERER,
            lightDirection=list(lk.light_dir), lightAmbientCoeff=lk.ambient, lightDiffuseCoeff=lk.diffuse,
            lightSpecularCoeff=0.05, shadow=0, physicsClientId=self.sim.world.cid)
        rgb = np.asarray(rgba, np.uint8).reshape(self.cam.height_px, self.cam.width_px, 4)[..., :3]
        if lk.gain_drift or lk.noise_sd:
            gain = 1.0 + lk.gain_drift * math.sin(2 * math.pi * frame_index / 47.0 + lk.seed % 7)
            noisy = rgb.astype(np.float32) * gain + self._noise_rng.normal(0, lk.noise_sd, rgb.shape).astype(np.float32)
            rgb = np.clip(noisy + 0.5, 0, 255).astype(np.uint8)
        if with_segmentation:
            seg = np.asarray(seg, np.int32).reshape(self.cam.height_px, self.cam.width_px)
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
